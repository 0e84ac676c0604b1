"""Stability of glass: the two delta children (reflected and transmitted)
that the ``whitted`` integrator asks a dielectric for, beyond the critical
angle and right at it, against float64 optics (the mirror formula and the
Fresnel oracle, ``validation/oracles/fresnel.py``)."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from validation.oracles import fresnel
from validation.stability.common import (U32, ULP32, CaseResult, angle_between, f32,
                                         perpendicular_basis, random_units, unit_rows)

IOR = 1.5


def delta_children(wi_local: np.ndarray, n_world: np.ndarray = None, d_world: np.ndarray = None):
    """The ``whitted`` integrator's two delta children of a glass hit
    (``bsdf.sample`` with one component and the Delta mask, as
    ``bsdf_query._delta_child`` does): weights and world directions. Either
    a local ``wi`` or a world normal and incident direction is given."""
    glass = mi.load_dict({"type": "dielectric", "int_ior": IOR, "ext_ior": 1.0})
    count = len(wi_local if wi_local is not None else n_world)
    si = dr.zeros(mi.SurfaceInteraction3f, count)
    if n_world is None:
        si.sh_frame = mi.Frame3f(mi.Normal3f(0, 0, 1))
        si.wi = mi.Vector3f(*wi_local.astype(np.float32).T)
    else:
        normal = mi.Normal3f(*n_world.astype(np.float32).T)
        si.n, si.sh_frame = normal, mi.Frame3f(normal)
        si.wi = si.to_local(-mi.Vector3f(*d_world.astype(np.float32).T))
    children = []
    for component in (0, 1):
        ctx = mi.BSDFContext(mi.TransportMode.Radiance, mi.BSDFFlags.Delta, component)
        bs, weight = glass.sample(ctx, si, 0.5, mi.Point2f(0.5), True)
        valid = np.array(bs.pdf > 0)
        children.append((np.where(valid, np.array(weight, dtype=np.float64)[0], 0.0),
                         np.array(si.to_world(bs.wo), dtype=np.float64).T))
    return children


def total_internal_reflection(n: int, rng) -> CaseResult:
    """Rays inside glass (index 1.5) hitting its surface beyond the critical
    angle (41.8 deg) up to grazing, with random world normals: the
    reflected child must have weight exactly 1 (up to float32 rounding, 4 u)
    and the direction of the float64 mirror formula within 8 ulp of angle
    (the integrator goes to the local frame and back, each a few ulp); the
    transmitted child weight 0 (it is then never traced)."""
    critical = np.arcsin(1 / IOR)
    theta = rng.uniform(critical + 1e-4, np.pi / 2 - 1e-4, n)
    normal = f32(random_units(rng, n))
    e1, e2 = perpendicular_basis(unit_rows(normal))
    phi = rng.uniform(0, 2 * np.pi, n)[:, None]
    tangent = np.cos(phi) * e1 + np.sin(phi) * e2
    d = f32(np.cos(theta)[:, None] * unit_rows(normal) + np.sin(theta)[:, None] * tangent)
    (w_r, wo_r), (w_t, _) = delta_children(None, normal, d)
    unit_n = unit_rows(normal)
    mirror = unit_rows(d - 2 * (d * unit_n).sum(axis=1, keepdims=True) * unit_n)
    angle = angle_between(unit_rows(wo_r), mirror)
    weight_error = np.maximum(np.abs(w_r - 1), np.abs(w_t))
    bound = 8 * ULP32
    nonfinite = int((~np.isfinite(w_r)).sum() + (~np.isfinite(wo_r)).sum())
    passed = bool(nonfinite == 0 and weight_error.max() <= 4 * U32 and angle.max() <= bound)
    return CaseResult(
        name="glass: total internal reflection", measures="delta children of dielectric via bsdf.sample",
        reference="float64 mirror formula; F = 1 beyond the critical angle",
        samples=n, nonfinite=nonfinite, disagreements=int((w_t > 0).sum()), excused=0,
        band="none (transmitted child must vanish)", worst_error=float(angle.max()),
        unit="reflected direction, rad", bound=bound, passed=passed,
        details=f"weights off by up to {weight_error.max():.1e} (<= 4 u = {4 * U32:.1e})")


#: Input perturbation a float32 Fresnel evaluation is allowed: cos θ_i moved
#: by 8 ulp (it goes through 1 - cos^2 and a square root), plus 8 ulp on the
#: output. Near the critical angle F has an infinite slope, so the allowance
#: is per ray: the change of the float64 F over that input interval.
FRESNEL_ULPS = 8


def fresnel_allowance(cos_i, n_i, n_t):
    step = FRESNEL_ULPS * ULP32 * np.abs(cos_i)
    low, high = (fresnel.reflectance(cos_i + sign * step, n_i, n_t) for sign in (-1, 1))
    return np.abs(high - low) + FRESNEL_ULPS * ULP32


def judge_fresnel(cos_i, w_r, w_t) -> tuple:
    """Worst weight error in units of the per-ray allowance (pass: <= 1).
    From inside (n_i = 1.5 to n_t = 1), the transmitted radiance weight is
    (1 - F) (n_i / n_t)^2: radiance is compressed into the denser medium."""
    ratio = (IOR / 1.0) ** 2
    reference = fresnel.reflectance(cos_i, IOR, 1.0)
    allowance = fresnel_allowance(cos_i, IOR, 1.0)
    error = np.maximum(np.abs(w_r - reference), np.abs(w_t - (1 - reference) * ratio) / ratio)
    return float((error / allowance).max()), float(error.max())


def fresnel_near_critical(n: int, rng) -> CaseResult:
    """Inside rays at the critical angle ± 1e-7 ... 1e-1 rad (local wi given
    directly, so the float32 cos θ_i is the exact input of both): the
    reflected and transmitted weights against the float64 textbook Fresnel
    equations, within the per-ray allowance of FRESNEL_ULPS."""
    critical = np.arcsin(1 / IOR)
    offset = np.sign(rng.uniform(-1, 1, n)) * 10.0 ** rng.uniform(-7, -1, n)
    theta = critical + offset
    wi = f32(np.c_[np.sin(theta), np.zeros(n), -np.cos(theta)])
    (w_r, _), (w_t, _) = delta_children(wi)
    worst, absolute = judge_fresnel(wi[:, 2], w_r, w_t)
    nonfinite = int((~np.isfinite(w_r)).sum() + (~np.isfinite(w_t)).sum())
    return CaseResult(
        name="glass: Fresnel near the critical angle", measures="delta children weights via bsdf.sample",
        reference="float64 textbook Fresnel (validation/oracles/fresnel.py)", samples=n,
        nonfinite=nonfinite,
        disagreements=0, excused=0, band="n/a", worst_error=worst,
        unit=f"x allowance (F64 change over {FRESNEL_ULPS} ulp of cos, + {FRESNEL_ULPS} ulp)",
        bound=1.0, passed=bool(nonfinite == 0 and worst <= 1.0),
        details=f"absolute weight error up to {absolute:.1e}")
