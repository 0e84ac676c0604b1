"""The COSC363 ray tracer's procedural "tartan" texture."""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import check
from ..parameters import LastValid, checked_numbers, resolution_at
from .common import HiddenParameter, apply_rows, inverse_rows, read_to_world

PLUGIN_NAME = "tartan"

#: Its "orange": full red, half green, no blue.
DEFAULT_COLOR = (1.0, 0.5, 0.0)
DEFAULT_FREQUENCY = 3.0


class Tartan(mi.Texture):
    """
    .. _texture-tartan:

    Tartan texture (:monosp:`tartan`)
    ---------------------------------

    .. pluginparameters::

     * - frequency
       - |float|
       - Angular frequency f of the squares, in radians per unit of texture
         space; must be > 0, and at most pi x 10^6, for squares float32
         resolves (1e-6 across). It only moves the squares' edges, where the
         colour jumps: like a silhouette, not differentiated. (Default: 3)
       - |exposed|

     * - color
       - |rgb|
       - Colour of the squares, each channel >= 0. (Default: orange, (1, 0.5, 0))
       - |exposed|, |differentiable|

     * - to_world
       - |transform|
       - Places the pattern in the world: it is evaluated at
         ``to_world⁻¹ · p`` for the surface point p; any invertible affine
         map. (Default: identity)
       - |exposed|, |differentiable|

    The procedural texture of the COSC363 ray tracer. At the (texture-space)
    point p = (x, y, z) the colour is ``color`` where sin(f·x) > 0 and
    cos(f·y) > 0, which draws a lattice of squares, and elsewhere the
    "multicoloured background" (sin x, sin y, sin z). That program used the
    raw sines, which are negative half of the time; here each channel is
    clamped to [0, 1] so the texture is a physical reflectance (a negative
    albedo would make a BSDF emit negative light).

    The pattern depends on the 3D point, not on uv, so it needs no
    parameterisation and works on any shape. It needs an RGB variant.

    ``mean()`` is the analytic expectation of the luminance over space,
    taking the squares (a quarter of space) and the background as
    independent: ``luminance(color)/4 + (3/4)·(1/π)``, where 1/π is the mean
    of max(sin t, 0). That independence is exact for the default frequency
    3 (over one period of 2π the background averages 1/π inside and outside
    the squares alike) and an estimate for other frequencies; Mitsuba's
    built-in BSDFs use the mean only to weigh their sampling strategies.

    .. tabs::
        .. code-tab:: xml

            <texture type="tartan" name="reflectance">
                <float name="frequency" value="3"/>
                <rgb name="color" value="1, 0.5, 0"/>
            </texture>

        .. code-tab:: python

            'type': 'tartan',
            'frequency': 3.0,
            'color': [1.0, 0.5, 0.0]
    """

    def __init__(self, props: mi.Properties):
        mi.Texture.__init__(self, props)
        # The background is an RGB triple of sines: no spectrum.
        check(mi.is_rgb, PLUGIN_NAME, "color",
              f"is RGB, which the variant '{mi.variant()}' cannot use: choose an RGB "
              "variant such as llvm_ad_rgb")
        self.frequency = mi.Float(*checked_numbers(props.get("frequency", DEFAULT_FREQUENCY),
                                                   PLUGIN_NAME, "frequency"))
        self.color = mi.Color3f(*checked_numbers(props.get("color", DEFAULT_COLOR), PLUGIN_NAME,
                                                 "color", size=3, broadcast=True))
        self._to_world = HiddenParameter(read_to_world(props, PLUGIN_NAME))
        self._last_valid = LastValid(PLUGIN_NAME)
        self.parameters_changed([])

    def parameters_changed(self, keys=()):
        with self._last_valid.updating(self):
            frequency = checked_numbers(self.frequency, PLUGIN_NAME, "frequency",
                                        greater_than=0)[0]
            # Squares finer than float32 resolves would be noise.
            finest = math.pi / resolution_at()
            check(frequency <= finest, PLUGIN_NAME, "frequency",
                  f"must be at most {finest:g}, for squares (pi / frequency across) that "
                  f"float32 resolves (got {frequency:g})")
            checked_numbers(self.color, PLUGIN_NAME, "color", size=3, at_least=0)
            self.to_local = inverse_rows(self._to_world.value, PLUGIN_NAME)
            # Opaque: a new value must not bake a new constant into every kernel.
            dr.make_opaque(self.frequency, self.color)

    def traverse(self, callback):
        callback.put("frequency", self.frequency, mi.ParamFlags.NonDifferentiable)
        callback.put("color", self.color, mi.ParamFlags.Differentiable)
        callback.put("to_world", self._to_world.value, mi.ParamFlags.Differentiable)

    def eval(self, si, active=True):
        p = apply_rows(self.to_local, si.p, translate=True)
        in_square = ((dr.sin(self.frequency * p.x) > 0)
                     & (dr.cos(self.frequency * p.y) > 0))
        background = dr.clip(mi.Color3f(dr.sin(p.x), dr.sin(p.y), dr.sin(p.z)), 0.0, 1.0)
        return dr.select(in_square, self.color, background)

    def eval_3(self, si, active=True):
        return self.eval(si, active)

    def eval_1(self, si, active=True):
        return mi.luminance(self.eval(si, active))

    def mean(self):
        return mi.luminance(self.color) / 4 + 0.75 / math.pi

    def is_spatially_varying(self):
        return True

    def to_string(self):
        to_world = str(self._to_world.value).replace("\n", "\n  ")
        return (f"Tartan[\n  frequency = {dr.slice(self.frequency, 0)},\n"
                f"  color = {np.ravel(self.color).tolist()},\n"
                f"  to_world = {to_world}\n]")


mi.register_texture(PLUGIN_NAME, lambda props: Tartan(props))
