"""The mitsuba-whitted command line, run as a user would."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mitsuba_whitted.imageio import read_image, to_8bit

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "scenes" / "cosc363.xml"


def cli(*args, check=True, env=None):
    return subprocess.run([sys.executable, "-m", "mitsuba_whitted.cli", *args],
                          capture_output=True, text=True, timeout=600, check=check, cwd=ROOT,
                          env=env)


def test_render_report_scene_small(tmp_path):
    out = tmp_path / "small.exr"
    result = cli("render", str(SCENE), "-o", str(out), "-D", "res=48", "-D", "aa_max_depth=3")
    image = read_image(out)
    assert image.shape == (48, 48, 3)
    assert np.isfinite(image).all() and image.max() > 0.1
    line = result.stdout.strip().splitlines()[-1]
    assert "48x48 rendered in" in line and "M rays/s" in line


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
    outputs = {subprocess.run([sys.executable, "-c", REGISTRY_IDS, str(SCENE)], cwd=ROOT,
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
    render = ("render", str(SCENE), "-o", str(tmp_path / "a.exr"), "-D", "res=16")
    cli(*render, env=env)
    first = set(cached.iterdir())
    cli(*render, env=env)
    assert first and set(cached.iterdir()) == first


def test_png_is_the_srgb_encoding_of_the_exr(tmp_path):
    for suffix in ("exr", "png"):
        cli("render", str(SCENE), "-o", str(tmp_path / f"a.{suffix}"), "-D", "res=24", "-D", "aa=none")
    linear = read_image(tmp_path / "a.exr")
    encoded = np.round(read_image(tmp_path / "a.png") * 255)
    np.testing.assert_array_equal(encoded, to_8bit(linear))


def test_info_names_variant_llvm_and_plugins():
    text = cli("info").stdout
    assert "variant llvm_ad_rgb" in text
    assert "libLLVM" in text and "version 19" in text
    for plugin in ("whitted", "phong", "capped_cylinder", "tartan", "sphere_map", "planar_map"):
        assert plugin in text


@pytest.mark.parametrize("args, message", [
    (["render", "missing.xml", "-o", "x.png"], "scene file 'missing.xml' does not exist"),
    (["render", str(SCENE), "-o", "x.png", "-D", "aa=fancy"], "whitted: parameter 'aa' must be one of"),
    (["render", str(SCENE), "-o", "x.png", "-D", "res"], "-D expects name=value"),
    (["render", str(SCENE), "-o", "x.gif", "-D", "res=8"], "cannot write 'x.gif'"),
    (["render", str(SCENE), "-o", "x.png", "--variant", "nope"], "variant 'nope' is not available"),
    (["render", str(SCENE), "-o", "x.png", "--variant", "scalar_rgb"], "whitted: the wavefront integrator needs a JIT variant"),
    (["render", str(SCENE), "-o", "x.png", "-D", "fov=3"], "Found unused parameters: $fov=3"),
    (["bench", "--quick", str(ROOT / "Makefile")], "Makefile' is not well-formed XML"),
])
def test_bad_input_is_one_sentence(args, message):
    result = cli(*args, check=False)
    assert result.returncode == 2
    assert message in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
