"""Speed against error: Whitted's settings and path's ladders, timed in
interleaved rounds, each image's error measured against a reference.

Every setting is rendered once to compile its kernels (that time is kept
as ``first_seconds``) and once more untimed (Whitted's frozen kernels are
recorded a second time then). Then come the rounds: in each, every
setting is timed once, Whitted's and path's settings taking turns, so
that the machine's drift from one minute to the next falls on all of
them alike, in an order shuffled anew in every round.
``dr.sync_thread()`` runs before each clock stops, so a time covers the
work and not just its launch. Each setting renders the same image every
time (Whitted is deterministic, path keeps its seed), so one image per
setting is measured.

Path's curve is rendered with two samplers, ``independent`` and
``multijitter`` (stratified, so its error falls faster on smooth
integrands): the fair peer at an error is whichever is faster there
(:mod:`.equal_error`).
"""

from __future__ import annotations

import json
import math
from contextlib import contextmanager
from dataclasses import dataclass, field
from itertools import zip_longest

import mitsuba as mi
import numpy as np

from ..integrators.settings import is_whitted
from ..jit import release_scenes, timed
from ..overrides import load_with
from .intervals import SEED, Draws, tile_pixels, tile_sums
from .metrics import TILE_SIDES, error_maps, rmse
from .converged import has_ambient
from .photon_reference import needs_photons
from .reference import PATH_DEPTH, Reference, path_settings, rgb_pixels

#: Path's samplers, each rendering a ladder of its own.
PATH_SAMPLERS = ("independent", "multijitter")


@dataclass(frozen=True)
class Setting:
    """One render of a sweep: an integrator for ``mi.load_dict``, and for
    path the sampler of its sensor, its samples per pixel and its seed
    (Whitted places its own samples). ``kind`` is "path" for path's
    ladders and "whitted" for what is measured against them."""

    label: str
    kind: str
    integrator: dict
    spp: int = 0
    sampler: str | None = None
    seed: int = 0


def scene_whitted_settings(scene: mi.Scene) -> dict:
    """The scene's own ``whitted`` settings (empty for other integrators)."""
    integrator = scene.integrator()
    if not is_whitted(integrator):
        return {}
    return integrator.properties()


#: Contrast refinement as the sweeps run it: edges of 2% contrast and more
#: are refined, within a budget that 256 points on every edge pixel of the
#: measured scenes stay under.
CONTRAST_AA = {"aa": "contrast", "aa_threshold": 0.02, "aa_budget": 256}


def _variants(base: dict, light: "PhotonRungs" = None) -> list[tuple[str, dict, bool]]:
    """Every labelled change of ``base`` that a sweep measures, and whether
    ``--quick`` keeps it; a new Whitted setting is added here. ``light``
    says which photon rungs the scene has light for (none if not given)."""
    # Three adaptive levels resolve edges to 1/16 pixel; deeper levels on a
    # low threshold would mostly spend the sample budget on noise.
    depth = min(base.get("aa_max_depth", 3), 3)
    variants = [
        ("as in the scene", {}, False),
        ("aa none", {"aa": "none"}, True),
        ("aa grid 2x2", {"aa": "grid", "aa_samples": 2}, True),
        ("aa adaptive 0.25", {"aa": "adaptive", "aa_threshold": 0.25, "aa_max_depth": depth},
         True),
        ("aa grid 4x4", {"aa": "grid", "aa_samples": 4}, False),
        ("aa adaptive 0.05", {"aa": "adaptive", "aa_threshold": 0.05, "aa_max_depth": depth},
         False),
        ("aa contrast 8x8", {**CONTRAST_AA, "aa_samples": 8}, False),
        ("max_depth 2", {"aa": "none", "max_depth": 2}, False),
        ("max_depth 4", {"aa": "none", "max_depth": 4}, False),
    ]
    if base.get("shadows", "physical") != "physical" or has_ambient(base):
        variants.append(("physical, aa none", {"aa": "none", **PHYSICAL}, False))
    variants += [(f"indirect {paths}, grid 2x2", indirect_change(paths, GRID_2X2),
                  paths in QUICK_PATHS) for paths in INDIRECT_PATHS]
    variants += [(f"indirect {side * side}, contrast {side}x{side}",
                  indirect_change(side * side, {**CONTRAST_AA, "aa_samples": side}), False)
                 for side in CONTRAST_SIDES]
    light = light or PhotonRungs(False, False)
    if light.interreflection:
        variants += [(f"photons {_count(photons)} x {passes}, {aa_label}",
                      photon_change(photons, passes, 0, anti_aliasing), in_quick)
                     for photons, passes, aa_label, anti_aliasing, in_quick in PHOTON_RUNGS]
    if light.caustics:
        variants += [(f"indirect {paths} + photons {_count(photons)} x {passes}, grid 2x2",
                      photon_change(photons, passes, paths, GRID_2X2), in_quick)
                     for paths, photons, passes, in_quick in CAUSTIC_RUNGS]
    return variants if base else variants[1:]


#: Whitted's model as path's: shadow rays pass only what does not bend
#: light, no ambient term.
PHYSICAL = {"shadows": "physical", "ambient": {"type": "rgb", "value": [0, 0, 0]}}
GRID_2X2 = {"aa": "grid", "aa_samples": 2}
#: The hybrid ladder's indirect paths per pixel, and those ``--quick`` keeps:
#: a 2 x 2 grid shares them among its four camera samples.
INDIRECT_PATHS, QUICK_PATHS = (4, 16, 64, 256), (4, 16)
#: Sides of contrast refinement with as many indirect paths per pixel as an
#: edge pixel's camera samples, one path each: finer edges where the image
#: is also less noisy.
CONTRAST_SIDES = (4, 8)


#: The photon ladder with no indirect paths, where the photons carry all
#: the light the tree leaves out: (photons per pass, passes, anti-aliasing's
#: label and settings, whether ``--quick`` keeps it). The budget grows
#: fourfold from rung to rung, first in passes, which shrink the gather
#: radius and with it the blur that more photons in one pass cannot, then in
#: photons per pass, which lowers the noise of each. ``--quick`` keeps none:
#: each pass traces photons and gathers at every pixel again, so that for the
#: diffuse light they cost more time per unit of error than indirect paths,
#: and a short ladder has those.
PHOTON_RUNGS = (
    (10_000, 4, "grid 2x2", GRID_2X2, False),
    (10_000, 16, "grid 2x2", GRID_2X2, False),
    (40_000, 16, "grid 2x2", GRID_2X2, False),
    (40_000, 16, "contrast 4x4", {**CONTRAST_AA, "aa_samples": 4}, False),
)
#: Indirect paths with photons for the caustics alone, the light no path
#: from the camera finds: (paths per pixel, photons per pass, passes,
#: whether ``--quick`` keeps it). The paths carry the diffuse light, so the
#: photons' budget grows with theirs, each part's noise kept alike.
CAUSTIC_RUNGS = ((16, 10_000, 4, True), (64, 40_000, 16, False))


@dataclass(frozen=True)
class PhotonRungs:
    """Which photon rungs a scene has light for: ``interreflection``, a
    light and a smooth (diffuse or glossy) surface to bounce it;
    ``caustics``, light that only photons find (:func:`needs_photons`)
    and a smooth surface for it to land on."""

    interreflection: bool
    caustics: bool

    @classmethod
    def of(cls, scene: mi.Scene) -> "PhotonRungs":
        smooth = has_smooth_surface(scene)
        return cls(smooth and bool(scene.emitters()), smooth and needs_photons(scene))


def has_smooth_surface(scene: mi.Scene) -> bool:
    """Whether a shape of ``scene`` has a diffuse or glossy lobe, where
    light that the tree leaves out can arrive."""
    return any(shape.bsdf() is not None
               and mi.has_flag(shape.bsdf().flags(), mi.BSDFFlags.Smooth)
               for shape in scene.shapes())


def _count(photons: int) -> str:
    return f"{photons // 1000}k" if photons % 1000 == 0 else str(photons)


def photon_change(photons: int, passes: int, paths: int, anti_aliasing: dict) -> dict:
    """Whitted on path's model with ``photons`` per pass for ``passes``
    passes and ``paths`` indirect paths per pixel (0: the photons carry
    every light the tree leaves out; more: only the caustics)."""
    return {**indirect_change(paths, anti_aliasing), "photons": photons,
            "photon_passes": passes}


def indirect_change(paths: int, anti_aliasing: dict) -> dict:
    """Whitted on path's model (its expectation is path's image) with
    ``paths`` indirect paths per pixel and ``anti_aliasing``."""
    return {**anti_aliasing, **PHYSICAL, "max_depth": PATH_DEPTH, "indirect_samples": paths}


def whitted_variants(base: dict, quick: bool = False, light: PhotonRungs | None = None) -> dict:
    """Labelled Whitted settings around ``base``: its AA modes, adaptive
    thresholds, contrast refinement and depths, the physical model when
    ``base`` differs, the hybrid ladder (indirect light on path's model),
    the photon rungs ``light`` allows (:meth:`PhotonRungs.of` the scene)
    and ``base`` itself when the scene has one."""
    return {label: {**base, **change} for label, change, in_quick in _variants(base, light)
            if in_quick or not quick}


def whitted_settings(variants: dict) -> list[Setting]:
    """A sweep's settings for labelled Whitted settings (as ``whitted_variants``)."""
    return [Setting(label, "whitted", {"type": "whitted", **settings})
            for label, settings in variants.items()]


def path_spp_ladder(largest: int) -> list[int]:
    """1, 2, 4, ... up to ``largest``."""
    return [1 << k for k in range(int(math.log2(max(largest, 1))) + 1)]


def path_ladder(largest: int, samplers=PATH_SAMPLERS, depth: int | None = None) -> list[Setting]:
    """Path at 1, 2, 4, ... up to ``largest`` spp with each sampler, or as
    near as the sampler takes (``multijitter`` rounds some counts up)."""
    integrator = path_settings(depth) if depth else path_settings()
    return [Setting(f"path {sampler} {spp} spp", "path", integrator, spp, sampler, seed=spp)
            for sampler in samplers
            for spp in sorted(set(sample_counts(sampler, path_spp_ladder(largest))))]


def sampler_sensors(scene_path, defines: dict, samplers=PATH_SAMPLERS) -> dict:
    """The scene file's sensor with each of ``samplers``, by sampler: each
    taken from a copy of the scene, which is let go (kept, its objects
    would slow every frozen call, which traverses every live instance)."""
    return {sampler: load_with(scene_path, defines, {"sampler": sampler}).sensors()[0]
            for sampler in samplers}


def sample_counts(sampler: str, requested: list[int]) -> list[int]:
    """The samples per pixel Mitsuba's ``sampler`` takes for each count of
    ``requested`` (asked with its warning about a rounded count quieted:
    the ladder renders the rounded count, which it does not warn about)."""
    with _log_level(mi.LogLevel.Error):
        return [mi.load_dict({"type": sampler, "sample_count": count}).sample_count()
                for count in requested]


@contextmanager
def _log_level(level):
    logger = mi.logger()
    before = logger.log_level()
    logger.set_log_level(level)
    try:
        yield
    finally:
        logger.set_log_level(before)


@dataclass
class SweepPoint:
    """A setting's renders: the first one's time, one time per round, and
    the image with its errors. ``tiles``: each metric's per-pixel error
    summed over the tiles of :func:`.intervals.tile_sums`."""

    setting: Setting
    first_seconds: float
    times: np.ndarray
    image: np.ndarray = field(repr=False)
    rel_mse: float = math.nan
    rmse: float = math.nan
    flip: float = math.nan
    tiles: dict = field(default_factory=dict, repr=False)

    @property
    def label(self) -> str:
        return self.setting.label

    @property
    def kind(self) -> str:
        return self.setting.kind

    @property
    def spp(self) -> int:
        return self.setting.spp

    def error(self, metric: str) -> float:
        return {"relmse": self.rel_mse, "flip": self.flip}[metric]


@dataclass
class Sweep:
    """Every point of a sweep, timed in the same rounds, the size of their
    images, and the draws of their bootstrap."""

    points: list[SweepPoint]
    size: tuple
    draws: Draws

    @property
    def metrics(self) -> list[str]:
        """The metrics every image was measured in."""
        return [m for m in self.points[0].tiles if all(m in p.tiles for p in self.points)]

    def of_kind(self, kind: str) -> list[SweepPoint]:
        return [p for p in self.points if p.kind == kind]

    def tile_pixels(self, metric: str) -> np.ndarray:
        """The pixels of each of ``metric``'s tiles."""
        return tile_pixels(*self.size, TILE_SIDES[metric])

    @property
    def times(self) -> np.ndarray:
        """Every point's time in every round (rounds x points)."""
        return np.stack([p.times for p in self.points], axis=1)

    def path_curves(self) -> list[tuple[str, list[int], np.ndarray]]:
        """Path's curves: each sampler, the indices of its points in spp
        order, and their spp."""
        curves = []
        for sampler in dict.fromkeys(p.setting.sampler for p in self.of_kind("path")):
            columns = sorted((i for i, p in enumerate(self.points)
                              if p.kind == "path" and p.setting.sampler == sampler),
                             key=lambda i: self.points[i].spp)
            curves.append((sampler, columns,
                           np.array([self.points[i].spp for i in columns], dtype=float)))
        return curves


def measure_errors(point: SweepPoint, reference: np.ndarray) -> SweepPoint:
    """The point's errors against ``reference``, and their tile sums."""
    maps = error_maps(point.image, reference)
    point.rel_mse = float(np.mean(maps["relmse"]))
    point.flip = float(np.mean(maps["flip"])) if "flip" in maps else math.nan
    point.rmse = rmse(point.image, reference)
    point.tiles = {metric: tile_sums(values, TILE_SIDES[metric])
                   for metric, values in maps.items()}
    return point


def run_sweep(scene: mi.Scene, reference: Reference, settings: list[Setting], sensors: dict,
              rounds: int, progress=None) -> Sweep:
    """Render, time and measure ``settings``: path's with the sensor of
    ``sensors`` that has their sampler, in ``rounds`` interleaved rounds."""
    # A scene an earlier comparison left to the collector would make every
    # render timed here dearer.
    release_scenes()
    integrators = {}
    renders = [_render_function(scene, setting, sensors, integrators) for setting in settings]
    steps = len(settings) + rounds
    first = []
    for setting, render in zip(settings, renders):
        image, (seconds,) = timed(render, 1)
        first.append((rgb_pixels(image), seconds))
        _report(progress, len(first), steps, setting.label)
    # Once every sampler has rendered: a path render with a sensor of its
    # own makes Whitted's frozen kernels record again at their next call.
    for render in renders:
        timed(render, 1)
    times = timed_rounds(renders, [s.kind for s in settings], rounds,
                         lambda done: _report(progress, len(settings) + done, steps,
                                              f"round {done} of {rounds}"))
    points = [measure_errors(SweepPoint(setting, seconds, times[:, index], image),
                             reference.image)
              for index, (setting, (image, seconds)) in enumerate(zip(settings, first))]
    return Sweep(points, reference.image.shape[:2], Draws.make(rounds))


def _render_function(scene: mi.Scene, setting: Setting, sensors: dict, integrators: dict):
    """``setting``'s render; settings with the same integrator share one
    (``integrators``, by its settings as text), as path's rungs do."""
    key = json.dumps(setting.integrator, sort_keys=True, default=str)
    if key not in integrators:
        integrators[key] = mi.load_dict(setting.integrator)
    integrator = integrators[key]
    sensor = sensors[setting.sampler] if setting.sampler else 0

    def render():
        return mi.render(scene, integrator=integrator, sensor=sensor, spp=setting.spp,
                         seed=setting.seed)

    return render


def timed_rounds(renders: list, kinds: list[str], rounds: int, done=None) -> np.ndarray:
    """The time of each of ``renders`` (rounds x renders) in ``rounds``
    rounds, each timing every render once in the order of
    :func:`round_order`; ``done(round)`` after each."""
    times = np.empty((rounds, len(renders)))
    for round_index in range(rounds):
        for index in round_order(kinds, round_index):
            times[round_index, index] = timed(renders[index], 1)[1][0]
        if done is not None:
            done(round_index + 1)
    return times


def round_order(kinds: list[str], round_index: int) -> list[int]:
    """The order of round ``round_index``: Whitted's settings and path's
    taking turns (those of the longer list left over at the end), each
    list shuffled anew in every round (from a fixed seed), so that no
    setting always follows the same one: what a render leaves behind
    (memory to allocate again, caches to fill) falls on each setting in
    some rounds and not in others, instead of always on the same one."""
    generator = np.random.default_rng([SEED, round_index])
    whitted = generator.permutation([i for i, kind in enumerate(kinds) if kind != "path"])
    path = generator.permutation([i for i, kind in enumerate(kinds) if kind == "path"])
    return [int(i) for pair in zip_longest(whitted, path) for i in pair if i is not None]


def _report(progress, done, total, what):
    if progress is not None:
        progress(done, total, what)

