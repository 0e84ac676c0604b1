"""The COSC363 ray tracer's ground-plane mapping: uv from world x and z, for any nested texture."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import check
from ..parameters import LastValid, checked_numbers, resolution_at
from .common import nested_texture, uv_remap_base

PLUGIN_NAME = "planar_map"

#: Mitsuba's ``rectangle`` spans [-1, 1]² before its ``to_world``.
DEFAULT_BOUNDS = {"x_min": -1.0, "x_max": 1.0, "z_min": -1.0, "z_max": 1.0}


class PlanarMap(uv_remap_base()):
    """
    .. _texture-planar_map:

    Planar mapping (:monosp:`planar_map`)
    -------------------------------------

    .. pluginparameters::

     * - texture
       - |texture|
       - The texture to map (e.g. a ``bitmap``); required.
       - |exposed|, |differentiable|

     * - x_min, x_max
       - |float|
       - World x range the image spans once: finite, with x_max above x_min
         by at least float32's resolution there, 1e-6 of the bounds'
         magnitude (taken at least 1). (Default: -1, 1)
       - |exposed|, |differentiable|

     * - z_min, z_max
       - |float|
       - World z range the image spans once, as for x. (Default: -1, 1)
       - |exposed|, |differentiable|

    The COSC363 ray tracer's mapping for its ground plane, for the world
    point p = (x, y, z), written exactly as it was:

        u = (x − x_min) / (x_max − x_min),   v = (z − z_min) / (z_min − z_max)

    u runs from 0 at x_min to 1 at x_max. The denominator for v is
    z_min − z_max, which is negative: v runs from 0 at z_min down to −1 at
    z_max, and with the nested bitmap's default ``repeat`` wrap that is the
    image once, with v ≡ 1 − (z − z_min)/(z_max − z_min). A Mitsuba bitmap
    has its top row at v = 0, so the image's top edge lies along z = z_max
    (the edge nearest a camera on the +z side) and its left edge along x_min.
    Seen from above (+y), with +x to the right, the picture is therefore
    mirrored top to bottom; it reads correctly from below. (That program
    drew with OpenGL, whose t = 0 is the bottom row: there the same formula puts
    the image upright for a viewer at +z looking down the −z axis.) Points
    outside the bounds repeat or clamp the image as the nested texture's
    wrap mode says. y is ignored.

    ``mean()`` is the nested texture's mean (the mapping is affine, so it is
    exact over whole tiles).

    .. tabs::
        .. code-tab:: xml

            <texture type="planar_map" name="reflectance">
                <float name="x_min" value="-20"/> <float name="x_max" value="20"/>
                <float name="z_min" value="-200"/> <float name="z_max" value="-40"/>
                <texture type="bitmap" name="texture">
                    <string name="filename" value="textures/pink_elephant.png"/>
                </texture>
            </texture>

        .. code-tab:: python

            'type': 'planar_map',
            'x_min': -20, 'x_max': 20, 'z_min': -200, 'z_max': -40,
            'texture': {'type': 'bitmap', 'filename': 'textures/pink_elephant.png'}
    """

    def __init__(self, props: mi.Properties):
        mi.Texture.__init__(self, props)
        self.texture = nested_texture(props, PLUGIN_NAME)
        for name, default in DEFAULT_BOUNDS.items():
            setattr(self, name, mi.Float(*checked_numbers(props.get(name, default),
                                                          PLUGIN_NAME, name)))
        self._last_valid = LastValid(PLUGIN_NAME)
        self.parameters_changed([])

    def parameters_changed(self, keys=()):
        with self._last_valid.updating(self):
            bounds = {name: checked_numbers(getattr(self, name), PLUGIN_NAME, name)[0]
                      for name in DEFAULT_BOUNDS}
            for axis in ("x", "z"):
                _check_span(bounds, axis, keys)
            dr.make_opaque(self.x_min, self.x_max, self.z_min, self.z_max)

    def remap_uv(self, si):
        return mi.Point2f((si.p.x - self.x_min) / (self.x_max - self.x_min),
                          (si.p.z - self.z_min) / (self.z_min - self.z_max))

    def traverse(self, callback):
        self.traverse_texture(callback)
        for name in DEFAULT_BOUNDS:
            callback.put(name, getattr(self, name), mi.ParamFlags.Differentiable)

    def to_string(self):
        bounds = ", ".join(f"{name} = {dr.slice(getattr(self, name), 0)}" for name in DEFAULT_BOUNDS)
        return f"PlanarMap[\n  {bounds},\n{self.nested_string()}\n]"


def _check_span(bounds: dict, axis: str, keys) -> None:
    """``{axis}_max > {axis}_min`` by a span float32 can hold and resolves
    where it lies. A span below the resolution of the surface points it
    maps puts a whole image, or millions of them, between two neighbouring
    points: the uv become noise, and past 2^31 texels the nested bitmap's
    integer lookup wraps into values like -1e8 (measured at u = 5e6). The error names the bound
    that was just changed: the maximum, unless only the minimum was."""
    low, high = f"{axis}_min", f"{axis}_max"
    name, problem = ((low, f"must be less than {high}") if low in keys and high not in keys
                     else (high, f"must be greater than {low}"))
    got = f"(got {low}={bounds[low]:g}, {high}={bounds[high]:g})"
    with np.errstate(over="ignore"):
        span = np.float32(bounds[high]) - np.float32(bounds[low])  # as the kernel subtracts
    check(np.isfinite(span), PLUGIN_NAME, name, f"{problem} by a span float32 can hold {got}")
    least = resolution_at(bounds[low], bounds[high])
    check(span >= least, PLUGIN_NAME, name,
          f"{problem} by at least {least:g}, the finest span float32 resolves at that position "
          f"{got}")


mi.register_texture(PLUGIN_NAME, lambda props: PlanarMap(props))
