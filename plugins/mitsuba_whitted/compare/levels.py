"""Speed at equal error, level by level: for each error from
:data:`TOP_LEVEL` down to :data:`NOISE_MULTIPLE` times the reference's own
noise, the time the Whitted family needs to reach it against the time
``path`` needs.

Whitted's family is every Whitted setting of a sweep. Two or more settings
that differ only in their indirect paths per pixel form a ladder, read like one of
path's curves (interpolated in log-log between its rungs: a user may ask
for any count); every other setting stands alone and reaches an error at
its own time when its error is at most that. The family's time at a level
is the least of these, the time of the cheapest way this package offers
to render the scene at that error. Path's time is the envelope of its
samplers' curves (:func:`.equal_error.path_reach`). Both come from the
sweep's bootstrap, so each carries its interval, and the speed-up spans
both (:func:`.intervals.quotient`).

An error that no Whitted setting reaches within the sweep leaves the
family's time open above: more samples of a setting (more paths, finer
anti-aliasing) would take more than its time, and could not reach an
error below its model's bias at all, since they converge to the model.
The speed-up is then bounded above (0 where no setting's model allows the
error). An error that path's largest rung does not reach leaves path's
time open above, and the speed-up bounded below; where neither reaches
it, nothing is measured.

Where the reference has light that ``path`` cannot find
(:mod:`.photon_reference`), ``path``'s error never falls below its floor,
the relMSE of ``path`` alone against the reference: at a level at or
below it, no number of samples gets there, and the level says so
(:attr:`Level.path_reaches` false, path's time infinite) instead of
extrapolating path's curves.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace

import numpy as np

from .equal_error import (Reach, envelope, path_reach, reach, replicated_errors,
                          replicated_times)
from .intervals import Estimate, bounded, quotient, verdict
from .sweep import Sweep

#: The least accurate level, and the lowest as a multiple of the
#: reference's own noise (an image's error against the reference holds
#: that noise too, so levels near 1x would measure the reference).
TOP_LEVEL, NOISE_MULTIPLE = 3e-2, 3.0
#: Levels between the two, evenly spaced on a log scale.
LEVELS_PER_DECADE = 2
#: The speed-up the family aims for at every level.
GOAL = 2.0
#: The metric the levels are measured in.
LEVEL_METRIC = "relmse"
#: What a level below path's floor says of path.
PATH_NEVER = "path never reaches"


def error_levels(noise: float, top: float = TOP_LEVEL) -> list[float]:
    """``top``, then lower by a factor of 10 every :data:`LEVELS_PER_DECADE`
    steps, down to :data:`NOISE_MULTIPLE` times ``noise`` (the last
    level); none where the reference is too noisy for ``top``."""
    floor = NOISE_MULTIPLE * noise
    if not floor < top:
        return []
    steps = math.ceil(LEVELS_PER_DECADE * math.log10(top / floor) - 1e-9)
    return [top * 10 ** (-k / LEVELS_PER_DECADE) for k in range(steps)] + [floor]


@dataclass
class Level:
    """One error level: path's time there (its spp, the sampler whose
    curve gives it), the family's time (its setting, and the indirect
    paths where a ladder gives it), and the speed-up (``None`` where
    neither reaches the level)."""

    error: float
    path: Estimate
    path_spp: Estimate
    sampler: str
    whitted: Estimate
    setting: str | None
    paths: float | None
    speedup: Estimate | None
    path_reaches: bool = True

    @property
    def verdict(self) -> str:
        if not self.path_reaches:
            return PATH_NEVER
        return "not measured" if self.speedup is None else verdict(self.speedup)

    @property
    def goal(self) -> str:
        """``met`` where the interval lies at or above :data:`GOAL` (or where
        the family reaches a level that path never does), ``missed`` where
        it lies below, else ``undecided``."""
        if not self.path_reaches:
            return "met" if self.setting is not None else "not measured"
        if self.speedup is None:
            return "not measured"
        if self.speedup.low >= GOAL:
            return "met"
        return "missed" if self.speedup.high < GOAL else "undecided"


@dataclass(frozen=True)
class FamilyCurve:
    """Whitted settings read as one curve: a ladder's rungs in order of
    their indirect paths, or one setting alone (``paths`` empty); and the
    bias of the model its last rung converges to (0 where unknown)."""

    columns: list
    paths: np.ndarray
    bias: float = 0.0

    @property
    def ladder(self) -> bool:
        return len(self.paths) > 0


def family_curves(sweep: Sweep, biases: dict | None = None) -> list[FamilyCurve]:
    """The Whitted family's curves: each ladder of two or more settings
    that differ only in ``indirect_samples``, and each other setting
    alone; ``biases``: each setting's model bias, by label."""
    groups = {}
    for index, point in enumerate(sweep.points):
        if point.kind != "whitted":
            continue
        settings = point.setting.integrator
        rest = {k: v for k, v in settings.items() if k != "indirect_samples"}
        key = (json.dumps(rest, sort_keys=True, default=str)
               if settings.get("indirect_samples", 0) > 0 else point.label)
        groups.setdefault(key, []).append((settings.get("indirect_samples", 0), index))
    curves = []
    for rungs in groups.values():
        rungs.sort()
        last = sweep.points[rungs[-1][1]].label
        curves.append(FamilyCurve([i for _, i in rungs],
                                  np.array([p for p, _ in rungs], dtype=float)
                                  if len(rungs) > 1 else np.array([]),
                                  (biases or {}).get(last, 0.0)))
    return curves


def analyse_levels(sweep: Sweep, noise: float, biases: dict | None = None,
                   path_floor: float = 0.0) -> list[Level]:
    """Path's and the family's time at each level of :func:`error_levels`
    for ``noise`` (the reference's own relMSE), from one bootstrap;
    ``biases``: each Whitted setting's model bias in relMSE, by label;
    ``path_floor``: the relMSE below which path never gets (0: none)."""
    errors = replicated_errors(sweep, LEVEL_METRIC)
    times = replicated_times(sweep)
    curves = family_curves(sweep, biases)
    return [_level(sweep, curves, errors, times, error, error > path_floor)
            for error in error_levels(noise)]


#: Path's time and samples at a level it never reaches.
NEVER = Estimate(math.inf, math.inf, math.inf, ">")


def _level(sweep: Sweep, curves: list[FamilyCurve], errors: np.ndarray, times: np.ndarray,
           error: float, path_reaches: bool = True) -> Level:
    target = np.full(len(errors), error)
    family = envelope([_family_reach(c, errors, times, target, number)
                       for number, c in enumerate(curves)])
    # A replicate's time: where the family reaches the level, the least
    # time that does; where it does not, the least time it could.
    seconds = np.where(np.isfinite(family.high), family.high, family.low)
    reached = math.isfinite(family.high[0])
    whitted_time = bounded(seconds[0], family.high[0], seconds[1:], family.high[1:])
    if not reached:
        whitted_time = replace(whitted_time, relation=">")
    curve = curves[family.curve[0]]
    setting, paths = _family_setting(sweep, curve, family.spp_high[0]) if reached else (None,
                                                                                      None)
    if not path_reaches:
        return Level(error, NEVER, NEVER, "none", whitted_time, setting, paths, None, False)
    path = path_reach(sweep, errors, times, target)
    path_time = bounded(path.low[0], path.high[0], path.low[1:], path.high[1:])
    return Level(error, path_time,
                 bounded(path.spp_low[0], path.spp_high[0], path.spp_low[1:], path.spp_high[1:]),
                 sweep.path_curves()[path.curve[0]][0], whitted_time, setting, paths,
                 _speedup(path_time, whitted_time))


def _family_reach(curve: FamilyCurve, errors: np.ndarray, times: np.ndarray,
                  target: np.ndarray, number: int) -> Reach:
    """Where ``curve`` reaches ``target``. Where it does not, more samples
    (paths, or anti-aliasing) would take more than its last rung's time,
    and could not at all below its model's bias, to which they converge."""
    found = reach(errors[:, curve.columns], times[:, curve.columns],
                  curve.paths if curve.ladder else np.ones(1), target, number)
    if curve.bias >= target[0]:
        found.low = np.where(np.isinf(found.high), np.inf, found.low)
    return found


def _family_setting(sweep: Sweep, curve: FamilyCurve, paths: float) -> tuple[str, float | None]:
    """The setting that reaches a level on ``curve``: a ladder's first rung
    with at least ``paths`` paths (and ``paths`` itself), or the setting."""
    if not curve.ladder:
        return sweep.points[curve.columns[0]].label, None
    rung = int(np.searchsorted(curve.paths, paths - 1e-9))
    return sweep.points[curve.columns[min(rung, len(curve.columns) - 1)]].label, float(paths)


def _speedup(path: Estimate, whitted: Estimate) -> Estimate | None:
    """Path's time over the family's; bounded above where the family does
    not reach the level, and ``None`` where path does not either."""
    if whitted.relation != ">":
        return quotient(path, whitted)
    if path.relation == ">":
        return None
    with np.errstate(divide="ignore"):
        return Estimate(float(np.divide(path.median, whitted.median)), 0.0,
                        float(np.divide(path.high, whitted.low)), "<")


@dataclass
class GoalSummary:
    """Whether the family is ``goal`` times faster at every level, and its
    least speed-up over the levels measured (``None`` where none is)."""

    goal: float
    levels: int
    met: int
    faster: int
    met_at_every_level: bool
    least_speedup: Estimate | None


def goal_summary(levels: list[Level]) -> GoalSummary:
    """Whether the family is :data:`GOAL` times faster at every level, and
    its least speed-up over the levels measured."""
    measured = [level.speedup for level in levels if level.speedup is not None]
    return GoalSummary(GOAL, len(levels), sum(level.goal == "met" for level in levels),
                       sum(level.verdict == "faster" for level in levels),
                       bool(levels) and all(level.goal == "met" for level in levels),
                       min(measured, key=lambda s: s.median) if measured else None)
