"""Scene files loaded with another resolution or integrator depth, whether
or not they declare those as $-parameters."""

import shutil

import mitsuba as mi
import pytest

from mitsuba_whitted.errors import UsageError
from mitsuba_whitted.overrides import load_with
from validation.scenes import REPORT_SCENE, ROOT


LITERAL_SCENE = """<scene version="3.0.0">
    <integrator type="whitted"><string name="aa" value="adaptive"/></integrator>
    <sensor type="perspective">
        <film type="hdrfilm">
            <integer name="width" value="80"/>
            <integer name="height" value="60"/>
        </film>
    </sensor>
    <emitter type="point"><point name="position" x="0" y="3" z="3"/></emitter>
    <shape type="sphere">
        <transform name="to_world"><translate z="-4"/></transform>
        <bsdf type="diffuse">
            <texture type="bitmap" name="reflectance">
                <string name="filename" value="maps/lemons.png"/>
            </texture>
        </bsdf>
    </shape>
</scene>
"""


@pytest.fixture
def literal_scene(tmp_path):
    """A scene with literal settings and a texture named relative to it."""
    (tmp_path / "maps").mkdir()
    shutil.copy(ROOT / "textures" / "lemons.png", tmp_path / "maps" / "lemons.png")
    path = tmp_path / "literal.xml"
    path.write_text(LITERAL_SCENE)
    return path


def _resolver_entries():
    resolver = mi.file_resolver()
    return [str(resolver[index]) for index in range(len(resolver))]


def test_literal_settings_are_changed_in_the_file(literal_scene):
    before = _resolver_entries()
    loaded = load_with(literal_scene, {}, {"res": 40, "max_depth": 3, "aa_max_depth": 2})
    assert list(loaded.sensors()[0].film().size()) == [40, 30]  # the 4:3 aspect kept
    whitted = loaded.integrator()
    assert (whitted.max_depth, whitted.aa_max_depth, whitted.aa) == (3, 2, "adaptive")
    # The texture was found next to the scene, and the resolver is as it was.
    assert _resolver_entries() == before


def test_parameters_the_scene_declares_are_set_through_them():
    """The report's scene names its resolution and depths as $res,
    $max_depth, $aa_max_depth: a define of one of them must not become an
    unused parameter (which Mitsuba refuses) when a setting replaces it."""
    loaded = load_with(REPORT_SCENE, {"res": "300", "max_depth": "3"},
                       {"res": 64, "aa_max_depth": 2})
    assert list(loaded.sensors()[0].film().size()) == [64, 64]
    whitted = loaded.integrator()
    assert (whitted.max_depth, whitted.aa_max_depth) == (3, 2)


def test_no_settings_load_the_scene_as_it_is(literal_scene):
    assert list(load_with(literal_scene, {}, {}).sensors()[0].film().size()) == [80, 60]


def test_a_scene_without_a_film_says_so(tmp_path):
    path = tmp_path / "bare.xml"
    path.write_text('<scene version="3.0.0"><integrator type="whitted"/></scene>')
    with pytest.raises(UsageError, match=r"bare.xml. has no <sensor><film>"):
        load_with(path, {}, {"res": 32})


def test_a_width_parameter_without_a_value_says_so(tmp_path):
    path = tmp_path / "open.xml"
    path.write_text(LITERAL_SCENE.replace('value="80"', 'value="$w"'))
    with pytest.raises(UsageError, match=r"refers to \$w, which has no value"):
        load_with(path, {}, {"res": 32})


def test_a_crop_window_keeps_its_place_on_the_film(literal_scene):
    """Half the width: the crop window halves too, where it was."""
    crop = ('<integer name="crop_offset_x" value="10"/><integer name="crop_offset_y" value="6"/>'
            '<integer name="crop_width" value="40"/><integer name="crop_height" value="30"/>')
    literal_scene.write_text(LITERAL_SCENE.replace('<integer name="height" value="60"/>',
                                                   '<integer name="height" value="60"/>' + crop))
    film = load_with(literal_scene, {}, {"res": 40}).sensors()[0].film()
    assert (list(film.size()), list(film.crop_offset()), list(film.crop_size())) == \
        ([40, 30], [5, 3], [20, 15])


def test_the_sampler_is_replaced_and_keeps_its_sample_count(tmp_path, literal_scene):
    """A sampler the scene names by type and parameters gives way to
    another type; its sample count (here a parameter) stays in use."""
    text = LITERAL_SCENE.replace(
        "<film ", '<sampler type="stratified"><integer name="sample_count" value="$spp"/>'
        '<boolean name="jitter" value="false"/></sampler><film ')
    (tmp_path / "sampled.xml").write_text('<scene version="3.0.0"><default name="spp" '
                                          'value="4"/>' + text.split(">", 1)[1])
    for path, count in ((literal_scene, 4), (tmp_path / "sampled.xml", 9)):
        sampler = load_with(path, {"spp": "9"} if count == 9 else {},
                            {"sampler": "multijitter"}).sensors()[0].sampler()
        assert sampler.class_name() == "MultijitterSampler"
        assert sampler.sample_count() == count
