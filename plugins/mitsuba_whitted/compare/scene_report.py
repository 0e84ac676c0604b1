"""The comparison of one scene file (``mitsuba-whitted compare``): a cached
path reference, the speed-against-error sweep, and a Markdown report with
images, error maps, a table, the error-against-time plot and
``results.json`` holding every number in it.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import mitsuba as mi
import numpy as np

from .. import load_file
from ..distributed import SceneSource
from ..files import check_readable, write_text
from ..film_format import developed_format, develops_to_rgb
from ..system import machine
from .cache import ReferenceCache, cache_key
from .metrics import missing_energy_share, missing_light, noise_rel_mse, rel_squared_error
from .reference import Reference, cached_reference, path_settings
from .report import MarkdownReport, number
from .sweep import (SweepPoint, crossing, path_spp_ladder, run_sweep, scene_whitted_settings,
                    speedup_text, speedups, whitted_variants)

REFERENCE_PASSES = 16


class CompareError(ValueError):
    """Bad input to the comparison, said in one sentence."""


@dataclass
class CompareOptions:
    reference_spp: int
    path_max_spp: int
    repeats: int    # warm renders per setting (their median is its time)
    quick: bool

    @classmethod
    def make(cls, quick: bool = False, reference_spp: int | None = None) -> "CompareOptions":
        if reference_spp is not None and reference_spp < REFERENCE_PASSES:
            raise CompareError(f"mitsuba-whitted: --reference-spp must be at least "
                               f"{REFERENCE_PASSES} (got {reference_spp}).")
        if quick:
            spp = reference_spp or 64
            return cls(spp, min(16, spp // 4), 2, True)
        spp = reference_spp or 1024
        return cls(spp, min(256, spp // 4), 3, False)


@dataclass
class SceneComparison:
    name: str
    reference: Reference
    points: list[SweepPoint]
    report: Path
    results: dict


def load_scene(path: str | Path, defines: dict | None = None) -> mi.Scene:
    path = check_readable(path)
    scene = load_file(path, **(defines or {}))
    if not scene.sensors():
        raise CompareError(f"mitsuba-whitted: scene '{path}' has no sensor, "
                           f"so there is no image to compare.")
    film = scene.sensors()[0].film()
    if not develops_to_rgb(film):
        raise CompareError(f"mitsuba-whitted: the film of scene '{path}' develops to "
                           f"{developed_format(film).name}, and compare measures RGB images; "
                           "give it a pixel_format of 'rgb' or 'rgba'.")
    return scene


def compare_scene(scene_path: str | Path, out_dir: str | Path, options: CompareOptions,
                  defines: dict | None = None, cache_dir: str | Path | None = None,
                  progress=None, keep_linear: bool = True, backend=None) -> SceneComparison:
    """Render, measure and report; the reference is cached in ``cache_dir``
    (default ``<out_dir>/cache``) and rendered by ``backend`` (default: in
    this process)."""
    scene_path, out_dir = Path(scene_path), Path(out_dir)
    scene = load_scene(scene_path, defines)
    source = SceneSource(scene_path, defines or {}, scene)
    cache = ReferenceCache(cache_dir or out_dir / "cache")
    settings = path_settings()
    key = cache_key(scene=source.digest, spp=options.reference_spp,
                    passes=REFERENCE_PASSES, integrator=settings)
    reference = cached_reference(cache, key, source, options.reference_spp, REFERENCE_PASSES,
                                 settings, progress, backend)
    _finish(progress)
    variants = whitted_variants(scene_whitted_settings(scene), options.quick)
    points = run_sweep(scene, reference, variants, path_spp_ladder(options.path_max_spp),
                       options.repeats, progress=progress)
    _finish(progress)
    results = _results(scene_path.name, reference, points)
    results["film_filter"] = scene.sensors()[0].film().rfilter().class_name()
    report = _write_report(out_dir, scene_path, defines, reference, points, results, keep_linear)
    return SceneComparison(scene_path.stem, reference, points, report, results)


def _finish(progress):
    if progress is not None and hasattr(progress, "finish"):
        progress.finish()


def slug(label: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", label.lower()).strip("_")


def _results(name: str, reference: Reference, points: list[SweepPoint]) -> dict:
    """Every number of the report, keyed for machines."""
    gains = speedups(points)
    best = crossing(points)
    return {
        "scene": name,
        "reference": {"spp": reference.spp, "passes": REFERENCE_PASSES,
                      "seconds": reference.seconds, "cached": reference.cached,
                      "noise_rel_mse": noise_rel_mse(reference.variance, reference.image),
                      "size": list(reference.image.shape[:2])},
        "points": [{"label": p.label, "kind": p.kind, "spp": p.spp, "seconds": p.seconds,
                    "first_seconds": p.first_seconds, "rel_mse": p.rel_mse, "rmse": p.rmse,
                    "flip": p.flip, "image": slug(p.label)} for p in points],
        "speedups": {g.point.label: {"factor": g.factor, "relation": g.path.relation,
                                     "path_seconds": g.path.seconds, "path_spp": g.path.spp}
                     for g in gains},
        "crossing": {"label": best.point.label, "path_seconds": best.path.seconds,
                     "path_spp": best.path.spp, "relation": best.path.relation},
        "missing_energy_share": missing_energy_share(_first_whitted(points).image,
                                                     reference.image),
    }


def _first_whitted(points):
    return next(p for p in points if p.kind == "whitted")


def _write_report(out_dir, scene_path, defines, reference, points, results, keep_linear):
    report = MarkdownReport(out_dir, f"Whitted against path tracing: {scene_path.name}")
    height, width = reference.image.shape[:2]
    defined = ", ".join(f"{k}={v}" for k, v in (defines or {}).items())
    origin = "taken from the cache" if reference.cached else "rendered for this report"
    report.paragraph(
        f"Scene `{scene_path.name}`{f' ({defined})' if defined else ''}, {width} x {height} "
        f"pixels. Reference: Mitsuba's `path` (max_depth {path_settings()['max_depth']}), "
        f"{reference.spp} spp in {REFERENCE_PASSES} independent passes, {origin} "
        f"({reference.seconds:.1f} s to render); its own noise, estimated from the spread of "
        f"the passes, is a relMSE of {number(results['reference']['noise_rel_mse'])}. "
        f"Times are the median of warm renders (kernels compiled), "
        f"the first render's time is shown apart. Machine: {machine()}.")
    if results["film_filter"] != "BoxFilter":
        report.paragraph(
            f"Note: the film's reconstruction filter is `{results['film_filter']}`; the path "
            "images use it, while Whitted averages each pixel over its own square (a box), "
            "so edges differ a little even where both agree. A `box` rfilter avoids this.")
    if keep_linear:
        report.linear("reference.exr", reference.image)
    _error_table(report, points, results)
    best = results["crossing"]
    report.paragraph(_crossing_sentence(best, results))
    report.figure(report.speed_plot("speed_vs_error.png", points, f"{scene_path.name}: "
                                    "error against time",
                                    results["reference"]["noise_rel_mse"]),
                  "relMSE against render time")
    _image_grid(report, reference, points, keep_linear)
    _missing_light(report, reference, points, results)
    write_text(Path(out_dir) / "results.json", json.dumps(results, indent=1))
    return report.write("report.md")


def _error_table(report, points, results):
    report.heading("Error and time")
    rows = []
    for p in points:
        gain = results["speedups"].get(p.label)
        equal = (f"{number(gain['path_seconds'])} s ({number(gain['path_spp'], 2)} spp)"
                 if gain else "")
        factor = speedup_text(gain["factor"], gain["relation"]) if gain else ""
        rows.append([p.label, number(p.first_seconds), number(p.seconds), number(p.rel_mse),
                     number(p.rmse), number(p.flip), equal, factor])
    report.table(["setting", "first render (s)", "warm render (s)", "relMSE", "RMSE", "FLIP",
                  "path at equal relMSE", "equal-error speed-up"], rows)
    report.paragraph(
        "Equal-error speed-up: the time `path` needs for Whitted's relMSE (interpolated on "
        "the log-log path curve) over Whitted's time; `<` or `>` marks a bound where that "
        "error lies outside the measured spp range.")


def _crossing_sentence(best, results) -> str:
    where = {"=": f"at {number(best['path_seconds'])} s (about {number(best['path_spp'], 2)} "
                  "spp)",
             "<": f"already at 1 spp ({number(best['path_seconds'])} s)",
             ">": f"beyond the measured range (after {number(best['path_seconds'])} s)"}
    return (f"The curves cross {where[best['relation']]}: from there on `path` is more "
            f"accurate than the most accurate Whitted setting here ({best['label']}).")


def _image_grid(report, reference, points, keep_linear):
    """Every Whitted setting and three rungs of the path ladder (1 spp,
    the middle, the most), each with its error map on one colour scale."""
    report.heading("Images and error maps")
    path = [p for p in points if p.kind == "path"]
    rungs = sorted({0, len(path) // 2, len(path) - 1})
    shown = [p for p in points if p.kind == "whitted"] + [path[i] for i in rungs]
    maps = [rel_squared_error(p.image, reference.image) for p in shown]
    vmax = max(float(np.percentile(np.concatenate([m.ravel() for m in maps]), 99.5)), 1e-12)
    report.figures([(report.image("reference.png", reference.image), "path reference")])
    for p, error in zip(shown, maps):
        name = slug(p.label)
        if keep_linear:
            report.linear(f"{name}.exr", p.image)
        report.figures([(report.image(f"{name}.png", p.image), p.label),
                        (report.heatmap(f"{name}_error.png", error, "relative squared error",
                                        vmax), f"{p.label}: error")])


def _missing_light(report, reference, points, results):
    point = _first_whitted(points)
    report.heading("What Whitted leaves out")
    link = report.heatmap("missing_light.png", missing_light(point.image, reference.image),
                          "luminance missing", cmap="viridis")
    report.paragraph(
        f"Reference minus Whitted ({point.label}), positive part: light the path tracer "
        f"finds and Whitted does not (indirect diffuse light, caustics). It is "
        f"{100 * results['missing_energy_share']:.1f}% of the reference's total luminance.")
    report.figure(link, "light Whitted leaves out")
