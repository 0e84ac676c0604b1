"""`mitsuba-whitted bench --quick` runs and reports every figure, and its
memory figures are the measured process's own.

No timing is asserted here: speed targets live in the benchmark itself."""

import json
import statistics

import numpy as np
import pytest

from conftest import cli
from mitsuba_whitted.bench.equal_error import HEADLINE
from validation.scenes import ROOT


def test_bench_quick_writes_every_figure(tmp_path):
    out = tmp_path / "bench.json"
    result = cli("bench", "--quick", "--json", str(out))
    assert result.returncode == 0, result.stderr
    figures = json.loads(out.read_text())
    for key in ("machine", "headline", "fresh_process", "fresh_process_empty_cache",
                "peak_rss_mib", "scaling", "equal_error", "gradient"):
        assert key in figures, key
    scene = figures["headline"]
    for key in ("timing", "rays", "rays_per_second", "bound", "split"):
        assert key in scene, key
    rays = scene["rays"]
    assert rays["total"] == sum(rays[k] for k in ("camera", "reflection", "refraction",
                                                    "passthrough", "shadow", "shadow_march"))
    bound = scene["bound"]
    assert bound["rays"]["ray_intersect"] == (rays["camera"] + rays["reflection"]
                                              + rays["refraction"] + rays["passthrough"])
    # The bound casts the render's own rays, the shadow rays and the
    # queries that march blocked ones through the tinted glass among them.
    assert (bound["rays"]["ray_test"], bound["rays"]["shadow_march"]) == (rays["shadow"],
                                                                          rays["shadow_march"])
    assert rays["shadow_march"] > 0
    assert 0 < bound["ratio"] == statistics.median(bound["ratios"])
    assert bound["render_seconds"] > 0 and len(bound["ratios"]) >= 2
    for cast in ("ray_intersect", "ray_test", "shadow_march"):
        assert bound["seconds_by_cast"][cast] > 0 and isinstance(bound["coherent"][cast], bool)
    assert bound["seconds"] == sum(bound["seconds_by_cast"][cast] for cast in
                                   ("ray_intersect", "ray_test", "shadow_march"))
    split = scene["split"]
    assert split["first_samples"] == 4 * 96 * 96  # the first adaptive level
    assert split["launches"] >= 2 and split["frozen_call_seconds"] > 0
    for part in ("first", "rest"):
        assert split[f"{part}_seconds"] > 0 and split[f"{part}_bound"] > 0
        assert split[f"{part}_ratio"] == statistics.median(split[f"{part}_ratios"]) > 0
    assert {row["parameter"] for row in figures["scaling"]} == {"res", "max_depth", "aa_max_depth"}
    assert all(row["seconds"]["median"] > 0 for row in figures["scaling"])
    assert all(mib > 0 for mib in figures["peak_rss_mib"].values())
    warm = scene["timing"]["warm"]
    assert 0 < warm["low"] <= warm["median"] <= warm["high"]
    equal_error = figures["equal_error"]
    assert len(equal_error["settings"]) > 1
    headline = next(row for row in equal_error["settings"] if row["whitted"] == HEADLINE)
    for metric in ("relmse", "flip"):
        assert headline["speedup"][metric]["median"] > 0
        assert headline["verdict"][metric] in ("faster", "slower", "tie")
    gradient = figures["gradient"]
    timing = gradient["timing"]
    assert timing["parameters"] > 0 and timing["replay"] == "tree"
    # The replay walks the render's trees, and traces some nodes again.
    assert timing["replay_rays"]["walked"] == timing["render_rays"] > 0
    assert 0 < timing["replay_rays"]["walked again"] < timing["render_rays"]
    assert 0 < timing["ratio"]["low"] <= timing["ratio"]["median"] <= timing["ratio"]["high"]
    assert timing["ratio"]["median"] == pytest.approx(
        timing["gradient_s"]["median"] / timing["render_s"]["median"])
    assert all(mib > 0 for mib in gradient["peak_rss_mib"].values())
    assert gradient["equal_error"]["prb"][0]["rel_error"] > 0
    table = result.stdout
    assert "bound / actual" in table and "equal-error speed-up" in table
    assert "gradient at equal error against prb" in table
    assert "first camera launch" in table and "a frozen call's fixed cost" in table


def test_the_first_launch_ends_after_its_camera_samples():
    """A launch traces its camera rays in parts, each part's generations
    in turn: the first launch's batches end where a generation 0 starts
    after all its samples."""
    from mitsuba_whitted.bench.bound import first_launch_end

    class Batch:
        def __init__(self, generation, n):
            self.generation, self.rays = generation, range(n)

    captured = [Batch(0, 6), Batch(1, 4), Batch(0, 4), Batch(1, 2), Batch(2, 1),
                Batch(0, 8), Batch(1, 3), Batch(0, 8)]
    assert first_launch_end(captured, 10) == 5
    assert first_launch_end(captured, 6) == 2
    assert first_launch_end(captured[:5], 10) == 5  # a single launch: all of it


def test_a_child_reports_its_own_peak_memory_not_its_parents():
    """Linux's ru_maxrss of a child starts at its parent's resident size:
    with 1 GiB resident here, a small render in a child must still read
    small."""
    from mitsuba_whitted.bench import DEFAULT_SCENE
    from mitsuba_whitted.bench.processes import child_peak_memory, peak_rss_mib
    resident = np.ones(2 ** 27)  # 1 GiB, touched
    assert peak_rss_mib() > 1024
    child = child_peak_memory(DEFAULT_SCENE, {"aa": "none"}, {"res": 16})
    assert 0 < child < 1024
    del resident


def test_bench_sweeps_a_scene_that_declares_no_parameters():
    """The mirror chain names neither its depth nor its anti-aliasing depth
    as $-parameters: the sweeps must still set them (a define would be an
    unused parameter, which Mitsuba refuses)."""
    from dataclasses import replace
    from mitsuba_whitted.bench import BenchSettings, run
    settings = replace(BenchSettings.quick(ROOT / "scenes" / "cases" / "mirror_chain.xml"),
                       fresh_processes=False)
    figures = run(settings, report=lambda line: None)
    assert figures.headline.resolution == [96, 96]
    rays = {(row.parameter, row.value): row.rays for row in figures.scaling}
    # Four times the pixels, about four times the rays; deeper trees, more rays.
    assert 3.5 < rays["res", 128] / rays["res", 64] < 4.5
    assert rays["max_depth", 6] > rays["max_depth", 2]


def _bound_of(description):
    """The bound of a one-generation render, its ray counts and how many
    camera rays hit."""
    import drjit as dr
    import mitsuba as mi
    from mitsuba_whitted.bench.bound import ray_casting_bound
    loaded = mi.load_dict(description)
    whitted = loaded.integrator()
    whitted.capture_rays = True
    mi.render(loaded)
    whitted.capture_rays = False
    first = whitted.last_rays[0]
    assert first.generation == 0
    hits = dr.count(loaded.ray_intersect(mi.Ray3f(first.rays.o, first.rays.d)).is_valid())[0]
    bound = ray_casting_bound(loaded, whitted.last_rays, lambda: mi.render(loaded), 2)
    return bound, whitted.last_stats, hits


def test_the_bound_of_a_light_no_hit_can_see():
    """A light under the floor adds no shadow ray (the floor faces away
    from it): its part of the replay is empty, next to the other light's."""
    from validation.scenes import camera, floor, integrator, point_light, scene
    description = scene(floor(), point_light((0, 3, 0)), point_light((0, -3, 0)),
                        sensor=camera(origin=(0, 2, 4), size=16), whitted=integrator())
    bound, stats, hits = _bound_of(description)
    assert 0 < hits < 16 * 16
    assert bound.rays["ray_test"] == stats["shadow"] == hits
    assert bound.seconds_by_cast["ray_test"] > 0


def test_the_bound_of_a_scene_without_shadow_rays():
    """Only a mirror under an environment: nothing to test, nothing to
    march (casting an empty batch would abort the process)."""
    from validation.scenes import camera, integrator, scene, sphere
    description = scene(sphere((0, 0, 0), 1.0, {"type": "conductor"}),
                        sensor=camera(size=16), whitted=integrator(),
                        env={"type": "constant"})
    bound, stats, hits = _bound_of(description)
    assert hits > 0
    assert stats["shadow"] == bound.rays["ray_test"] == bound.rays["shadow_march"] == 0
    assert bound.seconds_by_cast["ray_test"] == 0 and bound.seconds > 0


def test_a_scene_with_indirect_paths_counts_their_rays_and_says_what_is_not_measured():
    """The capture records the tree's rays only, so no bound is computed
    from it, and a sentence says why; the indirect paths' rays are counted
    with the rest."""
    from mitsuba_whitted.bench import BenchSettings
    from mitsuba_whitted.bench.suite import INDIRECT_UNCAPTURED, headline
    from validation.scenes import GLASS_BOX
    figures = headline(GLASS_BOX, BenchSettings.quick(GLASS_BOX), report=lambda line: None)
    assert figures.indirect_samples == 4
    assert figures.bound is None and figures.split is None
    assert figures.not_measured == {"bound": INDIRECT_UNCAPTURED}
    rays = figures.rays
    assert rays["indirect"] > rays["camera"] and rays["indirect_shadow"] > 0
