"""Everything a Whitted hit asks of its BSDF, in one dispatch per hit.

A hit needs its BSDF's diffuse albedo (for the ambient term), its value
towards each delta light, and a sample of each delta component (mirror
reflection, refraction, pass-through). Asked one method at a time, that is
up to six virtual calls per hit, and the BSDF looks up its textures anew in
each. Asked together through ``dr.dispatch``, each BSDF instance answers in
one function: Dr.Jit's value numbering merges the repeated texture lookups,
and the answer is specialised to the instance (a BSDF without a component
returns nothing for it, without a table lookup per lane).

Lanes outside a part of the query (no light work, no children wanted) get
that part computed anyway, as SIMD lanes do; callers mask with their own
conditions. BSDF evaluation and sampling are pure functions of their
inputs, so the values of the lanes that are used are exactly those of
separate calls.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

#: Codes stored per candidate child; 0 means "no child".
KIND_CODES = {"reflection": 1, "refraction": 2, "passthrough": 3}


@dataclass(frozen=True)
class BsdfQuery:
    """Which parts a hit wants besides the values towards the light
    directions it passes: the diffuse albedo, and one child per
    ``(kind, component)``."""
    albedo: bool
    components: tuple


@dataclass
class DeltaChild:
    """One delta component's sample at each lane: its weight, its local
    direction (none for pass-through: that ray goes straight on), whether
    it exists and its kind code."""
    weight: mi.Color3f
    wo: mi.Vector3f
    ok: mi.Bool
    code: mi.UInt32


@dataclass
class BsdfTerms:
    albedo: mi.Color3f
    values: list
    children: list


def query_bsdf(bsdf: mi.BSDFPtr, si: mi.SurfaceInteraction3f, query: BsdfQuery,
               directions: list, active: mi.Bool) -> BsdfTerms:
    """Answer ``query`` at ``si`` (``directions``: local, one per light)."""
    if not (query.albedo or directions or query.components):
        return BsdfTerms(mi.Color3f(0), [], [])
    def answer(instance, si, directions, active):
        return _answer(instance, query, si, directions)
    albedo, values, children = dr.dispatch(bsdf, answer, si, directions, active)
    return BsdfTerms(albedo, list(values), [DeltaChild(*child) for child in children])


def _answer(bsdf: mi.BSDF, query: BsdfQuery, si, directions) -> tuple:
    flags = bsdf.flags()
    albedo = mi.Color3f(0)
    if query.albedo and mi.has_flag(flags, mi.BSDFFlags.Diffuse):
        albedo = mi.Color3f(bsdf.eval_diffuse_reflectance(si))
    # Lights are seen only through the smooth (non-delta) part of a BSDF.
    smooth = mi.has_flag(flags, mi.BSDFFlags.Smooth)
    values = tuple(mi.Color3f(bsdf.eval(mi.BSDFContext(), si, wo)) if smooth
                   else mi.Color3f(0) for wo in directions)
    children = tuple(_null_child(bsdf, si) if kind == "null"
                     else _delta_child(bsdf, component, si)
                     for kind, component in query.components)
    return albedo, values, children


def has_delta_lobe(bsdf: mi.BSDF, component: int, kind=mi.BSDFFlags.Delta) -> bool:
    """Whether ``component`` of ``bsdf`` is a delta lobe of ``kind`` (any
    delta lobe, or e.g. ``DeltaTransmission``); null (pass-through) parts
    are not."""
    if component >= bsdf.component_count():
        return False
    flags = bsdf.flags(component)
    return mi.has_flag(flags, kind) and not mi.has_flag(flags, mi.BSDFFlags.Null)


def _no_child() -> tuple:
    return mi.Color3f(0), mi.Vector3f(0), mi.Bool(False), mi.UInt32(0)


def _delta_child(bsdf: mi.BSDF, component: int, si) -> tuple:
    if not has_delta_lobe(bsdf, component):
        return _no_child()
    ctx = mi.BSDFContext(mi.TransportMode.Radiance, mi.BSDFFlags.Delta, component)
    bs, weight = bsdf.sample(ctx, si, 0.5, mi.Point2f(0.5))
    weight = mi.Color3f(weight)
    ok = (bs.pdf > 0) & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta) & dr.any(weight > 0)
    reflected = mi.has_flag(bs.sampled_type, mi.BSDFFlags.DeltaReflection)
    code = dr.select(reflected, KIND_CODES["reflection"], KIND_CODES["refraction"])
    return weight, bs.wo, ok, mi.UInt32(code)


def _null_child(bsdf: mi.BSDF, si) -> tuple:
    if not mi.has_flag(bsdf.flags(), mi.BSDFFlags.Null):
        return _no_child()
    weight = mi.Color3f(bsdf.eval_null_transmission(si))
    return weight, mi.Vector3f(0), dr.any(weight > 0), mi.UInt32(KIND_CODES["passthrough"])
