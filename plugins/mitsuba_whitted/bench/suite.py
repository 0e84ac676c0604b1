"""The benchmark's settings, and the run of all its measurements."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import mitsuba as mi

from ..overrides import load_with
from ..system import machine
from .bound import Bound, LaunchSplit, launch_split, ray_casting_bound
from . import gradients
from .equal_error import equal_error_speedup
from .processes import child_peak_memory, fresh_process_render, peak_rss_mib
from ..jit import release_scenes
from .timing import RenderTiming, ScalingRow, scaling_table, time_render

DEFAULT_SCENE = Path(__file__).resolve().parents[3] / "scenes" / "cosc363.xml"


@dataclass
class BenchSettings:
    scene: Path = DEFAULT_SCENE
    defines: dict = field(default_factory=dict)
    #: Film width of the headline, memory and depth figures (the height
    #: keeps the film's aspect); ``None``: the scene's own.
    resolution: int | None = None
    repeats: int = 7
    #: Rounds of the bound (a render and the casts): the ratio of a round
    #: wanders more on a shared machine than a render's time does, so their
    #: median takes more rounds than ``repeats``.
    bound_rounds: int = 25
    resolutions: tuple = (256, 512, 1024, 2048)
    depths: tuple = (2, 4, 6, 10)
    aa_depths: tuple = (0, 2, 5, 10)
    memory_resolutions: tuple = (600, 2048)
    fresh_processes: bool = True
    #: Equal-error scene: resolution, reference spp, largest path spp. The
    #: reference's own noise (which the bench reports) must stay below
    #: every error compared, and path's ladder must reach past Whitted's
    #: best settings.
    equal_error: tuple = (128, 65536, 16384)
    #: Timing rounds of the equal-error sweep: each times path's two
    #: ladders up to the largest spp, seconds a round, so fewer than
    #: ``repeats``.
    equal_error_rounds: int = 5
    #: Gradients at equal error: resolution, largest prb spp, prb seeds.
    gradient: tuple = (64, 1024, 8)

    @classmethod
    def quick(cls, scene: Path = DEFAULT_SCENE, defines=None) -> "BenchSettings":
        """Small sizes and few repeats: every figure, in seconds."""
        return cls(scene, dict(defines or {}), resolution=96, repeats=2, bound_rounds=2,
                   resolutions=(64, 128), depths=(2, 6), aa_depths=(0, 3),
                   memory_resolutions=(96,), equal_error=(32, 512, 64), equal_error_rounds=3,
                   gradient=(16, 4, 2))

    @property
    def scene_settings(self) -> dict:
        """What :func:`~mitsuba_whitted.overrides.load_with` changes in the
        scene for the headline."""
        return {} if self.resolution is None else {"res": self.resolution}


@dataclass
class Headline:
    """The scene's own figures: its renders, rays and ray-casting bound.
    ``bound`` and ``split`` are ``None`` where ``not_measured`` says why."""

    scene: str
    defines: dict
    settings: dict
    resolution: list
    indirect_samples: int
    timing: RenderTiming
    rays: dict
    rays_per_second: float
    bound: Bound | None
    split: LaunchSplit | None
    not_measured: dict
    peak_rss_mib_this_process: float


@dataclass
class BenchResults:
    """Every figure of a bench run; :func:`results_json` writes it out.
    The fresh-process figures are ``None`` where they were not measured."""

    machine: str
    headline: Headline
    fresh_process: dict | None
    fresh_process_empty_cache: dict | None
    peak_rss_mib: dict
    scaling: list[ScalingRow]
    equal_error: dict
    gradient: dict


def results_json(results: BenchResults) -> dict:
    """The figures as JSON data: the dataclasses as dictionaries, an
    infinite bound of an interval as ``None`` (JSON has no infinity)."""
    return asdict(results, dict_factory=lambda items: {
        name: None if isinstance(value, float) and math.isinf(value) else value
        for name, value in items})


def headline(scene_path: Path, settings: BenchSettings, report) -> Headline:
    """Warm and first renders, rays by kind and the ray-casting bound of
    ``scene_path``; the scene is released when this returns."""
    scene = load_with(scene_path, settings.defines, settings.scene_settings)
    integrator = scene.integrator()
    if not hasattr(integrator, "capture_rays"):
        raise RuntimeError("mitsuba-whitted bench: the scene's integrator is not 'whitted'.")
    report("timing warm renders ...")
    timing = time_render(scene, integrator, settings.repeats)
    bound, split, not_measured = ((None, None, {"bound": INDIRECT_UNCAPTURED})
                                  if integrator.indirect_samples
                                  else (*ray_casting(scene, integrator, settings, report), {}))
    kinds = RAY_KINDS + (INDIRECT_KINDS if integrator.indirect_samples else ())
    return Headline(str(scene_path), settings.defines, settings.scene_settings,
                    list(scene.sensors()[0].film().crop_size()), integrator.indirect_samples,
                    timing, {kind: timing.stats[kind] for kind in kinds},
                    timing.stats["total"] / timing.warm.median, bound, split, not_measured,
                    peak_rss_mib())


#: The rays a render counts, by kind, and those of its indirect paths.
RAY_KINDS = ("camera", "reflection", "refraction", "passthrough", "shadow", "shadow_march",
             "refined", "total")
INDIRECT_KINDS = ("indirect", "indirect_shadow")
#: Why a render with indirect paths has no ray-casting bound.
INDIRECT_UNCAPTURED = ("the indirect paths cast their rays inside their own loop, which a "
                       "capturing render does not record, so a bound from the recorded rays "
                       "would leave most of the work out")


def ray_casting(scene: mi.Scene, integrator, settings: BenchSettings,
                report) -> tuple[Bound, LaunchSplit]:
    """The render's own rays cast through Mitsuba's ray casting: the bound
    on the whole render, and on its first launch and the rest apart."""
    report("casting the render's own rays through Mitsuba's ray casting ...")
    integrator.capture_rays = True
    mi.render(scene, integrator=integrator)
    integrator.capture_rays = False
    captured, first_samples = integrator.last_rays, integrator.last_stats["aa_per_level"][0]
    integrator.last_rays = None
    bound = ray_casting_bound(scene, captured, lambda: mi.render(scene, integrator=integrator),
                              settings.bound_rounds)
    report("timing the first launch and the rest apart ...")
    split = launch_split(scene, integrator, captured, first_samples, bound.coherent,
                         settings.bound_rounds)
    del captured
    return bound, split


def run(settings: BenchSettings, report=print) -> BenchResults:
    """All measurements; ``report`` receives progress lines."""
    scene_path = Path(settings.scene)
    scene_figures = headline(scene_path, settings, report)
    release_scenes()
    fresh = empty = None
    if settings.fresh_processes:
        report("fresh processes (warm and empty kernel cache) ...")
        fresh = fresh_process_render(scene_path, settings.defines, False)
        empty = fresh_process_render(scene_path, settings.defines, True)
    report("peak memory in child processes ...")
    memory = {str(res): child_peak_memory(scene_path, settings.defines,
                                          dict(settings.scene_settings, res=res))
              for res in settings.memory_resolutions}
    report("scaling ...")
    scaling = scaling_table(scene_path, settings.defines, settings.scene_settings,
                            {"res": settings.resolutions, "max_depth": settings.depths,
                             "aa_max_depth": settings.aa_depths}, settings.repeats)
    report("equal error against path ...")
    equal_error = equal_error_speedup(*settings.equal_error, settings.equal_error_rounds)
    gradient = gradients.measure(
        scene_path, settings.defines, settings.scene_settings, settings.repeats,
        settings.memory_resolutions[0], settings.gradient, report,
        indirect=scene_figures.indirect_samples > 0)
    return BenchResults(machine(), scene_figures, fresh, empty, memory, scaling, equal_error,
                        gradient)
