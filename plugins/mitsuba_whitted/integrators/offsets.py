"""Leaving a surface without hitting it again, at any scene scale.

A new ray must start a little off the surface it leaves, or float error puts
its origin behind the surface and it hits it again (acne). Mitsuba offsets
by ``(1 + max|p|) * RayEpsilon``: the ``1`` is a length in scene units, so a
scene a thousandth of a unit across gets offsets of a tenth of its objects'
size, and refracted rays visibly wander. Here that absolute term is
``min(1, scene size)``: scenes of unit size and larger get exactly
Mitsuba's offsets (so Whitted and Mitsuba's own integrators leave surfaces
identically and trace the very same rays, which the equivalence tests need:
a hit a hair's breadth elsewhere moves a pixel near a silhouette or a
terminator), and smaller scenes get offsets that shrink with them.

The price is that offsets are not a fixed share of a scene larger than a
unit: such a scene and its copy scaled by 1000 trace slightly different
rays, and a ray that bounces many times inside glass may end on the other
side of an edge in one of them (``validation/stability/acne.py``).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi


def scene_scale(scene: mi.Scene) -> float:
    """The absolute offset length: the largest extent of the scene's
    bounding box, but at most 1 (1 for an empty scene)."""
    bbox = scene.bbox()
    if not bbox.valid():
        return 1.0
    return min(1.0, float(max(bbox.extents())))


def _offset_origin(si: mi.SurfaceInteraction3f, d: mi.Vector3f, scale: float) -> mi.Point3f:
    magnitude = (dr.max(dr.abs(si.p)) + scale) * mi.math.RayEpsilon
    return dr.fma(si.n, dr.mulsign(magnitude, dr.dot(si.n, d)), si.p)


def spawn_ray(si: mi.SurfaceInteraction3f, d: mi.Vector3f, scale: float) -> mi.Ray3f:
    """Ray leaving ``si`` in direction ``d``."""
    return mi.Ray3f(_offset_origin(si, d, scale), d, si.time, si.wavelengths)


def spawn_ray_to(si: mi.SurfaceInteraction3f, target: mi.Point3f, scale: float) -> mi.Ray3f:
    """Ray from ``si`` to ``target``, stopping just short of it."""
    origin = _offset_origin(si, target - si.p, scale)
    d = target - origin
    distance = dr.norm(d)
    return mi.Ray3f(origin, d / distance, distance * (1 - mi.math.ShadowEpsilon),
                    si.time, si.wavelengths)
