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


def test_a_second_process_compiles_nothing(tmp_path):
    """Dr.Jit's kernel cache only helps if every kernel comes out the same
    in each process: a value that differs per process (an address, say)
    baked into the tracer's kernel would compile it anew on every run."""
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
])
def test_bad_input_is_one_sentence(args, message):
    result = cli(*args, check=False)
    assert result.returncode == 2
    assert message in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
