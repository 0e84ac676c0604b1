"""The comparison of one scene file (``mitsuba-whitted compare``): a cached
path reference, the speed-against-error sweep, Whitted's error split into
its sampling error and its model's bias, and a Markdown report with
images, error maps, crops, tables, the error-against-time plot and
``results.json`` holding every number in it (its keys are described in
the README, section *Speed against error*).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import mitsuba as mi
import numpy as np

from .. import load_file
from ..distributed import SceneSource
from ..errors import Error
from ..files import check_folder, check_readable, write_text
from ..integrators.film import developed_format, develops_to_rgb
from ..scene_digest import scene_without_integrator_digest
from ..scene_files import check_not_read
from ..system import machine
from .cache import ReferenceCache, cache_key
from .converged import CONVERGED_SIDE, QUICK_SIDE, converged_renders, mean_errors
from .equal_error import Analysis, Gain, analyse
from .levels import (GOAL, LEVEL_METRIC, NOISE_MULTIPLE, PATH_NEVER, TOP_LEVEL, analyse_levels,
                     goal_summary)
from .intervals import (RELATION_PREFIX, REPLICATES, SEED, TAIL, estimate_text, json_data,
                        verdict_text)
from .metrics import (METRIC_NAMES, TILE_SIDES, missing_energy_share, missing_light, noise_rel_mse,
                      rel_squared_error)
from .photon_reference import (PHOTON_SETTINGS, QUICK_PHOTON_SETTINGS, PhotonSettings,
                               full_reference, path_floor, reference_name)
from .reference import Reference, cached_reference, path_settings
from .results import (CompareResults, ConvergedFigures, ConvergedRender, Crossing, FamilyThere,
                      LevelEntry, LevelsFigures, PathRung, PathThere, PhotonFigures,
                      ReferenceFigures,
                      TimingFigures, WhittedFigures, gain_fields)
from .report import Curve, MarkdownReport, Marker, Panel, number, shared_vmax, worst_window
from .sweep import (PhotonRungs, Sweep, SweepPoint, path_ladder, run_sweep, sampler_sensors,
                    scene_whitted_settings, whitted_settings, whitted_variants)
from .viewer import ViewerImage, ViewerTable, write_viewer

REFERENCE_PASSES = 16
#: Most samples per pixel: ``mi.render`` takes a 32-bit count.
MAX_SPP = (1 << 32) - 1
#: Written into a comparison's folder before its first file: a later
#: comparison may write there again.
FOLDER_MARK = ".mitsuba-whitted-compare"
#: Side of the zoomed crops, in pixels of the image, and their width once
#: enlarged.
CROP_SIDE, CROP_WIDTH = 24, 192


class CompareError(Error, ValueError):
    """Bad input to the comparison, said in one sentence."""


@dataclass
class CompareOptions:
    reference_spp: int
    path_max_spp: int
    rounds: int          # timing rounds (every setting once in each)
    quick: bool

    @classmethod
    def make(cls, quick: bool = False, reference_spp: int | None = None) -> "CompareOptions":
        if reference_spp is not None and not REFERENCE_PASSES <= reference_spp <= MAX_SPP:
            raise CompareError(f"--reference-spp must be from "
                               f"{REFERENCE_PASSES} to {MAX_SPP} (got {reference_spp}).")
        if quick:
            spp = reference_spp or 64
            return cls(spp, min(16, spp // 4), 4, True)
        spp = reference_spp or 1024
        return cls(spp, min(256, spp // 4), 7, False)

    @property
    def converged_side(self) -> int:
        return QUICK_SIDE if self.quick else CONVERGED_SIDE

    @property
    def photon_settings(self) -> PhotonSettings:
        """How the reference's photon part converges, where it has one."""
        return QUICK_PHOTON_SETTINGS if self.quick else PHOTON_SETTINGS


@dataclass
class SceneComparison:
    scene_path: Path
    defines: dict
    reference: Reference
    sweep: Sweep
    analysis: Analysis
    converged: dict
    report: Path | None
    results: CompareResults

    @property
    def name(self) -> str:
        return self.scene_path.stem


def load_scene(path: str | Path, defines: dict | None = None) -> mi.Scene:
    path = check_readable(path)
    scene = load_file(path, **(defines or {}))
    if not scene.sensors():
        raise CompareError(f"scene '{path}' has no sensor, "
                           f"so there is no image to compare.")
    film = scene.sensors()[0].film()
    if not develops_to_rgb(film):
        raise CompareError(f"the film of scene '{path}' develops to "
                           f"{developed_format(film).name}, and compare measures RGB images; "
                           "give it a pixel_format of 'rgb' or 'rgba'.")
    return scene


def check_report_folder(out: str | Path) -> Path:
    """``out`` if a comparison may write its report there: a new or empty
    folder, or one that a comparison wrote (it holds :data:`FOLDER_MARK`);
    else a :class:`CompareError`, as the report would replace the files
    in it."""
    out = check_folder(out)
    found = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
    if found and FOLDER_MARK not in found:
        shown = ", ".join(f"'{name}'" for name in found[:3]) + (", ..." if len(found) > 3 else "")
        raise CompareError(f"folder '{out}' holds files that compare did not write "
                           f"({shown}), which its report would replace; give --out a new or "
                           "empty folder, or one that compare wrote.", "mitsuba-whitted compare")
    return out


def compare_scene(scene_path: str | Path, out_dir: str | Path, options: CompareOptions,
                  defines: dict | None = None, cache_dir: str | Path | None = None,
                  progress=None, keep_linear: bool = True, backend=None) -> SceneComparison:
    """Render, measure and report; the reference and the converged Whitted
    renders are cached in ``cache_dir`` (default ``<out_dir>/cache``), the
    reference rendered by ``backend`` (default: in this process). ``out_dir``
    is refused unless :func:`check_report_folder` accepts it, and so is
    one that holds a file the scene reads."""
    scene_path, out_dir = Path(scene_path), check_report_folder(out_dir)
    check_not_read([out_dir], scene_path, defines or {})
    source = loaded_source(scene_path, defines)
    write_text(out_dir / FOLDER_MARK, "A report of mitsuba-whitted compare, which writes "
               "here again.\n")
    comparison = measure_scene(source, options, cache_dir or out_dir / "cache", progress,
                               backend)
    comparison.report = write_scene_report(out_dir, comparison, keep_linear)
    return comparison


def loaded_source(scene_path: str | Path, defines: dict | None = None) -> SceneSource:
    """The scene file with its defines, loaded by :func:`load_scene`."""
    return SceneSource(scene_path, defines or {}, load_scene(scene_path, defines))


def measure_scene(source: SceneSource, options: CompareOptions, cache_dir: str | Path,
                  progress=None, backend=None) -> SceneComparison:
    """Every render and measurement of a comparison of the loaded scene
    file ``source``, and its results, without the report (``report`` is
    ``None``)."""
    cache = ReferenceCache(cache_dir)
    path = cached_reference(cache, reference_key(source.path, source.defines,
                                                 options.reference_spp),
                            source, options.reference_spp, REFERENCE_PASSES,
                            path_settings(), progress, backend)
    _finish(progress)
    scene = source.scene
    reference = full_reference(cache, scene_without_integrator_digest(source.path,
                                                                      source.defines),
                               scene, path, options.photon_settings)
    variants = whitted_variants(scene_whitted_settings(scene), options.quick,
                                PhotonRungs.of(scene))
    sweep = run_sweep(scene, reference,
                      whitted_settings(variants) + path_ladder(options.path_max_spp),
                      sampler_sensors(source.path, source.defines), options.rounds, progress)
    _finish(progress)
    analysis = analyse(sweep)
    # Whitted's settings on path's model converge to path's image, not to
    # the light path misses; with photons, to all of it.
    converged = converged_renders(scene, source.digest, variants, cache, options.converged_side,
                                  reference.path_alone(), reference)
    results = _results(source.path.name, reference, sweep, analysis, converged, options,
                       scene.sensors()[0].film().rfilter().class_name())
    return SceneComparison(source.path, source.defines, reference, sweep, analysis, converged,
                           None, results)


def reference_key(scene_path: Path, defines: dict, spp: int) -> str:
    """The cache key of a comparison's path reference. It takes the scene
    without its integrator, which path's own settings replace, so that a
    change only Whitted sees keeps a reference that takes minutes."""
    return cache_key(scene=scene_without_integrator_digest(scene_path, defines), spp=spp,
                     passes=REFERENCE_PASSES, integrator=path_settings())


def _finish(progress):
    if progress is not None and hasattr(progress, "finish"):
        progress.finish()


def slug(label: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", label.lower()).strip("_")


# ---------------------------------------------------------------- results

def _results(name: str, reference: Reference, sweep: Sweep, analysis: Analysis,
             converged: dict, options: CompareOptions, film_filter: str) -> CompareResults:
    """Every number of the report."""
    renders = list({id(c): c for c in converged.values()}.values())
    biases = {id(c): mean_errors(c.image, reference.image) for c in renders}
    shown = {p.label for p in shown_rungs(sweep)}
    noise = noise_rel_mse(reference.variance, reference.image)
    floor = path_floor(reference)
    levels = analyse_levels(sweep, noise, {label: biases[id(c)]["relmse"]
                                           for label, c in converged.items()}, floor)
    return CompareResults(
        scene=name,
        reference=ReferenceFigures(reference.spp, REFERENCE_PASSES, reference.seconds,
                                   reference.cached, noise, list(reference.image.shape[:2]),
                                   reference_name(reference), floor,
                                   photon_figures(reference)),
        metrics=sweep.metrics,
        timing=TimingFigures(options.rounds, REPLICATES, SEED, TILE_SIDES, 1 - 2 * TAIL),
        converged=ConvergedFigures(options.converged_side,
                                   [ConvergedRender(c.settings, c.seconds, c.cached)
                                    for c in renders]),
        whitted={p.label: WhittedFigures(
            **_point_fields(p, analysis, True), settings=p.setting.integrator,
            sampling_error=mean_errors(p.image, converged[p.label].image),
            model_bias=biases[id(converged[p.label])], **gain_fields(analysis.gains[p.label]))
            for p in sweep.of_kind("whitted")},
        path={sampler: [PathRung(**_point_fields(sweep.points[i], analysis,
                                                 sweep.points[i].label in shown),
                                 spp=sweep.points[i].spp) for i in columns]
              for sampler, columns, _ in sweep.path_curves()},
        levels=LevelsFigures(LEVEL_METRIC, TOP_LEVEL, NOISE_MULTIPLE,
                             [LevelEntry.of(level) for level in levels], goal_summary(levels),
                             floor),
        crossing={metric: _crossing(*analysis.crossing(sweep, metric))
                  for metric in sweep.metrics},
        missing_energy_share=missing_energy_share(_first_whitted(sweep).image, reference.image),
        film_filter=film_filter)


def photon_figures(reference: Reference) -> PhotonFigures | None:
    """The figures of the reference's photon part, if it has one."""
    part = reference.photons
    if part is None:
        return None
    return PhotonFigures(part.settings.photons, part.settings.passes, part.settings.runs,
                         part.seconds, part.cached, noise_rel_mse(part.variance, reference.image),
                         part.radius_first, part.radius_last)


def reference_sentence(figures: ReferenceFigures) -> str:
    """Which the reference is, and path's own error against it."""
    if figures.photons is None:
        return ("Reference: Mitsuba's `path` alone: the scene does not have both a point, "
                "spot or directional light and a surface with a delta or null lobe, which "
                "together make light that `path` misses.")
    part = figures.photons
    return (f"Reference: {figures.name}: `path` misses the light of delta lights through "
            "delta or null surfaces here (caustics, and the light through index-1 or null "
            "surfaces), which progressive photon mapping adds "
            f"({part.runs} independent runs of {part.passes} passes of {part.photons} "
            f"photons, {part.seconds:.1f} s, "
            f"{'taken from the cache' if part.cached else 'rendered for this report'}; "
            f"gather radius {number(part.radius_first)} in the first pass to "
            f"{number(part.radius_last)} in the last, scene units; its noise, from the "
            f"spread of the runs, a relMSE of {number(part.noise_rel_mse)}, and its blur "
            "over the radius not counted in it). *Path's floor*: `path` alone against this reference, less the "
            f"photon part's noise, a relMSE of {number(figures.path_floor_rel_mse)}: no "
            "number of `path` samples gets below it.")


def _point_fields(point: SweepPoint, analysis: Analysis, has_image: bool) -> dict:
    """A sweep point's :class:`PointFigures` fields."""
    return {"first_seconds": point.first_seconds,
            "image": slug(point.label) if has_image else None,
            "seconds": analysis.seconds[point.label], "rel_mse": point.rel_mse,
            "rmse": point.rmse, "flip": point.flip}


def _crossing(point: SweepPoint, gain: Gain) -> Crossing:
    return Crossing(point.label, gain.path_seconds, gain.path_spp, gain.sampler)


def _first_whitted(sweep: Sweep) -> SweepPoint:
    return sweep.of_kind("whitted")[0]


def shown_rungs(sweep: Sweep) -> list[SweepPoint]:
    """The rungs of path's ladders whose images the report shows: the
    first, the middle and the last of each sampler's."""
    shown = []
    for _, columns, _ in sweep.path_curves():
        shown += [sweep.points[columns[i]] for i in sorted({0, len(columns) // 2,
                                                            len(columns) - 1})]
    return shown


# ----------------------------------------------------------------- report

def write_scene_report(out_dir: str | Path, comparison: SceneComparison,
                       keep_linear: bool = True) -> Path:
    """The report of ``comparison`` into ``out_dir``: its text, figures,
    images and ``results.json``; the path of its Markdown file."""
    return _write_report(Path(out_dir), comparison.scene_path, comparison.defines,
                         comparison.reference, comparison.sweep, comparison.converged,
                         comparison.results, keep_linear)


def _write_report(out_dir, scene_path, defines, reference, sweep, converged, results,
                  keep_linear):
    title = f"Whitted against path tracing: {scene_path.name}"
    report = MarkdownReport(out_dir, title)
    height, width = reference.image.shape[:2]
    defined = ", ".join(f"{k}={v}" for k, v in (defines or {}).items())
    origin = "taken from the cache" if reference.cached else "rendered for this report"
    summary = (
        f"Scene `{scene_path.name}`{f' ({defined})' if defined else ''}, {width} x {height} "
        f"pixels. Reference: {results.reference.name}. Mitsuba's `path` "
        f"(max_depth {path_settings()['max_depth']}), "
        f"{reference.path_alone().spp} spp in {REFERENCE_PASSES} independent passes, {origin} "
        f"({reference.seconds:.1f} s to render in all); the reference's own noise, estimated "
        f"from the spread of the passes{' and of the photon runs' if reference.photons else ''}"
        ", is a relMSE of "
        f"{number(results.reference.noise_rel_mse)}. "
        f"{timing_sentence(results.timing.rounds)} Machine: {machine()}.")
    report.paragraph(summary)
    report.paragraph(reference_sentence(results.reference))
    if results.film_filter != "BoxFilter":
        report.paragraph(
            f"Note: the film's reconstruction filter is `{results.film_filter}`; the path "
            "images use it, while Whitted averages each pixel over its own square (a box), "
            "so edges differ a little even where both agree. A `box` rfilter avoids this.")
    if keep_linear:
        report.linear("reference.exr", reference.image)
    _error_tables(report, results)
    report.figure(report.speed_plot("speed_vs_error.png", speed_panels(results),
                                    f"{scene_path.name}: error against time"),
                  "error against render time, relMSE and FLIP")
    shown = _image_grid(report, reference, sweep, converged, keep_linear)
    _missing_light(report, reference, sweep, results)
    data = json_data(results)
    write_text(Path(out_dir) / "results.json", json.dumps(data, indent=1))
    write_viewer(report, title, summary, shown, data, viewer_tables(results))
    return report.write("report.md")


def viewer_tables(results: CompareResults) -> list[ViewerTable]:
    """The tables of the report, for its page."""
    tables = [ViewerTable("Whitted settings", *whitted_rows(results)),
              ViewerTable("Path's rungs", *path_rows(results))]
    if results.levels.entries:
        tables.append(ViewerTable("Level by level", *level_rows(results)))
    return tables


def timing_sentence(rounds: int) -> str:
    """How the times and their intervals of a sweep of ``rounds`` rounds
    were measured."""
    return (f"Times: every setting rendered once to compile (*first render*) and once more "
            f"untimed, then timed once in each of {rounds} rounds, in an order shuffled anew "
            "in every round (Whitted's and path's settings, where both are timed, taking "
            "turns); a time is the median of the rounds with its "
            f"{1 - 2 * TAIL:.0%} interval, from {REPLICATES} bootstrap replicates that draw "
            "the rounds with replacement (the same draws for every setting).")


def split_sentence(side: int) -> str:
    """What the two parts of a Whitted setting's error are."""
    return ("*Sampling error*: the setting's image against Whitted's own converged render "
            f"(the same settings with a {side} x {side} grid in every pixel); *model bias*: "
            "that converged render against path's reference, what no anti-aliasing can "
            "remove. The total is near their sum where the two are unrelated.")


def speedup_sentence() -> str:
    """What an equal-error speed-up, its interval and its verdict are."""
    tiles = " and ".join(f"{side} for {METRIC_NAMES[metric]}"
                         for metric, side in TILE_SIDES.items())
    return ("*Equal-error speed-up*, in each metric apart: the time `path` needs for the "
            "setting's error, on the faster of its two samplers' curves there (interpolated "
            "on the log-log curve), over the setting's time. Path's time there comes from the "
            "same bootstrap, whose replicates also draw square tiles of the error maps with "
            f"replacement (the same tiles for every image; pixels a side: {tiles}) and "
            "interpolate again; the speed-up's interval runs from path's lowest time over "
            "the setting's highest to the reverse. *faster* or *slower* only where the "
            "interval excludes 1, else *tie*. `<` and `>` mark bounds, where the error lies "
            "outside path's measured range (`<`: its 1-spp render is already as accurate; "
            "`>`: its most samples do not reach it), their intervals open at one end.")


def _error_tables(report, results):
    report.heading("Error and time")
    whitted_table(report, results)
    report.paragraph(f"{split_sentence(results.converged.side)} {speedup_sentence()}")
    report.table(*path_rows(results))
    for sentence in verdict_sentences(results):
        report.paragraph(sentence)
    levels_table(report, results)


def path_rows(results: CompareResults) -> tuple[list[str], list[list]]:
    """The header and rows of the table of path's rungs."""
    return (["path", "spp", "first render (s)", "warm render (s)", "relMSE", "RMSE", "FLIP"],
            [[sampler, rung.spp, number(rung.first_seconds),
              estimate_text(rung.seconds, digits=3), number(rung.rel_mse), number(rung.rmse),
              number(rung.flip)]
             for sampler, rungs in results.path.items() for rung in rungs])


def levels_sentence() -> str:
    """What the table of levels shows."""
    return (f"*Level by level*: at each relMSE from {TOP_LEVEL:g} down to {NOISE_MULTIPLE:g} "
            "times the reference's own noise, the time `path` needs (the envelope of its "
            "samplers' curves) against the time of the cheapest Whitted setting that reaches "
            "it, the hybrid ladder read as a curve of its indirect paths per pixel. The "
            f"goal is {GOAL:g}x: *met* where the speed-up's interval lies at or above it, "
            "*missed* where it lies below, else *undecided*.")


def levels_table(report: MarkdownReport, results: CompareResults) -> None:
    """The speed-up at each error level of ``results``, and its summary."""
    levels = results.levels
    summary = levels.summary
    if not levels.entries:
        report.paragraph(f"No error levels: the reference's own noise times "
                         f"{NOISE_MULTIPLE:g} is above {TOP_LEVEL:g}.")
        return
    report.paragraph(levels_sentence())
    if levels.path_floor > 0:
        report.paragraph(f"Path's floor here is a relMSE of {number(levels.path_floor)}: "
                         f"at the levels at or below it, *{PATH_NEVER}*, whatever its "
                         "samples.")
    report.table(*level_rows(results))
    report.paragraph(f"The goal is met at {summary.met} of {summary.levels} levels; "
                     f"the family is faster at {summary.faster}.")


def level_rows(results: CompareResults) -> tuple[list[str], list[list]]:
    """The header and rows of the table of error levels."""
    return (["relMSE level", "path there", "Whitted family there", "speed-up",
             f"{GOAL:g}x goal"],
            [[number(entry.error), _path_cell(entry.path, entry.path_reaches),
              _family_cell(entry.whitted),
              _speedup_cell(entry), entry.goal]
             for entry in results.levels.entries])


def _speedup_cell(entry: LevelEntry) -> str:
    if not entry.path_reaches:
        return PATH_NEVER
    return "-" if entry.speedup is None else verdict_text(entry.speedup)


def _path_cell(path: PathThere, reaches: bool = True) -> str:
    if not reaches:
        return f"{PATH_NEVER}: below its floor"
    return (f"{estimate_text(path.seconds, digits=3)} s, {number(path.spp.median, 2)} spp, "
            f"{path.sampler}")


def _family_cell(whitted: FamilyThere) -> str:
    if whitted.setting is None:
        return ("not reached: below every model's bias" if math.isinf(whitted.seconds.median)
                else f"not reached; more samples would take > {number(whitted.seconds.median)} s")
    paths = "" if whitted.paths is None else f", {number(whitted.paths, 2)} paths"
    return f"{estimate_text(whitted.seconds, digits=3)} s, {whitted.setting}{paths}"


def whitted_table(report: MarkdownReport, results: CompareResults) -> None:
    """Each Whitted setting of ``results``: its times, its error split in
    each metric, its speed-up in each metric with interval and verdict."""
    report.table(*whitted_rows(results))


def whitted_rows(results: CompareResults) -> tuple[list[str], list[list]]:
    """The header and rows of :func:`whitted_table`."""
    metrics = results.metrics
    return (["Whitted setting", "first render (s)", "warm render (s)"]
            + [f"{METRIC_NAMES[m]}: total / sampling / model bias" for m in metrics]
            + [f"speed-up at equal {METRIC_NAMES[m]}; path there" for m in metrics],
            [[label, number(entry.first_seconds), estimate_text(entry.seconds, digits=3)]
             + [_split_cell(entry, metric) for metric in metrics]
             + [_gain_cell(entry, metric) for metric in metrics]
             for label, entry in results.whitted.items()])


def verdict_sentences(results: CompareResults) -> list[str]:
    """Where the metrics' verdicts differ, and where path overtakes the
    most accurate Whitted setting in each metric."""
    return disagreements(results) + [crossing_sentence(results.crossing[metric], metric)
                                     for metric in results.metrics]


def _split_cell(entry: WhittedFigures, metric: str) -> str:
    return (f"{number(entry.total(metric))} / {number(entry.sampling_error[metric])} / "
            f"{number(entry.model_bias[metric])}")


def _gain_cell(entry: WhittedFigures, metric: str) -> str:
    path = entry.path_at_equal_error[metric]
    return (f"{verdict_text(entry.speedup[metric])}; path "
            f"{RELATION_PREFIX[path.seconds.relation]}{number(path.seconds.median)} s, "
            f"{number(path.spp.median, 2)} spp, {path.sampler}")


#: A verdict in a sentence.
VERDICT_WORDS = {"faster": "faster", "slower": "slower", "tie": "a tie"}


def disagreements(results: CompareResults) -> list[str]:
    """A sentence for each Whitted setting whose verdicts differ between
    the metrics."""
    sentences = []
    for label, entry in results.whitted.items():
        verdicts = entry.verdict
        if len(set(verdicts.values())) > 1:
            said = [f"at equal {METRIC_NAMES[m]} it is {VERDICT_WORDS[v]} "
                    f"({estimate_text(entry.speedup[m], 'x')})"
                    for m, v in verdicts.items()]
            sentences.append(f"The metrics disagree on *{label}*: {' while '.join(said)}.")
    return sentences


def crossing_sentence(cross: Crossing, metric: str) -> str:
    """Where path overtakes the most accurate Whitted setting in ``metric``."""
    seconds, spp = cross.path_seconds, cross.path_spp
    where = {"=": f"at {estimate_text(seconds, ' s')}, about {estimate_text(spp, ' spp')} "
                  f"with {cross.sampler}",
             "<": f"already at 1 spp ({estimate_text(seconds, ' s')})",
             ">": f"beyond the measured range (after {estimate_text(seconds, ' s')})"}
    return (f"In {METRIC_NAMES[metric]}, path's curves cross {where[seconds.relation]}: from "
            f"there on `path` is more accurate than the most accurate Whitted setting here "
            f"({cross.label}).")


def speed_panels(results: CompareResults) -> list[Panel]:
    """The speed plot's panels, one per metric, from ``results``."""
    return [Panel(METRIC_NAMES[metric],
                  [Curve(sampler, [r.seconds.median for r in rungs],
                         [r.total(metric) for r in rungs], [r.spp for r in rungs])
                   for sampler, rungs in results.path.items()],
                  [Marker(label, entry.seconds.median, entry.total(metric),
                          entry.sampling_error[metric])
                   for label, entry in results.whitted.items()],
                  _biases(results, metric),
                  results.reference.noise_rel_mse if metric == "relmse" else None)
            for metric in results.metrics]


def _biases(results: CompareResults, metric: str) -> list[tuple[str, float]]:
    """Each distinct model's bias, named by the first setting of that model
    and how many more share it."""
    models = {}
    for label, entry in results.whitted.items():
        models.setdefault(json.dumps(entry.model_bias, sort_keys=True), []).append(label)
    return [(labels[0] + (f" +{len(labels) - 1}" if len(labels) > 1 else ""),
             results.whitted[labels[0]].model_bias[metric])
            for labels in models.values()]


def _image_grid(report, reference, sweep, converged, keep_linear):
    """Every Whitted setting and three rungs of each path ladder at full
    size, each with its error map on one colour scale; then crops where
    anti-aliasing matters most. The images shown, the reference first, for
    the report's page."""
    report.heading("Images and error maps")
    shown = sweep.of_kind("whitted") + shown_rungs(sweep)
    maps = [rel_squared_error(p.image, reference.image) for p in shown]
    vmax = shared_vmax(maps)
    link = report.image("reference.png", reference.image)
    report.figures([(link, "reference")])
    images = [ViewerImage("reference", "reference", link, reference.image)]
    for p, error in zip(shown, maps):
        name = slug(p.label)
        if keep_linear:
            report.linear(f"{name}.exr", p.image)
        link = report.image(f"{name}.png", p.image)
        images.append(ViewerImage(p.label, name, link, p.image))
        report.figures([(link, p.label),
                        (report.heatmap(f"{name}_error.png", error, "relative squared error",
                                        vmax), f"{p.label}: error")])
    _crops(report, reference, sweep, converged)
    return images


def _crops(report, reference, sweep, converged):
    """The same square of every Whitted image, of its converged render and
    of the reference, enlarged: the square where the setting with the
    largest sampling error errs most against its converged render."""
    whitted = sweep.of_kind("whitted")
    sampling = {p.label: rel_squared_error(p.image, converged[p.label].image) for p in whitted}
    coarsest = max(whitted, key=lambda p: float(np.mean(sampling[p.label])))
    side = min(CROP_SIDE, *reference.image.shape[:2])
    corner = worst_window(sampling[coarsest.label], side)
    factor = max(1, CROP_WIDTH // side)
    report.heading("Where anti-aliasing matters", level=3)
    report.paragraph(
        f"The {side} x {side}-pixel square (top left at row {corner[0]}, column {corner[1]}) "
        f"where *{coarsest.label}*, the setting with the largest sampling error, differs "
        f"most from its converged render; each pixel enlarged {factor} times.")
    items = [(report.crop("crop_reference.png", reference.image, corner, side, factor),
              "reference"),
             (report.crop("crop_converged.png", converged[coarsest.label].image, corner, side,
                          factor), f"Whitted converged ({coarsest.label}'s model)")]
    items += [(report.crop(f"crop_{slug(p.label)}.png", p.image, corner, side, factor),
               p.label) for p in whitted]
    for start in range(0, len(items), 4):
        report.figures(items[start:start + 4])


def _missing_light(report, reference, sweep, results):
    point = _first_whitted(sweep)
    report.heading("What Whitted leaves out")
    link = report.heatmap("missing_light.png", missing_light(point.image, reference.image),
                          "luminance missing", cmap="viridis")
    report.paragraph(
        f"Reference minus Whitted ({point.label}), positive part: light the path tracer "
        f"finds and Whitted does not (indirect diffuse light, caustics). It is "
        f"{100 * results.missing_energy_share:.1f}% of the reference's total luminance.")
    report.figure(link, "light Whitted leaves out")
