"""What one Whitted hit computes: its local radiance and its delta children.

Both tracers share this: the wavefront tracer (:mod:`.tracers.wavefront`) calls it
once per generation with Python flags that leave unneeded work out of the
kernel, the depth-first tracer (:mod:`.tracers.depth_first`) calls it inside its
loop with per-lane masks, since lanes there are at different depths of
their trees.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi

from .bsdf_query import BsdfQuery, DeltaChild, query_bsdf
from .indirect import IndirectLight
from .lighting import DirectLighting
from .offsets import spawn_ray
from .scene_needs import SceneNeeds
from .scene_ref import ReadsScene, SceneRef

#: Most rays in the tree of one camera sample, itself included: a closed box
#: of mirrors and glass with no pruning (``min_throughput`` 0) would
#: otherwise double its rays at every generation and never finish.
MAX_TREE_RAYS = 1024


@dataclass
class TreeSettings:
    max_depth: int          # Mitsuba's convention, already mapped from -1
    min_throughput: float
    hide_emitters: bool


@dataclass(frozen=True)
class HitWork:
    """What a hit computes: each is ``False`` (left out of the kernel),
    ``True`` or a per-lane mask. With Python flags it serves as a key."""
    emit: object = False
    light: object = False
    spawn: object = False
    #: Paths of indirect light from the hit (:mod:`.indirect`).
    gather: object = False
    #: The photons' light at the hit (:mod:`.photons`).
    photons: object = False

    def any(self) -> bool:
        return any(part is not False
                   for part in (self.emit, self.light, self.spawn, self.photons))


@dataclass
class Shaded:
    """What a hit adds, each ``None`` where its work is left out: radiance
    (times the ray's throughput) from emission and the lights, and the same
    before the throughput (``own``, what the hit sends back along its ray),
    the indirect radiance gathered (:mod:`.indirect`, times the throughput
    too), the shadow rays of each lane (``ShadowRays``), the rays of the
    indirect paths (``IndirectRays``), and one :class:`Child` per component."""
    local: mi.Color3f = None
    own: mi.Color3f = None
    gathered: mi.Color3f = None
    shadow: object = None
    indirect_rays: object = None
    children: list = field(default_factory=list)


@dataclass
class Child:
    """A candidate child ray of each lane; ``code`` 0 where there is none.
    ``weight``: the BSDF's weight of the child, ``throughput`` that times
    the parent's."""
    o: mi.Point3f
    d: mi.Vector3f
    throughput: mi.Color3f
    weight: mi.Color3f
    key: mi.UInt32
    code: mi.UInt32


class HitShader(ReadsScene):
    """Local radiance and delta children of hits. Given ``photons`` (a
    :class:`.photons.grid.PhotonGrid` holder with ``estimate``), the
    shader of a photon pass: its hits add the photons' light alone, with
    no emission, lights or indirect paths, which the render adds."""

    def __init__(self, scene_ref: SceneRef, needs: SceneNeeds, settings: TreeSettings,
                 lighting: DirectLighting, indirect: IndirectLight | None = None,
                 photons=None):
        self.scene_ref = scene_ref
        self.needs = needs
        self.settings = settings
        self.lighting = lighting
        self.indirect = indirect
        self.photons = photons
        self.components = [("delta", c) for c in needs.delta_components]
        if needs.null_surfaces:
            self.components.append(("null", None))

    @property
    def fan_out(self) -> int:
        return len(self.components)

    def spawning_generations(self) -> int:
        """How many generations (0, 1, ...) can have children: the ones
        whose ``work`` may spawn, counted from its conditions rather than
        by asking each generation, so that a ``max_depth`` of 2^31 - 1 costs
        no more than the rays its trees hold."""
        if self.fan_out == 0:
            return 0
        # The last generation that spawns: its children must still see
        # emission (g + 2 <= depth) or, without emitters to hit, shade
        # (g + 3 <= depth).
        last = self.settings.max_depth - (2 if self.needs.hittable_emitters else 3)
        return max(last + 1, 0)

    def work(self, generation) -> HitWork:
        """What a hit of ``generation`` computes (an int, or per lane)."""
        depth = self.settings.max_depth
        if self.photons is not None:
            return self._photon_work(generation)
        direct = generation + 2 <= depth
        emit = self.needs.hittable_emitters and (generation + 1 <= depth)
        if self.settings.hide_emitters and emit is not False:
            emit = emit & (generation > 0)
        light = self.needs.smooth_surfaces and direct
        return HitWork(
            emit=emit,
            light=light,
            # Children are worth tracing if they can see emission or shade.
            spawn=self.fan_out > 0 and direct & (self.needs.hittable_emitters
                                                 | (generation + 3 <= depth)),
            # Indirect light has at least two segments past the hit.
            gather=(self.indirect is not None and light is not False
                    and light & (generation + 3 <= depth)))

    def _photon_work(self, generation) -> HitWork:
        """A photon pass's hit: a stored photon has at least two segments
        (from the light, bent on the way), so the hit gathers where its
        camera path leaves room for them, and spawns where its children's
        would."""
        depth = self.settings.max_depth
        return HitWork(photons=self.needs.smooth_surfaces and generation + 3 <= depth,
                       spawn=self.fan_out > 0 and generation + 4 <= depth,
                       # A path's vertex past the hit gathers photons too.
                       gather=(self.indirect is not None and self.needs.smooth_surfaces
                               and generation + 4 <= depth))

    def shade(self, si, ray, throughput, key, work: HitWork, generation=0,
              paths=None) -> "Shaded":
        """What the hits of ``ray`` add (:class:`Shaded`). ``generation``:
        the hits' (an int, or per lane); ``paths``: indirect paths per hit
        (per lane, a real number; ``None``: the integrator's
        ``indirect_samples``)."""
        shaded = Shaded()
        local = None
        if work.photons is not False:
            local, shaded.gathered, shaded.indirect_rays = self._photon_light(
                si, ray, throughput, key, work, generation, paths)
        if work.emit is not False:
            # Misses see the environment emitter, if any.
            local = si.emitter(self.scene).eval(si, mi.Bool(work.emit))
        if work.light is not False or work.spawn is not False:
            reflected, shaded.shadow, shaded.children, light = self._scatter(
                si, ray, throughput, key, work)
            if reflected is not None:
                local = reflected if local is None else local + reflected
            # A photon pass's paths gather photons instead (``_photon_light``).
            if work.gather is not False and work.photons is False:
                gathered, shaded.indirect_rays = self.indirect.estimate(
                    si, key, throughput, light & work.gather,
                    self.settings.max_depth - generation - 1, paths)
                shaded.gathered = gathered * throughput
        if local is not None:
            shaded.own = local
            shaded.local = local * throughput
        return shaded

    def _photon_light(self, si, ray, throughput, key, work: HitWork, generation, paths):
        """The photons' light leaving a smooth hit along ``-ray`` (the
        camera path to it has ``generation + 1`` segments), and, where the
        shader has paths, the photons' light they gather past the hit
        (times ``throughput``) and their rays."""
        bsdf = si.bsdf(ray)
        smooth = si.is_valid() & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        segments = mi.UInt32(self.settings.max_depth - 1 - generation)
        local = self.photons.estimate(si, bsdf, smooth & work.photons, segments)
        if work.gather is False:
            return local, None, None
        gathered, rays = self.indirect.estimate(si, key, throughput, smooth & work.gather,
                                                segments, paths)
        return local, gathered * throughput, rays

    def _scatter(self, si, ray, throughput, key, work: HitWork):
        """What the hit's BSDF adds: light reflected from the lights, the
        shadow rays that took, the candidate children, and the lanes that
        lights reach."""
        hit = si.is_valid()
        bsdf = si.bsdf(ray)
        light = spawn = mi.Bool(False)
        samples = []
        if work.light is not False:
            light = hit & work.light & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
            samples = self.lighting.delta_samples(si, light)
        if work.spawn is not False:
            spawn = hit & work.spawn
        query = BsdfQuery(albedo=work.light is not False and self.lighting.use_ambient,
                          components=self.components if work.spawn is not False else ())
        terms = query_bsdf(bsdf, si, query, [si.to_local(ds.d) for ds, _ in samples],
                           light | spawn)
        reflected = shadow = None
        if work.light is not False:
            reflected, shadow = self.lighting.radiance(si, bsdf, key, light, terms, samples)
        children = [self._candidate(index, kind, terms.children[index], si, ray,
                                    throughput, key, spawn)
                    for index, (kind, _) in enumerate(query.components)]
        return reflected, shadow, children, light

    def _candidate(self, index, kind, child: DeltaChild, si, ray, throughput, key, spawn):
        """The child ray of one component, coded 0 where it is not traced
        (no such lobe, no children wanted, or pruned by throughput)."""
        child_throughput = throughput * child.weight
        ok = spawn & child.ok & (dr.max(child_throughput) > max(self.settings.min_throughput, 0.0))
        # A pass-through child goes straight on: the ray's own direction.
        direction = ray.d if kind == "null" else si.to_world(child.wo)
        spawned = spawn_ray(si, direction, self.needs.scale)
        child_key = mi.sample_tea_32(key, mi.UInt32(index + 1))[0]
        return Child(spawned.o, spawned.d, child_throughput, child.weight, child_key,
                     dr.select(ok, child.code, 0))
