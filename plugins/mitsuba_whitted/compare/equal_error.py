"""Path's time to reach an error: its curves, the lower envelope of its
samplers' curves, and the equal-error speed-up of a Whitted setting.

A curve is one sampler's ladder of renders (1, 2, 4, ... spp), each with
its time and error. On log-log axes it is close to a line between two
rungs (error falls about as 1/spp, time grows about as spp), so the time
at an error between two rungs is interpolated there. An error its first
rung already beats, or its last rung never reaches, gives a bound. Every
function here takes arrays with one row per bootstrap replicate (see
:mod:`.intervals`), so that the interpolation's own uncertainty, from the
times and errors of the rungs, enters the interval.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .intervals import Estimate, bounded, quotient, spread
from .sweep import Sweep, SweepPoint


@dataclass
class Reach:
    """Where a curve reaches an error, one entry per replicate: in
    ``low`` to ``high`` seconds, with ``spp_low`` to ``spp_high`` samples
    per pixel. The ends are equal where the error lies on the curve; the
    lower ones are 0 where the curve's first rung already beats it, the
    upper ones infinite where its last rung does not reach it. ``curve``:
    the index of the curve the figures come from (of an envelope's)."""

    low: np.ndarray
    high: np.ndarray
    spp_low: np.ndarray
    spp_high: np.ndarray
    curve: np.ndarray


def reach(errors: np.ndarray, times: np.ndarray, spp: np.ndarray, target: np.ndarray,
          curve: int = 0) -> Reach:
    """Where the curve of rungs with ``errors`` and ``times`` (replicates x
    rungs, the rungs in the order of ``spp``) first reaches ``target``
    (one error per replicate): interpolated in log time and log spp
    against log error between that rung and the one before."""
    rows = np.arange(len(target))
    below = errors <= target[:, None]
    found = below.any(axis=1)
    upper = np.clip(np.argmax(below, axis=1), 1, errors.shape[1] - 1)
    lower = upper - 1
    seconds, samples = _interpolated(errors[rows, lower], errors[rows, upper], target,
                                     (times[rows, lower], times[rows, upper]),
                                     (spp[lower], spp[upper]))
    before = errors[:, 0] <= target
    beyond = ~found
    return Reach(np.where(before, 0.0, np.where(beyond, times[:, -1], seconds)),
                 np.where(before, times[:, 0], np.where(beyond, np.inf, seconds)),
                 np.where(before, 0.0, np.where(beyond, spp[-1], samples)),
                 np.where(before, spp[0], np.where(beyond, np.inf, samples)),
                 np.full(len(target), curve))


def _interpolated(error_a, error_b, target, *pairs):
    """Each of ``pairs`` ((a, b) arrays) interpolated in log-log against
    the error, from ``error_a`` at a to ``error_b`` at b, at ``target``;
    b itself where the curve does not fall between the two rungs."""
    # Targets beyond the rungs give shares far from [0, 1], whose values
    # overflow and which the caller replaces with bounds.
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        share = np.where(error_a > error_b,
                         np.log(error_a / target) / np.log(error_a / error_b), 1.0)
        return [np.exp(np.log(a) + share * (np.log(b) - np.log(a))) for a, b in pairs]


def envelope(reaches: list[Reach]) -> Reach:
    """The lower envelope of several curves: at each error the least time
    any of them needs, with the spp of the curve that gives it (where
    none reaches the error, the one that comes closest in time)."""
    low = np.min([r.low for r in reaches], axis=0)
    high = np.min([r.high for r in reaches], axis=0)
    highs = np.array([r.high for r in reaches])
    key = np.where(np.isinf(highs).all(axis=0), [r.low for r in reaches], highs)
    pick = np.argmin(key, axis=0)
    columns = np.arange(len(low))
    return Reach(low, high, np.array([r.spp_low for r in reaches])[pick, columns],
                 np.array([r.spp_high for r in reaches])[pick, columns],
                 np.array([r.curve for r in reaches])[pick, columns])


@dataclass
class Gain:
    """The equal-error speed-up of one Whitted setting in one metric:
    path's time (and spp) to reach the setting's error, on the faster of
    its samplers' curves there (``sampler``), over the setting's time.
    Path's time and its interval come from the bootstrap, which draws the
    setting's tiles with those of path's images and so carries the
    uncertainty of both errors and of the interpolation; the speed-up's
    interval is as wide as the intervals of path's time and of the
    setting's time allow together (:func:`.intervals.quotient`)."""

    speedup: Estimate
    path_seconds: Estimate
    path_spp: Estimate
    sampler: str


@dataclass
class Analysis:
    """Each setting's time, and each Whitted setting's gain in each metric
    (by label), with their intervals."""

    seconds: dict
    gains: dict

    def crossing(self, sweep: Sweep, metric: str) -> tuple[SweepPoint, Gain]:
        """Where path's curve reaches the most accurate Whitted setting in
        ``metric``: beyond that time, path is more accurate than every
        Whitted setting."""
        best = min(sweep.of_kind("whitted"), key=lambda p: p.error(metric))
        return best, self.gains[best.label][metric]


def analyse(sweep: Sweep) -> Analysis:
    """Times and equal-error speed-ups, from one bootstrap over the sweep's
    rounds and tiles (the first row of each array is the estimate from all
    of them)."""
    times = replicated_times(sweep)
    seconds = time_estimates(sweep, times)
    gains = {p.label: {} for p in sweep.of_kind("whitted")}
    for metric in sweep.metrics:
        errors = replicated_errors(sweep, metric)
        for index, point in enumerate(sweep.points):
            if point.kind == "whitted":
                gains[point.label][metric] = _gain(sweep, errors, times, index,
                                                   seconds[point.label])
    return Analysis(seconds, gains)


def time_estimates(sweep: Sweep, times: np.ndarray | None = None) -> dict:
    """Each point's median time over the rounds with its interval, by
    label (``times``: :func:`replicated_times`, when already drawn)."""
    times = replicated_times(sweep) if times is None else times
    return {p.label: spread(times[0, i], times[1:, i]) for i, p in enumerate(sweep.points)}


def replicated_times(sweep: Sweep) -> np.ndarray:
    """Every point's median time (replicates x points), the first row from
    all the rounds, the others from the bootstrap's draws."""
    return _with_estimate(np.median(sweep.times, axis=0), sweep.draws.medians(sweep.times))


def replicated_errors(sweep: Sweep, metric: str) -> np.ndarray:
    """Every point's mean error in ``metric`` (replicates x points), the
    first row from all the pixels, the others from the drawn tiles."""
    sums = np.array([p.tiles[metric] for p in sweep.points])
    pixels = sweep.tile_pixels(metric)
    return _with_estimate(sums.sum(axis=1) / pixels.sum(), sweep.draws.means(sums, pixels))


def _with_estimate(estimate: np.ndarray, replicates: np.ndarray) -> np.ndarray:
    return np.concatenate([estimate[None], replicates])


def _gain(sweep: Sweep, errors: np.ndarray, times: np.ndarray, index: int,
          own: Estimate) -> Gain:
    """Point ``index``'s gain: ``errors`` and ``times`` are replicates x
    points, ``own`` the point's time."""
    found = path_reach(sweep, errors, times, errors[:, index])
    path = bounded(found.low[0], found.high[0], found.low[1:], found.high[1:])
    return Gain(quotient(path, own), path,
                bounded(found.spp_low[0], found.spp_high[0], found.spp_low[1:],
                        found.spp_high[1:]),
                sweep.path_curves()[found.curve[0]][0])


def path_reach(sweep: Sweep, errors: np.ndarray, times: np.ndarray,
               target: np.ndarray) -> Reach:
    """Where the envelope of path's curves reaches ``target`` (one error
    per replicate); ``errors`` and ``times`` are replicates x points."""
    return envelope([reach(errors[:, columns], times[:, columns], spp, target, number)
                     for number, (_, columns, spp) in enumerate(sweep.path_curves())])
