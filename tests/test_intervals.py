"""The speed comparison's arithmetic: path's time at an error, the
envelope of its curves, the bootstrap's intervals and the verdicts.

Oracles: a power-law path curve, on which log-log interpolation is exact;
closed forms for the bootstrap of a mean and for a speed-up measured
without noise; the coverage of a median's interval over many synthetic
data sets drawn from a known distribution."""

import math

import numpy as np
import pytest

from mitsuba_whitted.compare import (Estimate, Setting, Sweep, SweepPoint, analyse, envelope,
                                     estimate_text, reach, verdict)
from mitsuba_whitted.compare.intervals import (Draws, json_data, median_estimate, quotient,
                                               tile_pixels, tile_sums)
from mitsuba_whitted.compare.metrics import TILE_SIDES
from mitsuba_whitted.compare.sweep import round_order

SPP = np.array([1.0, 2, 4, 8, 16])
#: Path's power law: relMSE 1/spp at 10 ms per spp.
SECONDS_PER_SPP = 0.01


def power_law(rows: int, error_scale: float = 1.0, time_scale: float = 1.0):
    """Errors and times of a path curve, the same in ``rows`` replicates."""
    return (np.tile(error_scale / SPP, (rows, 1)),
            np.tile(time_scale * SECONDS_PER_SPP * SPP, (rows, 1)))


# -------------------------------------------------------- equal-error time

def test_reach_interpolates_a_power_law_exactly():
    # On log-log axes a power law is a line, so interpolation is exact.
    spp = np.array([1.5, 3.0, 5.657, 8.0, 12.5, 16.0])
    found = reach(*power_law(len(spp)), SPP, 1 / spp)
    for ends in (found.spp_low, found.spp_high):
        np.testing.assert_allclose(ends, spp, rtol=1e-12)
    for ends in (found.low, found.high):
        np.testing.assert_allclose(ends, SECONDS_PER_SPP * spp, rtol=1e-12)


def test_an_error_outside_the_curve_is_a_bound():
    found = reach(*power_law(2), SPP, np.array([2.0, 1e-3]))
    # Its first rung already beats 2: at most 1 spp, 10 ms.
    assert (found.low[0], found.high[0], found.spp_low[0], found.spp_high[0]) == (0, 0.01, 0, 1)
    # Its last rung does not reach 1e-3: at least 16 spp, 160 ms.
    assert (found.low[1], found.high[1], found.spp_low[1], found.spp_high[1]) == (
        pytest.approx(0.16), math.inf, 16, math.inf)


def test_the_envelope_takes_the_faster_curve_at_each_error():
    # The second sampler costs twice as much per spp with a quarter of the
    # error: 1/8 takes the first 8 spp (80 ms), the second 2 spp (40 ms).
    targets = np.array([1 / 8, 1e-3])
    curves = [reach(*power_law(2), SPP, targets, 0),
              reach(*power_law(2, 0.25, 2.0), SPP, targets, 1)]
    found = envelope(curves)
    assert found.low[0] == found.high[0] == pytest.approx(0.04)
    assert (found.spp_high[0], found.curve[0]) == (pytest.approx(2), 1)
    # Neither reaches 1e-3: at least the sooner of their last rungs.
    assert (found.low[1], found.high[1], found.curve[1]) == (pytest.approx(0.16), math.inf, 0)


# ---------------------------------------------------------------- verdicts

@pytest.mark.parametrize("estimate, expected", [
    (Estimate(4.1, 3.6, 4.7), "faster"),
    (Estimate(0.5, 0.4, 0.6), "slower"),
    (Estimate(1.1, 0.9, 1.3), "tie"),
    # Bounds give a verdict where all of the interval lies on one side.
    (Estimate(0.8, 0.0, 0.9, "<"), "slower"),
    (Estimate(3.0, 0.0, 3.4, "<"), "tie"),
    (Estimate(2.0, 1.5, math.inf, ">"), "faster"),
    (Estimate(0.5, 0.4, math.inf, ">"), "tie"),
])
def test_a_verdict_needs_the_whole_interval_on_one_side_of_1(estimate, expected):
    assert verdict(estimate) == expected


def test_estimates_are_written_with_their_interval_and_bound():
    assert estimate_text(Estimate(4.1, 3.6, 4.7), "x") == "4.1x (3.6-4.7)"
    assert estimate_text(Estimate(3.0, 0.0, 3.4, "<"), "x") == "< 3x (0-3.4)"
    assert estimate_text(Estimate(2.0, 1.5, math.inf, ">"), "x") == "> 2x (1.5-∞)"
    bound = Estimate(2.0, 1.5, math.inf, ">")
    assert json_data(bound) == {"median": 2.0, "low": 1.5, "high": None, "relation": ">"}


def test_a_quotient_spans_both_intervals():
    assert quotient(Estimate(6, 4, 9), Estimate(2, 1, 3)) == Estimate(3, 4 / 3, 9)
    assert quotient(Estimate(6, 0, 9, "<"), Estimate(2, 1, 3)).low == 0


# ---------------------------------------------------------------- bootstrap

def test_the_interval_of_a_median_covers_it_about_as_often_as_it_claims():
    # 300 data sets of 9 rounds (as the report times) from a log-normal
    # whose median is 1.
    samples = np.random.default_rng(5).lognormal(0.0, 0.2, size=(300, 9))
    covered = [e.low <= 1.0 <= e.high for e in map(median_estimate, samples)]
    assert 0.9 <= np.mean(covered) <= 0.995


def test_drawn_tiles_spread_a_mean_as_the_closed_form_says():
    # The bootstrap variance of a mean of T values is their variance
    # (divided by T, not T - 1) over T.
    values = np.random.default_rng(7).normal(1.0, 0.3, size=400)
    replicates = Draws.make(5).means(values[None], np.ones(400))[:, 0]
    assert np.std(replicates) == pytest.approx(np.std(values) / math.sqrt(400), rel=0.05)
    assert np.mean(replicates) == pytest.approx(np.mean(values), rel=1e-3)


def test_tiles_hold_every_pixel_once():
    values = np.arange(10 * 13, dtype=float).reshape(10, 13)
    sums, pixels = tile_sums(values, 4), tile_pixels(10, 13, 4)
    assert sums.sum() == values.sum() and pixels.sum() == 130
    assert len(sums) == len(pixels) == 3 * 4
    assert pixels[0] == 16 and pixels[-1] == 2  # a full tile; the corner's 2 x 1


def test_rounds_alternate_kinds_in_an_order_that_changes():
    kinds = ["whitted"] * 3 + ["path"] * 5
    orders = [round_order(kinds, index) for index in range(6)]
    for order in orders:
        assert sorted(order) == list(range(8))
        assert [kinds[i] for i in order[:6]] == ["whitted", "path"] * 3
    assert len({tuple(order) for order in orders}) > 1
    assert orders == [round_order(kinds, index) for index in range(6)]


# ----------------------------------------------------------- synthetic sweeps

SIZE = (16, 16)


def _point(label: str, kind: str, seconds, error: float, spp: int = 0) -> SweepPoint:
    """A point whose images err by ``error`` at every pixel, in both metrics."""
    tiles = {metric: error * tile_pixels(*SIZE, side) for metric, side in TILE_SIDES.items()}
    return SweepPoint(Setting(label, kind, {}, spp, "independent" if spp else None), 0.0,
                      np.asarray(seconds, dtype=float), None, error, error, error, tiles)


def _sweep(whitted: dict, rounds: int = 5, noise=None) -> Sweep:
    """Path's power law, and ``whitted`` (label: (seconds, error)); each
    time of each round multiplied by ``noise(rounds)`` if given."""
    def times(seconds):
        return seconds * (noise(rounds) if noise else np.ones(rounds))

    points = [_point(label, "whitted", times(seconds), error)
              for label, (seconds, error) in whitted.items()]
    points += [_point(f"path {n}", "path", times(SECONDS_PER_SPP * n), 1 / n, int(n))
               for n in SPP]
    return Sweep(points, SIZE, Draws.make(rounds))


def test_a_sweep_without_noise_gives_the_exact_speedup():
    # relMSE 1/6 takes path 6 spp, 60 ms: 3 times Whitted's 20 ms.
    sweep = _sweep({"faster": (0.02, 1 / 6), "slower": (0.05, 1 / 1.5),
                    "beyond": (1.0, 1e-3), "before": (0.001, 2.0)})
    gains = analyse(sweep).gains
    for metric in TILE_SIDES:
        assert gains["faster"][metric].speedup == Estimate(pytest.approx(3), pytest.approx(3),
                                                           pytest.approx(3))
        assert gains["faster"][metric].path_spp.median == pytest.approx(6)
        assert verdict(gains["faster"][metric].speedup) == "faster"
        assert gains["slower"][metric].speedup.median == pytest.approx(0.3)
        assert verdict(gains["slower"][metric].speedup) == "slower"
        # Bounds: at least 160 ms over 1 s; at most 10 ms over 1 ms.
        beyond, before = gains["beyond"][metric].speedup, gains["before"][metric].speedup
        assert (beyond.relation, beyond.median, beyond.high) == (">", pytest.approx(0.16),
                                                                 math.inf)
        assert (before.relation, before.median, before.low) == ("<", pytest.approx(10), 0)
        assert verdict(beyond) == verdict(before) == "tie"


def test_noisy_times_widen_the_interval_around_the_truth_and_repeat_exactly():
    def noise(rounds, generator=np.random.default_rng(11)):
        return generator.lognormal(0.0, 0.05, size=rounds)

    sweep = _sweep({"faster": (0.02, 1 / 6)}, rounds=9, noise=noise)
    speedup = analyse(sweep).gains["faster"]["relmse"].speedup
    assert speedup.low < 3 < speedup.high < 1.5 * speedup.low
    assert analyse(sweep).gains["faster"]["relmse"].speedup == speedup
