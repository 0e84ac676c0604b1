"""What this package's textures share.

The transform parameters (``to_world``) are inverted once, with a check.

``sphere_map`` and ``planar_map`` compute texture coordinates from the
surface point or normal, as the report does, and hand them to any nested
texture (usually a ``bitmap``). ``mi.Texture`` is a different class in each
Mitsuba variant (and nanobind types admit one base only, so a mixin will not
do): :func:`uv_remap_base` builds the shared base for the active variant, and
each plugin module calls it when it is (re)imported after a variant change.
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from ..errors import check


def read_to_world(props: mi.Properties) -> mi.AffineTransform4f:
    """The optional ``to_world`` property (identity if absent) as a JIT
    transform (the parser hands over double precision; plugins use float)."""
    if "to_world" not in props:
        return mi.AffineTransform4f()
    matrix = np.array(props.get("to_world").matrix, dtype=np.float32)
    return mi.AffineTransform4f(mi.ScalarTransform4f(matrix))


def inverse_to_world(to_world: mi.AffineTransform4f, plugin: str) -> mi.AffineTransform4f:
    """``to_world⁻¹``, or a :class:`ParameterError` if it does not exist."""
    to_local = to_world.inverse()
    check(np.isfinite(to_local.matrix.numpy()).all(), plugin, "to_world",
          "must be invertible (its matrix is singular)")
    return to_local


def nested_texture(props: mi.Properties, plugin: str) -> mi.Texture:
    """The required nested ``texture`` of a uv-mapping plugin (an RGB value
    is accepted too and becomes a constant texture, as in Mitsuba's BSDFs)."""
    check("texture" in props, plugin, "texture",
          "is required: nest the texture to map, e.g. <texture type=\"bitmap\" name=\"texture\">")
    return props.get_texture("texture")


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
