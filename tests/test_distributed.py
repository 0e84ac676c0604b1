"""The execution backends' parts that need no Ray: scenes shipped as bytes,
the in-process backend, merging in task order, ``render-many``, the
progress bar, and the commands when Ray is not installed."""

import hashlib
import os
import shutil

import mitsuba as mi
import numpy as np
import pytest

import mitsuba_whitted
from conftest import cli, one_line
from mitsuba_whitted.compare import render_reference
from mitsuba_whitted.compare.reference import REFERENCE_SEED, path_settings
from mitsuba_whitted.distributed import SceneShippingError, SceneSource, in_order
from mitsuba_whitted.distributed.scene import load_bundle
from mitsuba_whitted.imageio import read_image
from validation.scenes import REPORT_SCENE, ROOT

GLASS = ROOT / "scenes" / "cases" / "glass_spheres.xml"


def test_a_bundle_renders_the_scene_without_its_files(tmp_path):
    """The report's scene names two textures as ../textures/*.png; its
    bundle carries them by content hash, and the scene rebuilt from the
    bundle renders what the original renders, bit for bit, after the
    original files are gone."""
    copy = tmp_path / "copy"
    shutil.copytree(ROOT / "textures", copy / "textures")
    (copy / "scenes").mkdir()
    shutil.copy(REPORT_SCENE, copy / "scenes")
    source = SceneSource(copy / "scenes" / "cosc363.xml", {"res": "24"})
    expected = mi.render(source.load()).numpy()
    bundle, contents = source.bundle()
    shutil.rmtree(copy)
    assert sorted(name for name, _ in bundle.files) == ["../textures/lemons.png",
                                                        "../textures/pink_elephant.png"]
    for name, digest in bundle.files:
        original = (ROOT / "scenes" / name).read_bytes()
        assert digest == hashlib.sha256(original).hexdigest() and contents[digest] == original
    np.testing.assert_array_equal(mi.render(load_bundle(bundle, contents)).numpy(), expected)


def test_a_scene_made_in_python_is_not_shipped():
    scene = mi.load_dict({"type": "scene", "sensor": {"type": "perspective"}})
    with pytest.raises(SceneShippingError, match="has no file"):
        SceneSource.loaded(scene).bundle()


def _pass_loop_reference(scene, spp, passes=16):
    """The reference as one loop over the passes, float64 sums in pass order."""
    integrator = mi.load_dict(path_settings())
    per_pass = -(-spp // passes)
    total = square = None
    for index in range(passes):
        image = np.asarray(mi.render(scene, integrator=integrator, spp=per_pass,
                                     seed=REFERENCE_SEED + index), dtype=np.float64)[..., :3]
        total = image if total is None else total + image
        square = image ** 2 if square is None else square + image ** 2
    mean = total / passes
    return mean, np.maximum(square / passes - mean ** 2, 0) / (passes - 1)


@pytest.mark.parametrize("how", ["loaded scene", "scene file"])
def test_in_process_reference_is_the_pass_loop_bit_for_bit(how):
    defines = {"res": "16"}
    scene = mitsuba_whitted.load_file(GLASS, **defines)
    given = scene if how == "loaded scene" else SceneSource(GLASS, defines)
    mean, variance = _pass_loop_reference(scene, 64)
    reference = render_reference(given, 64)
    np.testing.assert_array_equal(reference.image, mean)
    np.testing.assert_array_equal(reference.variance, variance)
    assert reference.spp == 64


def test_in_order_hands_results_on_in_task_order():
    seen = []
    receive = in_order(seen.append)
    for index in (2, 0, 3, 1, 5, 4):
        receive(index, f"image {index}")
    assert seen == [f"image {index}" for index in range(6)]


def test_render_many_in_process_writes_what_render_writes(tmp_path):
    scenes = [REPORT_SCENE, GLASS]
    result = cli("render-many", *map(str, scenes), "--out", str(tmp_path / "many"),
                 "-D", "res=20")
    assert result.returncode == 0, result.stderr
    assert "2 images" in result.stdout and "in-process" in result.stdout
    for scene in scenes:
        single = tmp_path / f"{scene.stem}.exr"
        assert cli("render", str(scene), "-o", str(single), "-D", "res=20").returncode == 0
        np.testing.assert_array_equal(read_image(tmp_path / "many" / f"{scene.stem}.exr"),
                                      read_image(single))


def _twin(tmp_path):
    """The report's scene and a copy of it in another folder: one stem."""
    shutil.copy(REPORT_SCENE, tmp_path / "cosc363.xml")
    return [str(REPORT_SCENE), str(tmp_path / "cosc363.xml")]


@pytest.mark.parametrize("make_args, words", [
    (lambda tmp: [str(REPORT_SCENE), str(tmp / "missing.xml")], "missing.xml' does not exist"),
    (_twin, "would both be written to"),
    (lambda tmp: [str(REPORT_SCENE), "--workers", "0"],
     "argument --workers: expected a whole number of at least 1, got '0'"),
])
def test_render_many_refuses_bad_input_in_one_sentence(tmp_path, make_args, words):
    out = tmp_path / "out"
    result = cli("render-many", *make_args(tmp_path), "--out", str(out))
    assert result.returncode == 2
    assert words in one_line(result.stderr)
    assert not out.exists()


@pytest.fixture
def without_ray(tmp_path):
    """An environment where ``import ray`` fails, as on a plain install."""
    stub = tmp_path / "no_ray" / "ray"
    stub.mkdir(parents=True)
    (stub / "__init__.py").write_text("raise ImportError('No module named ray')\n")
    env = dict(os.environ, PYTHONPATH=str(stub.parent))
    env.pop("RAY_ADDRESS", None)
    return env


def test_render_needs_no_ray(tmp_path, without_ray):
    result = cli("render", str(REPORT_SCENE), "-o", str(tmp_path / "a.png"), "-D", "res=16",
                 env=without_ray)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "a.png").is_file()


@pytest.mark.parametrize("option", [["--workers", "2"], ["--cluster", "127.0.0.1:6379"]])
def test_workers_without_ray_is_one_sentence(tmp_path, without_ray, option):
    result = cli("render-many", str(GLASS), "--out", str(tmp_path), *option, env=without_ray)
    assert result.returncode == 2
    line = one_line(result.stderr)
    assert "needs Ray" in line and "[cluster]" in line and option[0] in line
