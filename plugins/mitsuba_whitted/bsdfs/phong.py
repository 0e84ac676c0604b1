"""The ``phong`` BSDF: the COSC363 ray tracer's Phong shading, normalized so that a path
tracer renders it correctly too."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import check
from ..parameters import LastValid, checked_numbers, read_texture, value_text

PLUGIN_NAME = "phong"

#: A moderately sharp highlight; the COSC363 ray tracer's is not known.
DEFAULT_EXPONENT = 30.0

_DIFFUSE = mi.BSDFFlags.DiffuseReflection
_GLOSSY = mi.BSDFFlags.GlossyReflection

#: The parameters that hold reflectances.
REFLECTANCES = ("diffuse_reflectance", "specular_reflectance")
#: The relative error of a number rounded to float32 (half an ulp, 2^-24):
#: 0.8 and 0.2 are 0.800000012 and 0.200000003 in float32, whose sum passes
#: 1 by 1.5e-8, less than this rounding of the two.
_ROUNDING = float(np.finfo(np.float32).eps) / 2


class Phong(mi.BSDF):
    r"""
    .. _bsdf-phong:

    Phong BSDF (:monosp:`phong`)
    ----------------------------

    .. pluginparameters::

     * - diffuse_reflectance
       - |spectrum| or |texture|
       - Albedo of the diffuse lobe, :math:`\rho_d`: finite, and >= 0 where
         it is constant. (Default: 0.5)
       - |exposed|, |differentiable|

     * - specular_reflectance
       - |spectrum| or |texture|
       - Weight of the specular highlight, :math:`\rho_s`; white in the
         classic model. Finite, and >= 0 where constant. (Default: 0.2)
       - |exposed|, |differentiable|

     * - exponent
       - |float|
       - Phong exponent (shininess) :math:`n \ge 0`; larger values give a
         smaller, sharper highlight, 0 a uniform glossy term. (Default: 30)
       - |exposed|, |differentiable|

    The classic Phong model (a Lambertian term plus a white highlight around
    the mirror direction), in the energy-normalized form of Lafortune and
    Willems (1994), the "modified Phong" BRDF:

    .. math::

        f(\omega_i, \omega_o) = \frac{\rho_d}{\pi}
            + \rho_s \, \frac{n + 2}{2\pi} \, \max(0, \cos\alpha)^n,

    where :math:`\alpha` is the angle between :math:`\omega_o` and the mirror
    reflection of :math:`\omega_i` about the shading normal (the highlight is
    zero for :math:`\cos\alpha \le 0`, also when :math:`n = 0`). The normalization
    makes the highlight's albedo exactly :math:`\rho_s` at normal incidence
    (less at grazing angles, where part of the lobe falls below the surface),
    so :math:`\rho_d + \rho_s \le 1` per channel conserves energy. The plugin
    warns when constant reflectances break that bound; spatially varying
    textures are not inspected.

    The BSDF is one-sided like ``diffuse``: it is zero unless both directions
    lie above the surface. Component 0 is the diffuse lobe
    (``DiffuseReflection``), component 1 the highlight
    (``GlossyReflection``). ``sample`` picks a lobe with probability
    proportional to the mean of its reflectance at the hit, then samples it
    exactly: a cosine-weighted hemisphere for the diffuse lobe, a density
    :math:`\frac{n + 1}{2\pi} \cos^n\alpha` about the mirror direction for the
    highlight (a direction below the surface is rejected with weight 0).
    ``pdf`` is the matching mixture density. Unpolarized variants only.

    .. tabs::

        .. code-tab:: xml

            <bsdf type="phong">
                <rgb name="diffuse_reflectance" value="0.1, 0.2, 0.6"/>
                <rgb name="specular_reflectance" value="0.3"/>
                <float name="exponent" value="50"/>
            </bsdf>

        .. code-tab:: python

            'type': 'phong',
            'diffuse_reflectance': {'type': 'rgb', 'value': [0.1, 0.2, 0.6]},
            'specular_reflectance': {'type': 'rgb', 'value': 0.3},
            'exponent': 50.0
    """

    def __init__(self, props: mi.Properties):
        mi.BSDF.__init__(self, props)
        self.diffuse_reflectance = read_texture(props, "diffuse_reflectance", PLUGIN_NAME, 0.5)
        self.specular_reflectance = read_texture(props, "specular_reflectance", PLUGIN_NAME, 0.2)
        self.exponent = mi.Float(*checked_numbers(props.get("exponent", DEFAULT_EXPONENT),
                                                  PLUGIN_NAME, "exponent"))
        self._last_valid = LastValid(PLUGIN_NAME)
        self.parameters_changed([])

        diffuse = _DIFFUSE | mi.BSDFFlags.FrontSide
        glossy = _GLOSSY | mi.BSDFFlags.FrontSide
        self.m_components = [diffuse, glossy]
        self.m_flags = diffuse | glossy

    # -- Parameters ---------------------------------------------------------

    def traverse(self, callback):
        callback.put("diffuse_reflectance", self.diffuse_reflectance,
                     mi.ParamFlags.Differentiable)
        callback.put("specular_reflectance", self.specular_reflectance,
                     mi.ParamFlags.Differentiable)
        callback.put("exponent", self.exponent, mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys=()):
        with self._last_valid.updating(self):
            checked_numbers(self.exponent, PLUGIN_NAME, "exponent", at_least=0)
            constants = {name: _constant_value(getattr(self, name)) for name in REFLECTANCES}
            for name, value in constants.items():
                check(value is None or (value >= 0).all(), PLUGIN_NAME, name,
                      f"must not be negative (got {value_text(value)})")
            # Opaque, so that changing it through mi.traverse reuses the kernels.
            dr.make_opaque(self.exponent)
            self._warn_if_not_energy_conserving(constants)

    def _exponent_value(self) -> float:
        # A one-entry array in the JIT variants, a float in the scalar ones.
        return float(self.exponent[0] if dr.is_jit_v(self.exponent) else self.exponent)

    def _warn_if_not_energy_conserving(self, constants: dict) -> None:
        """Warn when constant reflectances reflect more than they receive in
        some channel; textures that vary are skipped."""
        if any(value is None for value in constants.values()):
            return
        diffuse, specular = np.broadcast_arrays(*constants.values())
        total = diffuse + specular
        worst = int(np.argmax(total))
        # Each float32 reflectance may be up to _ROUNDING above the number
        # written, so a sum up to that much over 1 may have been 1 or less.
        if total[worst] * (1 - _ROUNDING) <= 1:
            return
        mi.Log(mi.LogLevel.Warn,
               f"{PLUGIN_NAME}: diffuse_reflectance + specular_reflectance of {self._name()} "
               f"reach {_shown(diffuse[worst])} + {_shown(specular[worst])} = "
               f"{total[worst]:.8g} > 1, so the BSDF reflects more energy than it receives.")

    def _name(self) -> str:
        """How a sentence names this BSDF: by its id, if the scene gave one."""
        name = self.id()
        if name and not name.startswith("_unnamed"):
            return f"bsdf '{name}'"
        return "a bsdf without an id"

    # -- Evaluation ---------------------------------------------------------

    def eval_diffuse_reflectance(self, si, active=True):
        return self.diffuse_reflectance.eval(si, active)

    def eval(self, ctx, si, wo, active=True):
        rho_d, rho_s = self._reflectances(si, active)
        return self._eval_and_pdf(ctx, si, wo, rho_d, rho_s, active)[0]

    def pdf(self, ctx, si, wo, active=True):
        rho_d, rho_s = self._reflectances(si, active)
        return self._eval_and_pdf(ctx, si, wo, rho_d, rho_s, active)[1]

    def eval_pdf(self, ctx, si, wo, active=True):
        rho_d, rho_s = self._reflectances(si, active)
        return self._eval_and_pdf(ctx, si, wo, rho_d, rho_s, active)

    def sample(self, ctx, si, sample1, sample2, active=True):
        bs = dr.zeros(mi.BSDFSample3f)
        has_diffuse, has_glossy = _enabled_lobes(ctx)
        if not (has_diffuse or has_glossy):
            return bs, dr.zeros(mi.Spectrum)

        active = mi.Bool(active) & (mi.Frame3f.cos_theta(si.wi) > 0)
        rho_d, rho_s = self._reflectances(si, active)
        pick_glossy = sample1 < _glossy_probability(ctx, rho_d, rho_s)

        bs.wo = dr.select(pick_glossy, self._sample_highlight(si.wi, sample2),
                          mi.warp.square_to_cosine_hemisphere(sample2))
        bs.eta = 1.0
        bs.sampled_component = dr.select(pick_glossy, mi.UInt32(1), mi.UInt32(0))
        bs.sampled_type = dr.select(pick_glossy, mi.UInt32(+_GLOSSY),
                                    mi.UInt32(+_DIFFUSE))

        value, pdf = self._eval_and_pdf(ctx, si, bs.wo, rho_d, rho_s, active)
        valid = active & (pdf > 0)
        bs.pdf = dr.select(valid, pdf, 0.0)
        return bs, dr.select(valid, value / pdf, 0.0)

    def _reflectances(self, si, active):
        return (self.diffuse_reflectance.eval(si, active),
                self.specular_reflectance.eval(si, active))

    def _sample_highlight(self, wi, sample2):
        """Direction with density (n + 1)/(2 pi) cos^n(alpha) about the mirror
        direction of ``wi`` (inverting the CDF 1 - cos^(n+1) of alpha)."""
        cos_alpha = dr.power(sample2.x, dr.rcp(self.exponent + 1.0))
        sin_alpha = dr.safe_sqrt(1.0 - dr.square(cos_alpha))
        sin_phi, cos_phi = dr.sincos(dr.two_pi * sample2.y)
        local = mi.Vector3f(sin_alpha * cos_phi, sin_alpha * sin_phi, cos_alpha)
        return mi.Frame3f(mi.reflect(wi)).to_world(local)

    def _eval_and_pdf(self, ctx, si, wo, rho_d, rho_s, active):
        """f cos(theta_o) of the enabled lobes, and the density of ``sample``."""
        cos_i = mi.Frame3f.cos_theta(si.wi)
        cos_o = mi.Frame3f.cos_theta(wo)
        has_diffuse, has_glossy = _enabled_lobes(ctx)
        active = (mi.Bool(active) & (has_diffuse or has_glossy)
                  & (cos_i > 0) & (cos_o > 0))

        cos_alpha = dr.dot(wo, mi.reflect(si.wi))
        # power() goes through log: the clamp keeps the discarded branch (and
        # its derivatives) finite where cos(alpha) <= 0.
        lobe = dr.select(cos_alpha > 0,
                         dr.power(dr.maximum(cos_alpha, 1e-30), self.exponent), 0.0)

        value = dr.zeros(mi.Spectrum)
        if has_diffuse:
            value += rho_d * (dr.inv_pi * cos_o)
        if has_glossy:
            value += rho_s * ((self.exponent + 2.0) * dr.inv_two_pi * lobe * cos_o)

        p_glossy = _glossy_probability(ctx, rho_d, rho_s)
        pdf = dr.lerp(dr.inv_pi * cos_o,
                      (self.exponent + 1.0) * dr.inv_two_pi * lobe, p_glossy)
        return dr.select(active, value, 0.0), dr.select(active, pdf, 0.0)

    def to_string(self):
        return (f"Phong[\n"
                f"  diffuse_reflectance = {self.diffuse_reflectance},\n"
                f"  specular_reflectance = {self.specular_reflectance},\n"
                f"  exponent = {self._exponent_value()}\n"
                f"]")


def _enabled_lobes(ctx) -> tuple[bool, bool]:
    return ctx.is_enabled(_DIFFUSE, 0), ctx.is_enabled(_GLOSSY, 1)


def _glossy_probability(ctx, rho_d, rho_s):
    """Probability of sampling the highlight: its share of the two lobes'
    mean reflectances (an even split where both are 0), or 0/1 when the
    context enables only one lobe."""
    has_diffuse, has_glossy = _enabled_lobes(ctx)
    if has_diffuse != has_glossy:
        return mi.Float(1.0 if has_glossy else 0.0)
    weight_d = dr.maximum(dr.mean(rho_d), 0.0)
    weight_s = dr.maximum(dr.mean(rho_s), 0.0)
    total = weight_d + weight_s
    return dr.select(total > 0, weight_s / total, 0.5)


def _shown(value: float) -> str:
    """A float32 reflectance as it was written (its shortest text)."""
    return np.format_float_positional(np.float32(value), trim="-")


def _constant_value(texture) -> np.ndarray | None:
    """The value of a texture that does not vary (its channels), else
    ``None``."""
    if texture.is_spatially_varying():
        return None
    return np.array(texture.eval(dr.zeros(mi.SurfaceInteraction3f)), dtype=np.float64).ravel()


mi.register_bsdf(PLUGIN_NAME, lambda props: Phong(props))
