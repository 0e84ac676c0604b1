"""Numerical stability: hard cases, each against an independent float64 reference.

Every case builds rays (or surface interactions) that sit on a numerical
edge, runs what the ``whitted`` integrator actually runs on them, compares
with a reference computed in float64 (or long double) from the very same
float32 inputs, and judges the result against a bound stated in the case's
docstring. The cases live by subject (``cylinder``, ``sphere``, ``glass``,
``textures``, ``acne``); this module lists them in table order and writes
the table. ``run_stability(quick=True)`` runs the same cases on fewer rays
and pixels; the test suite runs it and fails on any regression.

Disagreements on hit/miss are excused only inside a stated band around the
decision (a ray that close to a threshold may flip under any rounding of its
own float32 coordinates), or where a subject states another excuse; those
are counted apart and capped.
"""

from __future__ import annotations

import math

import numpy as np

from validation.stability import acne, cylinder, glass, sphere, textures
from validation.stability.common import SEED, CaseResult


def _cases(rays: int, pixels: int):
    """(name-less) thunks of every case, in table order; each gets its own
    seeded generator so a case's rays do not depend on the others."""
    def seeded(case, *args):
        return lambda: case(rays, np.random.default_rng(SEED), *args)

    reference = {}

    def scaled(scale):
        def run():
            if "image" not in reference:
                reference["image"] = acne.render(acne.scaled_glass_scene(1.0, pixels))
            return acne.acne_at_scale(pixels, scale, reference["image"])
        return run

    return [
        seeded(cylinder.cylinder_parallel_to_axis), seeded(cylinder.cylinder_grazing),
        seeded(cylinder.cylinder_cap_plane, 0.0), seeded(cylinder.cylinder_cap_plane, 1.0),
        seeded(cylinder.cylinder_rim), seeded(cylinder.cylinder_from_inside),
        seeded(cylinder.cylinder_far_away),
        seeded(cylinder.cylinder_scaled, 1e3), seeded(cylinder.cylinder_scaled, 1e-3),
        seeded(sphere.sphere_tangents), seeded(glass.total_internal_reflection),
        seeded(glass.fresnel_near_critical),
        seeded(textures.sphere_map_poles, "asin"), seeded(textures.sphere_map_poles, "atan"),
        seeded(textures.sphere_map_poles, "equirect"), seeded(textures.tartan_far),
        scaled(1e-3), scaled(1e3), lambda: acne.shadow_acne_plane(pixels),
    ]


def run_stability(quick: bool = False) -> list[CaseResult]:
    """Every hard case; ``quick`` uses fewer rays and smaller images (same
    cases and bounds) so the test suite can run it."""
    rays, pixels = (2048, 32) if quick else (65536, 96)
    return [case() for case in _cases(rays, pixels)]


def _number(value: float) -> str:
    if not math.isfinite(value):
        return "n/a (nothing to compare)"
    return "0" if value == 0 else f"{value:.2g}"


def stability_markdown(results: list[CaseResult]) -> str:
    """One Markdown table row per case."""
    header = ("| case | measured | float64 reference | rays/pixels | NaN/Inf | "
              "hit/miss disagreements (excused: band) | worst error | bound | verdict | notes |")
    rows = [header, "|" + "---|" * 10]
    for r in results:
        rows.append(
            f"| {r.name} | {r.measures} | {r.reference} | {r.samples} | {r.nonfinite} | "
            f"{r.disagreements} ({r.excused} excused: {r.band}) | {_number(r.worst_error)} {r.unit} | "
            f"{_number(r.bound)} | {'pass' if r.passed else '**FAIL**'} | {r.details} |")
    return "\n".join(rows) + "\n"
