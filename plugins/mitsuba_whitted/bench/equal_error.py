"""The equal-error speed-up over ``path``: how much longer Mitsuba's path
tracer takes to match Whitted's error on a scene both render alike."""

from __future__ import annotations

from dataclasses import dataclass

import mitsuba as mi

from ..compare import (PATH_SAMPLERS, analyse, noise_rel_mse, path_ladder, path_settings,
                       render_reference, run_sweep, whitted_settings)
from ..compare.intervals import Estimate
from ..compare.results import PathThere, gain_fields
from ..compare.sweep import CONTRAST_AA

#: Longest path of every render in the equal-error comparison (the
#: reference's too, so that all of them model the same light).
EQUAL_ERROR_DEPTH = 12


def fresnel_scene(resolution: int) -> dict:
    """An equivalence scene: a glass sphere before an emitting checkerboard.
    Every path of light is a chain of Fresnel reflections and refractions,
    which Whitted follows exactly and ``path`` samples one branch at a time."""
    backdrop = {"type": "checkerboard", "color0": {"type": "rgb", "value": [0.1, 0.25, 0.8]},
                "color1": {"type": "rgb", "value": [1.0, 0.8, 0.3]},
                "to_uv": mi.ScalarTransform4f().scale([6, 6, 1])}
    return {
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 35,
                   "to_world": mi.ScalarTransform4f().look_at([0, 0, 5], [0, 0, 0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": resolution, "height": resolution,
                            "rfilter": {"type": "box"}}},
        "glass": {"type": "sphere", "radius": 1.0, "bsdf": {"type": "dielectric", "int_ior": 1.5}},
        "backdrop": {"type": "rectangle",
                     "to_world": mi.ScalarTransform4f().translate([0, 0, -3]).scale(4),
                     "emitter": {"type": "area", "radiance": backdrop}},
    }


def equal_error_settings() -> dict:
    """Labelled Whitted settings for the equal-error comparison: n x n grids
    (n = 1, 2, 4, 8), and contrast-driven refinement with 64 and 256 points
    per edge pixel, each with the default ray-tree pruning and coarser ones
    (``min_throughput`` 1e-3 and 1e-2: branches carrying under 0.1% or 1%
    are left out)."""
    settings = {f"whitted grid {n}x{n}": {"aa": "grid", "aa_samples": n} for n in (1, 2, 4, 8)}
    for n in (8, 16):
        for pruning in (1e-4, 1e-3, 1e-2):
            settings[f"whitted contrast {n}x{n}, min_throughput {pruning:g}"] = {
                **CONTRAST_AA, "aa_samples": n, "min_throughput": pruning}
    return {label: {"max_depth": EQUAL_ERROR_DEPTH, **values} for label, values in settings.items()}


#: The setting of the headline figure, always the same one (the best of a
#: run would change from run to run with the noise): contrast refinement
#: with the most points and the default pruning.
HEADLINE = "whitted contrast 16x16, min_throughput 0.0001"


@dataclass
class EqualErrorSetting:
    """A Whitted setting's error and time, and, by metric, its speed-up
    over path at that error, the verdict and path's figures there."""
    whitted: str
    whitted_rel_mse: float
    whitted_flip: float | None
    whitted_seconds: Estimate
    speedup: dict[str, Estimate]
    verdict: dict[str, str]
    path_at_equal_error: dict[str, PathThere]


@dataclass
class EqualErrorFigures:
    """The comparison: its scene, its reference, and every setting; the
    headline is :data:`HEADLINE`'s row."""
    scene: str
    resolution: int
    reference_spp: int
    reference_noise_rel_mse: float
    rounds: int
    settings: list[EqualErrorSetting]

    @property
    def headline(self) -> EqualErrorSetting:
        return next(row for row in self.settings if row.whitted == HEADLINE)


def equal_error_speedup(resolution: int, reference_spp: int, largest_spp: int,
                        rounds: int, progress=None) -> EqualErrorFigures:
    """Time ``path`` needs to match Whitted's error on ``fresnel_scene``,
    over Whitted's time (both warm, timed in ``rounds`` interleaved rounds,
    against one converged reference), in relMSE and FLIP with their 95%
    intervals, for Whitted's anti-aliasing settings
    (:func:`equal_error_settings`): its only error is aliasing, which they
    shrink, while path's is noise. The headline is :data:`HEADLINE`.
    ``progress(done, total, what)`` hears of the reference's passes and the
    sweep's renders."""
    description = fresnel_scene(resolution)
    scene = mi.load_dict(description)
    reference = render_reference(scene, reference_spp,
                                 settings=path_settings(EQUAL_ERROR_DEPTH), progress=progress)
    sensors = {sampler: mi.load_dict({**description["sensor"], "sampler": {"type": sampler}})
               for sampler in PATH_SAMPLERS}
    sweep = run_sweep(scene, reference, whitted_settings(equal_error_settings())
                      + path_ladder(largest_spp, depth=EQUAL_ERROR_DEPTH), sensors, rounds,
                      progress)
    analysis = analyse(sweep)
    rows = [EqualErrorSetting(p.label, p.rel_mse, p.flip, analysis.seconds[p.label],
                              **gain_fields(analysis.gains[p.label]))
            for p in sweep.of_kind("whitted")]
    return EqualErrorFigures("glass sphere before an emitting checkerboard", resolution,
                             reference.spp,
                             noise_rel_mse(reference.variance, reference.image), rounds, rows)

