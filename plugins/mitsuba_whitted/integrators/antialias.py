"""Pixel sampling patterns: pixel centres, n x n grids, the COSC363 ray tracer's
adaptive 4-way subdivision and contrast-driven supersampling.

Every pattern is deterministic and every reduction has a fixed order, so the
same scene always gives the same image bit for bit: samples of one pixel (or
one cell) are contiguous and summed block by block in a fixed order, never
by atomic scatter-adds whose order would vary between runs.

Adaptive subdivision (its recursive anti-aliasing): a pixel is first
sampled at the centres of its four quadrants. A quadrant whose colour differs
from the mean of its three siblings by more than ``threshold`` (largest
per-channel difference of the colours clamped to [0, 1], as that program
compares displayable colours) becomes a cell of its own and is sampled again
at the centres of its four quadrants, up to ``max_depth`` levels. A leaf at
level L covers 4^-(L+1) of its pixel, so each cell's value is the mean of its
four quadrants, computed bottom-up.

Contrast-driven supersampling (Mitchell 1987): every pixel centre is traced
first. A pixel whose 3 x 3 neighbourhood of centre samples has a contrast
``(max - min) / (max + min)`` above ``threshold`` in some channel (R, G, B or
alpha) is traced again with ``n^2`` points of the Hammersley set and takes
their mean. Looking at the neighbours finds edges that pass between sample
points, which the adaptive per-pixel rule cannot see (its error stops
falling however deep it goes), and the Hammersley points resolve an edge
far finer than a grid of the same count: where aliasing is the only error,
this converges much faster than either.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import zip_longest
from typing import Callable

import drjit as dr
import mitsuba as mi

from ..jit import full_width, in_launches, index_range, opaque_float, read_runs, sum_blocks
from ..mathutil import hammersley
from . import lens as lens_points
from .render_plan import Band

#: Offsets (dy, dx) of a pixel's 8 neighbours.
NEIGHBOURS = tuple((dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0))

#: ``shade(positions, keys, lens=None, share=1) -> (radiance, alpha)``, or
#: ``(radiance, alpha, decision)``: positions are in pixel units inside the
#: crop window, keys identify samples for decorrelation, ``lens`` holds
#: their points of the aperture (``None``: its centre, a pinhole), ``share``
#: is how many camera samples of the pattern cover a pixel (among which a
#: pixel's indirect paths are shared). ``decision``, where given, is the radiance
#: the patterns decide refinement by: the noiseless part of ``radiance``,
#: so that noise does not read as contrast. A shader may say how many
#: samples it traces in one launch (``batch``).
ShadeFn = Callable[..., tuple]


@dataclass
class SampleCount:
    """How many camera samples a pattern used, and where refinement stopped."""
    samples: int = 0
    levels: int = 0
    per_level: tuple = ()
    budget_hit_at: int | None = None
    #: Camera samples per pixel (row-major), for adaptive sampling.
    per_pixel: object = None
    #: Samples beyond the pattern's fixed first pass (their keys follow
    #: those of the first pass of the whole film).
    refined: int = 0

    def add(self, band: "SampleCount") -> None:
        """Count a band's samples in with those of the bands before it."""
        self.samples += band.samples
        self.refined += band.refined
        self.levels = max(self.levels, band.levels)
        self.per_level = tuple(a + b for a, b in zip_longest(self.per_level, band.per_level,
                                                               fillvalue=0))
        if band.budget_hit_at is not None:
            self.budget_hit_at = min(band.budget_hit_at, self.budget_hit_at or band.budget_hit_at)
        self.per_pixel = band.per_pixel


@dataclass(frozen=True)
class SampleBudget:
    """Most camera samples a band may take: ``per_pixel`` on average over
    it (``aa_budget``), and at most ``band_limit`` in all (what a band may
    keep in memory at once)."""
    per_pixel: float
    band_limit: int | None = None

    def samples(self, pixels: int) -> int:
        limit = int(self.per_pixel * pixels)
        return limit if self.band_limit is None else min(limit, self.band_limit)

    def passed(self, pixels: int) -> str:
        """What a refinement would pass, and what to change."""
        if self.band_limit is not None and self.band_limit < self.per_pixel * pixels:
            return (f"the {self.band_limit:,} samples a band of the film keeps in memory at "
                    "once; raise 'aa_threshold'")
        return (f"the budget of {self.per_pixel:g} samples per pixel ('aa_budget'); raise "
                "'aa_budget' or 'aa_threshold'")


def _traced(shade: ShadeFn, positions: mi.Point2f, keys: mi.UInt32, lens=None,
            share: int = 1) -> tuple:
    """``shade``'s radiance, alpha and decision radiance (its radiance where
    it gives none), every component full width: the samplers scatter
    refined values into them, and a scatter into a component broadcast from
    width 1 (a shader returning ``Color3f(r, g, 0.5)``) writes past its one
    entry and corrupts the heap. ``lens``: the samples' lens points, for
    cameras with an aperture; ``share``: samples per pixel (``ShadeFn``)."""
    radiance, alpha, *decision = shade(positions, keys, lens, share)
    width = dr.width(positions)
    radiance, alpha = full_width(radiance, width), full_width(alpha, width)
    return radiance, alpha, full_width(decision[0], width) if decision else radiance


def _grid_positions(width: int, first_pixel: int, pixels: int, n: int, lens: bool = False):
    """Centres of an n x n grid in each of ``pixels`` pixels from
    ``first_pixel`` on (row-major in a crop window ``width`` wide),
    pixel-major; their keys (each sample's index in that order over the
    whole crop window); and, if ``lens``, their lens points (the strata of
    an n x n grid over the lens, permuted per pixel; a single sample takes
    a hashed point)."""
    index = dr.arange(mi.UInt32, pixels * n * n)
    pixel = index // (n * n) + dr.opaque(mi.UInt32, first_pixel)
    sub = index % (n * n)
    x = mi.Float(pixel % width) + (mi.Float(sub % n) + 0.5) / n
    y = mi.Float(pixel // width) + (mi.Float(sub // n) + 0.5) / n
    # Modulo 2^32, as UInt32 sums wrap: a grid asked for explicitly may
    # number more samples than that over the film, and keys only seed hashes.
    keys = index + dr.opaque(mi.UInt32, first_pixel * n * n % (1 << 32))
    if not lens:
        return mi.Point2f(x, y), keys, None
    seed = lens_points.pixel_seed(pixel)
    points = (lens_points.hashed_lens(seed) if n == 1
              else lens_points.grid_lens(sub, n, seed))
    return mi.Point2f(x, y), keys, points


def _block_means(radiance: mi.Color3f, alpha: mi.Float, block: int) -> tuple:
    """Mean radiance and alpha of each run of ``block`` consecutive samples."""
    scale = 1.0 / block
    return sum_blocks(radiance, block) * scale, sum_blocks(alpha, block) * scale


class GridSampler:
    """Pixel centres (``n`` = 1) or n x n grids (:func:`render_grid`), called
    as the adaptive and contrast samplers are: a first pass and nothing
    after it."""

    #: Passes a band may take after its first (the progress display
    #: counts them).
    refinement_levels = 0

    def __init__(self, n: int, lens: bool = False):
        self.n = n
        self.lens = lens

    def render(self, band: Band, shade: ShadeFn, refined_before: int = 0):
        """Pixels of ``band``; grids refine nothing, so no key follows
        ``refined_before``."""
        return render_grid(band, self.n, shade, self.lens)

    def first_pass_samples(self, band: Band) -> int:
        return band.pixels * self.n * self.n


def render_grid(band: Band, n: int, shade: ShadeFn, lens: bool = False):
    """Box-filtered pixels of ``band`` from n x n stratified samples (n = 1:
    centres), stratified on the lens too if ``lens``. The samples are
    traced a launch of whole pixels at a time and only their means kept,
    so memory follows the pixels, not the samples."""
    per_pixel = n * n
    launch = max(1, getattr(shade, "batch", band.pixels * per_pixel) // per_pixel)
    count = SampleCount(band.pixels * per_pixel, 0, (band.pixels * per_pixel,))
    radiance, alpha = in_launches(
        band.pixels, launch,
        lambda start, stop, _: _grid_means(band, start, stop - start, n, shade, lens))
    return radiance, alpha, count


def _grid_means(band: Band, start: int, pixels: int, n: int, shade: ShadeFn,
                lens: bool) -> tuple:
    """Mean radiance and alpha of ``pixels`` pixels of ``band`` from its
    ``start``-th on."""
    radiance, alpha, _ = _traced(shade, *_grid_positions(band.width, band.first_pixel + start,
                                                         pixels, n, lens), share=n * n)
    if n == 1:
        return radiance, alpha
    return _block_means(radiance, alpha, n * n)


def _quadrant_positions(origins: mi.Point2f, size: float) -> mi.Point2f:
    """The four quadrant centres of each cell (lower corner ``origins``),
    cell by cell in the order (1/4, 1/4), (3/4, 1/4), (1/4, 3/4), (3/4, 3/4)
    of its size: the order in which a cell's children are stored."""
    index = dr.arange(mi.UInt32, 4 * dr.width(origins))
    cell, quadrant = index // 4, index % 4
    corner = dr.gather(mi.Point2f, origins, cell)
    qx = mi.Float(quadrant % 2) * 0.5 + 0.25
    qy = mi.Float(quadrant // 2) * 0.5 + 0.25
    return mi.Point2f(corner + mi.Vector2f(qx, qy) * opaque_float(size))


def _quadrant_lens_cells(origins: mi.Point2f, lens_origins: mi.Point2f,
                         size: float) -> mi.Point2f:
    """The lower corner, on the lens, of each quadrant of each cell (cells
    at film ``origins`` covering lens squares at ``lens_origins``, both of
    side ``size``): the cell's lens square split in four, the quarters
    handed to the quadrants in an order permuted per cell."""
    index = dr.arange(mi.UInt32, 4 * dr.width(origins))
    cell, quadrant = index // 4, index % 4
    # Seeded by the cell's centre, which no cell of another level shares: a
    # cell's first quadrant has the cell's origin, and pairings seeded by
    # origins would repeat down that chain and pin its lens points to the
    # lens's edges.
    seed = lens_points.position_seed(dr.gather(mi.Point2f, origins, cell)
                                      + opaque_float(size / 2))
    column, row = lens_points.paired_strata(quadrant % 2, quadrant // 2, 2, seed)
    offset = mi.Vector2f(mi.Float(column), mi.Float(row)) * opaque_float(size / 2)
    return mi.Point2f(dr.gather(mi.Point2f, lens_origins, cell) + offset)


def _split_codes(colors: mi.Color3f, threshold: float) -> mi.UInt32:
    """Per cell, a 4-bit code of the quadrants that differ from the mean of
    their 3 siblings.

    Worked out per cell, whose four quadrants are read as one packet per
    channel, rather than by per-quadrant lanes each gathering its
    siblings."""
    worst = [mi.Float(0)] * 4
    for channel in range(3):
        quadrants = [dr.clip(value, 0.0, 1.0) for value in read_runs(colors[channel], 4)]
        total = ((quadrants[0] + quadrants[1]) + quadrants[2]) + quadrants[3]
        worst = [dr.maximum(w, dr.abs(q - (total - q) / 3.0)) for w, q in zip(worst, quadrants)]
    code = mi.UInt32(0)
    for quadrant, difference in enumerate(worst):
        code |= dr.select(difference > threshold, mi.UInt32(1 << quadrant), 0)
    return code


def _quadrants_to_split(colors: mi.Color3f, threshold: float) -> mi.UInt32:
    """Indices of the quadrants that differ from their siblings, in order.

    The cells with any are found first and only their quadrants tested:
    few cells differ, so a compaction over the cells and one over the
    quadrants of the cells found cost less than one over every quadrant."""
    code = _split_codes(colors, threshold)
    # Evaluated once per cell: Dr.Jit would otherwise fold it into the
    # gathers below and work it out once per quadrant.
    dr.eval(code)
    cells = dr.compress(code != 0)
    if dr.width(cells) == 0:
        return cells
    index = dr.arange(mi.UInt32, 4 * dr.width(cells))
    cell, quadrant = dr.gather(mi.UInt32, cells, index >> 2), index & 3
    differs = ((dr.gather(mi.UInt32, code, cell) >> quadrant) & 1) != 0
    return dr.gather(mi.UInt32, cell * 4 + quadrant, dr.compress(differs))


class AdaptiveSampler:
    """Recursive 4-way subdivision of the pixels, one level per wavefront."""

    def __init__(self, threshold: float, max_depth: int, budget: SampleBudget,
                 warn: Callable[[str], None], lens: bool = False):
        self.threshold = threshold
        self.max_depth = max_depth
        self.budget = budget
        self.warn = warn
        #: Whether samples take lens points: each cell covers a square of
        #: the lens as it covers one of its pixel, its quadrants take that
        #: square's four quarters (paired as ``lens.paired_strata`` pairs
        #: a 2 x 2 grid), and a sample looks from a point of its quarter.
        self.lens = lens

    @property
    def refinement_levels(self) -> int:
        """Levels a band may take after its first (the progress display
        counts them)."""
        return self.max_depth

    @staticmethod
    def first_pass_samples(band: Band) -> int:
        """Samples of ``band``'s first level: its pixels' four quadrants."""
        return 4 * band.pixels

    def render(self, band: Band, shade: ShadeFn, refined_before: int = 0):
        """Pixels of ``band``. Its first level's keys are four per pixel of
        the crop window; deeper levels' keys follow the first level of the
        whole crop window and the ``refined_before`` samples the bands
        above refined."""
        first_refined_key = 4 * band.width * band.height + refined_before
        centres, _, _ = _grid_positions(band.width, band.first_pixel, band.pixels, 1)
        origins = mi.Point2f(centres - 0.5)
        lens_origins = dr.zeros(mi.Point2f, band.pixels) if self.lens else None
        # Every pixel starts with its four quadrant samples.
        levels, count = [], SampleCount(per_pixel=dr.full(mi.UInt32, 4, band.pixels))
        size = 1.0
        while True:
            positions = _quadrant_positions(origins, size)
            if levels:
                first = first_refined_key + count.refined
                count.refined += dr.width(positions)
            else:
                first = 4 * band.first_pixel
            keys = index_range(first, first + dr.width(positions))
            lens = None
            if self.lens:
                lens_origins = _quadrant_lens_cells(origins, lens_origins, size)
                spread = lens_points.jitter(lens_points.position_seed(positions), mi.UInt32(0))
                lens = mi.Point2f(lens_origins + spread * opaque_float(size / 2))
            radiance, alpha, decision = _traced(shade, positions, keys, lens,
                                                share=4 ** (len(levels) + 1))
            count.samples += dr.width(positions)
            count.per_level += (dr.width(positions),)
            cells = self._cells_to_split(decision, len(levels), count, band.pixels)
            levels.append((radiance, alpha, cells))
            if cells is None:
                break
            centres = dr.gather(mi.Point2f, positions, cells)
            pixel = ((mi.UInt32(centres.y) - dr.opaque(mi.UInt32, band.first_row)) * band.width
                     + mi.UInt32(centres.x))
            # A few thousand scattered adds: atomics on the map itself cost
            # less than the per-thread copies Dr.Jit would make of it.
            dr.scatter_reduce(dr.ReduceOp.Add, count.per_pixel, mi.UInt32(4), pixel,
                              mode=dr.ReduceMode.Direct)
            origins = mi.Point2f(centres - opaque_float(size / 4))
            if self.lens:
                lens_origins = dr.gather(mi.Point2f, lens_origins, cells)
            size *= 0.5
        count.levels = len(levels) - 1
        return self._combine(levels) + (count,)

    def _cells_to_split(self, radiance, level: int, count: SampleCount, pixels: int):
        """Indices of the quadrants to refine, or ``None`` when this level
        is the last (one wait for the device: the compaction's size)."""
        if level >= self.max_depth:
            return None
        cells = _quadrants_to_split(radiance, self.threshold)
        wanted = 4 * dr.width(cells)
        if wanted == 0:
            return None
        if count.samples + wanted > self.budget.samples(pixels):
            count.budget_hit_at = level + 1
            self.warn(f"whitted: adaptive anti-aliasing stopped before level {level + 1}: its "
                      f"{wanted} samples would pass {self.budget.passed(pixels)}.")
            return None
        return cells

    def _combine(self, levels):
        """Bottom-up: a refined quadrant takes the mean of its four children."""
        child_radiance, child_alpha = None, None
        for radiance, alpha, cells in reversed(levels):
            if child_radiance is not None:
                mean_radiance, mean_alpha = _block_means(child_radiance, child_alpha, 4)
                dr.scatter(radiance, mean_radiance, cells)
                dr.scatter(alpha, mean_alpha, cells)
            child_radiance, child_alpha = radiance, alpha
        return _block_means(child_radiance, child_alpha, 4)


def neighbourhood_contrast(radiance: mi.Color3f, alpha: mi.Float, width: int,
                           height: int) -> mi.Float:
    """Per pixel (row-major): the largest contrast ``(max - min) / (max + min)``
    over the channels R, G, B and alpha of the pixel and its 8 neighbours
    (those inside the image). 0 where a channel is 0 throughout."""
    index = dr.arange(mi.Int32, width * height)
    x, y = index % width, index // width
    channels = (radiance.x, radiance.y, radiance.z, alpha)
    high, low = list(channels), list(channels)
    for dy, dx in NEIGHBOURS:
        neighbour = (dr.clip(y + dy, 0, height - 1) * width
                     + dr.clip(x + dx, 0, width - 1))
        for c, values in enumerate(channels):
            value = dr.gather(mi.Float, values, mi.UInt32(neighbour))
            high[c], low[c] = dr.maximum(high[c], value), dr.minimum(low[c], value)
    contrast = mi.Float(0)
    for hi, lo in zip(high, low):
        spread = hi + lo
        contrast = dr.maximum(contrast, dr.select(spread > 0, (hi - lo) / spread, 0))
    return contrast


class ContrastSampler:
    """Mitchell's contrast-driven supersampling: pixel centres, then
    ``samples_per_side^2`` Hammersley points in every pixel whose
    neighbourhood contrast passes ``threshold``."""

    #: Passes a band may take after its centres (the progress display
    #: counts them).
    refinement_levels = 1

    def __init__(self, threshold: float, samples_per_side: int, budget: SampleBudget,
                 warn: Callable[[str], None], lens: bool = False):
        self.threshold = threshold
        self.samples = samples_per_side * samples_per_side
        self.budget = budget
        self.warn = warn
        #: Whether samples take lens points: a pixel's centre sample looks
        #: from a point hashed from the pixel (so blur shows as contrast),
        #: its refinement's points from their next Halton coordinates.
        self.lens = lens

    @staticmethod
    def first_pass_samples(band: Band) -> int:
        """Samples of ``band``'s centres, those of the rows next to it
        included (see :meth:`render`)."""
        return band.widened(1).pixels

    def render(self, band: Band, shade: ShadeFn, refined_before: int = 0):
        """Pixels of ``band``. Centre samples are keyed by their pixel in the
        crop window; refinement keys follow the centres of the whole crop
        window and the ``refined_before`` samples the bands above refined.
        The centres of the rows next to the band are traced too, as its
        edge pixels' neighbours."""
        first_refined_key = band.width * band.height + refined_before
        radiance, alpha, contrast = self._centres(band, shade, self.lens)
        count = SampleCount(band.pixels, 0, (band.pixels,),
                            per_pixel=dr.full(mi.UInt32, 1, band.pixels))
        refined = dr.compress(contrast > self.threshold)
        if dr.width(refined) == 0:
            return radiance, alpha, count
        samples = self._samples_within_budget(dr.width(refined), band.pixels)
        positions, lens = _pattern_positions(refined + dr.opaque(mi.UInt32, band.first_pixel),
                                             band.width, samples, self.lens)
        keys = index_range(first_refined_key, first_refined_key + dr.width(positions))
        fine_radiance, fine_alpha, _ = _traced(shade, positions, keys, lens, share=samples)
        fine_radiance, fine_alpha = _block_means(fine_radiance, fine_alpha, samples)
        dr.scatter(radiance, fine_radiance, refined)
        dr.scatter(alpha, fine_alpha, refined)
        dr.scatter(count.per_pixel, mi.UInt32(1 + samples), refined)
        count.samples += dr.width(positions)
        count.refined = dr.width(positions)
        count.per_level += (dr.width(positions),)
        count.levels = 1
        return radiance, alpha, count

    @staticmethod
    def _centres(band: Band, shade: ShadeFn, lens: bool) -> tuple:
        """Radiance, alpha and neighbourhood contrast of the centre of each
        pixel of ``band``."""
        widened = band.widened(1)
        radiance, alpha, decision = _traced(shade, *_grid_positions(
            band.width, widened.first_pixel, widened.pixels, 1, lens))
        contrast = neighbourhood_contrast(decision, alpha, band.width, widened.rows)
        if widened == band:
            return radiance, alpha, contrast
        start = band.first_pixel - widened.first_pixel
        inside = index_range(start, start + band.pixels)
        return (dr.gather(mi.Color3f, radiance, inside), dr.gather(mi.Float, alpha, inside),
                dr.gather(mi.Float, contrast, inside))

    def _samples_within_budget(self, refined: int, pixels: int) -> int:
        """Points per refined pixel: as asked, or fewer (with a warning)
        where that would pass the budget of samples per pixel."""
        allowed = (self.budget.samples(pixels) - pixels) // refined
        if allowed >= self.samples:
            return self.samples
        samples = max(allowed, 1)
        self.warn(f"whitted: contrast anti-aliasing refines {refined} pixels with {samples} "
                  f"samples each instead of {self.samples}: more would pass "
                  f"{self.budget.passed(pixels)}.")
        return samples


def _pattern_positions(pixels: mi.UInt32, width: int, samples: int, lens: bool = False):
    """``samples`` Hammersley points in each of ``pixels``, pixel-major, and
    if ``lens`` their lens points (``None`` otherwise)."""
    pattern = hammersley(samples)
    offsets = mi.Point2f(mi.Float(pattern[:, 0]), mi.Float(pattern[:, 1]))
    index = dr.arange(mi.UInt32, dr.width(pixels) * samples)
    pixel, sub = dr.gather(mi.UInt32, pixels, index // samples), index % samples
    corner = mi.Point2f(mi.Float(pixel % width), mi.Float(pixel // width))
    positions = mi.Point2f(corner + mi.Vector2f(dr.gather(mi.Point2f, offsets, sub)))
    if not lens:
        return positions, None
    return positions, lens_points.halton_lens(sub, samples, lens_points.pixel_seed(pixel))
