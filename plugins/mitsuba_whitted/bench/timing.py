"""Render times in this process: the first renders apart from the warm
ones, and the warm time as one setting at a time varies."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import mitsuba as mi

from ..compare.intervals import Estimate, median_estimate
from ..jit import release_scenes, timed
from ..overrides import load_with


@dataclass
class RenderTiming:
    first: float
    second: float
    warm: Estimate
    warm_all: list
    stats: dict


def time_render(scene: mi.Scene, integrator, repeats: int) -> RenderTiming:
    """First render (in this process), the second, and the median of the
    warm renders after them with its 95% interval. The second is kept
    apart: it is the first to replay the kernels the first recorded, and
    anything that makes it record them again shows there."""
    def render():
        mi.render(scene, integrator=integrator)

    (first, second), warm = timed(render, 2)[1], timed(render, repeats)[1]
    return RenderTiming(first, second, median_estimate(warm), warm,
                        dict(integrator.last_stats))


@dataclass
class ScalingRow:
    parameter: str
    value: object
    seconds: Estimate
    rays: int
    #: Derived, a field so that the bench's JSON holds it.
    rays_per_second: float = field(init=False)

    def __post_init__(self):
        self.rays_per_second = self.rays / self.seconds.median


def warm_timing(scene_path: Path, defines: dict, settings: dict, repeats: int) -> RenderTiming:
    scene = load_with(scene_path, defines, settings)
    return time_render(scene, scene.integrator(), repeats)


def scaling_table(scene_path: Path, defines: dict, base: dict, sweeps: dict,
                  repeats: int) -> list[ScalingRow]:
    """Warm render time as each setting of ``sweeps`` varies alone from
    ``base`` (settings of :func:`~mitsuba_whitted.overrides.load_with`)."""
    rows = []
    for parameter, values in sweeps.items():
        for value in values:
            release_scenes()
            timing = warm_timing(scene_path, defines, dict(base, **{parameter: value}), repeats)
            rows.append(ScalingRow(parameter, value, timing.warm, timing.stats["total"]))
    return rows
