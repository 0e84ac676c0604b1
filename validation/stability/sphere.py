"""Stability of Mitsuba's sphere at tangency: the float32 quadratic that
decides hit or miss for rays grazing spheres of every size, against the
long-double oracle (``validation/oracles/sphere.py``) on the same float32
rays."""

from __future__ import annotations

import math

import mitsuba as mi
import numpy as np

from validation.oracles import sphere as oracle
from validation.stability.common import (U32, CaseResult, f32, float32_rays, perpendicular_basis,
                                         random_units)

#: Mitsuba's sphere test runs in float32 in the differentiable and CUDA
#: variants, on a foot point about |o - c| from the origin: rounding there
#: moves the line's distance from the centre by ~u |o - c|, so a tangency
#: flip is excused within 4 u (1 + |o - c| / r) of the radius (the flips
#: that rounding causes lie within 0.4 of that unit).
SPHERE_BAND_ULPS = 4
#: The hit point must lie on the sphere: its distance from the surface is
#: what a near-tangent t error turns into (Δt · h / r, h the half chord),
#: and is well conditioned, unlike t itself; bound 4 u (1 + |o - c| / r) r.
SPHERE_RESIDUAL_ULPS = 4


def sphere_tangents(n: int, rng) -> CaseResult:
    """Rays from 5 radii away passing the centre at r (1 + delta), delta
    from -1e-1 to 1e-1 down to 1e-9, on spheres of radius 1e-3, 1 and 1e3:
    Mitsuba's float32 quadratic decides tangency, so hit/miss may flip only
    in the band; the hit point must lie on the sphere."""
    radius = np.choose(np.arange(n) % 3, [1e-3 * np.ones(n), np.ones(n), 1e3 * np.ones(n)])
    center = radius[:, None] * np.array([0.3, -0.2, 0.1])
    d = random_units(rng, n)
    e1, _ = perpendicular_basis(d)
    delta = np.sign(rng.uniform(-1, 1, n)) * 10.0 ** rng.uniform(-9, -1, n)
    o = center + radius[:, None] * ((1 + delta)[:, None] * e1 - 5 * d)
    hits, ts, refs = [], [], []
    for r in (1e-3, 1.0, 1e3):
        rows = radius == r
        scene = mi.load_dict({"type": "scene", "sphere": {"type": "sphere", "radius": r,
                                                          "center": list(center[rows][0])}})
        si = scene.ray_intersect(float32_rays(o[rows], d[rows]))
        hits.append(np.array(si.is_valid()))
        ts.append(np.array(si.t, dtype=np.float64))
        refs.append(oracle.intersect(f32(o[rows]), f32(d[rows]), center[rows][0], r))
    order = np.concatenate([np.flatnonzero(radius == r) for r in (1e-3, 1.0, 1e3)])
    o, d, radius, center = o[order], d[order], radius[order], center[order]
    hit, t = np.concatenate(hits), np.concatenate(ts)
    ref = {key: np.concatenate([part[key] for part in refs]) for key in refs[0]}
    scale = U32 * (1 + np.linalg.norm(f32(o) - center, axis=1) / radius)
    return judge_sphere(ref, hit, t, o, d, center, radius, scale)


def judge_sphere(ref, hit, t, o, d, center, radius, scale) -> CaseResult:
    """Flips outside the band, and the hit point's distance from the sphere
    in units of ``scale * radius`` (``scale`` = u (1 + |o - c| / r))."""
    near = ref["margin"] < SPHERE_BAND_ULPS * scale
    differ = hit != ref["hit"]
    both = hit & ref["hit"]
    point = f32(o)[both] + t[both, None] * f32(d)[both]
    residual = np.abs(np.linalg.norm(point - center[both], axis=1) / radius[both] - 1) / scale[both]
    t_rel = np.abs(t[both] - ref["t"][both]) / ref["t"][both]
    worst = float(residual.max()) if both.any() else math.inf
    nonfinite = int((~np.isfinite(t[hit])).sum())
    return CaseResult(
        name="sphere: tangent rays", measures="Mitsuba sphere, scene.ray_intersect",
        reference="long-double closed form (validation/oracles/sphere.py)",
        samples=len(hit), nonfinite=nonfinite, disagreements=int((differ & ~near).sum()),
        excused=int((differ & near).sum()),
        band=f"|rho/r - 1| < {SPHERE_BAND_ULPS} u (1 + |o-c|/r)",
        worst_error=worst, unit="hit point off the sphere, u (1 + |o-c|/r) r",
        bound=SPHERE_RESIDUAL_ULPS,
        passed=bool(nonfinite == 0 and not (differ & ~near).any() and worst <= SPHERE_RESIDUAL_ULPS),
        details=(f"{int(both.sum())} hits compared; relative t error up to {t_rel.max():.1e} "
                 "(ill-conditioned at tangency, not bounded)"))
