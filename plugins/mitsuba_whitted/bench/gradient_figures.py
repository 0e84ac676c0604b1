"""The bench's gradient figures: a gradient of the scene beside its render,
the peak memory of one, and Mitsuba's ``prb`` at equal gradient error.

A gradient here is what one step of an optimisation runs:
``mi.render(scene, params)`` and ``dr.backward`` of the image, with every
differentiable parameter of the scene enabled (materials, textures, lights,
the ambient term). It is timed in alternating rounds with a plain render:
each time is a median with its 95% interval over the rounds, and the
ratio spans what the two intervals allow together
(:func:`~mitsuba_whitted.compare.intervals.quotient`); the first gradient
(tracing and compiling its kernels) is reported apart, and so is the way
the integrator replayed the samples (``tree`` or ``graph``, see
:mod:`mitsuba_whitted.integrators.gradients`).

Equal error: on a scene where Whitted and path tracing agree in expectation
(a Phong ball before a gold mirror, two point lights), the derivative of the
pixel-centre image is exact for ``whitted`` and estimated by ``prb`` from
``spp`` paths per pixel. prb's error (relative RMS over the parameters'
entries, against whitted's, averaged over independent seeds) falls as
1/sqrt(spp); whitted's own error is its rounding, measured as the
difference between its forward- and reverse-mode derivatives. prb's time
to reach that error is extrapolated from its ladder at that rate.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from ..compare.intervals import Estimate, estimate_text, median_estimate, quotient
from ..jit import timed
from ..overrides import load_with
from .processes import child_peak_memory

#: Longest path in the equal-error comparison (whitted's and prb's).
EQUAL_ERROR_DEPTH = 6


def differentiable_keys(params) -> list:
    """Keys of ``params`` that a gradient of a ``whitted`` image can take:
    floating-point arrays marked differentiable, outside shapes and sensors."""
    keys = []
    for key in params.keys():
        value, node, flags = params[key], params.properties[key][2], params.flags(key)
        if flags & (mi.ParamFlags.NonDifferentiable | mi.ParamFlags.ReadOnly):
            continue
        if isinstance(node, (mi.Shape, mi.Sensor)) or not dr.is_diff_v(value):
            continue
        if dr.is_float_v(value):
            keys.append(key)
    return keys


class GradientStep:
    """One optimisation step's derivative of ``scene``: every
    :func:`differentiable_keys` enabled, the image rendered with them and
    differentiated; ``__call__`` returns the gradients."""

    def __init__(self, scene: mi.Scene):
        self.scene = scene
        self.params = mi.traverse(scene)
        self.keys = differentiable_keys(self.params)
        for key in self.keys:
            dr.enable_grad(self.params[key])
        self.params.update()

    def __call__(self) -> list:
        image = mi.render(self.scene, self.params)
        dr.backward(image)
        gradients = [dr.grad(self.params[key]) for key in self.keys]
        dr.eval(gradients)
        for key in self.keys:
            dr.clear_grad(self.params[key])
            # As an optimiser's update does: the plugins derive their
            # values anew from the parameters.
            self.params.set_dirty(key)
        self.params.update()
        return gradients


@dataclass
class GradientTiming:
    """A gradient of the scene beside its render, in alternating rounds;
    ``replay``: how the integrator traced the samples again."""
    parameters: int
    entries: int
    replay: str
    #: Rays the tree replay walked and walked again (empty for the graph
    #: replay), and those the render traced, in the last round.
    replay_rays: dict
    render_rays: int
    first_gradient_s: float
    render_s: Estimate
    gradient_s: Estimate
    ratio: Estimate


def gradient_timing(scene_path: Path, defines: dict, settings: dict,
                    repeats: int) -> GradientTiming:
    """Warm render and gradient of the scene, in alternating rounds."""
    scene = load_with(scene_path, defines, settings)
    step = GradientStep(scene)
    _, (first,) = timed(step, 1)
    renders, steps = [], []
    for _ in range(repeats):
        renders += timed(lambda: mi.render(scene), 1)[1]
        steps += timed(step, 1)[1]
    render, gradient = median_estimate(renders), median_estimate(steps)
    whitted = scene.integrator()
    stats = whitted.last_stats
    traced = sum(stats[kind] for kind in ("camera", "reflection", "refraction",
                                          "passthrough")) - stats["cut"]
    return GradientTiming(len(step.keys), sum(_entries(step.params[key]) for key in step.keys),
                          whitted.last_replay, whitted.last_replay_rays, traced, first, render,
                          gradient, quotient(gradient, render))


def equivalence_scene(resolution: int) -> dict:
    """A Phong ball before a gold mirror, lit by two point lights: whitted
    and path tracing agree in expectation, and so do their derivatives (a
    second ball would light the first, which Whitted leaves out)."""
    def rgb(*value):
        return {"type": "rgb", "value": list(value)}

    def phong(r, g, b, exponent):
        return {"type": "phong", "diffuse_reflectance": rgb(r, g, b),
                "specular_reflectance": rgb(0.2, 0.2, 0.2), "exponent": exponent}

    return {
        "type": "scene",
        "integrator": {"type": "whitted", "max_depth": EQUAL_ERROR_DEPTH, "min_throughput": 0.0},
        "sensor": {"type": "perspective", "fov": 40,
                   "to_world": mi.ScalarTransform4f().look_at([-1, 0.5, 4], [0, 0, 0], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": resolution, "height": resolution,
                            "rfilter": {"type": "box"}}},
        "ball": {"type": "sphere", "center": [0.3, 0, 0.3], "radius": 0.7,
                 "bsdf": phong(0.7, 0.3, 0.2, 20.0)},
        "mirror": {"type": "rectangle",
                   "to_world": mi.ScalarTransform4f().translate([0, 0, -1.5]).scale(3),
                   "bsdf": {"type": "conductor", "material": "Au"}},
        "key": {"type": "point", "position": [2, 3, 4], "intensity": rgb(25, 25, 25)},
        "fill": {"type": "point", "position": [-3, 1, 4], "intensity": rgb(10, 10, 10)},
    }


#: The parameters differentiated in the equal-error comparison.
EQUAL_ERROR_KEYS = ("ball.bsdf.diffuse_reflectance.value", "ball.bsdf.specular_reflectance.value",
                    "key.intensity.value", "fill.intensity.value")


def relative_error(estimate: np.ndarray, exact: np.ndarray) -> float:
    """Relative RMS error of a gradient over its entries."""
    return float(np.sqrt(np.mean((estimate - exact) ** 2) / np.mean(exact ** 2)))


@dataclass
class PrbRung:
    """prb at ``spp`` paths per pixel: its median time and mean error."""
    spp: int
    seconds: float
    rel_error: float


@dataclass
class GradientEqualError:
    """whitted's exact gradient against prb's ladder on one scene, and
    prb's samples and time extrapolated to whitted's (rounding) error."""
    scene: str
    resolution: int
    entries: int
    whitted_seconds: float
    whitted_rel_error: float
    prb: list[PrbRung]
    prb_at_one_percent: PrbRung | None
    prb_spp_at_whitted_error: float
    prb_seconds_at_whitted_error: float


@dataclass
class GradientFigures:
    """Every gradient figure of the bench: of the scene's own gradient,
    ``timing`` and ``peak_rss_mib`` are ``None`` where ``not_measured``
    says why."""
    timing: GradientTiming | None
    peak_rss_mib: dict | None
    not_measured: str | None
    equal_error: GradientEqualError


def equal_error_gradient(resolution: int, largest_spp: int, seeds: int,
                         repeats: int) -> GradientEqualError:
    """Time and error of whitted's gradient and of prb's at 1, 4, ...
    ``largest_spp`` paths per pixel (see the module's docstring)."""
    from ..compare.gradient_equivalence import prb_gradient_batches, whitted_gradient

    scene = mi.load_dict(equivalence_scene(resolution))
    params = mi.traverse(scene)
    keys = list(EQUAL_ERROR_KEYS)
    for key in keys:
        dr.enable_grad(params[key])
    params.update()
    exact, seconds = timed(lambda: whitted_gradient(scene, params, keys), repeats + 1)
    rounding = relative_error(_forward_gradient(scene, params, keys), exact)
    ladder = []
    spp = 1
    while spp <= largest_spp:
        estimates, prb_seconds = [], []
        for seed in range(seeds):
            estimate, (elapsed,) = timed(lambda: prb_gradient_batches(
                scene, params, keys, 1, spp, EQUAL_ERROR_DEPTH, seed)[0], 1)
            estimates.append(estimate)
            prb_seconds.append(elapsed)
        ladder.append(PrbRung(spp, statistics.median(prb_seconds),
                              statistics.mean(relative_error(e, exact) for e in estimates)))
        spp *= 4
    last = ladder[-1]
    # prb's error falls as 1/sqrt(spp) and its time grows as spp.
    needed = last.spp * (last.rel_error / max(rounding, 1e-12)) ** 2
    percent = next((row for row in ladder if row.rel_error <= 0.01), None)
    return GradientEqualError("a Phong ball before a gold mirror, two point lights", resolution,
                              int(exact.size), statistics.median(seconds[1:]), rounding, ladder,
                              percent, needed, last.seconds * needed / last.spp)


def _entries(value) -> int:
    return np.asarray(value).size


def _forward_gradient(scene, params, keys) -> np.ndarray:
    """The same gradient entry by entry in forward mode (colours)."""
    rows = []
    for key in keys:
        row = []
        for entry in range(_entries(params[key])):
            values = [0.0] * _entries(params[key])
            values[entry] = 1.0
            # Opaque: a frozen kernel takes the parameters' tangents as
            # inputs, and records anew for every literal value.
            tangent = type(params[key])(*values)
            dr.make_opaque(tangent)
            dr.set_grad(params[key], tangent)
            image = mi.render(scene, params)
            dr.forward_to(image)
            row.append(float(np.asarray(dr.grad(image), dtype=np.float64)[..., :3].sum()))
            dr.clear_grad(params[key])
        rows.append(row)
    return np.array(rows)


#: Why a scene with indirect paths has no gradient figures.
INDIRECT_NOT_DIFFERENTIATED = ("the scene's whitted gathers indirect light "
                               "(indirect_samples > 0), which is not differentiated")


def measure_gradients(scene_path: Path, defines: dict, scene_settings: dict, repeats: int,
                      memory_resolution: int, equal_error: tuple, report=print,
                      indirect: bool = False) -> GradientFigures:
    """Every gradient figure of the bench; of the scene's own gradient none
    where it has ``indirect`` paths."""
    timing = memory = not_measured = None
    if indirect:
        not_measured = INDIRECT_NOT_DIFFERENTIATED
    else:
        report("timing gradients ...")
        timing = gradient_timing(scene_path, defines, scene_settings, repeats)
        report("peak memory of a gradient in a child process ...")
        memory = {str(memory_resolution): child_peak_memory(
            scene_path, defines, dict(scene_settings, res=memory_resolution), work="gradient")}
    report("equal gradient error against prb ...")
    return GradientFigures(timing, memory, not_measured,
                           equal_error_gradient(*equal_error, repeats=repeats))


def _replay_rays_line(timing: GradientTiming) -> list:
    """The rays the tree replay walked beside the render's (none for the
    graph replay)."""
    if not timing.replay_rays:
        return []
    walked, again = timing.replay_rays["walked"], timing.replay_rays["walked again"]
    return [f"    its replay walked {walked:,} rays (the render traced {timing.render_rays:,} "
            f"besides shadow rays) and traced {again:,} of them again ({again / walked:.0%})"]


def format_lines(figures: GradientFigures) -> list:
    """The gradient figures as lines of the bench's table."""
    eq, timing = figures.equal_error, figures.timing
    lines = [f"  gradient: not measured: {figures.not_measured}"] if timing is None else [
        f"  gradient (mi.render + dr.backward, {timing.parameters} parameters, "
        f"{timing.entries:,} entries, {timing.replay} replay)  "
        f"{estimate_text(timing.gradient_s, ' s', 3)} = {estimate_text(timing.ratio, ' x')} "
        f"the render ({estimate_text(timing.render_s, ' s', 3)} in those rounds; target 5 x); "
        f"first {timing.first_gradient_s:.3f} s",
        *_replay_rays_line(timing),
        "  gradient peak RSS: " + ", ".join(f"{res} px {mib:,.0f} MiB"
                                          for res, mib in figures.peak_rss_mib.items())]
    lines += [
        f"  gradient at equal error against prb on {eq.scene} at {eq.resolution}^2"
        f" ({eq.entries} entries): whitted {eq.whitted_seconds:.3f} s, rounding error "
        f"{eq.whitted_rel_error:.1e}; prb would need ~{eq.prb_spp_at_whitted_error:.2g} spp, "
        f"~{eq.prb_seconds_at_whitted_error:.3g} s (extrapolated as 1/sqrt(spp))",
    ]
    percent = eq.prb_at_one_percent
    if percent is not None:
        lines.append(f"    prb first within 1%: {percent.spp} spp, {percent.seconds:.3f} s "
                     f"({percent.seconds / eq.whitted_seconds:.1f} x whitted's time)")
    for row in eq.prb:
        lines.append(f"    prb {row.spp:6d} spp  {row.seconds:7.3f} s  relative error "
                     f"{row.rel_error:.2e}")
    return lines
