"""Speed at equal error, level by level: the levels themselves, the
Whitted family's curves, and the speed-up at each level.

Oracles: power-law curves, on which log-log interpolation is exact, so
that a ladder four times cheaper than path's at every error must give a
speed-up of exactly 4 at every level; closed forms for the levels."""

import math

import numpy as np
import pytest

from mitsuba_whitted.compare import Setting, Sweep, SweepPoint
from mitsuba_whitted.compare.intervals import Draws, json_data, tile_pixels
from mitsuba_whitted.compare.levels import (GOAL, NOISE_MULTIPLE, TOP_LEVEL, analyse_levels,
                                            error_levels, family_curves, goal_summary)
from mitsuba_whitted.compare.metrics import TILE_SIDES
from mitsuba_whitted.compare.results import LevelEntry

SIZE = (16, 16)
SPP = (1, 2, 4, 8, 16, 32, 64)
#: Path's curve: relMSE 0.1/spp at 10 ms per spp.
PATH_ERROR, PATH_SECONDS = 0.1, 0.01


def _point(label, kind, seconds, error, spp=0, integrator=None) -> SweepPoint:
    tiles = {metric: error * tile_pixels(*SIZE, side) for metric, side in TILE_SIDES.items()}
    return SweepPoint(Setting(label, kind, integrator or {}, spp,
                              "independent" if kind == "path" else None),
                      0.0, np.full(5, seconds), None, error, error, error, tiles)


def _ladder(paths, error_scale, seconds_per_path) -> list[SweepPoint]:
    return [_point(f"indirect {n}", "whitted", seconds_per_path * n, error_scale / n,
                   integrator={"type": "whitted", "aa": "grid", "indirect_samples": n})
            for n in paths]


def _sweep(whitted: list[SweepPoint]) -> Sweep:
    path = [_point(f"path {n}", "path", PATH_SECONDS * n, PATH_ERROR / n, n) for n in SPP]
    return Sweep(whitted + path, SIZE, Draws.make(5, replicates=200))


def test_levels_run_from_the_top_down_to_three_times_the_noise():
    levels = error_levels(1e-4)
    assert levels[0] == TOP_LEVEL and levels[-1] == pytest.approx(NOISE_MULTIPLE * 1e-4)
    ratios = np.array(levels[:-1]) / np.array(levels[1:-1] + [math.nan])
    np.testing.assert_allclose(ratios[:-1], math.sqrt(10))
    # 3e-2 down to 3e-4: two decades, two levels each, and the floor.
    assert len(levels) == 5
    assert error_levels(0.02) == []


def test_a_ladder_is_one_curve_and_other_settings_stand_alone():
    alone = _point("aa none", "whitted", 0.001, 0.05, integrator={"type": "whitted"})
    ladder = _ladder((16, 4, 64), 0.1, 0.001)
    # A setting with indirect paths and no other rung is no ladder.
    single = _point("indirect 4, deeper", "whitted", 0.001, 0.05,
                    integrator={"type": "whitted", "max_depth": 40, "indirect_samples": 4})
    curves = family_curves(_sweep([alone] + ladder + [single]), {"indirect 64": 1e-5})
    assert [c.columns for c in curves] == [[0], [2, 1, 3], [4]]
    assert list(curves[1].paths) == [4, 16, 64] and not curves[2].ladder
    # A ladder's bias is its last rung's model's.
    assert [c.bias for c in curves] == [0, 1e-5, 0]


def test_a_ladder_four_times_cheaper_is_four_times_faster_at_every_level():
    # The same errors as path's at a quarter of the time per sample.
    sweep = _sweep(_ladder((1, 4, 16, 64), PATH_ERROR, PATH_SECONDS / 4))
    levels = analyse_levels(sweep, noise=PATH_ERROR / 64 / NOISE_MULTIPLE)
    assert len(levels) == 4
    for level in levels:
        assert level.speedup.median == pytest.approx(4)
        assert level.speedup.low == pytest.approx(4) and level.verdict == "faster"
        assert level.goal == "met"
        assert level.paths == pytest.approx(PATH_ERROR / level.error)
    assert goal_summary(levels).met_at_every_level


def test_a_setting_reaches_a_level_at_its_own_time_when_it_is_below_it():
    # One classic setting, far more accurate than it needs to be for the
    # top level, is charged its own time there, not an interpolated one.
    classic = _point("grid 8x8", "whitted", 0.05, 1e-3, integrator={"type": "whitted"})
    level = analyse_levels(_sweep([classic]), noise=1e-3)[0]
    assert level.setting == "grid 8x8" and level.whitted.median == pytest.approx(0.05)
    # Path reaches 3e-2 at 10/3 spp: 33 ms, so the setting is slower.
    assert level.path.median == pytest.approx(PATH_SECONDS * PATH_ERROR / TOP_LEVEL)
    assert level.verdict == "slower" and level.goal == "missed"


def test_a_level_below_every_models_bias_is_out_of_reach():
    # A classic setting whose model errs 2e-2 cannot reach 1e-2 with any
    # number of samples.
    biased = _point("aa none", "whitted", 0.001, 2e-2, integrator={"type": "whitted"})
    levels = analyse_levels(_sweep([biased]), noise=1e-3, biases={"aa none": 2e-2})
    below = [level for level in levels if level.error < 2e-2]
    assert below
    for level in below:
        assert level.setting is None and level.whitted.relation == ">"
        assert math.isinf(level.whitted.median)
        assert level.speedup.high == 0 and level.verdict == "slower" and level.goal == "missed"
        assert json_data(LevelEntry.of(level))["whitted"]["seconds"]["median"] is None
    assert not goal_summary(levels).met_at_every_level


def test_a_level_above_a_models_bias_takes_more_than_the_setting():
    # The same setting, its error all sampling (a bias of 1e-4): more
    # samples would reach 1e-2, in more than its 1 ms.
    noisy = _point("aa none", "whitted", 0.001, 2e-2, integrator={"type": "whitted"})
    level = [level for level in analyse_levels(_sweep([noisy]), noise=1e-3,
                                               biases={"aa none": 1e-4})
             if level.error < 2e-2][0]
    assert level.whitted.relation == ">" and level.whitted.median == pytest.approx(0.001)
    path_seconds = PATH_SECONDS * PATH_ERROR / level.error
    assert level.speedup.relation == "<"
    assert level.speedup.median == pytest.approx(path_seconds / 0.001)


def test_a_ladder_that_stops_short_takes_more_than_its_last_rung():
    # Its last rung errs 0.1/16 at 1.6 ms; 1e-3 would take it more paths.
    ladder = _ladder((4, 16), PATH_ERROR, PATH_SECONDS / 10)
    level = [level for level in analyse_levels(_sweep(ladder), noise=2e-4)
             if level.error < PATH_ERROR / 16][0]
    assert level.setting is None and level.whitted.relation == ">"
    assert level.whitted.median == pytest.approx(16 * PATH_SECONDS / 10)
    # Path reaches it at 0.1/error spp; the speed-up is at most path's time
    # over the last rung's.
    path_seconds = PATH_SECONDS * PATH_ERROR / level.error
    assert level.path.median == pytest.approx(path_seconds)
    assert level.speedup.relation == "<"
    assert level.speedup.median == pytest.approx(path_seconds / (16 * PATH_SECONDS / 10))


def test_a_level_neither_reaches_is_not_measured():
    biased = _point("aa none", "whitted", 0.001, 2e-2, integrator={"type": "whitted"})
    # Path's last rung reaches 0.1/64 = 1.6e-3; the floor is 3e-4.
    levels = analyse_levels(_sweep([biased]), noise=1e-4, biases={"aa none": 2e-2})
    assert levels[-1].speedup is None
    assert levels[-1].verdict == levels[-1].goal == "not measured"
    assert GOAL == 2.0


def test_levels_below_paths_floor_read_as_never_reached():
    """Against a reference with light path cannot find, path's error stops
    at its floor: the levels at or below it say path never reaches them,
    with no time extrapolated from its curves, and the levels above are as
    without a floor; results.json carries it."""
    ladder = _ladder((1, 4, 16, 64), PATH_ERROR, PATH_SECONDS / 4)
    noise = PATH_ERROR / 64 / NOISE_MULTIPLE
    plain = analyse_levels(_sweep(ladder), noise=noise)
    floor = 4e-3
    levels = analyse_levels(_sweep(ladder), noise=noise, path_floor=floor)
    assert [level.error for level in levels] == [level.error for level in plain]
    below = [level for level in levels if level.error <= floor]
    assert below and len(below) < len(levels)
    for level, before in zip(levels, plain):
        if level.error > floor:
            assert level.path_reaches and level.speedup == before.speedup
            continue
        assert not level.path_reaches and level.speedup is None
        assert level.verdict == "path never reaches" and math.isinf(level.path.median)
        # The ladder still reaches it, which path never does.
        assert level.setting is not None and level.goal == "met"
    entry = json_data(LevelEntry.of(below[0]))
    assert entry["path_reaches"] is False and entry["path"]["seconds"]["median"] is None
    assert entry["verdict"] == "path never reaches" and entry["speedup"] is None
    # No floor (a path reference) leaves every level as it was.
    assert all(level.path_reaches for level in plain)
