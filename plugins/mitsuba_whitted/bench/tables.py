"""The benchmark's figures as a plain-text table, a part at a time: the
bench prints each part as soon as it is measured."""

from __future__ import annotations

from ..compare.intervals import estimate_text, verdict_text
from ..compare.metrics import METRIC_NAMES
from . import gradient_figures
from .bound import CASTS, Bound, LaunchSplit
from .equal_error import EqualErrorFigures, EqualErrorSetting
from .processes import ProcessTiming
from .results import BenchResults, Headline
from .timing import ScalingRow


def _mode(coherent: bool) -> str:
    return "coherent" if coherent else "incoherent"


def _count(number: int, one: str, many: str) -> str:
    return f"{number} {one if number == 1 else many}"


def _split_lines(split: LaunchSplit) -> list:
    more = split.launches - 1
    return [
        f"    first camera launch       {split.first_seconds:8.3f} s, its rays' bound "
        f"{split.first_bound:.3f} s: {split.first_ratio:.2f}"
        f"  ({split.first_samples:,} samples, from the render's start)",
        f"    the rest                  {split.rest_seconds:8.3f} s, its rays' bound "
        f"{split.rest_bound:.3f} s: {split.rest_ratio:.2f}"
        f"  ({_count(more, 'later launch', 'later launches')} and all the render does"
        " between and after them)",
        f"    a frozen call's fixed cost {split.frozen_call_seconds * 1e3:7.2f} ms (Dr.Jit traverses"
        f" the scene at every call) x {_count(split.launches, 'launch', 'launches')} = "
        f"{split.frozen_call_seconds * split.launches * 1e3:.1f} ms",
    ]


def _gain_text(row: EqualErrorSetting, metric: str) -> str:
    """A setting's error, path's spp at that error and the speed-up, in ``metric``."""
    error = row.whitted_rel_mse if metric == "relmse" else row.whitted_flip
    path = row.path_at_equal_error[metric]
    return (f"\n      {METRIC_NAMES[metric]:<6} {error:.2e}: path "
            f"{estimate_text(path.spp, ' spp', 3)} {path.sampler}, "
            f"{verdict_text(row.speedup[metric])}")


def _bound_lines(bound: Bound, split: LaunchSplit) -> list:
    return [
        "  bound: " + " + ".join(
            f"{name} {bound.rays[name]:,} rays {bound.seconds_by_cast[name]:.3f} s"
            f" ({_mode(bound.coherent[name])})" for name in CASTS)
        + f" = {bound.seconds:.3f} s",
        f"  bound / actual              {bound.ratio:8.2f}  (median of {len(bound.ratios)}"
        f" rounds of render and casts: {min(bound.ratios):.2f}"
        f" to {max(bound.ratios):.2f}; render {bound.render_seconds:.3f} s in those rounds)",
        *_split_lines(split),
    ]


def headline_lines(machine: str, scene: Headline) -> list:
    """The scene's renders, rays and ray-casting bound."""
    width, height = scene.resolution
    return [
        f"machine: {machine}",
        f"scene {scene.scene} at {width}x{height} {scene.defines}",
        f"  warm render (median)        {estimate_text(scene.timing.warm, ' s', 3)}",
        f"  first render in process     {scene.timing.first:8.3f} s"
        f"  (second {scene.timing.second:.3f} s)",
        "  rays: " + ", ".join(f"{k} {v:,}" for k, v in scene.rays.items()),
        f"  rays/s                      {scene.rays_per_second / 1e6:8.2f} M",
        *(_bound_lines(scene.bound, scene.split) if scene.bound is not None
          else [f"  bound: not measured: {scene.not_measured['bound']}"]),
    ]


def fresh_process_lines(fresh: ProcessTiming, empty: ProcessTiming) -> list:
    """A whole render process, with the kernel cache warm and empty."""
    return [
        f"  whole render process        {fresh.process_seconds:8.3f} s  "
        f"(render {fresh.render_seconds:.3f} s, kernel cache warm; the scene as "
        "`mitsuba-whitted render` renders it)",
        f"  same, empty kernel cache    {empty.process_seconds:8.3f} s  "
        f"(render {empty.render_seconds:.3f} s)",
    ]


def memory_lines(peak_rss_mib: dict) -> list:
    return ["  peak RSS by film width: " + ", ".join(f"{res} px {mib:,.0f} MiB"
                                                 for res, mib in peak_rss_mib.items())]


def scaling_lines(rows: list[ScalingRow]) -> list:
    return ["  scaling (warm):"] + [
        f"    {row.parameter:>12} = {str(row.value):>5}  {estimate_text(row.seconds, ' s', 3)}"
        f"  {row.rays:>12,} rays  {row.rays_per_second / 1e6:6.2f} M rays/s" for row in rows]


def equal_error_lines(eq: EqualErrorFigures) -> list:
    """Whitted's settings against path at equal error, and the headline."""
    return [
        f"  equal-error speed-up over path on {eq.scene} at {eq.resolution}^2 "
        f"(reference {eq.reference_spp} spp, its own noise relMSE "
        f"{eq.reference_noise_rel_mse:.1e}; {eq.rounds} rounds):",
        *(f"    {row.whitted:<46} {estimate_text(row.whitted_seconds, ' s', 3)}"
          + "".join(_gain_text(row, metric) for metric in row.speedup)
          for row in eq.settings),
        f"  headline: {eq.headline.whitted}, "
        + ", ".join(f"{METRIC_NAMES[m]} {verdict_text(s)}"
                    for m, s in eq.headline.speedup.items()),
    ]


def format_table(results: BenchResults) -> str:
    """The benchmark as a plain-text table, in the order the bench
    measures (and prints) its parts."""
    fresh = ([] if results.fresh_process is None
             else fresh_process_lines(results.fresh_process, results.fresh_process_empty_cache))
    return "\n".join(headline_lines(results.machine, results.headline) + fresh
                     + memory_lines(results.peak_rss_mib) + scaling_lines(results.scaling)
                     + equal_error_lines(results.equal_error)
                     + gradient_figures.format_lines(results.gradient))
