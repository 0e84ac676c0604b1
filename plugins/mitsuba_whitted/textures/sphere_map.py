"""The COSC363 ray tracer's sphere mapping: uv from the normal, for any nested texture."""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import check_choice
from ..parameters import LastValid, checked_numbers
from .common import (HiddenParameter, apply_rows, inverse_rows, nested_texture,
                     read_to_world, uv_remap_base)

PLUGIN_NAME = "sphere_map"


def unit_direction(d: mi.Vector3f) -> mi.Vector3f:
    """``d / |d|`` that never overflows, underflows or divides by zero: ``d``
    is first divided by its largest component (|d|² of 1e-25 or 1e25 is not
    a float32), and a zero vector stays zero. The clamp to [-1, 1] keeps
    asin/acos defined where rsqrt is an approximation (CUDA's is within
    2 ulp, so a component of a unit vector may come out as 1 + ε)."""
    largest = dr.maximum(dr.maximum(dr.abs(d.x), dr.abs(d.y)), dr.abs(d.z))
    scaled = d / dr.select(largest > 0, largest, 1.0)
    n = scaled * dr.rsqrt(dr.maximum(dr.squared_norm(scaled), 1.0))
    return dr.clip(n, -1.0, 1.0)


def asin_uv(n: mi.Vector3f) -> mi.Point2f:
    """The ``asin`` mapping: u = 0.5 − asin(n_x)/π, v = 0.5 − asin(n_y)/π."""
    return mi.Point2f(0.5 - dr.asin(n.x) / math.pi, 0.5 - dr.asin(n.y) / math.pi)


def atan_uv(n: mi.Vector3f) -> mi.Point2f:
    """The ``atan`` mapping u = 0.5 + tan⁻¹(n_y/n_x)/(2π), written with
    atan2 (quadrant-correct, finite at n_x = 0); v as in :func:`asin_uv`."""
    return mi.Point2f(0.5 + dr.atan2(n.y, n.x) / (2 * math.pi),
                      0.5 - dr.asin(n.y) / math.pi)


def equirect_uv(n: mi.Vector3f) -> mi.Point2f:
    """Longitude/latitude with +y up: u = 0.5 + atan2(n_x, n_z)/(2π) (u = 0.5
    facing +z, growing towards +x), v = acos(n_y)/π (0 at +y, 1 at −y)."""
    return mi.Point2f(0.5 + dr.atan2(n.x, n.z) / (2 * math.pi),
                      dr.acos(n.y) / math.pi)


MAPPINGS = {"asin": asin_uv, "atan": atan_uv, "equirect": equirect_uv}


class SphereMap(uv_remap_base()):
    """
    .. _texture-sphere_map:

    Sphere mapping (:monosp:`sphere_map`)
    -------------------------------------

    .. pluginparameters::

     * - texture
       - |texture|
       - The texture to map (e.g. a ``bitmap``); required.
       - |exposed|, |differentiable|

     * - mapping
       - |string|
       - ``asin``, ``atan`` or ``equirect`` (see below). (Default: ``asin``)

     * - center
       - |point|
       - If given (three finite numbers), the direction is
         ``normalize(p − center)`` for the surface point p; otherwise it is
         the shading normal. (Default: none)
       - |exposed|, |differentiable|

     * - to_world
       - |transform|
       - Orientation of the mapping frame: the direction d is mapped as
         ``to_world⁻¹ · d`` before the formulas below; any invertible affine
         map. (Default: identity)
       - |exposed|, |differentiable|

    The COSC363 ray tracer's "non planar texturing": texture coordinates come from a
    unit direction n, by default the shading normal, and the nested texture
    is evaluated at them (with a copy of the surface interaction whose uv is
    replaced, so it works with any shape's own uv and any texture):

    - ``asin`` (its choice): u = 0.5 − asin(n_x)/π, v = 0.5 − asin(n_y)/π.
      Front (n_z > 0) and back hemispheres get the same uv: the back shows
      the image mirrored. It was chosen because it did not stretch the
      lemons.
    - ``atan`` (its alternative): u = 0.5 + atan2(n_y, n_x)/(2π),
      v as ``asin``: the image is wrapped once around the z axis, which
      stretches it, as its author found. The seam is at n_x < 0, n_y = 0.
    - ``equirect``: longitude/latitude about +y,
      u = 0.5 + atan2(n_x, n_z)/(2π), v = acos(n_y)/π. The seam is at
      n_x = 0, n_z < 0 (the back, seen from +z).

    A Mitsuba bitmap puts its top row at v = 0, so n_y = +1 shows the top of
    the image in every mapping and pictures appear upright.

    Robustness: the direction is normalised without overflow and clamped
    to [-1, 1], so a normal of length 1 + 1e-6, the poles, the seams and a
    zero direction (a point at ``center``: it gets uv (0.5, 0.5)) all give
    finite uv. ``mean()`` is the nested texture's mean: the mapping is not
    area-preserving, so this is an estimate of the mean over the sphere.

    .. tabs::
        .. code-tab:: xml

            <texture type="sphere_map" name="reflectance">
                <string name="mapping" value="asin"/>
                <texture type="bitmap" name="texture">
                    <string name="filename" value="textures/lemons.png"/>
                </texture>
            </texture>

        .. code-tab:: python

            'type': 'sphere_map',
            'mapping': 'asin',
            'texture': {'type': 'bitmap', 'filename': 'textures/lemons.png'}
    """

    def __init__(self, props: mi.Properties):
        mi.Texture.__init__(self, props)
        self.texture = nested_texture(props, PLUGIN_NAME)
        self.mapping = check_choice(props.get("mapping", "asin"), tuple(MAPPINGS),
                                    PLUGIN_NAME, "mapping")
        self.center = (mi.Point3f(*checked_numbers(props.get("center"), PLUGIN_NAME, "center",
                                                   size=3))
                       if "center" in props else None)
        self._to_world = HiddenParameter(read_to_world(props, PLUGIN_NAME))
        self._last_valid = LastValid(PLUGIN_NAME)
        self.parameters_changed([])

    def parameters_changed(self, keys=()):
        with self._last_valid.updating(self):
            if self.center is not None:
                checked_numbers(self.center, PLUGIN_NAME, "center", size=3)
                dr.make_opaque(self.center)
            self.to_local = inverse_rows(self._to_world.value, PLUGIN_NAME)

    def direction(self, si: mi.SurfaceInteraction3f) -> mi.Vector3f:
        d = si.sh_frame.n if self.center is None else si.p - self.center
        return apply_rows(self.to_local, d, translate=False)

    def remap_uv(self, si):
        return MAPPINGS[self.mapping](unit_direction(self.direction(si)))

    def traverse(self, callback):
        self.traverse_texture(callback)
        if self.center is not None:
            callback.put("center", self.center, mi.ParamFlags.Differentiable)
        callback.put("to_world", self._to_world.value, mi.ParamFlags.Differentiable)

    def to_string(self):
        return (f"SphereMap[\n  mapping = {self.mapping},\n"
                f"  center = {None if self.center is None else np.ravel(self.center).tolist()},\n"
                f"{self.nested_string()}\n]")


mi.register_texture(PLUGIN_NAME, lambda props: SphereMap(props))
