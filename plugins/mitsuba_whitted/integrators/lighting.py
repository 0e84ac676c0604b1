"""Local illumination at a hit: ambient, delta lights with hard shadows,
sampled lights (area, environment) with a fixed number of shadow rays, and
the transmittance of shadow rays through surfaces that let light pass.

Nothing here draws from a random stream: sampled lights use a rotated R2
low-discrepancy sequence whose rotation is a hash of the ray's key, so the
result is a deterministic function of the scene and the render seed.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..jit import unit_pair
from .bsdf_query import has_delta_lobe
from .offsets import spawn_ray_to
from .scene_needs import SceneNeeds
from .scene_ref import ReadsScene, SceneRef

#: Shadow rays cross at most this many pass-through surfaces.
MAX_SHADOW_CROSSINGS = 16
#: R2 sequence steps (Roberts 2018): well-spread 2D points for any count.
R2_STEP = (0.7548776662466927, 0.5698402909980532)
#: A direction this close to the incoming one counts as "straight through".
STRAIGHT_COSINE = 1.0 - 1e-5
#: Shapes none of whose points sees any other part of the same shape: an
#: area light on one cannot light itself, so its own hits skip its samples.
SELF_HIDDEN_SHAPES = (mi.ShapeType.Rectangle, mi.ShapeType.Disk, mi.ShapeType.Sphere)
#: Oblique local direction used to tell index-matched from refracting
#: surfaces: at normal incidence even glass does not bend a ray.
PROBE_DIRECTION = (0.6, 0.0, 0.8)


@dataclass
class LightingSettings:
    #: A colour; an ``mi.Color3f`` to differentiate it (``gradients``).
    ambient: mi.ScalarColor3f
    emitter_samples: int
    seed: int
    #: Paths of indirect light per smooth hit (:mod:`.indirect`); 0: none.
    indirect_samples: int = 0


class ShadowTester(ReadsScene):
    """Transmittance of the segment from a hit to a point on a light.

    ``shadows``: ``"physical"`` and ``"tinted"`` are the integrator's modes
    (:meth:`_passes`); ``"blocking"``, every surface blocks, as the shadow
    rays of Mitsuba's path tracer do (the indirect paths' own shadow rays,
    :mod:`.indirect`). An analytic shape blocks only where its exact
    surface is, in every mode."""

    def __init__(self, scene_ref: SceneRef, needs: SceneNeeds, shadows: str, intersect):
        self.scene_ref = scene_ref
        #: Whether the march through pass-through surfaces carries its
        #: derivative in sums (:meth:`_march_by_parts`): set for the kernels
        #: that differentiate inside a symbolic loop (the gradients' tree
        #: replay), where Dr.Jit 1.5 cannot differentiate a product through
        #: the march's own loop.
        self.by_parts = False
        self.needs = needs
        self.tinted = shadows == "tinted"
        self.blocking = shadows == "blocking"
        self.intersect = intersect
        self.opaque = not needs.analytic_shapes and (self.blocking or not needs.transmissive)
        #: The :class:`~.shadow_log.ShadowLog` the rays are written to while
        #: a capturing render traces a kernel (:meth:`logging_to`), else
        #: ``None``: then nothing is written and the kernel does no more.
        self.log = None

    @contextmanager
    def logging_to(self, log):
        """Write the rays of the shadow tests traced meanwhile to ``log``."""
        self.log = log
        try:
            yield
        finally:
            self.log = None

    @dr.syntax
    def transmittance(self, si: mi.SurfaceInteraction3f, target: mi.Point3f,
                      active: mi.Bool, slot):
        """What reaches ``target`` from ``si`` (0 outside ``active``), and
        the closest-hit queries the segment took past its any-hit test
        (:meth:`_march`; 0 where it was not blocked). ``slot``: which of a
        lane's shadow rays this is, where the log keeps it.

        A SIMD packet none of whose lanes casts a shadow ray skips the test
        (a symbolic branch): Embree called with an empty packet still costs
        about as much as a full one's setup, and many packets have no
        shadow ray at all (packets of sky, of glass, of finished ray
        trees)."""
        if dr.hint(self.by_parts and dr.grad_enabled(target), mode="scalar"):
            # Dr.Jit 1.5 aborts on a symbolic branch whose input carries a
            # derivative inside such a kernel (a light that moves).
            return self._cast(si, target, active, slot)
        passed = mi.Color3f(0)
        marched = mi.UInt32(0)
        if active:
            passed, marched = self._cast(si, target, active, slot)
        return passed, marched

    def _cast(self, si: mi.SurfaceInteraction3f, target: mi.Point3f, active: mi.Bool, slot):
        ray = spawn_ray_to(si, target, self.needs.scale)
        if self.log is not None:
            self.log.test(slot, ray, active)
        blocked = self.scene.ray_test(ray, active)
        free = dr.select(active & ~blocked, mi.Color3f(1), mi.Color3f(0))
        if self.opaque:
            return free, mi.UInt32(0)
        # Only rays the fast any-hit test found blocked can still carry light
        # (through a pass-through surface, or past a proxy that the exact
        # surface does not fill): march those alone.
        weight, marched = self._march(ray, target, active & blocked, slot)
        if self.log is not None:
            self.log.followed(slot, marched, active)
        return free + weight, marched

    @dr.syntax
    def _march(self, ray: mi.Ray3f, target: mi.Point3f, active: mi.Bool, slot):
        """Follow the shadow ray through pass-through surfaces to the light:
        what arrives, and how many closest-hit queries that took."""
        if dr.hint(self.by_parts, mode="scalar"):
            return self._march_by_parts(ray, target, active, slot)
        weight = dr.select(active, mi.Color3f(1), mi.Color3f(0))
        crossings = mi.UInt32(0)
        while active:
            passed, hit, going_on, ray = self._crossing(ray, target, active, slot, crossings)
            weight[hit] = weight * passed
            weight[hit & ~going_on] = mi.Color3f(0)
            crossings += 1
            active = going_on
        return weight, crossings

    @dr.syntax
    def _march_by_parts(self, ray: mi.Ray3f, target: mi.Point3f, active: mi.Bool, slot):
        """``_march`` whose loop carries no derivative, so that it can stay
        symbolic where a derivative is taken inside the kernel (see
        ``by_parts``): the product of what each crossing passes is held
        without derivative, beside the sums that give the derivative of
        that product, a loop of sums (``max_iterations=-1``) for Dr.Jit.

        Per channel, with ``p_i`` what crossing ``i`` passes, ``Q`` the
        product of the non-zero ones and ``z`` the count of zeros:
        ``d(prod p_i) = Q sum_i dp_i / p_i`` if ``z`` is 0, ``Q dp_k`` for
        the zero ``k`` if ``z`` is 1, else 0. A blocked ray's weight is a
        constant 0, without derivative.

        The ray too is held without derivative. A light that moves turns
        it: every crossing lies on the one segment from the hit, so each
        segment's direction takes the derivative of the first one's, which
        depends on the target alone (a constant of the loop)."""
        start = dr.detach(ray.o)
        ray = dr.detach(ray)
        weight = dr.select(active, mi.Color3f(1), mi.Color3f(0))
        nonzero = mi.Color3f(1)
        zeros = mi.Color3f(0)
        relative = mi.Color3f(0)
        at_zeros = mi.Color3f(0)
        blocked = mi.Bool(False)
        crossings = mi.UInt32(0)
        while dr.hint(active, max_iterations=-1):
            turning = mi.Ray3f(ray)
            turning.d = dr.replace_grad(ray.d, dr.normalize(target - start))
            passed, hit, going_on, ray = self._crossing(turning, target, active, slot,
                                                        crossings)
            ray = dr.detach(ray)
            value = dr.detach(passed)
            zero = value == 0
            weight[hit] = weight * value
            nonzero[hit] = nonzero * dr.select(zero, 1, value)
            zeros[hit] = zeros + dr.select(zero, 1, 0)
            relative += dr.select(hit & ~zero, passed / dr.select(zero, 1, value), 0)
            at_zeros += dr.select(hit & zero, passed, 0)
            blocked |= hit & ~going_on
            weight[blocked] = mi.Color3f(0)
            crossings += 1
            active = going_on
        parts = dr.select(zeros == 0, relative, dr.select(zeros == 1, at_zeros, 0))
        return dr.replace_grad(weight, dr.select(blocked, 0, nonzero * parts)), crossings

    def _crossing(self, ray: mi.Ray3f, target: mi.Point3f, active: mi.Bool, slot, crossings):
        """The next surface a marching shadow ray meets: what it passes,
        where it was met, where the ray goes on, and the ray from there."""
        self._log_query(slot, crossings, ray, active)
        si = self.intersect(ray, active)
        hit = active & si.is_valid()
        passed = self._pass_weight(si, ray, hit)
        going_on = hit & dr.any(passed > 0) & (crossings + 1 < MAX_SHADOW_CROSSINGS)
        ray = dr.select(going_on, spawn_ray_to(si, target, self.needs.scale), ray)
        return passed, hit, going_on, ray

    def _log_query(self, slot, crossing, ray: mi.Ray3f, active: mi.Bool) -> None:
        if self.log is not None:
            self.log.query(slot, crossing, ray, active)

    def _pass_weight(self, si: mi.SurfaceInteraction3f, ray: mi.Ray3f,
                    active: mi.Bool) -> mi.Color3f:
        """What a surface lets through along the shadow ray, 0 if it blocks:
        one dispatch, in which a BSDF that cannot let light through answers
        0 without any call (see :meth:`_passes`)."""
        if self.blocking:
            return mi.Color3f(0)
        return dr.dispatch(si.bsdf(ray), self._passes, si, active)

    def _passes(self, bsdf: mi.BSDF, si: mi.SurfaceInteraction3f, active) -> mi.Color3f:
        """What ``bsdf`` lets through.

        "physical": only surfaces that transmit without bending the ray
        (index-matched dielectrics, thin dielectrics, null and masks);
        "tinted": refracting surfaces too, for the lightened, tinted
        shadows behind glass of the COSC363 ray tracer.
        """
        passed = mi.Color3f(0)
        for component in self.needs.transmission_components:
            if not has_delta_lobe(bsdf, component, mi.BSDFFlags.DeltaTransmission):
                continue
            ctx = mi.BSDFContext(mi.TransportMode.Importance,
                                 mi.BSDFFlags.DeltaTransmission, component)
            weight, ok = self._transmission(bsdf, ctx, si)
            if not self.tinted:
                ok &= self._bends_no_ray(bsdf, ctx, si)
            passed += dr.select(ok, weight, mi.Color3f(0))
        if mi.has_flag(bsdf.flags(), mi.BSDFFlags.Null):
            passed += bsdf.eval_null_transmission(si)
        return passed

    @staticmethod
    def _transmission(bsdf, ctx, si):
        """The transmitted part where the straight shadow ray meets the
        surface, as if it arrived there from outside: 1 - F at that angle
        times the surface's transmittance.

        The shadow ray is not bent, so it leaves a closed object at the
        angle at which it entered; seen from inside, that angle can lie past
        the critical one, and total internal reflection there would cut a
        dark ring into the shadow, which no ray entering a sphere can cause.
        Importance transport leaves out the 1/eta^2 scaling of radiance
        entering a denser medium (and the eta^2 of leaving it), which cancel
        over the two crossings of a closed object."""
        outside = mi.SurfaceInteraction3f(si)
        outside.wi = mi.Vector3f(si.wi.x, si.wi.y, dr.abs(si.wi.z))
        bs, weight = bsdf.sample(ctx, outside, 0.5, mi.Point2f(0.5))
        ok = (bs.pdf > 0) & mi.has_flag(bs.sampled_type, mi.BSDFFlags.DeltaTransmission)
        return mi.Color3f(weight), ok

    @staticmethod
    def _bends_no_ray(bsdf, ctx, si) -> mi.Bool:
        """Whether the transmission leaves an oblique ray unbent."""
        probe = mi.SurfaceInteraction3f(si)
        probe.wi = dr.mulsign(mi.Vector3f(*PROBE_DIRECTION), si.wi.z)
        bs, _ = bsdf.sample(ctx, probe, 0.5, mi.Point2f(0.5))
        return dr.dot(bs.wo, -probe.wi) >= STRAIGHT_COSINE


class DirectLighting:
    """Radiance reflected at a hit from every light, with hard shadows."""

    def __init__(self, needs: SceneNeeds, settings: LightingSettings, shadows: ShadowTester):
        self.needs = needs
        self.settings = settings
        self.shadows = shadows
        # An ambient term of 0 is left out, unless its gradient is wanted.
        self.use_ambient = dr.grad_enabled(settings.ambient) or bool(
            dr.any(settings.ambient != 0, axis=None))

    @property
    def shadow_slots(self) -> int:
        """The most shadow rays a hit tests: one per delta light, then one
        per sample of each sampled light, in this order (their slots)."""
        return (len(self.needs.delta_lights)
                + len(self.needs.sampled_lights) * self.settings.emitter_samples)

    def delta_samples(self, si, active) -> list:
        """``(ds, spectrum)`` towards each delta light: the directions the
        BSDF is asked about (``bsdf_query``) before shading."""
        return [light.sample_direction(si, mi.Point2f(0.5), active)
                for light in self.needs.delta_lights]

    def radiance(self, si, bsdf, key, active, terms, samples):
        """Reflected radiance, and the shadow rays each lane cast
        (:class:`ShadowRays`). ``terms``: the BSDF's albedo and values
        towards ``samples`` (the ``delta_samples``); ``active``: lanes
        lights reach (smooth BSDFs)."""
        result = mi.Color3f(0)
        rays = ShadowRays(mi.UInt32(0), mi.UInt32(0))
        if self.use_ambient:
            result += dr.select(active, terms.albedo, 0) * mi.Color3f(self.settings.ambient)
        for slot, ((ds, spectrum), value) in enumerate(zip(samples, terms.values)):
            radiance, cast = self._shadowed(si, ds, value * spectrum, active, slot)
            result += radiance
            rays += cast
        for index, light in enumerate(self.needs.sampled_lights):
            radiance, cast = self._sampled(light, index, si, bsdf, key, active)
            result += radiance
            rays += cast
        return result, rays

    def _from_light(self, light, si, bsdf, sample, active, slot):
        """Shadowed radiance from one light sample, and its shadow rays."""
        ds, spectrum = light.sample_direction(si, sample, active)
        f = bsdf.eval(mi.BSDFContext(), si, si.to_local(ds.d), active)
        return self._shadowed(si, ds, f * spectrum, active, slot)

    def _shadowed(self, si, ds, contribution, active, slot):
        """``contribution`` through the shadow ray to ``ds`` (the ``slot``-th
        of the hit's), and the rays that took (a shadow ray only where it
        could add light)."""
        lit = active & (ds.pdf > 0) & dr.any(contribution > 0)
        passed, marched = self.shadows.transmittance(si, ds.p, lit, slot)
        # A select, not the product with a transmittance of 0: lanes that
        # are not lit may hold Inf or NaN. A miss's interaction lies at the
        # origin, and a light there is at distance 0 from it (1/0^2).
        return (dr.select(lit, contribution * passed, 0),
                ShadowRays(mi.UInt32(lit), marched))

    def _sample_points(self, key: mi.UInt32, index: int):
        """Where the shadow rays of ray ``key`` sample the ``index``-th of
        ``needs.sampled_lights``: ``point(s)`` for the s-th of them."""
        # Modulo 2^32: any seed of mi.render is a valid one (a seed the
        # size of a hash, as gradients may receive, overflowed).
        rotation = unit_pair(key, (self.settings.seed * 7919 + index) % (1 << 32))

        def point(sample) -> mi.Point2f:
            step = mi.Float(sample)
            u = mi.Point2f(rotation[0] + step * R2_STEP[0], rotation[1] + step * R2_STEP[1])
            return u - dr.floor(u)

        return point

    def _lights_reach(self, light, si: mi.SurfaceInteraction3f, active: mi.Bool) -> mi.Bool:
        """Where a sampled ``light`` is tested from ``si`` at all."""
        return active & ~_on_own_shape(light, si)

    @dr.syntax
    def _sampled(self, light, index, si, bsdf, key, active):
        """Mean of ``emitter_samples`` shadow rays, spread by the R2 sequence.
        Where the march carries its derivative by parts, the samples are
        unrolled: Dr.Jit 1.5 cannot differentiate this loop around that
        march inside a kernel that differentiates in its own loop."""
        count = self.settings.emitter_samples
        first_slot = len(self.needs.delta_lights) + index * count
        active = self._lights_reach(light, si, active)
        point = self._sample_points(key, index)
        total = mi.Color3f(0)
        rays = ShadowRays(mi.UInt32(0), mi.UInt32(0))
        if dr.hint(self.shadows.by_parts, mode="scalar"):
            for sample in range(count):
                radiance, cast = self._from_light(light, si, bsdf, point(sample), active,
                                                  first_slot + sample)
                total += radiance
                rays += cast
        else:
            s = mi.UInt32(0)
            while active & (s < count):
                radiance, cast = self._from_light(light, si, bsdf, point(s), active,
                                                  first_slot + s)
                total += radiance
                rays += cast
                s += 1
        return total / count, rays


@dataclass
class ShadowRays:
    """Per lane: shadow rays tested (any-hit queries) and the closest-hit
    queries that marched blocked ones through pass-through surfaces."""
    tested: mi.UInt32
    marched: mi.UInt32

    def __add__(self, other: "ShadowRays") -> "ShadowRays":
        return ShadowRays(self.tested + other.tested, self.marched + other.marched)


def _on_own_shape(light, si: mi.SurfaceInteraction3f) -> mi.Bool:
    """Hits on the light's own shape, where that shape cannot see itself
    (every sample there would be at or past grazing and add nothing)."""
    shape = light.get_shape()
    if shape is None or shape.shape_type() not in SELF_HIDDEN_SHAPES:
        return mi.Bool(False)
    return si.shape == mi.ShapePtr(shape)
