"""What this package's textures share.

The transform parameters (``to_world``) are inverted once, with a check.

``sphere_map`` and ``planar_map`` compute texture coordinates from the
surface point or normal, as the COSC363 ray tracer does, and hand them to any nested
texture (usually a ``bitmap``). ``mi.Texture`` is a different class in each
Mitsuba variant (and nanobind types admit one base only, so a mixin will not
do): :func:`uv_remap_base` builds the shared base for the active variant, and
each plugin module calls it when it is (re)imported after a variant change.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import check
from ..jit import device_array
from ..parameters import checked_transform, read_texture


def read_to_world(props: mi.Properties, plugin: str) -> mi.AffineTransform4f:
    """The optional ``to_world`` property (identity if absent), checked, as a
    JIT transform (the parser hands over double precision; plugins use
    float)."""
    if "to_world" not in props:
        return mi.AffineTransform4f()
    matrix, _ = checked_transform(props.get("to_world"), plugin)
    return mi.AffineTransform4f(mi.ScalarTransform4f(matrix.astype(np.float32)))


def inverse_rows(to_world: mi.AffineTransform4f, plugin: str) -> mi.Float:
    """The top three rows of ``to_world⁻¹`` as one array of 12 entries
    (row-major), differentiable with ``to_world``, or a
    :class:`ParameterError` unless ``to_world`` is a finite, invertible
    affine map.

    One flat array, not a transform: Dr.Jit traverses a Python plugin's
    attributes on every call of a frozen kernel, at a cost that grows with
    the number of arrays it finds (a transform holds 16 nested ones)."""
    _, inverse = checked_transform(to_world, plugin)
    rows = device_array(mi.Float, inverse[:3].astype(np.float32))
    if not dr.grad_enabled(to_world):
        return rows
    # Differentiated (``whitted`` gradients): the value stays the float64
    # inverse's, the derivative is that of Dr.Jit's inverse.
    inverted = dr.rcp(to_world.matrix)
    traced = dr.concat([mi.Float(inverted[row][column]) for row in range(3)
                        for column in range(4)])
    return rows + (traced - dr.detach(traced))


def apply_rows(rows: mi.Float, v, translate: bool) -> mi.Vector3f:
    """The affine map of :func:`inverse_rows` applied to a point
    (``translate``) or to a direction."""
    m = [dr.gather(mi.Float, rows, index) for index in range(12)]
    result = []
    for row in range(3):
        value = m[4 * row] * v.x + m[4 * row + 1] * v.y + m[4 * row + 2] * v.z
        result.append(value + m[4 * row + 3] if translate else value)
    return mi.Vector3f(*result)


class HiddenParameter:
    """A parameter that ``mi.traverse`` exposes and no kernel reads (the
    kernels read what ``parameters_changed`` derives from it), kept in
    ``__slots__``, where Dr.Jit's traversal of frozen-kernel inputs does not
    look (see :func:`inverse_rows` for what that traversal costs)."""

    __slots__ = ("value",)

    def __init__(self, value):
        self.value = value


def nested_texture(props: mi.Properties, plugin: str) -> mi.Texture:
    """The required nested ``texture`` of a uv-mapping plugin (an RGB value
    is accepted too and becomes a constant texture, as in Mitsuba's BSDFs)."""
    check("texture" in props, plugin, "texture",
          "is required: nest the texture to map, e.g. <texture type=\"bitmap\" name=\"texture\">")
    return read_texture(props, "texture", plugin)


def uv_remap_base() -> type:
    """A base class, for the active variant, of an ``mi.Texture`` whose
    ``remap_uv(si)`` gives the uv at which ``self.texture`` is evaluated;
    everything else is delegated to that nested texture."""

    class UVRemapTexture(mi.Texture):

        def remapped(self, si: mi.SurfaceInteraction3f) -> mi.SurfaceInteraction3f:
            # A copy: the caller (a BSDF) still needs its own uv.
            si_new = mi.SurfaceInteraction3f(si)
            si_new.uv = self.remap_uv(si)
            return si_new

        def eval(self, si, active=True):
            return self.texture.eval(self.remapped(si), active)

        def eval_1(self, si, active=True):
            return self.texture.eval_1(self.remapped(si), active)

        def eval_3(self, si, active=True):
            return self.texture.eval_3(self.remapped(si), active)

        def mean(self):
            return self.texture.mean()

        def is_spatially_varying(self):
            return self.texture.is_spatially_varying()

        def traverse_texture(self, callback):
            callback.put("texture", self.texture, mi.ParamFlags.Differentiable)

        def nested_string(self) -> str:
            return "  texture = " + str(self.texture).replace("\n", "\n  ")

    return UVRemapTexture
