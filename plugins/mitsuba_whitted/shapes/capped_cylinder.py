"""The ``capped_cylinder`` shape: a closed cylinder as a circumscribed mesh."""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from ..errors import ParameterError, check
from ..jit import device_array
from ..parameters import LastValid, checked_numbers, checked_transform
from .analytic import analytic

PLUGIN_NAME = "capped_cylinder"

#: How far (as a share of the height) the proxy reaches past each cap. A
#: ray lying exactly in a cap plane would otherwise run along the edges of
#: the side triangles, which Mitsuba's float32 triangle test misses; with
#: the pad it crosses their interior and is refined to the exact surface.
CAP_PAD = 1e-4

#: Traversed parameters whose change rebuilds the mesh.
SHAPE_KEYS = ("center", "radius", "height", "segments")

#: Most sides of the proxy polygon. Its largest gap to the true surface,
#: r (1/cos(pi/n) - 1) ~ r pi^2 / (2 n^2), is 1e-9 r here, below float32's
#: resolution of r (6e-8 r): more sides cannot change a float32 render, and
#: only cost memory.
MAX_SEGMENTS = 1 << 16

#: Longest and shortest edges of the proxy's triangles in the world.
#: Mitsuba's float32 ray test (Embree's) multiplies two edges (the
#: triangle's normal) and the ray's distance to its plane: past float32's
#: range (3.4e38) or below its normal numbers (1.2e-38) it overflows or
#: flushes to zero, and the cylinder silently vanishes (measured: radius
#: 3e18 seen from 5 units away). The bounds leave a factor 2^12 for the
#: ray's distance, so rays from up to 4096 units away hit.
MAX_LENGTH = float(np.sqrt(np.finfo(np.float32).max / 2.0 ** 12))
MIN_LENGTH = float(np.sqrt(np.finfo(np.float32).tiny * 2.0 ** 12))


def _translate(offset) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = offset
    return m


def _scale(factors) -> np.ndarray:
    return np.diag([*factors, 1.0])


def canonical_mesh(segments: int):
    """Circumscribed tessellation of the canonical cylinder (axis +y, radius
    1, ``0 <= y <= 1``) as float64 arrays ``(positions, normals, uv, faces)``.

    Side: ``segments + 1`` columns of two vertices (the last repeats the
    first's position with ``u = 1``: the uv seam), at radius
    ``1/cos(pi/segments)`` so every polygon edge touches the unit circle and
    the true surface lies inside; exact radial normals. Caps: a fan around a
    centre vertex at ``y = -CAP_PAD`` and ``y = 1 + CAP_PAD`` (just outside
    the true caps), sharing the side rim's positions bit for bit
    (watertight), flat normals, planar uv
    ``((x + 1)/2, (z + 1)/2)``. Triangles wind counter-clockwise seen from
    outside.
    """
    n = segments
    column = np.arange(n + 1)
    angle = 2 * np.pi * (column % n) / n  # column n reuses column 0's angle exactly
    ring_radius = 1 / np.cos(np.pi / n)
    cos, sin = np.cos(angle), np.sin(angle)
    zeros, ones = np.zeros(n + 1), np.ones(n + 1)
    low, high = -CAP_PAD * ones, (1 + CAP_PAD) * ones

    side_positions = np.concatenate([np.stack([ring_radius * cos, low, ring_radius * sin], 1),
                                     np.stack([ring_radius * cos, high, ring_radius * sin], 1)])
    side_normals = np.concatenate([np.stack([cos, zeros, sin], 1)] * 2)
    side_uv = np.concatenate([np.stack([column / n, zeros], 1), np.stack([column / n, ones], 1)])

    bottom, top = column[:-1], column[:-1] + n + 1
    side_faces = np.concatenate([np.stack([bottom, top + 1, bottom + 1], 1),
                                 np.stack([bottom, top, top + 1], 1)])

    positions, normals, uv, faces = [side_positions], [side_normals], [side_uv], [side_faces]
    for ring_start, facing in ((0, -1.0), (n + 1, 1.0)):
        rim = side_positions[ring_start:ring_start + n]
        cap = np.concatenate([[[0.0, rim[0, 1], 0.0]], rim])
        first = sum(len(p) for p in positions)
        ring = first + 1 + np.arange(n)
        ring_next = first + 1 + (np.arange(n) + 1) % n
        centre = np.full(n, first)
        # Counter-clockwise seen from +y is (centre, next, current).
        fan = (np.stack([centre, ring_next, ring], 1) if facing > 0
               else np.stack([centre, ring, ring_next], 1))
        positions.append(cap)
        normals.append(np.tile([0.0, facing, 0.0], (n + 1, 1)))
        uv.append((cap[:, [0, 2]] + 1) / 2)
        faces.append(fan)
    return (np.concatenate(positions), np.concatenate(normals),
            np.concatenate(uv), np.concatenate(faces).astype(np.uint32))


@analytic
class CappedCylinder(mi.Mesh):
    r"""
    .. _shape-capped_cylinder:

    Capped cylinder (:monosp:`capped_cylinder`)
    -------------------------------------------

    .. pluginparameters::

     * - center
       - |point|
       - Centre of the bottom cap, finite (default: (0, 0, 0))
       - |exposed|
     * - radius
       - |float|
       - Radius, finite and > 0; placed in the world, the proxy's triangles
         must be 7e-18 to 2.9e17 long, what Mitsuba's float32 ray test can
         hit (default: 1)
       - |exposed|
     * - height
       - |float|
       - Height along the axis, finite and > 0 (default: 1)
       - |exposed|
     * - to_world
       - |transform|
       - Placement in the world, applied after ``center``/``radius``/
         ``height``; any invertible affine map, scaling included
         (default: identity)
     * - segments
       - |int|
       - Number of sides of the proxy polygon, from 3 to 65536 (default: 64)
       - |exposed|

    A closed cylinder standing on its bottom cap: in object space the solid
    ``x^2 + z^2 <= 1``, ``0 <= y <= 1`` (axis +y), placed in the world by
    ``to_world . translate(center) . scale(radius, height, radius)``. The
    standard shape properties (a nested ``bsdf``, ``emitter``, media,
    ``face_normals``, ``flip_normals``) work as on any mesh.

    Mitsuba's acceleration structure and every built-in integrator see a
    *circumscribed* tessellation (the true surface lies inside it; side and
    caps share rim vertices, so it is watertight; smooth radial normals on
    the side, flat on the caps). The ``whitted`` integrator refines each hit
    on it with the exact analytic intersection of
    :mod:`mitsuba_whitted.geometry.cylinder`, for which
    :meth:`world_to_canonical_matrix` gives the ray transform.
    """

    def __init__(self, props: mi.Properties):
        self._to_world, self._to_world_inverse = checked_transform(
            props.get("to_world", mi.ScalarAffineTransform4d()), PLUGIN_NAME)
        self._shape = {
            "center": mi.Point3f(*checked_numbers(props.get("center", (0, 0, 0)), PLUGIN_NAME,
                                                  "center", size=3)),
            "radius": mi.Float(*checked_numbers(props.get("radius", 1.0), PLUGIN_NAME, "radius")),
            "height": mi.Float(*checked_numbers(props.get("height", 1.0), PLUGIN_NAME, "height")),
            "segments": mi.UInt32(_checked_segments(props.get("segments", 64))),
        }
        self._validate()
        positions, *_ , faces = canonical_mesh(self.segments)
        super().__init__(props.id() or PLUGIN_NAME, len(positions), len(faces), props,
                         has_vertex_normals=True, has_vertex_texcoords=True)
        # The shape's BSDF, emitter and media are objects of their own.
        self._last_valid = LastValid(PLUGIN_NAME, nested=False)
        self._write_mesh()

    # -- Parameters --------------------------------------------------------

    @property
    def center(self) -> np.ndarray:
        return np.array(self._shape["center"].numpy()[:, 0], dtype=np.float64)

    @property
    def radius(self) -> float:
        return float(self._shape["radius"].numpy()[0])

    @property
    def height(self) -> float:
        return float(self._shape["height"].numpy()[0])

    @property
    def segments(self) -> int:
        return int(self._shape["segments"].numpy()[0])

    def _validate(self) -> None:
        for name in ("radius", "height"):
            checked_numbers(self._shape[name], PLUGIN_NAME, name, greater_than=0)
        checked_numbers(self._shape["center"], PLUGIN_NAME, "center", size=3)
        _checked_segments(self._shape["segments"])

    # -- Transforms for the analytic intersection --------------------------

    def canonical_to_world_matrix(self) -> np.ndarray:
        """``M = to_world . translate(center) . scale(r, h, r)``, float64."""
        return self._to_world @ _translate(self.center) @ _scale(
            [self.radius, self.height, self.radius])

    def world_to_canonical_matrix(self) -> np.ndarray:
        """``M^-1`` in float64, composed from the exact inverses of the factors
        (no general inversion of a possibly badly scaled product)."""
        inverse_scale = _scale([1 / self.radius, 1 / self.height, 1 / self.radius])
        return inverse_scale @ _translate(-self.center) @ self._to_world_inverse

    # -- Mesh --------------------------------------------------------------

    def _write_mesh(self) -> None:
        positions, normals, uv, faces = canonical_mesh(self.segments)
        to_world = self.canonical_to_world_matrix()
        linear = to_world[:3, :3]
        positions = positions @ linear.T + to_world[:3, 3]
        self._check_lengths(positions, faces)
        # Normals take the inverse transpose: n_world = W^T n.
        normals = normals @ self.world_to_canonical_matrix()[:3, :3]
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        if np.linalg.det(linear) < 0:
            # A mirroring placement reverses the winding; keep it outward.
            faces = faces[:, ::-1]
        params = mi.traverse(self)
        params["vertex_positions"] = device_array(mi.Float, positions)
        params["vertex_normals"] = device_array(mi.Float, normals)
        params["vertex_texcoords"] = device_array(mi.Float, uv)
        params["faces"] = device_array(mi.UInt32, faces)
        params.update()

    def _check_lengths(self, positions: np.ndarray, faces: np.ndarray) -> None:
        """Refuse a placement whose triangles Mitsuba's ray test cannot hit
        in float32 (``MAX_LENGTH``), naming the radius or height that is out
        of range, else the placement that scaled them."""
        corners = positions[faces]
        lengths = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)
        own = {"radius": self.radius, "height": self.height}
        for length, large in ((lengths.max(), True), (lengths.min(), False)):
            if MIN_LENGTH <= length <= MAX_LENGTH:
                continue
            name = (max if large else min)(own, key=own.get)
            if (own[name] <= 1) if large else (own[name] >= 1):
                name = "to_world"
            raise ParameterError(
                PLUGIN_NAME, name,
                f"makes the cylinder's triangles {length:.3g} long in the world, and Mitsuba's "
                f"float32 ray test, which multiplies two of their edges, hits only triangles "
                f"{MIN_LENGTH:.2g} to {MAX_LENGTH:.2g} long")

    def traverse(self, callback) -> None:
        super().traverse(callback)
        for name in SHAPE_KEYS:
            callback.put(name, self._shape[name], mi.ParamFlags.NonDifferentiable)

    def parameters_changed(self, keys) -> None:
        with self._last_valid.updating(self):
            if any(key in SHAPE_KEYS for key in keys):
                self._validate()
                self._write_mesh()  # notifies the mesh of its new buffers
            super().parameters_changed(keys)

    def to_string(self) -> str:
        return (f"CappedCylinder[center={self.center.tolist()}, radius={self.radius}, "
                f"height={self.height}, segments={self.segments}, "
                f"vertex_count={self.vertex_count()}, face_count={self.face_count()}]")


def _checked_segments(value) -> int:
    count = checked_numbers(value, PLUGIN_NAME, "segments")[0]
    check(count.is_integer() and 3 <= count <= MAX_SEGMENTS, PLUGIN_NAME, "segments",
          f"must be a whole number from 3 to {MAX_SEGMENTS} (got {count:g})")
    return int(count)


mi.register_shape(PLUGIN_NAME, lambda props: CappedCylinder(props))
