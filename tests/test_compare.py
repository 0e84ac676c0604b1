"""The comparison library and ``mitsuba-whitted compare``.

Oracles: closed forms for the metrics and the log-log interpolation,
recomputation from the images the report wrote, Mitsuba's path tracer for
the equivalence verdicts, and the files on disk for the cache.
"""

import json
import re
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

from mitsuba_whitted.compare import (ReferenceCache, cache_key, cached_reference, flip_error,
                                     luminance, missing_energy_share, noise_rel_mse, rel_mse,
                                     rmse)
from mitsuba_whitted.compare.converged import converged_renders, converges_to_reference
from mitsuba_whitted.compare.levels import error_levels
from mitsuba_whitted.compare.reference import render_reference
from mitsuba_whitted.compare.sweep import (PhotonRungs, _variants, indirect_change,
                                           whitted_variants)
from mitsuba_whitted.compare.report import number
from mitsuba_whitted.compare.scene_report import (FOLDER_MARK, CompareError, CompareOptions,
                                                  check_report_folder, compare_scene)
from mitsuba_whitted.imageio import read_image
from mitsuba_whitted.scene_digest import scene_digest

from conftest import assert_finite, cli, one_line
from validation import scenes
from validation.scenes import REPORT_SCENE, glass_scene

RNG = np.random.default_rng(363)


# ---------------------------------------------------------------- metrics

def test_metrics_match_closed_forms():
    c, d, eps = 0.4, 0.05, 1e-2
    reference = np.full((8, 8, 3), c)
    image = reference + d
    assert rel_mse(image, reference, eps) == pytest.approx(d ** 2 / (c ** 2 + eps), rel=1e-12)
    assert rmse(image, reference) == pytest.approx(d, rel=1e-12)
    # Rec. 709 weights sum to 1: grey keeps its value.
    assert luminance(reference) == pytest.approx(np.full((8, 8), c), rel=1e-5)
    assert missing_energy_share(0.75 * reference, reference) == pytest.approx(0.25, rel=1e-12)
    # Light an image adds is not light it leaves out.
    assert missing_energy_share(1.5 * reference, reference) == 0.0
    variance = np.full_like(reference, 1e-4)
    assert noise_rel_mse(variance, reference, eps) == pytest.approx(1e-4 / (c ** 2 + eps))


def test_rel_mse_against_an_explicit_sum():
    reference, image = RNG.random((5, 7, 3)), RNG.random((5, 7, 3))
    explicit = sum((image[i, j, k] - reference[i, j, k]) ** 2 / (reference[i, j, k] ** 2 + 0.01)
                   for i in range(5) for j in range(7) for k in range(3)) / (5 * 7 * 3)
    assert rel_mse(image, reference) == pytest.approx(explicit, rel=1e-12)


def test_flip_is_zero_for_equal_images_and_grows_with_the_error():
    reference = RNG.random((32, 32, 3)).astype(np.float32)
    assert flip_error(reference, reference)[0] == 0.0
    small, large = (flip_error(reference * factor, reference)[0] for factor in (1.1, 2.0))
    assert 0 < small < large <= 1


# ------------------------------------------------------------------ cache

def _write_scene(directory: Path, radius: float) -> Path:
    (directory / "tex.png").write_bytes(b"texture v1")
    scene = directory / "scene.xml"
    scene.write_text(f"""<scene version="3.0.0">
    <default name="res" value="16"/>
    <sensor type="perspective">
        <film type="hdrfilm"><integer name="width" value="$res"/>
            <integer name="height" value="$res"/></film>
    </sensor>
    <emitter type="constant"/>
    <shape type="sphere"><float name="radius" value="{radius}"/>
        <transform name="to_world"><translate z="5"/></transform>
        <bsdf type="diffuse"><texture type="bitmap" name="reflectance">
            <string name="filename" value="tex.png"/></texture></bsdf>
    </shape>
</scene>""")
    return scene


def test_scene_digest_follows_the_content(tmp_path):
    scene = _write_scene(tmp_path, 1.0)
    base = scene_digest(scene, {"res": "16"})
    (tmp_path / "unrelated.txt").write_text("not named by the scene")
    scene.touch()
    assert scene_digest(scene, {"res": "16"}) == base
    assert scene_digest(scene, {"res": "32"}) != base
    (tmp_path / "tex.png").write_bytes(b"texture v2")
    assert scene_digest(scene, {"res": "16"}) != base


def test_scene_digest_changes_with_the_scene_text(tmp_path):
    first = scene_digest(_write_scene(tmp_path, 1.0))
    second = scene_digest(_write_scene(tmp_path, 1.5))
    assert first != second
    assert scene_digest(_write_scene(tmp_path, 1.0)) == first


def test_cache_key_changes_with_the_settings_only():
    key = cache_key(scene="abc", spp=64, integrator={"type": "path", "max_depth": 32})
    assert key == cache_key(integrator={"max_depth": 32, "type": "path"}, spp=64, scene="abc")
    assert key != cache_key(scene="abc", spp=128, integrator={"type": "path", "max_depth": 32})
    assert key != cache_key(scene="abd", spp=64, integrator={"type": "path", "max_depth": 32})
    assert key != cache_key(scene="abc", spp=64, integrator={"type": "path", "max_depth": 8})


def test_second_reference_comes_from_the_cache(tmp_path):
    scene = mi.load_dict({
        "type": "scene", "emitter": {"type": "constant"},
        "sphere": {"type": "sphere", "center": [0, 0, 4], "bsdf": {"type": "diffuse"}},
        "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 24,
                                                   "height": 24}}})
    cache = ReferenceCache(tmp_path)
    first = cached_reference(cache, "key", scene, spp=512)
    second = cached_reference(cache, "key", scene, spp=512)
    assert (cache.misses, cache.hits) == (1, 1)
    assert not first.cached and second.cached
    np.testing.assert_array_equal(first.image, second.image)
    np.testing.assert_array_equal(first.variance, second.variance)
    assert_finite(first.image)
    # The spread of the passes is a real noise estimate: the sky seen past
    # the sphere is noiseless, the diffuse sphere under it is not.
    assert first.variance[0, 0].max() == 0 and first.variance[12, 12].min() > 0


@pytest.mark.parametrize("cut", [
    lambda data: b"", lambda data: data[:len(data) // 2], lambda data: data[:-1],
    lambda data: b"not an archive\n" * 8,
], ids=["empty", "half", "last-byte-cut", "other-file"])
def test_an_unreadable_cache_entry_is_computed_again(tmp_path, cut):
    """An entry cut short (a disk that failed, a copy stopped midway) or
    replaced by another file is missing, with a warning, and its new value
    replaces it."""
    cache = ReferenceCache(tmp_path)
    cache.store("key", {"image": np.arange(48.0)})
    path = cache.path("key")
    path.write_bytes(cut(path.read_bytes()))
    with pytest.warns(UserWarning, match=re.escape(f"the cache entry '{path}' cannot be read")):
        arrays = cache.get_or_compute("key", lambda: {"image": np.ones(3)})
    np.testing.assert_array_equal(arrays["image"], np.ones(3))
    assert (cache.misses, cache.hits) == (1, 0)
    np.testing.assert_array_equal(cache.get_or_compute("key", None)["image"], np.ones(3))
    assert cache.hits == 1


def test_converged_renders_are_shared_by_a_model_and_cached(tmp_path):
    """Settings that differ only in their anti-aliasing converge to one
    image, rendered once; a second comparison takes it from the cache, and
    another model or another scene is another entry."""
    scene = mi.load_dict(glass_scene(size=16))
    cache = ReferenceCache(tmp_path)
    whitted = {"none": {"aa": "none"}, "grid": {"aa": "grid", "aa_samples": 2},
               "shallow": {"aa": "none", "max_depth": 2}}
    first = converged_renders(scene, "scene a", whitted, cache, side=4)
    assert first["none"] is first["grid"] and first["none"] is not first["shallow"]
    assert (cache.misses, cache.hits) == (2, 0)
    again = converged_renders(scene, "scene a", whitted, cache, side=4)
    assert (cache.misses, cache.hits) == (2, 2) and again["none"].cached
    np.testing.assert_array_equal(again["none"].image, first["none"].image)
    converged_renders(scene, "scene b", {"none": whitted["none"]}, cache, side=4)
    assert cache.misses == 3
    # A finer grid changes it far less than the grid changed the image of
    # the pixel centres.
    finer = converged_renders(scene, "scene a", {"none": whitted["none"]}, cache, side=16)
    centres = np.asarray(mi.render(scene, integrator=mi.load_dict({"type": "whitted"})))
    assert (rel_mse(first["none"].image, finer["none"].image)
            < rel_mse(centres[..., :3], finer["none"].image) / 5)


def test_indirect_light_on_paths_model_converges_to_the_reference(tmp_path):
    """Settings whose expectation is path's image share the reference as
    their converged render; with an ambient term, another depth or tinted
    shadows the model differs from path's and is rendered."""
    scene = mi.load_dict(glass_scene(size=16))
    reference = render_reference(scene, 16, passes=2)
    cache = ReferenceCache(tmp_path)
    path_model = indirect_change(4, {"aa": "none"})
    whitted = {"ladder 4": path_model, "ladder 16": {**path_model, "indirect_samples": 16},
               "ambient": {**path_model, "ambient": {"type": "rgb", "value": [0.1, 0.1, 0.1]}},
               "shallow": {**path_model, "max_depth": 3},
               "tinted": {**path_model, "shadows": "tinted"}}
    converged = converged_renders(scene, "scene", whitted, cache, side=2, reference=reference)
    assert converged["ladder 4"] is converged["ladder 16"]
    assert converged["ladder 4"].image is reference.image
    for label in ("ambient", "shallow", "tinted"):
        assert converged[label].image is not reference.image, label
    assert cache.misses == 3


def _rungs(description: dict) -> set:
    scene = mi.load_dict(description)
    return {label for label in whitted_variants({}, False, PhotonRungs.of(scene))
            if "photons" in label}


def test_photon_rungs_only_where_the_scene_has_light_for_them():
    """No smooth surface, no light the tree leaves out: no photon rungs.
    Diffuse surfaces without a delta light through glass: the photons for
    interreflection, not those for caustics. A glass ball under a point
    light: both."""
    mirror = {"type": "conductor", "material": "none"}
    assert _rungs(scenes.scene(scenes.sphere((0, 0, 0), 1.0, mirror),
                               scenes.point_light((0, 3, 3)))) == set()
    diffuse_only = _rungs(scenes.scene(scenes.floor(), scenes.sphere((0, 0, 0), 1.0, mirror),
                                       scenes.sky()))
    assert diffuse_only == {label for label, *_ in _photon_labels(caustics=False)}
    assert all(label.startswith("photons ") for label in diffuse_only)
    both = _rungs(scenes.glass_ball_caustic(size=8))
    assert both == {label for label, *_ in _photon_labels(caustics=True)}
    assert any(label.startswith("indirect ") for label in both)


def _photon_labels(caustics: bool) -> list:
    return [(label, change) for label, change, _ in _variants({}, PhotonRungs(True, caustics))
            if change.get("photons")]


def test_photon_rungs_are_on_paths_model():
    """Every photon rung is physical at path's depth, so that it converges
    to the reference; those with indirect paths carry only the caustics."""
    for label, change in _photon_labels(caustics=True):
        assert converges_to_reference(change), label
        assert change["photons"] > 0 and change["photon_passes"] >= 1, label
        assert ("indirect_samples" in change) and (
            (change["indirect_samples"] > 0) == label.startswith("indirect")), label


# -------------------------------------------------------- compare --quick

def test_compare_quick_writes_a_consistent_report(tmp_path):
    result = cli("compare", str(REPORT_SCENE), "-D", "res=64", "--quick", "--out", str(tmp_path),
                 timeout=300)
    assert result.returncode == 0, result.stderr
    report = (tmp_path / "report.md").read_text()
    results = json.loads((tmp_path / "results.json").read_text())
    images = tmp_path / "images"
    for link in re.findall(r"\]\((images/[^)]+)\)", report):
        assert (tmp_path / link).is_file(), link
    assert (images / "speed_vs_error.png").is_file()

    reference = read_image(images / "reference.exr")
    assert reference.shape == (64, 64, 3)
    # Shown pixel for pixel, and enlarged where anti-aliasing matters.
    assert read_image(images / "aa_none.png").shape == (64, 64, 3)
    assert read_image(images / "crop_aa_none.png").shape == (192, 192, 3)
    assert_finite(reference)
    whitted = results["whitted"]
    assert set(whitted) == {"aa none", "aa grid 2x2", "aa adaptive 0.25",
                            "indirect 4, grid 2x2", "indirect 16, grid 2x2",
                            "indirect 16 + photons 10k x 4, grid 2x2"}
    assert set(results["path"]) == {"independent", "multijitter"}
    for rungs in results["path"].values():
        assert [rung["spp"] for rung in rungs] == [1, 2, 4, 8, 16]
    path = results["path"]["independent"]
    reference_figures = results["reference"]
    assert reference_figures["name"] == "path + photons (100000 photons x 8 passes)"
    assert reference_figures["name"] in report and "*Path's floor*" in report
    assert reference_figures["path_floor_rel_mse"] > 0
    assert results["levels"]["path_floor"] == reference_figures["path_floor_rel_mse"]
    for label, point in whitted.items():
        image = read_image(images / f"{point['image']}.exr")
        assert_finite(image)
        # The images are stored as float32, the report computed in float64.
        assert rel_mse(image, reference) == pytest.approx(point["rel_mse"], rel=1e-5)
        row = next(line for line in report.splitlines() if line.startswith(f"| {label} |"))
        assert f"| {number(point['rel_mse'])} / " in row
        for metric in ("relmse", "flip"):
            speedup = point["speedup"][metric]
            assert speedup["low"] <= speedup["median"] <= (speedup["high"] or np.inf)
            assert point["verdict"][metric] in ("faster", "slower", "tie")
            assert point["verdict"][metric] in row
            there = point["path_at_equal_error"][metric]["seconds"]["median"]
            assert speedup["median"] == pytest.approx(there / point["seconds"]["median"])
            if point["settings"].get("photons"):
                # Photons on path's model converge to the whole light,
                # which is the reference itself.
                assert point["model_bias"][metric] == 0
                assert point["sampling_error"][metric] == point["rel_mse" if metric == "relmse"
                                                                else "flip"]
            elif point["settings"].get("indirect_samples"):
                # Path's model: it converges to path's part of the
                # reference, which here lacks the photons' light (glass
                # under point lights): its bias is path's floor, with the
                # photons' noise that the floor leaves out.
                if metric == "relmse":
                    assert point["model_bias"][metric] == pytest.approx(
                        reference_figures["path_floor_rel_mse"]
                        + reference_figures["photons"]["noise_rel_mse"], rel=1e-9)
                else:
                    assert point["model_bias"][metric] > 0
            else:
                # A setting's sampling error is against its own converged
                # render, which shares the model's bias.
                assert point["sampling_error"][metric] < point["model_bias"][metric]
        assert point["seconds"]["low"] <= point["seconds"]["median"] <= point["seconds"]["high"]
    # Path error falls with the sample count (about as 1/spp).
    assert path[-1]["rel_mse"] < path[0]["rel_mse"] / 4
    levels = results["levels"]
    noise = results["reference"]["noise_rel_mse"]
    assert [entry["error"] for entry in levels["entries"]] == pytest.approx(error_levels(noise))
    for entry in levels["entries"]:
        assert f"| {number(entry['error'])} | " in report
        assert entry["goal"] in ("met", "missed", "undecided", "not measured")
        assert entry["path_reaches"] == (entry["error"] > levels["path_floor"])
    share = results["missing_energy_share"]
    assert 0 < share < 1 and f"{100 * share:.1f}%" in report
    # Marked as a comparison's folder, which the next comparison may rewrite.
    assert (tmp_path / FOLDER_MARK).is_file()
    assert check_report_folder(tmp_path) == tmp_path


# -------------------------------------------------------------- bad input

def _scene_file(tmp_path, body):
    path = tmp_path / "bad.xml"
    path.write_text(f'<scene version="3.0.0">{body}</scene>')
    return str(path)


@pytest.mark.parametrize("body, message", [
    (None, "scene file 'missing.xml' does not exist"),
    ('<shape type="sphere"/>', "has no sensor, so there is no image to compare"),
    ('<integrator type="nosuch"/><sensor type="perspective"/>', 'Plugin "nosuch" not found'),
    ('<sensor type="perspective"><film type="hdrfilm"><string name="pixel_format" '
     'value="luminance"/></film></sensor>',
     "develops to Y, and compare measures RGB images; give it a pixel_format of 'rgb'"),
])
def test_bad_input_to_compare_is_one_sentence(tmp_path, body, message):
    scene = "missing.xml" if body is None else _scene_file(tmp_path, body)
    result = cli("compare", scene, "--quick", "--out", str(tmp_path / "out"), timeout=300)
    assert result.returncode == 2
    assert message in one_line(result.stderr)


@pytest.mark.parametrize("spp, message", [
    ("4", "--reference-spp must be from 16 to 4294967295 (got 4)"),
    (str(2**32), f"--reference-spp must be from 16 to 4294967295 (got {2**32})"),
    (str(2**40), f"--reference-spp must be from 16 to 4294967295 (got {2**40})"),
    ("-1", "argument --reference-spp: expected a whole number of at least 1, got '-1'"),
    ("many", "argument --reference-spp: expected a whole number of at least 1, got 'many'"),
])
def test_a_reference_sample_count_out_of_range_is_one_sentence(tmp_path, spp, message):
    """Not a count, fewer samples than passes, or more than ``mi.render``'s
    32-bit count."""
    result = cli("compare", str(REPORT_SCENE), "--reference-spp", spp, "--out", str(tmp_path),
                 timeout=300)
    assert result.returncode == 2
    assert message in one_line(result.stderr)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("names", [["report.md", "results.json"], ["notes.txt"], [".keep"],
                                   ["a", "b", "c", "d", "images/x.png"]],
                         ids=["a-report", "notes", "hidden", "many"])
def test_compare_refuses_a_folder_of_the_users(tmp_path, names):
    """``--out`` into a folder that compare did not write replaced the
    user's report.md and results.json; now nothing in it changes."""
    out = tmp_path / "out"
    for name in names:
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_text(f"the user's {name}")

    def contents():
        return {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}

    before = contents()
    shown = sorted({name.split("/")[0] for name in names})
    listed = ", ".join(f"'{name}'" for name in shown[:3]) + (", ..." if len(shown) > 3 else "")
    sentence = (f"mitsuba-whitted compare: folder '{out}' holds files that compare did not "
                f"write ({listed}), which its report would replace; give --out a new or empty "
                "folder, or one that compare wrote.")
    result = cli("compare", str(REPORT_SCENE), "--quick", "-D", "res=16", "--out", str(out))
    assert result.returncode == 2
    assert one_line(result.stderr) == sentence
    with pytest.raises(CompareError) as refused:
        compare_scene(REPORT_SCENE, out, CompareOptions.make(True), {"res": "16"})
    assert str(refused.value) == sentence
    assert contents() == before
