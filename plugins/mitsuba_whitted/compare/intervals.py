"""Medians with 95% intervals, and the verdicts they allow.

The figures of a sweep come from renders timed in rounds (every setting
once per round) and from images whose error is a mean over pixels. A
bootstrap replicate draws the rounds with replacement, the same draws for
every setting (a round times them all under the same conditions, so the
rounds are paired), and the image's tiles with replacement, the same
draws for every image (they show the same pixels); whatever is computed
from the measurements is computed again from each replicate. Tiles rather
than pixels are drawn because neighbouring pixels' errors go together (an
edge, a noisy highlight). The 2.5th and 97.5th percentiles of the
replicates bound a 95% interval. The draws come from a fixed seed: the
same measurements give the same interval.

An estimate may be a bound: a speed-up read off a path curve that never
reaches, or already beats, the error it is asked for. Each replicate then
gives a range of values rather than one value (``low`` and ``high``
arrays); the interval runs from the low percentile of the lower ends to
the high percentile of the upper ends, and may be open (0 or infinity).

A speed-up, one time over another, spans what the two times' intervals
allow together (:func:`quotient`) rather than the percentiles of the
replicates' quotients, which would credit the pairing of the rounds with
more than it holds from one process to the next.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

#: Replicates of every bootstrap: enough for steady 2.5% and 97.5%
#: percentiles (50 replicates beyond each), few enough to take well under
#: a second for a sweep.
REPLICATES = 2000
#: The seed of every bootstrap's draws.
SEED = 23
#: Share of the replicates below and above the interval, each.
TAIL = 0.025
#: Tile draws kept in memory at once (replicates times tiles).
DRAWS_AT_ONCE = 1 << 22


@dataclass(frozen=True)
class Estimate:
    """A figure with its 95% interval. ``relation`` says whether ``median``
    is the figure ("=") or a bound of it: "<" at most, ">" at least. An
    open end is 0 below or ``math.inf`` above."""

    median: float
    low: float
    high: float
    relation: str = "="


def _finite_or_none(value: float) -> float | None:
    return None if math.isinf(value) else value


def json_data(figures) -> dict:
    """Figures held in dataclasses (an :class:`Estimate` among them) as JSON
    data, by ``dataclasses.asdict``: an infinite number of a dataclass is
    ``None``, as JSON has no infinity (an open end of an :class:`Estimate`)."""
    return asdict(figures, dict_factory=lambda items: {
        name: _finite_or_none(value) if isinstance(value, float) else value
        for name, value in items})


def verdict(speedup: Estimate) -> str:
    """``faster`` or ``slower`` where the interval lies wholly on one side of
    1, ``tie`` where it holds 1."""
    if speedup.low > 1:
        return "faster"
    if speedup.high < 1:
        return "slower"
    return "tie"


#: How a figure that is a bound is written before its value.
RELATION_PREFIX = {"=": "", "<": "< ", ">": "> "}


def estimate_text(estimate: Estimate, unit: str = "", digits: int = 2) -> str:
    """``4.1x (3.6-4.7)``; a bound as ``< 0.66x (0-0.71)`` or
    ``> 2.1x (1.9-∞)``."""
    def value(x):
        return "∞" if math.isinf(x) else f"{x:.{digits}g}"

    return (f"{RELATION_PREFIX[estimate.relation]}{value(estimate.median)}{unit} "
            f"({value(estimate.low)}-{value(estimate.high)})")


def verdict_text(speedup: Estimate) -> str:
    """The speed-up, its interval and its verdict: ``4.1x (3.6-4.7), faster``."""
    return f"{estimate_text(speedup, 'x')}, {verdict(speedup)}"


# ------------------------------------------------------------------ draws

@dataclass(frozen=True)
class Draws:
    """The draws of one bootstrap: ``rounds`` (replicates x rounds) round
    indices, and the seed of its tile draws (made as they are used, a few
    replicates at a time, so that large images need little memory)."""

    rounds: np.ndarray
    seed: int

    @classmethod
    def make(cls, rounds: int, replicates: int = REPLICATES, seed: int = SEED) -> "Draws":
        generator = np.random.default_rng(seed)
        return cls(generator.integers(0, rounds, size=(replicates, rounds)), seed)

    @property
    def replicates(self) -> int:
        return len(self.rounds)

    def medians(self, times: np.ndarray) -> np.ndarray:
        """Median time of each setting in each replicate: ``times`` is
        rounds x settings, the result replicates x settings."""
        return np.median(times[self.rounds], axis=1)

    def means(self, sums: np.ndarray, counts: np.ndarray) -> np.ndarray:
        """Mean of each image's per-pixel values in each replicate:
        ``sums`` (images x tiles) and ``counts`` (tiles) are the values'
        sums and the pixels of each tile; the result is replicates x
        images."""
        tiles = len(counts)
        generator = np.random.default_rng([self.seed, tiles])
        step = max(1, DRAWS_AT_ONCE // tiles)
        parts = []
        for start in range(0, self.replicates, step):
            size = min(step, self.replicates - start)
            weights = generator.multinomial(tiles, np.full(tiles, 1 / tiles), size=size)
            parts.append((weights @ sums.T) / (weights @ counts)[:, None])
        return np.concatenate(parts)


def _tile_starts(size: int, tile: int) -> np.ndarray:
    return np.arange(0, size, tile)


def tile_sums(values: np.ndarray, tile: int) -> np.ndarray:
    """Sums of a per-pixel map over square tiles of ``tile`` pixels (the
    last row and column of tiles may be narrower), flat."""
    height, width = values.shape
    sums = np.add.reduceat(values, _tile_starts(height, tile), axis=0)
    return np.add.reduceat(sums, _tile_starts(width, tile), axis=1).ravel()


def tile_pixels(height: int, width: int, tile: int) -> np.ndarray:
    """The pixels of each tile of :func:`tile_sums`, flat."""
    return np.outer(np.diff(_tile_starts(height, tile), append=height),
                    np.diff(_tile_starts(width, tile), append=width)).ravel().astype(float)


# -------------------------------------------------------------- intervals

def median_estimate(times) -> Estimate:
    """The median of ``times`` (one setting's renders) with its interval,
    the times drawn with replacement."""
    column = np.asarray(times, dtype=float)[:, None]
    return spread(float(np.median(column)), Draws.make(len(column)).medians(column)[:, 0])


def quotient(numerator: Estimate, denominator: Estimate) -> Estimate:
    """``numerator`` over ``denominator``, from the low end of one over the
    high end of the other to the reverse.

    Not the percentiles of the replicates' quotients: those cancel what
    the two times share within the rounds of one process, but the same
    render loaded twice, or run in another process, takes a few percent
    more or less for reasons the rounds of one process do not show (where
    its memory lies, what ran before it, which cores are free), and two
    different renders answer a busy machine differently. Each time's own
    interval moves with the machine; the quotient keeps both."""
    return Estimate(numerator.median / denominator.median,
                    numerator.low / denominator.high, numerator.high / denominator.low,
                    numerator.relation)


def spread(point: float, replicates: np.ndarray) -> Estimate:
    """``point`` with the interval of its replicates."""
    return bounded(point, point, replicates, replicates)


def bounded(low: float, high: float, lows: np.ndarray, highs: np.ndarray) -> Estimate:
    """A figure known to lie between ``low`` and ``high`` (equal where it is
    known exactly; 0 or infinity where a side is open), each replicate's
    range between ``lows`` and ``highs``."""
    relation = "=" if low == high else ">" if math.isinf(high) else "<"
    median = low if relation == ">" else high
    return Estimate(float(median), float(np.quantile(lows, TAIL, method="lower")),
                    float(np.quantile(highs, 1 - TAIL, method="higher")), relation)
