"""The benchmark's settings, and the run of all its measurements."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import mitsuba as mi

from .. import scenes
from ..errors import UsageError
from ..integrators.settings import is_whitted
from ..overrides import load_with
from ..system import machine
from . import gradient_figures, tables
from .bound import Bound, LaunchSplit, launch_split, ray_casting_bound
from .results import BenchResults, Headline
from .equal_error import equal_error_speedup
from .processes import child_peak_memory, fresh_process_render, peak_rss_mib
from ..jit import release_scenes
from ..progress import Progress
from .timing import scaling_table, time_render

#: The report's scene, as the package ships it.
DEFAULT_SCENE = scenes.path(scenes.REPORT)


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
    #: reference's own noise (which the bench reports) must stay well below
    #: every error compared, and path's ladder must reach past Whitted's
    #: best settings. relMSE is a mean over pixels, so a smaller film
    #: leaves the errors compared as they are (its edge pixels, where
    #: Whitted's error lies, weigh a little more) and costs path a quarter
    #: of the time per halving of its side.
    equal_error: tuple = (64, 65536, 8192)
    #: Timing rounds of the equal-error sweep: each times path's two
    #: ladders up to the largest spp, seconds a round, so fewer than
    #: ``repeats``.
    equal_error_rounds: int = 3
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


def headline(scene_path: Path, settings: BenchSettings, report) -> Headline:
    """Warm and first renders, rays by kind and the ray-casting bound of
    ``scene_path``; the scene is released when this returns."""
    scene = load_with(scene_path, settings.defines, settings.scene_settings)
    integrator = scene.integrator()
    if not is_whitted(integrator):
        raise UsageError("the scene's integrator is not 'whitted'.", "mitsuba-whitted bench")
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


def run(settings: BenchSettings, report=print, show=None) -> BenchResults:
    """All measurements; ``report`` receives progress lines, and ``show``
    (when given) each part's table as soon as that part is measured: the
    full bench takes minutes."""
    show = show or (lambda text: None)
    scene_path = Path(settings.scene)
    scene_figures = headline(scene_path, settings, report)
    this_machine = machine()
    show("\n".join(tables.headline_lines(this_machine, scene_figures)))
    release_scenes()
    fresh = empty = None
    if settings.fresh_processes:
        report("fresh processes (warm and empty kernel cache) ...")
        fresh = fresh_process_render(scene_path, settings.defines, False)
        empty = fresh_process_render(scene_path, settings.defines, True)
        show("\n".join(tables.fresh_process_lines(fresh, empty)))
    report("peak memory in child processes ...")
    memory = {str(res): child_peak_memory(scene_path, settings.defines,
                                          dict(settings.scene_settings, res=res))
              for res in settings.memory_resolutions}
    show("\n".join(tables.memory_lines(memory)))
    report("scaling ...")
    scaling = scaling_table(scene_path, settings.defines, settings.scene_settings,
                            {"res": settings.resolutions, "max_depth": settings.depths,
                             "aa_max_depth": settings.aa_depths}, settings.repeats)
    show("\n".join(tables.scaling_lines(scaling)))
    report("equal error against path ...")
    progress = Progress()
    equal_error = equal_error_speedup(*settings.equal_error, settings.equal_error_rounds,
                                      progress)
    progress.finish()
    show("\n".join(tables.equal_error_lines(equal_error)))
    gradient = gradient_figures.measure_gradients(
        scene_path, settings.defines, settings.scene_settings, settings.repeats,
        settings.memory_resolutions[0], settings.gradient, report,
        indirect=scene_figures.indirect_samples > 0)
    show("\n".join(gradient_figures.format_lines(gradient)))
    return BenchResults(this_machine, scene_figures, fresh, empty, memory, scaling,
                        equal_error, gradient)
