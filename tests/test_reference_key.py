"""The path reference's cache key follows what path renders: the scene
without its integrator, the files it names, and the reference's settings.
A change that only Whitted sees keeps the reference."""

from pathlib import Path

import pytest

from mitsuba_whitted.compare.scene_report import reference_key

SPP = 64
INTEGRATOR = """<integrator type="whitted" id="look">
        <integer name="aa_samples" value="2"/>
        <string name="shadows" value="tinted"/>
    </integrator>"""


def write_scene(folder: Path, integrator: str = INTEGRATOR, colour: str = "0.5 0.5 0.5",
                comment: str = "", indent: str = "    ") -> Path:
    """A scene with a Whitted integrator, a texture, an included shape and
    a sphere whose radius is the define ``radius``."""
    if not (folder / "tex.png").exists():
        (folder / "tex.png").write_bytes(b"texture v1")
        (folder / "floor.xml").write_text("""<scene version="3.0.0">
    <shape type="rectangle"><bsdf type="diffuse"/></shape>
</scene>""")
    scene = folder / "scene.xml"
    scene.write_text(f"""<scene version="3.0.0">{comment}
{indent}<default name="radius" value="1"/>
{indent}{integrator}
{indent}<sensor type="perspective">
{indent}{indent}<film type="hdrfilm"><integer name="width" value="16"/>
{indent}{indent}    <integer name="height" value="16"/></film>
{indent}</sensor>
{indent}<emitter type="constant"><rgb name="radiance" value="{colour}"/></emitter>
{indent}<include filename="floor.xml"/>
{indent}<shape type="sphere"><float name="radius" value="$radius"/>
{indent}{indent}<bsdf type="diffuse"><texture type="bitmap" name="reflectance">
{indent}{indent}    <string name="filename" value="tex.png"/></texture></bsdf>
{indent}</shape>
</scene>""")
    return scene


def key(scene: Path, defines: dict | None = None, spp: int = SPP) -> str:
    return reference_key(scene, defines or {}, spp)


@pytest.mark.parametrize("change", [
    {"integrator": INTEGRATOR.replace('value="2"', 'value="3"')},
    {"integrator": INTEGRATOR.replace('id="look"', 'id="other"')},
    {"integrator": '<integrator type="whitted"/>'},
    {"integrator": ""},
    {"comment": "<!-- a note -->"},
    {"indent": "\t"},
], ids=["aa_samples", "integrator id", "default settings", "no integrator", "comment",
        "whitespace"])
def test_a_change_only_whitted_sees_keeps_the_key(tmp_path, change):
    base = key(write_scene(tmp_path))
    assert key(write_scene(tmp_path, **change)) == base


def test_a_colour_changes_the_key(tmp_path):
    base = key(write_scene(tmp_path))
    assert key(write_scene(tmp_path, colour="0.5 0.5 0.6")) != base


def test_a_texture_s_bytes_change_the_key(tmp_path):
    scene = write_scene(tmp_path)
    base = key(scene)
    (tmp_path / "tex.png").write_bytes(b"texture v2")
    assert key(scene) != base


def test_an_included_file_changes_the_key(tmp_path):
    scene = write_scene(tmp_path)
    base = key(scene)
    floor = tmp_path / "floor.xml"
    floor.write_text(floor.read_text().replace("<bsdf", '<boolean name="flip_normals" '
                                               'value="true"/><bsdf'))
    assert key(scene) != base


def test_a_define_a_shape_uses_changes_the_key(tmp_path):
    scene = write_scene(tmp_path)
    assert key(scene, {"radius": "1"}) == key(scene)
    assert key(scene, {"radius": "2"}) != key(scene)


def test_the_reference_s_samples_change_the_key(tmp_path):
    scene = write_scene(tmp_path)
    assert key(scene, spp=2 * SPP) != key(scene)
