"""The photons of a pass in a hashed grid, and the density estimate that
gathers them around a point.

The cells are cubes twice the gather radius wide, so the sphere of radius
r about any point lies in the 2 x 2 x 2 block of cells nearest to it.
A cell's photons sit together in one flat array, in the order of a stable
sort by the cell's hash (NumPy's, so the order, and with it every sum of
the gather, is the same on every run); two tables give each hash's first
photon and count. Distinct cells can share a hash: the gather visits each
distinct hash of its block once and keeps only photons within the radius,
so no photon counts twice and none of another cell counts at all.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from ...jit import device_array
from .tracing import Photons

#: The hash's primes (Teschner et al. 2003).
_PRIMES = (73856093, 19349663, 83492791)
#: Photons cast from a surface towards a point nearly in its plane add
#: nothing to its estimate (their BSDF value over cosine is ill defined).
_MIN_COSINE = 1e-4


def cell_hash_numpy(cells: np.ndarray, mask: int) -> np.ndarray:
    """The hash of integer cells (n x 3, int64), as the kernels compute it."""
    wrapped = cells.astype(np.int64).astype(np.uint32)
    value = wrapped[:, 0] * np.uint32(_PRIMES[0])
    value ^= wrapped[:, 1] * np.uint32(_PRIMES[1])
    value ^= wrapped[:, 2] * np.uint32(_PRIMES[2])
    return value & np.uint32(mask)


def cell_hash(x: mi.Int32, y: mi.Int32, z: mi.Int32, mask) -> mi.UInt32:
    value = mi.UInt32(x) * _PRIMES[0]
    value ^= mi.UInt32(y) * _PRIMES[1]
    value ^= mi.UInt32(z) * _PRIMES[2]
    return value & mask


class PhotonGrid:
    """The photons of a pass, by cell, with the radius they are gathered
    in. ``emitted``: the photons whose powers they are shares of (the
    powers are already divided by it)."""

    def __init__(self, photons: Photons, radius: float):
        self.radius = radius
        count = len(photons)
        table = 1 << max(int(math.ceil(math.log2(max(count, 1)))) + 1, 4)
        cell = 2.0 * radius
        position = photons.position.numpy().T if count else np.zeros((0, 3))
        cells = np.floor(position.astype(np.float64) / cell)
        hashes = cell_hash_numpy(cells, table - 1)
        order = np.argsort(hashes, kind="stable").astype(np.uint32)
        counts = np.bincount(hashes, minlength=table).astype(np.uint32)
        starts = (np.cumsum(counts) - counts).astype(np.uint32)
        index = device_array(mi.UInt32, order) if count else mi.UInt32(0)
        self.position = dr.gather(mi.Point3f, photons.position, index) if count else \
            mi.Point3f(1e30)
        self.direction = dr.gather(mi.Vector3f, photons.direction, index) if count else \
            mi.Vector3f(0, 0, 1)
        self.power = dr.gather(mi.Color3f, photons.power, index) if count else mi.Color3f(0)
        self.segments = dr.gather(mi.UInt32, photons.segments, index) if count else \
            mi.UInt32(0)
        self.starts = device_array(mi.UInt32, starts)
        self.counts = device_array(mi.UInt32, counts)
        self.mask = dr.opaque(mi.UInt32, table - 1)
        self.inverse_cell = dr.opaque(mi.Float64, 1.0 / cell)
        self.radius_squared = dr.opaque(mi.Float, radius * radius)
        self.normalisation = dr.opaque(mi.Float, 1.0 / (math.pi * radius * radius))
        dr.eval(self.position, self.direction, self.power, self.segments)

    def arrays(self) -> tuple:
        """The JIT arrays the gather reads (a frozen kernel's inputs)."""
        return (self.position, self.direction, self.power, self.segments, self.starts,
                self.counts, self.mask, self.inverse_cell, self.radius_squared,
                self.normalisation)

    @dr.syntax
    def estimate(self, si: mi.SurfaceInteraction3f, bsdf: mi.BSDFPtr, active: mi.Bool,
                 segments) -> mi.Color3f:
        """Radiance leaving ``si`` towards ``si.wi`` from the photons within
        the radius whose paths have at most ``segments`` segments (per lane),
        reflected by the smooth part of ``bsdf``."""
        scaled = mi.Point3d(si.p) * self.inverse_cell - 0.5
        base = [mi.Int32(dr.floor(scaled[axis])) for axis in range(3)]
        ctx = mi.BSDFContext()
        total = mi.Color3f(0)
        seen = []
        for corner in range(8):
            h = cell_hash(base[0] + (corner & 1), base[1] + ((corner >> 1) & 1),
                          base[2] + ((corner >> 2) & 1), self.mask)
            fresh = mi.Bool(active)
            for earlier in seen:
                fresh &= h != earlier
            seen.append(h)
            i = dr.gather(mi.UInt32, self.starts, h, fresh)
            end = i + dr.gather(mi.UInt32, self.counts, h, fresh)
            while fresh & (i < end):
                q = dr.gather(mi.Point3f, self.position, i)
                near = dr.squared_norm(q - si.p) < self.radius_squared
                near &= dr.gather(mi.UInt32, self.segments, i) <= segments
                wo = si.to_local(dr.gather(mi.Vector3f, self.direction, i))
                cosine = dr.abs(wo.z)
                near &= cosine > _MIN_COSINE
                value = bsdf.eval(ctx, si, wo, near)
                power = dr.gather(mi.Color3f, self.power, i, near)
                total += dr.select(near, mi.Color3f(value) * power / cosine, 0)
                i += 1
        return total * self.normalisation
