"""The light classic Whitted ray tracing leaves out, estimated by path
tracing from the smooth hits of the ray tree (``indirect_samples``).

At a hit whose BSDF has a smooth (diffuse or glossy) part, the tree adds
the emission, the light of every emitter through that part (its shadow
rays) and the light of the delta children. Light reaches the hit along
other paths too: reflected by other smooth surfaces (interreflection), or
through delta chains from area and environment lights (caustics). Whitted
has no path for them. With ``indirect_samples`` N, each such hit estimates
that light with N paths:

- A path's first direction is drawn from the smooth part of the hit's BSDF
  alone: its delta lobes are the tree's. Emission reached along it
  straight, through surfaces that let light pass without bending it (null,
  mask, index-matched and thin dielectrics), is the light the hit's own
  shadow rays counted, and is left out.
- At every later vertex, a path tracer's step, with every light taken
  as the tree takes them: each delta light exactly, and one sample of each
  area or environment light (next-event estimation, whose shadow rays any
  surface blocks), where a path tracer picks one light at random; then one
  sample of the whole BSDF, delta lobes included. Where the BSDF's
  direction reaches emission, it and that light's own sample are weighed
  by the power heuristic (Veach 1995); delta lobes and delta lights take
  weight 1.
- A hit gathers with as many paths as its camera sample was given (a
  pixel's ``indirect_samples`` shared among its camera samples) times the
  throughput of the tree to the hit: a wall seen in a 4% Fresnel
  reflection adds 4% of its light to the pixel, and its noise matters that
  much less, so it gathers with that share of the paths.
- The camera samples of a pixel draw their paths from one sequence, each
  its own window of it (:func:`path_window`, keyed by
  :func:`camera_key`): the pixel's first directions, and its directions at
  every later vertex, are one stratified set, as a sampler's samples of a
  pixel are, where a sequence per camera sample stratified only each
  sample's few paths, and a sample given one path drew an unstratified
  one. The windows are rounded so that the pixel traces the paths it was
  given: a camera sample given half a path traces one every other sample,
  weighed by 2. A delta child's hit, whose key is a hash, has a sequence
  of its own and at least one path, the count rounded up or down at
  random to keep its mean. (A roulette there, one path with the
  probability asked for and weighted by its inverse, keeps the cost to the
  count but gave 2.3 times the relMSE x rays on ``cylinder.xml`` with
  contrast anti-aliasing: its weights make bright outliers where the
  refined edges are.)
- Russian roulette ends paths that carry little from their fourth vertex
  on, by the product of the tree's throughput and the path's, so a hit
  seen in a dim reflection spends little on long paths too.
- The samples come from Owen-scrambled Sobol points (:mod:`.sequence`),
  seeded by the hit's key and the render seed: deterministic, as the rest.

A path has at most ``max_depth`` segments from the camera, as in Mitsuba's
path tracer, so that with no ambient term and physical shadows the image's
expectation is that of ``path`` at the same ``max_depth``.

One loop runs the N paths of a lane one after the other: a lane whose path
ends starts its next one at once, rather than waiting for the longest path
of its SIMD packet.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from .offsets import spawn_ray
from .scene_ref import ReadsScene
from .sequence import PaddedSobol, mix, to_unit

#: Paths start Russian roulette at this vertex (0 is the tree's hit).
ROULETTE_FROM = 3
#: Most a path survives a roulette with, so that every path ends.
ROULETTE_CAP = 0.95
#: A direction this close to the incoming one is "straight through".
STRAIGHT_COSINE = 1.0 - 1e-5
#: Mixed into a key for the rounding of a path count, so that the rounding
#: is independent of the paths' own samples.
_ROUNDING_SALT = 0x5BD1E995


#: The top bits of a camera sample's key (:func:`camera_key`): its pixel
#: is below them, above ``SLOT_BITS``, and its slot among the pixel's
#: samples below that. Three bits, so that a delta child's key (a hash)
#: passes for a camera key once in eight.
CAMERA_TAG, _TAG_MASK = 0b101 << 29, 0b111 << 29
#: Bits of a camera key for the sample's slot in its pixel.
SLOT_BITS = 9
_SLOT_MASK = (1 << SLOT_BITS) - 1
_PIXEL_MASK = (1 << (29 - SLOT_BITS)) - 1


def camera_key(pixel: mi.UInt32, slot: mi.UInt32) -> mi.UInt32:
    """The key of a camera sample in ``pixel`` that takes the ``slot``-th
    share of the pixel's paths. The paths of every camera sample of a pixel
    are then points of one scrambled sequence, the ``slot``-th window of it
    (:func:`path_window`): over the pixel they form one stratified set, as
    a sampler's samples of a pixel do, where sequences of their own per
    camera sample would be stratified only within each sample. (Pixels
    2^20 apart and slots 2^9 apart share windows, which correlates their
    paths but keeps each estimate's mean.)"""
    return (mi.UInt32(CAMERA_TAG) | ((pixel & _PIXEL_MASK) << SLOT_BITS)
            | (slot & _SLOT_MASK))


def path_window(wanted: mi.Float, key: mi.UInt32, salt: int) -> tuple:
    """The sequence's seed, the first sample and the count of the paths of a
    hit that wants ``wanted`` (per lane, a real number) and is keyed
    ``key``, and the weight of their sum.

    A camera key's hit takes the window ``[slot w + r, (slot + 1) w + r)``
    of its pixel's sequence, rounded down, with ``w`` = ``wanted`` and one
    shift ``r`` per pixel and render seed, uniform in [0, 1): the windows of
    a pixel's samples tile its sequence from its start, so the pixel traces
    the paths it was given, and each count has the mean ``w`` over the
    shift. Where ``w`` >= 1 the count is at least 1 and the sum is weighed
    by the count; below 1 a window holds one path or none, weighed by 1 / w
    (a pixel's samples take turns, in slot order). Any other key (a delta
    child's, or a ray of ``trace_rays``) takes the window of slot 0 of a
    sequence of its own, of at least one path."""
    camera = (key & _TAG_MASK) == CAMERA_TAG
    seed = mix(dr.select(camera, key >> SLOT_BITS, key) ^ salt)
    slot = mi.Float(dr.select(camera, key & _SLOT_MASK, 0))
    shift = to_unit(mix(seed ^ _ROUNDING_SALT))
    first = mi.UInt32(dr.floor(slot * wanted + shift))
    count = mi.UInt32(dr.floor((slot + 1) * wanted + shift)) - first
    # Elsewhere at least one path: a delta child's hit is on its own, and
    # one path or none, weighed by 1 / w, made outliers where w is small.
    count[~camera] = dr.maximum(count, 1)
    weight = dr.select(camera & (wanted < 1), dr.rcp(wanted), dr.rcp(mi.Float(dr.maximum(count, 1))))
    return seed, first, count, dr.select(count > 0, weight, 0)


@dataclass
class IndirectRays:
    """Per lane: the closest-hit rays of the indirect paths, and their
    shadow rays (any-hit tests, and the closest-hit queries that follow a
    blocked one past a proxy mesh)."""
    traced: mi.UInt32
    shadow: mi.UInt32

    def __add__(self, other: "IndirectRays") -> "IndirectRays":
        return IndirectRays(self.traced + other.traced, self.shadow + other.shadow)


def power_heuristic(a: mi.Float, b: mi.Float) -> mi.Float:
    """Veach's power heuristic (exponent 2) for the strategy of density ``a``."""
    a2 = a * a
    weight = a2 / (a2 + b * b)
    return dr.select(dr.isfinite(weight), weight, 0)


class IndirectLight(ReadsScene):
    """``estimate``: the mean of ``samples`` path-traced estimates of the
    light a smooth hit receives other than from its shadow rays and delta
    children."""

    def __init__(self, scene_ref, needs, samples: int, seed: int, intersect, shadow_test,
                 photons=None):
        self.scene_ref = scene_ref
        #: In a photon pass (:mod:`.photons.progressive`), the lookup its
        #: paths gather from at every vertex past the hit, in place of the
        #: lights and emission they meet: the photons' light that the
        #: tree's hits see only through other smooth surfaces.
        self.photons = photons
        self.needs = needs
        self.samples = samples
        #: Mixed into every hit's key, so each render seed gives other samples.
        self.salt = int(mix(mi.UInt32((seed * 0x27D4EB2D + 0x165667B1) % (1 << 32)))[0])
        self.intersect = intersect
        #: Blocks at every surface but where a proxy holds no exact surface.
        self.shadow_test = shadow_test
        #: Dimension pairs one vertex draws: the BSDF's direction, its lobe
        #: and the roulette, and a point of each sampled light.
        self.pairs_per_vertex = 2 + len(needs.sampled_lights)

    @dr.syntax
    def estimate(self, si: mi.SurfaceInteraction3f, key: mi.UInt32, throughput: mi.Color3f,
                 active: mi.Bool, segments, paths=None):
        """Indirect radiance leaving ``si`` towards ``-ray`` (not yet times
        ``throughput``), and the rays cast. The radiance is the mean of
        ``paths`` paths (per lane, a real number; ``None``: ``samples``)
        times the tree's ``throughput`` to the hit, as
        :func:`path_window` rounds it. ``segments``: per lane, how many segments
        a path from ``si`` may have (``max_depth`` less those of the camera
        path to ``si``)."""
        seed, sample, count, weight = path_window(
            mi.Float(self.samples if paths is None else paths)
            * dr.minimum(dr.max(throughput), 1), key, self.salt)
        end = sample + count
        sequence = PaddedSobol(seed)
        total = mi.Color3f(0)
        rays = IndirectRays(mi.UInt32(0), mi.UInt32(0))
        vertex = mi.UInt32(0)
        here = dr.zeros(mi.SurfaceInteraction3f)
        beta = mi.Color3f(1)
        eta = mi.Float(1)
        straight = mi.Bool(True)
        active = mi.Bool(active) & (segments >= 2) & (count > 0)
        while active:
            # A lane at vertex 0 starts its next path at the tree's hit.
            start = vertex == 0
            here = dr.select(start, si, here)
            beta[start] = 1
            eta[start] = 1
            pair = vertex * self.pairs_per_vertex
            u_direction = sequence.point(sample, pair)
            u_more = sequence.point(sample, pair + 1)
            lights = ([] if self.photons is not None else
                      self._light_samples(here, sequence, sample, pair + 2, active & ~start))
            step = self._step(here, start, lights, u_more.x, u_direction, active)
            total += beta * step.light
            rays.shadow += step.shadow_rays
            delta = mi.has_flag(step.bs.sampled_type, mi.BSDFFlags.Delta)
            straight = start | (straight & self._passes_straight(here, step.bs))
            beta *= step.weight
            eta *= step.bs.eta
            go = active & (step.bs.pdf > 0) & dr.any(beta > 0)
            survival = dr.minimum(dr.max(beta * throughput) * eta * eta, ROULETTE_CAP)
            roulette = go & (vertex >= ROULETTE_FROM)
            go &= ~roulette | (u_more.y < survival)
            beta[roulette] = beta / survival
            ray = spawn_ray(here, here.to_world(step.bs.wo), self.needs.scale)
            hit = self.intersect(ray, go)
            rays.traced += mi.UInt32(go)
            if dr.hint(self.photons is None, mode="scalar"):
                total += beta * self._emission(hit, here, step.bs.pdf, delta, go & ~straight)
            else:
                total += beta * self._photon_light(hit, ray, go, segments - vertex - 1)
            # Another segment may follow: a light sample or a direction.
            go &= hit.is_valid() & (vertex + 2 <= segments)
            here = dr.select(go, hit, here)
            vertex = dr.select(go, vertex + 1, 0)
            sample[~go] = sample + 1
            active &= go | (sample < end)
        return total * weight, rays

    def _photon_light(self, hit, ray, active, segments) -> mi.Color3f:
        """The photons' light leaving a smooth ``hit`` along ``-ray``, of
        photons with at most ``segments`` segments (at least two)."""
        bsdf = hit.bsdf(ray)
        smooth = (active & hit.is_valid() & (segments >= 2)
                  & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth))
        return self.photons.estimate_far(hit, bsdf, smooth, segments)

    def _light_samples(self, here, sequence, sample, first_pair, active) -> list:
        """``(ds, radiance over density)`` towards each light from ``here``:
        each delta light, then a point of each sampled light from the pairs
        from ``first_pair`` on."""
        samples = [light.sample_direction(here, mi.Point2f(0.5), active)
                   for light in self.needs.delta_lights]
        samples += [light.sample_direction(here, sequence.point(sample, first_pair + index),
                                           active)
                    for index, light in enumerate(self.needs.sampled_lights)]
        return samples

    def _step(self, here, start, lights, u_lobe, u_direction, active):
        """At ``here``: the light of the samples ``lights`` (none at the
        tree's hit, whose shadow rays lit it) and a sample of the BSDF for
        the next direction (of its smooth part alone at the tree's hit)."""
        lit = active & ~start
        values, pdfs, bs, weight = dr.dispatch(
            here.bsdf(), _vertex_bsdf, here, [here.to_local(ds.d) for ds, _ in lights],
            u_lobe, u_direction, start, active)
        light, shadow_rays = mi.Color3f(0), mi.UInt32(0)
        for slot, ((ds, emitted), value, pdf) in enumerate(zip(lights, values, pdfs)):
            contribution = value * mi.Color3f(emitted)
            reaches = lit & (ds.pdf > 0) & dr.any(contribution > 0)
            passed, marched = self.shadow_test.transmittance(here, ds.p, reaches, slot)
            mis = dr.select(ds.delta, 1, power_heuristic(ds.pdf, pdf))
            light += dr.select(reaches, contribution * passed * mis, 0)
            shadow_rays += mi.UInt32(reaches) + marched
        return VertexStep(light, bs, weight, shadow_rays)

    def _emission(self, hit, origin, bsdf_pdf, delta, active) -> mi.Color3f:
        """Emission reached at ``hit`` from ``origin`` by a BSDF sample of
        density ``bsdf_pdf`` (``delta``: of a delta lobe), weighed against
        the sample of that light which could have found it."""
        emitter = hit.emitter(self.scene, active)
        radiance = emitter.eval(hit, active)
        ds = mi.DirectionSample3f(self.scene, hit, origin)
        light_pdf = emitter.pdf_direction(origin, ds, active & ~delta)
        weight = dr.select(delta, 1, power_heuristic(bsdf_pdf, light_pdf))
        return dr.select(active, mi.Color3f(radiance) * weight, 0)

    @staticmethod
    def _passes_straight(here, bs) -> mi.Bool:
        """Whether the sampled lobe lets the path on unbent (null, or a
        delta transmission along the incoming direction)."""
        null = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Null)
        transmitted = mi.has_flag(bs.sampled_type, mi.BSDFFlags.DeltaTransmission)
        return null | (transmitted & (dr.dot(bs.wo, -here.wi) >= STRAIGHT_COSINE))


@dataclass
class VertexStep:
    light: mi.Color3f     # the light sample's contribution (times nothing yet)
    bs: mi.BSDFSample3f   # the next direction
    weight: mi.Color3f    # its BSDF value over density
    shadow_rays: mi.UInt32


def _vertex_bsdf(bsdf: mi.BSDF, si, directions, u_lobe, u_direction, start, active):
    """One BSDF's answers at a path vertex: its values and densities towards
    the light samples' ``directions`` (local), and its next direction, of
    the smooth part alone where the path starts (``start``). Specialised to
    the instance: a BSDF without a smooth part evaluates nothing, one with
    no delta or null part samples once."""
    flags = bsdf.flags()
    ctx = mi.BSDFContext()
    smooth = mi.has_flag(flags, mi.BSDFFlags.Smooth)
    values, pdfs = [], []
    for wo in directions:
        value, pdf = bsdf.eval_pdf(ctx, si, wo, active) if smooth else (0, 0)
        values.append(mi.Color3f(value))
        pdfs.append(mi.Float(pdf))
    bs, weight = bsdf.sample(ctx, si, u_lobe, u_direction, active)
    if smooth and mi.has_flag(flags, mi.BSDFFlags.Delta | mi.BSDFFlags.Null):
        smooth_part = mi.BSDFContext(mi.TransportMode.Radiance, mi.BSDFFlags.Smooth)
        first, first_weight = bsdf.sample(smooth_part, si, u_lobe, u_direction, active & start)
        bs = dr.select(start, first, bs)
        weight = dr.select(start, first_weight, weight)
    return tuple(values), tuple(pdfs), bs, mi.Color3f(weight)
