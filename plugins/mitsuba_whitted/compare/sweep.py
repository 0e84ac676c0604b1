"""Speed against error: each integrator setting timed warm, its error
measured against a reference.

Every setting is rendered once to compile its kernels (that time is kept
as ``first_seconds``) and once more untimed (Whitted's frozen kernels are
recorded a second time then), then ``repeats`` more times; the median of
those is its time. ``dr.sync_thread()`` runs before each clock stops, so
the time covers the work and not just its launch.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, field

import mitsuba as mi
import numpy as np

from ..jit import timed
from .metrics import flip_error, rel_mse, rmse
from .reference import Reference, path_settings, rgb


@dataclass
class SweepPoint:
    label: str
    kind: str             # "whitted" or "path"
    settings: dict
    spp: int | None       # path only
    seconds: float        # median of the warm renders
    first_seconds: float  # the first (compiling) render
    image: np.ndarray = field(repr=False)
    rel_mse: float = math.nan
    rmse: float = math.nan
    flip: float = math.nan


#: A render that takes longer than this is timed warm once instead of
#: ``repeats`` times: its run-to-run noise is small next to its length.
LONG_RENDER_S = 5.0


def timed_render(scene: mi.Scene, integrator, repeats: int = 3, **render_args):
    """(image, first render's seconds, median of ``repeats`` warm renders,
    or of one where the first took longer than :data:`LONG_RENDER_S`)."""
    def render():
        return mi.render(scene, integrator=integrator, **render_args)

    image, (first,) = timed(render, 1)
    if first > LONG_RENDER_S:
        _, warm = timed(render, 1)
    else:
        # The second render of a Whitted setting records its frozen kernels
        # once more, many times a warm render's time; with it among three
        # timed renders, one more stall would make the median.
        timed(render, 1)
        _, warm = timed(render, repeats)
    return rgb(image), first, statistics.median(warm)


def scene_whitted_settings(scene: mi.Scene) -> dict:
    """The scene's own ``whitted`` settings (empty for other integrators)."""
    integrator = scene.integrator()
    if integrator is None or not hasattr(integrator, "properties"):
        return {}
    return integrator.properties()


#: Contrast refinement as the sweeps run it: edges of 2% contrast and more
#: are refined, within a budget that 256 points on every edge pixel of the
#: measured scenes stay under.
CONTRAST_AA = {"aa": "contrast", "aa_threshold": 0.02, "aa_budget": 256}


def whitted_variants(base: dict, quick: bool = False) -> dict:
    """Labelled Whitted settings around ``base``: its AA modes, adaptive
    thresholds, contrast refinement and depths, and the physical model when
    ``base`` differs."""
    # Three adaptive levels resolve edges to 1/16 pixel; deeper levels on a
    # low threshold would mostly spend the sample budget on noise.
    depth = min(base.get("aa_max_depth", 3), 3)
    variants = {"aa none": {"aa": "none"},
                "aa grid 2x2": {"aa": "grid", "aa_samples": 2},
                "aa adaptive 0.25": {"aa": "adaptive", "aa_threshold": 0.25,
                                     "aa_max_depth": depth}}
    if not quick:
        variants.update({
            "aa grid 4x4": {"aa": "grid", "aa_samples": 4},
            "aa adaptive 0.05": {"aa": "adaptive", "aa_threshold": 0.05, "aa_max_depth": depth},
            "aa contrast 8x8": {**CONTRAST_AA, "aa_samples": 8},
            "max_depth 2": {"aa": "none", "max_depth": 2},
            "max_depth 4": {"aa": "none", "max_depth": 4},
        })
        if base.get("shadows", "physical") != "physical" or _has_ambient(base):
            variants["physical, aa none"] = {"aa": "none", "shadows": "physical",
                                             "ambient": {"type": "rgb", "value": [0, 0, 0]}}
    if base and not quick:
        variants = {"as in the scene": {}, **variants}
    return {label: {**base, **change} for label, change in variants.items()}


def _has_ambient(settings: dict) -> bool:
    return any(settings.get("ambient", {}).get("value", [0]))


def path_spp_ladder(largest: int) -> list[int]:
    """1, 2, 4, ... up to ``largest``."""
    return [1 << k for k in range(int(math.log2(max(largest, 1))) + 1)]


def measure(point: SweepPoint, reference: Reference) -> SweepPoint:
    point.rel_mse = rel_mse(point.image, reference.image)
    point.rmse = rmse(point.image, reference.image)
    point.flip, _ = flip_error(point.image, reference.image)
    return point


def run_sweep(scene: mi.Scene, reference: Reference, whitted: dict, path_spp: list[int],
              repeats: int = 3, path_depth: int | None = None, progress=None) -> list[SweepPoint]:
    """Time and measure each labelled Whitted setting and ``path`` at each
    spp of ``path_spp``."""
    total = len(whitted) + len(path_spp)
    points = []
    for label, settings in whitted.items():
        integrator = mi.load_dict({"type": "whitted", **settings})
        image, first, seconds = timed_render(scene, integrator, repeats)
        points.append(measure(SweepPoint(label, "whitted", settings, None, seconds, first, image),
                              reference))
        _report(progress, len(points), total, label)
    settings = path_settings(path_depth) if path_depth else path_settings()
    integrator = mi.load_dict(settings)
    for spp in path_spp:
        image, first, seconds = timed_render(scene, integrator, repeats, spp=spp, seed=spp)
        points.append(measure(SweepPoint(f"path {spp} spp", "path", settings, spp, seconds,
                                         first, image), reference))
        _report(progress, len(points), total, f"path {spp} spp")
    return points


def _report(progress, done, total, what):
    if progress is not None:
        progress(done, total, what)


@dataclass
class EqualError:
    """Time ``path`` needs to reach an error: exact (``relation`` "="),
    or a bound when the error lies outside the measured spp range."""
    seconds: float
    spp: float
    relation: str  # "=", "<" (path at 1 spp is already better), ">" (not reached)


def equal_error(path_points: list[SweepPoint], error: float) -> EqualError:
    """Interpolate the path curve (log time and log spp against log relMSE)
    at ``error``."""
    points = sorted(path_points, key=lambda p: p.spp)
    if error >= points[0].rel_mse:
        return EqualError(points[0].seconds, points[0].spp, "<")
    for low, high in zip(points, points[1:]):
        if high.rel_mse <= error:
            share = (math.log(low.rel_mse / error) / math.log(low.rel_mse / high.rel_mse)
                     if low.rel_mse > high.rel_mse else 1.0)
            return EqualError(_log_lerp(low.seconds, high.seconds, share),
                              _log_lerp(low.spp, high.spp, share), "=")
    return EqualError(points[-1].seconds, points[-1].spp, ">")


def _log_lerp(a: float, b: float, share: float) -> float:
    return math.exp(math.log(a) + share * (math.log(b) - math.log(a)))


@dataclass
class Speedup:
    point: SweepPoint
    path: EqualError

    @property
    def factor(self) -> float:
        """Path's time at Whitted's error over Whitted's time."""
        return self.path.seconds / self.point.seconds


#: How an equal-error figure is written: exact, or a bound.
RELATION_PREFIX = {"=": "", "<": "< ", ">": "> "}


def speedup_text(factor: float, relation: str) -> str:
    """A speed-up factor, with ``<``/``>`` when it is a bound."""
    return f"{RELATION_PREFIX[relation]}{factor:.3g}x"


def speedups(points: list[SweepPoint]) -> list[Speedup]:
    path_points = [p for p in points if p.kind == "path"]
    return [Speedup(p, equal_error(path_points, p.rel_mse)) for p in points if p.kind == "whitted"]


def crossing(points: list[SweepPoint]) -> Speedup:
    """Where the path curve reaches the most accurate Whitted setting:
    beyond that time, path is more accurate than every Whitted setting."""
    return min(speedups(points), key=lambda s: s.point.rel_mse)
