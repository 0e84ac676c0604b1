"""Exact analytic surfaces behind mesh proxies.

Mitsuba 3.9 lets Python shapes only be meshes, so a ``capped_cylinder`` is a
circumscribed tessellation for the BVH. This module replaces every hit on
such a proxy by the exact intersection with the true surface: the ray is
mapped into the shape's canonical space (``t`` is preserved), intersected
there, and the hit point, normal, frame and uv are rebuilt exactly. A ray
that crosses the proxy but misses the true surface continues behind it.

All analytic shapes share one table indexed by Mitsuba's shape registry id,
so any number of cylinders costs one gather, not one pass each.

Known limit: an object lying in the thin sliver between a proxy and its true
surface (at most r (1 - cos(pi / segments)) deep) can be skipped by a ray
that is refined onto the true surface behind it.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..geometry.cylinder import (canonical_normal_to_world, canonical_point_to_world,
                                 intersect_canonical, world_ray_to_canonical)
from ..jit import device_array
from .offsets import scene_scale, spawn_ray
from .scene_ref import ReadsScene, SceneRef

#: A ray crosses a missed proxy twice (in and out); four lets it pass two
#: overlapping proxies before giving up (and reporting the proxy hit).
MAX_PROXY_CROSSINGS = 4


def _shape_id(shape) -> int:
    return int(dr.reinterpret_array(mi.UInt32, mi.ShapePtr(shape))[0])


def _rows(matrix: np.ndarray) -> list:
    """The 12 entries of the top three rows of an affine 4x4 matrix."""
    return list(np.asarray(matrix, dtype=np.float64)[:3, :4].ravel())


class AnalyticRefiner(ReadsScene):
    """``intersect(ray, active)``: Mitsuba's intersection, with hits on
    analytic proxies replaced by the exact surface."""

    def __init__(self, scene_ref: SceneRef, shapes: list, scale: float = None):
        self.scene_ref = scene_ref
        #: Absolute term of the offsets past a missed proxy (``offsets``).
        self.scale = scene_scale(scene_ref.get()) if scale is None else scale
        self.shapes = shapes
        self.F64 = dr.float64_array_t(mi.Float)
        self.load_tables()

    def load_tables(self) -> None:
        """Read the shapes' placements (again, after a parameter update)."""
        ids = [_shape_id(shape) for shape in self.shapes]
        size = max(ids) + 1
        to_canonical = np.zeros((size, 12))
        to_world = np.zeros((size, 12))
        analytic = np.zeros(size, dtype=bool)
        for shape, index in zip(self.shapes, ids):
            to_canonical[index] = _rows(shape.world_to_canonical_matrix())
            to_world[index] = _rows(shape.canonical_to_world_matrix())
            analytic[index] = True
        self.to_canonical = device_array(self.F64, to_canonical)
        self.to_world = device_array(self.F64, to_world)
        self.analytic = device_array(mi.Bool, analytic)
        self.size = size

    def tables(self) -> tuple:
        """The JIT arrays this refiner reads."""
        return self.to_canonical, self.to_world, self.analytic

    def on_proxy(self, si: mi.SurfaceInteraction3f, active) -> mi.Bool:
        index = dr.reinterpret_array(mi.UInt32, si.shape)
        inside = active & si.is_valid() & (index < self.size)
        return inside & dr.gather(mi.Bool, self.analytic, index, inside)

    def intersect(self, ray: mi.Ray3f, active: mi.Bool,
                  coherent: bool = False) -> mi.SurfaceInteraction3f:
        # Differentiated renders trace loops in evaluated mode, for reverse-
        # mode AD (``gradients``), but a ray that carries no derivatives
        # gives the loop none to follow: it keeps the faster symbolic one.
        if dr.flag(dr.JitFlag.SymbolicLoops) or dr.grad_enabled(ray):
            return self._intersect(ray, active, coherent)
        with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, True), \
                dr.scoped_set_flag(dr.JitFlag.SymbolicCalls, True):
            return self._intersect(ray, active, coherent)

    @dr.syntax
    def _intersect(self, ray: mi.Ray3f, active: mi.Bool,
                   coherent: bool) -> mi.SurfaceInteraction3f:
        si = self.scene.ray_intersect(ray, mi.RayFlags.All, coherent, active)
        pending = self.on_proxy(si, active)
        # ``current`` only finds the next proxy behind a missed one; the exact
        # test always uses the original ray, so offsets taken to leave a
        # proxy face never move the line that is tested.
        current = mi.Ray3f(ray)
        travelled = mi.Float(0)      # ray parameter of ``current``'s origin
        crossings = mi.UInt32(0)
        while pending:
            hit, t, p, n, uv = self._exact(si, ray, pending)
            self._fill(si, ray, hit, t, p, n, uv)
            missed = pending & ~hit
            travelled[missed] = travelled + si.t
            current[missed] = spawn_ray(si, ray.d, self.scale)
            current.maxt[missed] = ray.maxt - travelled
            si[missed] = self.scene.ray_intersect(current, missed)
            si.t[missed] = si.t + travelled
            crossings += 1
            pending = missed & self.on_proxy(si, missed) & (crossings < MAX_PROXY_CROSSINGS)
        return si

    def _matrix_rows(self, table, index, active):
        base = index * 12
        return [[dr.gather(self.F64, table, base + 4 * i + j, active) for j in range(4)]
                for i in range(3)]

    def _exact(self, si, ray, active):
        """Exact hit of ``ray`` with the analytic shape ``si`` lies on."""
        index = dr.reinterpret_array(mi.UInt32, si.shape)
        to_canonical = self._matrix_rows(self.to_canonical, index, active)
        o, d = world_ray_to_canonical(to_canonical, mi.Point3d(ray.o), mi.Vector3d(ray.d))
        exact = intersect_canonical(o, d, mi.Float(0.0), ray.maxt, active)
        p = canonical_point_to_world(self._matrix_rows(self.to_world, index, active), exact.p)
        return (exact.valid, exact.t, p, canonical_normal_to_world(to_canonical, exact.n),
                exact.uv)

    @staticmethod
    def _fill(si, ray, hit, t, p, n, uv):
        si.t[hit] = t
        si.p[hit] = p
        si.n[hit] = n
        si.sh_frame[hit] = mi.Frame3f(n)
        si.uv[hit] = uv
        si.dp_du[hit] = si.sh_frame.s
        si.dp_dv[hit] = si.sh_frame.t
        si.wi[hit] = si.to_local(-ray.d)
