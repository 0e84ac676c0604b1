"""The scenes the package ships: one copy of each file, reached by name from
Python and from the command line, with the checkout's top-level ``scenes``
and ``textures`` as links to them."""

import numpy as np
import pytest

import mitsuba as mi

import mitsuba_whitted
from conftest import cli
from mitsuba_whitted import scenes
from mitsuba_whitted.errors import UsageError
from mitsuba_whitted.files import ReadError
from mitsuba_whitted.imageio import read_image
from validation.scenes import REPORT_SCENE, ROOT

NAMES = ["cosc363", "cylinder", "glass_ball_caustic", "glass_box", "glass_spheres", "mirror_chain"]


def test_every_example_scene_is_shipped_by_name():
    assert list(scenes.shipped()) == NAMES
    assert scenes.path("cosc363").samefile(REPORT_SCENE)


def test_the_top_level_folders_are_the_package_data():
    """One copy of each file: ``scenes`` and ``textures`` at the top level
    lead to the package's own folders."""
    package = ROOT / "plugins" / "mitsuba_whitted" / "data"
    for name in ("scenes", "textures"):
        assert (ROOT / name).is_symlink()
        assert (ROOT / name).resolve() == (package / name).resolve()


def test_a_bad_name_is_one_sentence_listing_the_names():
    with pytest.raises(UsageError, match="there is no shipped scene 'nope'; the shipped "
                       "scenes are cosc363, cylinder, glass_ball_caustic, glass_box, glass_spheres, mirror_chain."):
        scenes.path("nope")


def test_load_sets_defaults_and_reads_relative_textures():
    mitsuba_whitted.set_variant()
    scene = scenes.load("cosc363", res=16, aa="none")
    assert tuple(scene.sensors()[0].film().crop_size()) == (16, 16)
    image = np.asarray(mi.render(scene))
    assert np.isfinite(image).all() and image.max() > 0.1


def test_render_renders_a_shipped_scene_by_name(tmp_path):
    out = tmp_path / "named.png"
    cli("render", "glass_spheres", "-o", str(out), "-D", "res=16", check=True)
    assert read_image(out).shape == (16, 16, 3)


@pytest.mark.parametrize("argument, message", [
    ("nope", "'nope' is neither a scene file nor a shipped scene; the shipped scenes are "
             "cosc363, cylinder"),
    ("nope.xml", "scene file 'nope.xml' does not exist"),
    ("sub/cosc363", "scene file 'sub/cosc363' does not exist"),
])
def test_a_scene_argument_is_a_file_or_a_shipped_name(argument, message):
    with pytest.raises((UsageError, ReadError), match=message):
        scenes.resolve(argument)


def test_an_existing_file_wins_over_a_shipped_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "cosc363").write_text("<scene version='3.0.0'/>")
    assert scenes.resolve("cosc363") == tmp_path.joinpath("cosc363").relative_to(tmp_path)


#: The kinds of object that mi.traverse names by id, or by a number that
#: differs from process to process when there is none.
NAMED_KINDS = {"integrator", "sensor", "emitter", "shape", "bsdf", "texture"}


@pytest.mark.parametrize("name", NAMES)
def test_every_object_of_a_shipped_scene_has_an_id(name):
    import xml.etree.ElementTree as ElementTree

    elements = [e for e in ElementTree.parse(scenes.path(name)).iter() if e.tag in NAMED_KINDS]
    assert [e.tag for e in elements if "id" not in e.attrib] == []
    ids = [e.attrib["id"] for e in elements]
    assert len(ids) == len(set(ids))
    mitsuba_whitted.set_variant()
    keys = mi.traverse(scenes.load(name, res=8)).keys()
    assert not [key for key in keys if key.startswith("object_")]
