"""The mitsuba-whitted command line, run as a user would."""

import os
import re
import resource
import struct
import subprocess
import sys
import zlib

import drjit as dr
import mitsuba as mi
import numpy as np
import OpenImageIO
import pytest

import mitsuba_whitted
from conftest import SRGB_TO_XYZ, cli, one_line
from mitsuba_whitted import imageio, startup
from mitsuba_whitted.cli import main
from mitsuba_whitted.command import run_command
from mitsuba_whitted.compare.scene_report import FOLDER_MARK
from mitsuba_whitted.files import ReadError
from mitsuba_whitted.imageio import read_image, to_8bit, write_image
from mitsuba_whitted.system import size_text
from validation.scenes import REPORT_SCENE, ROOT


def test_render_report_scene_small(tmp_path):
    out = tmp_path / "small.exr"
    result = cli("render", str(REPORT_SCENE), "-o", str(out), "-D", "res=48",
                 "-D", "aa_max_depth=3", check=True)
    image = read_image(out)
    assert image.shape == (48, 48, 3)
    assert np.isfinite(image).all() and image.max() > 0.1
    line = result.stdout.strip().splitlines()[-1]
    assert "48x48 rendered and written in" in line and "M rays/s" in line


#: Prints the registry id of every shape's BSDF and of every shape.
REGISTRY_IDS = """
import sys, drjit as dr, mitsuba as mi, mitsuba_whitted
mitsuba_whitted.set_variant()
scene = mitsuba_whitted.load_file(sys.argv[1])
ids = lambda ptrs: [int(dr.reinterpret_array(mi.UInt32, p)[0]) for p in ptrs]
print(ids(mi.BSDFPtr(s.bsdf()) for s in scene.shapes()), ids(mi.ShapePtr(s) for s in scene.shapes()))
"""


def test_scenes_load_with_the_same_registry_ids_in_every_process():
    """Dr.Jit compiles registry ids into the kernels' virtual calls, so the
    kernel cache hits in a new process only if they come out the same
    (Mitsuba's parallel loading hands them out in thread order)."""
    outputs = {subprocess.run([sys.executable, "-c", REGISTRY_IDS, str(REPORT_SCENE)], cwd=ROOT,
                              capture_output=True, text=True, check=True).stdout.splitlines()[-1]
               for _ in range(4)}
    assert len(outputs) == 1


def test_a_second_process_compiles_nothing(tmp_path):
    """The kernel cache helps only if every kernel comes out the same in each
    process. The depth-first tracer's kernel makes the camera rays itself, so a
    sensor value that differs per process baked into it (or registry ids
    handed out in another order, or a mesh buffer whose alignment depends on
    where NumPy allocated it) would compile it anew on every run."""
    env = dict(os.environ, HOME=str(tmp_path / "home"), XDG_CACHE_HOME=str(tmp_path / "cache"))
    cached = tmp_path / "home" / ".drjit"
    render = ("render", str(REPORT_SCENE), "-o", str(tmp_path / "a.exr"), "-D", "res=16")
    cli(*render, env=env, check=True)
    first = set(cached.iterdir())
    cli(*render, env=env, check=True)
    assert first and set(cached.iterdir()) == first


def test_png_is_the_srgb_encoding_of_the_exr(tmp_path):
    for suffix in ("exr", "png"):
        cli("render", str(REPORT_SCENE), "-o", str(tmp_path / f"a.{suffix}"), "-D", "res=24",
            "-D", "aa=none", check=True)
    linear = read_image(tmp_path / "a.exr")
    encoded = np.round(read_image(tmp_path / "a.png") * 255)
    np.testing.assert_array_equal(encoded, to_8bit(linear))


#: A pixel's associated colour (RGB, or its first value as luminance) and
#: alpha: half covered, so its unassociated colour is twice this.
COLOUR, ALPHA = np.array([0.1, 0.25, 0.4]), 0.5


def srgb_8bit(linear):
    """IEC 61966-2-1's transfer curve, in 8 bits."""
    linear = np.asarray(linear, dtype=np.float64)
    return np.round(255 * np.where(linear <= 0.0031308, 12.92 * linear,
                                   1.055 * linear ** (1 / 2.4) - 0.055))


def read_stored(path):
    """The values a file stores, as they are: alpha not associated by the
    reader, PFM's rows (bottom to top) read here, since OpenImageIO's
    reader leaves them upside down."""
    if path.suffix == ".pfm":
        header, width_height, scale, data = path.read_bytes().split(b"\n", 3)
        width, height = map(int, width_height.split())
        channels = 3 if header == b"PF" else 1
        values = np.frombuffer(data, "<f4" if float(scale) < 0 else ">f4")
        return values.reshape(height, width, channels)[::-1]
    config = OpenImageIO.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    image = OpenImageIO.ImageInput.open(str(path), config)
    try:
        return image.read_image(OpenImageIO.UINT8 if path.suffix in (".png", ".jpg")
                                else OpenImageIO.FLOAT)
    finally:
        image.close()


@pytest.mark.parametrize("channels", [1, 2, 3, 4], ids=["Y", "YA", "RGB", "RGBA"])
@pytest.mark.parametrize("suffix", [".png", ".jpg", ".exr", ".hdr", ".pfm"])
def test_every_format_stores_what_it_can_of_every_layout(tmp_path, suffix, channels):
    """PNG: sRGB colour unassociated from a linear alpha; EXR: as it is;
    JPEG, HDR, PFM (no alpha): the colour alone, the image over black; HDR
    (RGB only): luminance three times. Written whatever the layout, so no
    render is lost to a format at the end."""
    colour = COLOUR[:1 if channels <= 2 else 3]
    alpha = [ALPHA] if channels in (2, 4) else []
    image = np.tile(np.r_[colour, alpha], (8, 8, 1)).astype(np.float32)
    write_image(tmp_path / f"a{suffix}", image)
    if suffix == ".hdr":
        colour = np.resize(colour, 3)
    expected = {".png": np.r_[srgb_8bit(colour / (alpha[0] if alpha else 1)),
                              np.round(255 * np.array(alpha))],
                ".jpg": srgb_8bit(colour), ".exr": np.r_[colour, alpha]}.get(suffix, colour)
    stored = read_stored(tmp_path / f"a{suffix}")
    assert stored.shape == (8, 8, len(expected))
    # RGBE keeps 8 bits of mantissa; JPEG's transform rounds a flat block
    # to within a level.
    tolerance = {".hdr": 2 ** -8 * np.max(colour), ".jpg": 1}.get(suffix, 1e-7)
    np.testing.assert_allclose(stored, np.broadcast_to(expected, stored.shape), atol=tolerance)


def test_a_png_keeps_the_colour_of_a_pixel_without_alpha(tmp_path):
    """Nothing to divide by: an environment seen where nothing was hit."""
    write_image(tmp_path / "a.png", np.array([[[0.25, 0.5, 1.0, 0.0]]], np.float32))
    np.testing.assert_array_equal(read_stored(tmp_path / "a.png")[0, 0],
                                  np.r_[srgb_8bit([0.25, 0.5, 1.0]), 0])


GLASS = ROOT / "scenes" / "cases" / "glass_spheres.xml"


def with_pixel_format(folder, pixel_format: str):
    scene = folder / f"{pixel_format}.xml"
    scene.write_text(GLASS.read_text().replace(
        '<film type="hdrfilm">',
        f'<film type="hdrfilm"><string name="pixel_format" value="{pixel_format}"/>'))
    return scene


@pytest.mark.parametrize("pixel_format",
                         ["rgb", "rgba", "luminance", "luminance_alpha", "xyz", "xyza"])
def test_a_film_gets_its_pixel_format(tmp_path, pixel_format):
    """From the command line, which streams bands without a film, and from
    mi.render, which develops one: luminance and XYZ are the RGB image
    through the sRGB matrix, alpha as it is."""
    rgba = tmp_path / "rgba.exr"
    out = tmp_path / f"{pixel_format}.exr"
    for scene, image in ((with_pixel_format(tmp_path, "rgba"), rgba),
                         (with_pixel_format(tmp_path, pixel_format), out)):
        cli("render", str(scene), "-o", str(image), "-D", "res=24", check=True)
    colour, alpha = read_image(rgba)[..., :3].astype(np.float64), read_image(rgba)[..., 3:]
    without_alpha = {"rgba": "rgb", "luminance_alpha": "luminance", "xyza": "xyz"}.get(
        pixel_format, pixel_format)
    matrix = {"rgb": np.eye(3), "luminance": SRGB_TO_XYZ[1:2], "xyz": SRGB_TO_XYZ}[without_alpha]
    expected = colour @ matrix.T
    if without_alpha != pixel_format:
        expected = np.concatenate([expected, alpha], axis=2)
    written = read_image(out)
    np.testing.assert_allclose(written, expected, rtol=1e-6, atol=1e-7)

    import mitsuba_whitted

    developed = mi.render(mitsuba_whitted.load_file(tmp_path / f"{pixel_format}.xml", res="24"))
    np.testing.assert_allclose(np.array(developed), written, rtol=1e-6, atol=1e-7)


def test_info_names_variant_llvm_and_plugins():
    text = cli("info", check=True).stdout
    assert "variant llvm_ad_rgb" in text
    assert "libLLVM" in text and "version 19" in text
    for plugin in ("whitted", "phong", "capped_cylinder", "tartan", "sphere_map", "planar_map"):
        assert plugin in text


def assert_one_sentence(result, message, code=2):
    """Exit code ``code`` and exactly one line on stderr (see
    :func:`conftest.one_line`), which says ``message``."""
    assert result.returncode == code, result.stderr
    line = one_line(result.stderr)
    assert message in line, line


@pytest.mark.parametrize("args, message", [
    (["render", "missing.xml", "-o", "x.png"], "scene file 'missing.xml' does not exist"),
    (["render", "scenes", "-o", "x.png"], "scene file 'scenes' is a folder, not a file"),
    (["render", str(REPORT_SCENE), "-o", "x.png", "-D", "aa=fancy"],
     "whitted: parameter 'aa' must be one of"),
    (["render", str(REPORT_SCENE), "-o", "x.png", "-D", "res"], "-D expects name=value"),
    (["render", str(REPORT_SCENE), "-o", "x.gif", "-D", "res=8"], "cannot write 'x.gif'"),
    (["render", str(REPORT_SCENE), "-o", "x.png", "--variant", "nope"],
     "variant 'nope' is not available"),
    (["render", str(REPORT_SCENE), "-o", "x.png", "--variant", "scalar_rgb"],
     "whitted: the wavefront integrator needs a JIT variant"),
    (["render", str(REPORT_SCENE), "-o", "x.png", "-D", "fov=3"],
     "Found unused parameters: $fov=3"),
    (["bench", "--quick", str(ROOT / "Makefile")], "Makefile' is not well-formed XML"),
    (["render", str(REPORT_SCENE), "-o", "x.png", "--fast"],
     "mitsuba-whitted: unrecognized arguments: --fast; 'mitsuba-whitted --help' lists"),
    ([], "mitsuba-whitted: the following arguments are required: command"),
])
def test_bad_input_is_one_sentence(args, message):
    assert_one_sentence(cli(*args), message)


VALIDATION_BAD_INPUT = [
    ("validation.run", ["--workers", "0"],
     "argument --workers: expected a whole number of at least 1, got '0'"),
    ("validation.run", ["--bogus"], "validation.run: unrecognized arguments: --bogus"),
    ("validation.inverse_texture", ["--iterations", "0"],
     "argument --iterations: expected a whole number of at least 1, got '0'"),
    ("validation.inverse_texture_prb", ["--iterations", "many"],
     "argument --iterations: expected a whole number of at least 1, got 'many'"),
    ("validation.inverse_texture", ["--out", "{file}"], "'{file}': it is a file, not a folder"),
    ("validation.cluster_speed", ["--res", "-3"],
     "argument --res: expected a whole number of at least 1, got '-3'"),
    ("validation.cluster_speed", ["--workers", "2", "0"], "argument --workers"),
    ("validation.cluster_speed", ["--json", "{folder}"], "'{folder}': it is a folder"),
]


@pytest.mark.parametrize("module, args, message", VALIDATION_BAD_INPUT,
                         ids=[" ".join([module, *args])
                              for module, args, _ in VALIDATION_BAD_INPUT])
def test_the_validation_commands_refuse_bad_input_in_one_sentence(tmp_path, module, args,
                                                                 message):
    """Before any work: the file named stays as it was."""
    names = {"file": tmp_path / "a-file", "folder": tmp_path}
    names["file"].write_text("kept")
    result = cli(*[arg.format(**names) for arg in args], module=module)
    assert_one_sentence(result, message.format(**names))
    assert names["file"].read_text() == "kept"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"]


#: A small scene; the body of each hostile case goes at the end.
HOSTILE = """<scene version="3.0.0">
    <integrator type="whitted"/>
    <sensor type="perspective">
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    </sensor>
    <shape type="sphere"><transform name="to_world"><translate z="5"/></transform></shape>
    <emitter type="point"><point name="position" x="0" y="3" z="0"/></emitter>
    {body}
</scene>"""


@pytest.mark.parametrize("body, message", [
    ('<include filename="nope.xml"/>', 'included file "nope.xml" not found'),
    ('<include filename="broken.xml"/>', 'Parsing of XML file "{folder}/broken.xml" failed: '
                                         'Start-end tags mismatch'),
    ('<shape type="sphere"><bsdf type="diffuse"><texture type="bitmap" name="reflectance">'
     '<string name="filename" value="nope.png"/></texture></bsdf></shape>',
     '"nope.png": I/O error while attempting to open file: No such file or directory'),
    ('<shape type="spheer"/>', 'failed to instantiate shape plugin of type "spheer": '
                               '[PluginManager] Plugin "spheer" not found!'),
    ('<shape type="sphere">', 'Start-end tags mismatch'),
    (None, "has no sensor to render from; add a <sensor>"),
], ids=["include-missing", "include-broken", "texture-missing", "unknown-plugin", "malformed",
        "no-sensor"])
def test_a_broken_scene_is_one_sentence(tmp_path, body, message):
    (tmp_path / "broken.xml").write_text('<scene version="3.0.0"><shape type="sphere">')
    text = HOSTILE.format(body=body or "")
    if body is None:
        text = text[:text.index("<sensor")] + text[text.index("</sensor>") + 9:]
    scene = tmp_path / "scene.xml"
    scene.write_text(text)
    result = cli("render", str(scene), "-o", str(tmp_path / "x.png"))
    assert_one_sentence(result, message.format(folder=tmp_path))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["broken.xml", "scene.xml"]


def test_warnings_go_to_stderr_in_plain_lines(tmp_path):
    scene = tmp_path / "scene.xml"
    scene.write_text(HOSTILE.format(body="").replace(
        '<integrator type="whitted"/>',
        '<integrator type="whitted"><string name="aa" value="adaptive"/>'
        '<float name="aa_threshold" value="0"/><float name="aa_budget" value="4"/></integrator>'))
    result = cli("render", str(scene), "-o", str(tmp_path / "x.exr"), check=True)
    assert re.fullmatch(
        r"warning: whitted: adaptive anti-aliasing stopped before level 1: its \d+ samples "
        r"would pass the budget of 4 samples per pixel \('aa_budget'\); raise 'aa_budget' or "
        r"'aa_threshold'\.\n", result.stderr), result.stderr
    assert result.stdout.startswith(f"{tmp_path / 'x.exr'}: 8x8 rendered and written in ")
    assert len(result.stdout.splitlines()) == 1


# ------------------------------------- errors raised while a render runs


class _Failing(mi.SamplingIntegrator):
    """An integrator whose render raises what ``failure()`` raises."""

    failure = None

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        _Failing.failure()


class _BrokenBSDF(mi.BSDF):
    def __init__(self, props):
        super().__init__(props)
        raise TypeError("unsupported operand type(s) for +: 'int' and 'str'")


def _recurse(depth=0):
    return _recurse(depth + 1)


def _raise(error):
    raise error


@pytest.mark.parametrize("failure, message", [
    (lambda: mi.Float([1, 2, 3]) + mi.Float([1, 2]),
     "Dr.Jit: operands have incompatible sizes! (sizes: 3, 2)."),
    (lambda: dr.arange(mi.UInt32, 2**32 + 5),
     "Dr.Jit: tried to create an array with 4294967301 entries, which exceeds the limit of "
     "2^32 == 4294967296 entries; lower the film's resolution or its samples per pixel."),
    (lambda: dr.arange(mi.UInt32, 2.5),
     "TypeError: arange(): incompatible function arguments (invoked with types: "
     "nanobind.nb_type, float)."),
    (_recurse, "Python's recursion limit was reached (maximum recursion depth exceeded)."),
    (lambda: np.empty(2**50), "the machine ran out of memory (Unable to allocate 8.00 PiB "
                              "for an array with shape (1125899906842624,) and data type "
                              "float64)."),
    (lambda: _raise(KeyError("x")), "KeyError: 'x'."),
], ids=["size-mismatch", "size-limit", "wrong-type", "recursion", "memory", "python-error"])
def test_an_error_during_a_render_is_one_sentence(tmp_path, monkeypatch, capsys, failure, message):
    """The real cause, not Dr.Jit's '(see above)' wrapper of ``mi.render``."""
    mi.register_integrator("test_failing", lambda props: _Failing(props))
    monkeypatch.setattr(_Failing, "failure", staticmethod(failure))
    scene = tmp_path / "scene.xml"
    scene.write_text(HOSTILE.format(body="").replace('"whitted"', '"test_failing"'))
    assert main(["render", str(scene), "-o", str(tmp_path / "x.png")]) == 2
    assert capsys.readouterr().err == message + "\n"


def test_an_error_while_a_python_plugin_loads_is_one_sentence(tmp_path, capsys):
    """Mitsuba puts the plugin's Python traceback into its own message."""
    mi.register_bsdf("test_broken", lambda props: _BrokenBSDF(props))
    scene = tmp_path / "scene.xml"
    scene.write_text(HOSTILE.format(body='<shape type="sphere"><bsdf type="test_broken"/></shape>'))
    assert main(["render", str(scene), "-o", str(tmp_path / "x.png")]) == 2
    assert capsys.readouterr().err == (
        f"At {scene} (line 8, col 27): failed to instantiate bsdf plugin of type "
        "\"test_broken\": TypeError: unsupported operand type(s) for +: 'int' and 'str'.\n")


def test_python_warnings_of_a_command_are_plain_lines(capsys):
    import warnings

    assert run_command(lambda: warnings.warn("a deprecated option") or 0) == 0
    assert capsys.readouterr().err == "warning: a deprecated option\n"


# ----------------------------------------------- films, streams and pipes

@pytest.mark.parametrize("side, value", [("width", 0), ("height", -3)])
def test_a_film_without_pixels_is_refused_by_its_own_name(tmp_path, side, value):
    """Mitsuba's camera divides by the film's size first, and blamed its
    field of view."""
    scene = tmp_path / "scene.xml"
    scene.write_text(HOSTILE.format(body="").replace(
        f'<integer name="{side}" value="8"/>', f'<integer name="{side}" value="{value}"/>'))
    result = cli("render", str(scene), "-o", str(tmp_path / "x.png"))
    assert_one_sentence(result, f"hdrfilm: parameter '{side}' must be at least 1 "
                                f"(got {value}), at {scene} (line 4, col ")
    assert "field of view" not in result.stderr


def small_render(target, **options):
    """``mitsuba-whitted render`` of a small image, in a process whose
    streams ``options`` set as for ``subprocess.run``."""
    return subprocess.run([sys.executable, "-m", "mitsuba_whitted.cli", "render",
                           str(REPORT_SCENE), "-D", "res=16", "-D", "aa=none", "-o", str(target)],
                          cwd=ROOT, timeout=300, **options)


def close_descriptors(*descriptors):
    def close():
        for descriptor in descriptors:
            os.close(descriptor)
    return close


@pytest.mark.parametrize("closed", [(2,), (1, 2), (0, 1, 2)], ids=["2", "1-2", "0-1-2"])
def test_a_command_started_without_its_streams_renders_as_usual(tmp_path, closed):
    """``2>&-``: Python has no sys.stderr, and every render failed with an
    AttributeError, printed on stdout."""
    target = tmp_path / "x.png"
    result = small_render(target, stdout=subprocess.PIPE, text=True,
                          preexec_fn=close_descriptors(*closed))
    assert result.returncode == 0
    expected = "" if 1 in closed else f"{target}: 16x16 rendered and written in "
    assert result.stdout.startswith(expected)
    assert read_image(target).shape == (16, 16, 3)
    assert list(tmp_path.iterdir()) == [target]


def test_an_error_without_stderr_leaves_stdout_empty(tmp_path):
    result = small_render(tmp_path / "x.gif", stdout=subprocess.PIPE, text=True,
                          preexec_fn=close_descriptors(2))
    assert (result.returncode, result.stdout) == (2, "")


@pytest.mark.parametrize("suffix", [".png", ".exr"])
@pytest.mark.parametrize("streams", ["stdout", "stdout-and-stderr"])
def test_output_into_a_pipe_nobody_reads_ends_quietly_with_141(tmp_path, streams, suffix):
    """``render ... | head -c1``: the reader is gone when the summary line
    comes. As a command that SIGPIPE ends: exit code 141, nothing said; the
    image is written whole, as it was done before."""
    reader, writer = os.pipe()
    os.close(reader)
    target = tmp_path / f"x{suffix}"
    try:
        result = small_render(target, stdout=writer, text=True,
                              stderr=writer if streams == "stdout-and-stderr" else subprocess.PIPE)
    finally:
        os.close(writer)
    assert result.returncode == 141
    assert not result.stderr
    assert read_image(target).shape[:2] == (16, 16)
    assert list(tmp_path.iterdir()) == [target]


# ------------------------------------------ outputs that the scene reads

def textured_scenes(folder):
    """``scene.xml`` reads ``wall.png`` (a default, which a define may
    change) and includes ``parts/ball.xml``, which reads ``parts/ball.exr``;
    ``other.xml`` reads ``scene.png``."""
    image = np.linspace(0, 1, 4 * 4 * 3, dtype=np.float32).reshape(4, 4, 3)
    (folder / "parts").mkdir()
    for name in ("wall.png", "parts/ball.exr", "scene.png", "spare.png"):
        write_image(folder / name, image)

    def textured(name):
        return ('<bsdf type="diffuse"><texture type="bitmap" name="reflectance">'
                f'<string name="filename" value="{name}"/></texture></bsdf>')

    (folder / "parts" / "ball.xml").write_text(
        f'<scene version="3.0.0"><shape type="sphere">{textured("parts/ball.exr")}</shape></scene>')
    body = (f'<default name="wall" value="wall.png"/><shape type="rectangle">{textured("$wall")}'
            '</shape><include filename="parts/ball.xml"/>')
    (folder / "scene.xml").write_text(HOSTILE.format(body=body))
    (folder / "other.xml").write_text(HOSTILE.format(
        body=f'<shape type="rectangle">{textured("scene.png")}</shape>'))
    return {name: (folder / name).read_bytes() for name in
            ("wall.png", "parts/ball.exr", "scene.png", "spare.png", "scene.xml",
             "parts/ball.xml")}


@pytest.mark.parametrize("case", ["texture", "link", "define", "include", "render-many",
                                  "compare", "bench"])
def test_no_command_writes_over_a_file_the_scene_reads(tmp_path, case):
    before = textured_scenes(tmp_path)
    scene = str(tmp_path / "scene.xml")
    (tmp_path / "link.png").symlink_to(tmp_path / "wall.png")
    (tmp_path / "parts" / FOLDER_MARK).write_text("")  # as if an earlier compare wrote there
    args, output, read = {
        "texture": (["render", scene, "-o", "{}/wall.png"], "wall.png", "it"),
        "link": (["render", scene, "-o", "{}/link.png"], "link.png", "it"),
        "define": (["render", scene, "-D", "wall=spare.png", "-o", "{}/spare.png"], "spare.png",
                   "it"),
        "include": (["render", scene, "-o", "{}/parts/ball.exr"], "parts/ball.exr", "it"),
        "render-many": (["render-many", str(tmp_path / "other.xml"), scene, "--out", "{}",
                         "--format", "png"], "scene.png", "it"),
        "compare": (["compare", "--quick", scene, "--out", "{}/parts"], "parts",
                    "'{}/parts/ball.exr' in it"),
        "bench": (["bench", "--quick", scene, "--json", "{}/parts/ball.xml"],
                  "parts/ball.xml", "it"),
    }[case]
    result = cli(*[arg.format(tmp_path) for arg in args])
    reader = "other.xml" if case == "render-many" else "scene.xml"
    assert_one_sentence(result, f"cannot write '{tmp_path / output}': scene "
                                f"'{tmp_path / reader}' reads {read.format(tmp_path)}; "
                                "choose another output.")
    assert {name: (tmp_path / name).read_bytes() for name in before} == before


# ------------------------------------------------ names that are not UTF-8

#: A byte that is not UTF-8 in a file name, as Python decodes it
#: (surrogateescape), and as the command shows it.
NOT_UTF8, SHOWN = "\udcff", "\\xff"


def shown(path) -> str:
    return str(path).replace(NOT_UTF8, SHOWN)


@pytest.mark.parametrize("command, scene", [
    ("render", f"sc{NOT_UTF8}ene.xml"), ("render", f"f{NOT_UTF8}lder/scene.xml"),
    ("render-many", f"sc{NOT_UTF8}ene.xml"), ("compare", f"sc{NOT_UTF8}ene.xml"),
    ("bench", f"sc{NOT_UTF8}ene.xml")])
def test_a_scene_path_that_is_not_utf8_is_one_sentence(tmp_path, command, scene):
    """Mitsuba takes strings as UTF-8 only: its parser failed in nanobind's
    type error (``bench``, whose first load Python reads, in its child
    process after minutes of work). Nothing is written."""
    scene = tmp_path / scene
    scene.parent.mkdir(exist_ok=True)
    scene.write_text(HOSTILE.format(body=""))
    out = str(tmp_path / "out")
    args = {"render": ["-o", f"{out}.png"], "render-many": ["--out", out],
            "compare": ["--quick", "--out", out], "bench": ["--quick"]}[command]
    result = cli(command, str(scene), *args)
    assert_one_sentence(result, f"mitsuba-whitted: scene file '{shown(scene)}' has a path that "
                                "is not UTF-8, which Mitsuba cannot open; rename it, or link to "
                                "it under a UTF-8 name.")
    assert sorted(tmp_path.rglob("*")) == sorted({scene, scene.parent} - {tmp_path})


def test_a_define_that_is_not_utf8_is_one_sentence(tmp_path):
    result = cli("render", str(REPORT_SCENE), "-o", str(tmp_path / "x.png"),
                 "-D", f"res=1{NOT_UTF8}")
    assert_one_sentence(result, f"mitsuba-whitted: -D res=1{SHOWN} is not UTF-8, which "
                                "Mitsuba's parser cannot take.")


@pytest.mark.parametrize("output", [f"o{NOT_UTF8}ut.png", f"o{NOT_UTF8}ut.exr",
                                    f"f{NOT_UTF8}lder/x.jpg"])
def test_an_output_path_that_is_not_utf8_is_written(tmp_path, output):
    """The package writes the image itself, so it takes any name the
    system takes: OpenImageIO's writer, which was given the name to choose
    the format (a ``TypeError``), is now chosen by the extension. The line
    on stdout, which Python refused to encode, shows the byte escaped."""
    target = tmp_path / output
    render = ("render", str(REPORT_SCENE), "-D", "res=16", "-D", "aa=none", "-o")
    result = cli(*render, str(target), check=True)
    assert result.stdout.startswith(f"{shown(target)}: 16x16 rendered and written in ")
    reference = tmp_path / f"reference{target.suffix}"
    cli(*render, str(reference), check=True)
    copy = tmp_path / f"copy{target.suffix}"
    copy.write_bytes(target.read_bytes())  # OpenImageIO cannot open the name itself
    np.testing.assert_array_equal(read_image(copy), read_image(reference))


# ---------------------------------------------- a small address space

def address_space(kib: int):
    """``ulimit -v kib`` in the process about to start (``preexec_fn``)."""
    return lambda: resource.setrlimit(resource.RLIMIT_AS, (kib << 10, kib << 10))


@pytest.mark.parametrize("kib", [100_000, 400_000, 700_000])
def test_an_address_space_too_small_to_start_is_one_sentence(tmp_path, kib):
    """``ulimit -v``: the imports failed, in a different way at each size:
    an ``ImportError`` that never said memory, a fatal error of Python's
    exit (134), OpenBLAS's abort, a thread's ``std::bad_alloc``, a variant
    'that cannot be used on this machine'."""
    result = cli("render", str(REPORT_SCENE), "-o", str(tmp_path / "x.png"),
                 preexec_fn=address_space(kib))
    assert_one_sentence(result, f"mitsuba-whitted: the address-space limit of "
                                f"{size_text(kib << 10)} (ulimit -v {kib}) is below the ")
    assert result.stderr.endswith("; raise the limit or remove it.\n")
    assert list(tmp_path.iterdir()) == []


#: The command, in a process that lowers its address-space limit to what it
#: has mapped (and 8 MiB) when it starts to import ``sys.argv[1]``: the
#: import fails as under a limit that passes the check at the start.
SQUEEZED = """
import resource, sys

module = sys.argv.pop(1)


class Squeeze:
    def find_spec(self, name, path, target=None):
        if name == module:
            status = open("/proc/self/status").read()
            mapped = int(status.split("VmSize:")[1].split()[0]) << 10
            resource.setrlimit(resource.RLIMIT_AS, (mapped + (8 << 20),) * 2)


sys.meta_path.insert(0, Squeeze())
sys.argv[0] = "mitsuba-whitted"
from mitsuba_whitted.cli import main
sys.exit(main())
"""


@pytest.mark.parametrize("module, library", [("drjit", "_drjit_ext"),
                                             ("OpenImageIO", "libOpenImageIO")])
def test_a_library_that_cannot_be_mapped_is_one_sentence(tmp_path, module, library):
    """Dr.Jit's ``ImportError`` ended in a ``NameError`` (Dr.Jit goes on
    after it) and a fatal error at Python's exit; the sentence names the
    library and the limit."""
    result = subprocess.run([sys.executable, "-c", SQUEEZED, module, "render",
                             str(REPORT_SCENE), "-o", str(tmp_path / "x.png")],
                            cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert result.returncode == 2, result.stderr
    assert re.fullmatch(rf"the process ran out of memory \({library}\S* could not be mapped\) "
                        r"under the address-space limit of [\d.]+ MiB \(ulimit -v \d+\); raise "
                        r"the limit or remove it\.", one_line(result.stderr)), result.stderr


# ------------------------------------------- images larger than memory

def declaring_png(path, width: int, height: int, padding: int = 0):
    """A valid 4 x 4 PNG whose header is made to declare ``width`` x
    ``height`` pixels (its IHDR chunk's CRC computed again), followed by
    ``padding`` bytes of a private ancillary chunk that readers skip."""
    write_image(path, np.zeros((4, 4, 3), np.float32))
    data = bytearray(path.read_bytes())
    assert data[12:16] == b"IHDR"
    data[16:24] = struct.pack(">II", width, height)
    data[29:33] = struct.pack(">I", zlib.crc32(data[12:29]))
    if padding:
        body = b"zzZz" + bytes(padding)
        data[33:33] = struct.pack(">I", padding) + body + struct.pack(">I", zlib.crc32(body))
    path.write_bytes(data)
    return path


def textured(image: str, mapping: str = "") -> str:
    """A sphere whose phong BSDF reads ``image`` through a ``bitmap``,
    nested in the package's ``mapping`` texture if one is given."""
    name = "texture" if mapping else "diffuse_reflectance"
    bitmap = (f'<texture type="bitmap" name="{name}">'
              f'<string name="filename" value="{image}"/></texture>')
    if mapping:
        bitmap = f'<texture type="{mapping}" name="diffuse_reflectance">{bitmap}</texture>'
    return f'<shape type="sphere"><bsdf type="phong">{bitmap}</bsdf></shape>'


@pytest.mark.parametrize("case", ["implausible", "beyond-memory", "sphere_map"])
def test_an_image_declaring_more_pixels_than_memory_is_one_sentence(tmp_path, case):
    """A PNG whose header declares 100000 x 100000 pixels ended the render
    in Mitsuba's ``std::bad_alloc``. One with a file that small is refused
    as OpenImageIO refuses it (it cannot hold what it declares); one padded
    until it could (8 MiB of the 67 GB it declares) is refused by its size
    against the memory available, before Mitsuba allocates anything."""
    size, padding = (100_000, 0) if case == "implausible" else (150_000, 8 << 20)
    image = declaring_png(tmp_path / "wall.png", size, size, padding)
    scene = tmp_path / "scene.xml"
    mapping = "sphere_map" if case == "sphere_map" else ""
    scene.write_text(HOSTILE.format(body=textured("wall.png", mapping)))
    result = cli("render", str(scene), "-o", str(tmp_path / "x.png"))
    reason = ("OpenImageIO cannot read it (png header claims a 28610 MB image from a "
              if case == "implausible" else
              "its header declares 150000 x 150000 pixels of 3 channels, 251 GiB as float32, "
              "and ")
    assert_one_sentence(result, f"bitmap: parameter 'filename' names '{image}': {reason}")
    assert f"at {scene} (line " in result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.xml", "wall.png"]


def test_an_image_beyond_the_address_space_limit_is_refused_naming_the_limit(tmp_path):
    """Under ``ulimit -v`` (above what the command needs to start), an
    image that fits in the machine's memory and not under the limit ended
    the render in a Dr.Jit worker's segmentation fault: the memory
    available is what the limit leaves."""
    kib = (startup.BASE_ADDRESS_SPACE + startup.THREAD_ADDRESS_SPACE * os.cpu_count()
           + (512 << 20)) >> 10
    side = int(((kib << 10) * 2 / 12) ** 0.5)  # twice the limit as float32 RGB
    image = declaring_png(tmp_path / "wall.png", side, side, padding=side * side * 3 // 10000)
    scene = tmp_path / "scene.xml"
    scene.write_text(HOSTILE.format(body=textured("wall.png")))
    result = cli("render", str(scene), "-o", str(tmp_path / "x.png"),
                 preexec_fn=address_space(kib))
    assert_one_sentence(result, f"bitmap: parameter 'filename' names '{image}': its header "
                                f"declares {side} x {side} pixels of 3 channels, ")
    assert (f"of memory are available under the address-space limit of {size_text(kib << 10)} "
            f"(ulimit -v {kib}); at {scene} (line ") in result.stderr


def test_an_image_that_fits_is_read_and_one_that_does_not_is_refused(tmp_path, monkeypatch):
    """The same check where the package reads images itself, and in the
    Python API's ``load_file``, against the memory the system reports."""
    texture = ROOT / "textures" / "lemons.png"  # 512 x 512 RGB: 3.0 MiB as float32
    scene = tmp_path / "scene.xml"
    scene.write_text(HOSTILE.format(body=textured(str(texture), "sphere_map")))
    monkeypatch.setattr(imageio, "available_memory", lambda: 3 << 20)
    assert read_image(texture).shape == (512, 512, 3)
    mitsuba_whitted.load_file(scene)
    monkeypatch.setattr(imageio, "available_memory", lambda: (3 << 20) - 1)
    with pytest.raises(ReadError):
        read_image(texture)
    monkeypatch.setattr(imageio, "available_memory", lambda: 2 << 20)
    with pytest.raises(ReadError, match=re.escape(
            f"mitsuba-whitted: cannot read '{texture}': its header declares 512 x 512 pixels of "
            "3 channels, 3.0 MiB as float32, and 2.0 MiB of memory are available.")):
        read_image(texture)
    with pytest.raises(mitsuba_whitted.ParameterError, match=re.escape(
            f"bitmap: parameter 'filename' names '{texture}': its header declares 512 x 512 "
            f"pixels of 3 channels, 3.0 MiB as float32, and 2.0 MiB of memory are available; "
            f"at {scene} (line ")):
        mitsuba_whitted.load_file(scene)
