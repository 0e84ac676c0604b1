"""Wavefront evaluation of Whitted ray trees.

One generation of rays is traced at a time for a whole batch of camera
samples. Each hit adds its local radiance (emission, ambient, lights) and
spawns one child per delta component of its BSDF (mirror reflection,
refraction, straight-through transmission); children whose throughput falls
below ``min_throughput`` are pruned (Hall & Greenberg 1983), the rest are
compacted into the next generation.

Determinism: children are stored in (parent, component) order, so each
parent owns a fixed slot per component. After a generation is finished its
radiance is folded back into the parents' slots by plain scatters (each slot
written once) and summed in component order. No atomic adds, so the same
input gives the same bits.

Memory: a generation wider than ``wavefront_size`` rays is split into parts
traced one after the other (depth first), so memory stays bounded by about
``depth x fan-out x wavefront_size`` rays whatever the depth.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi

from ..jit import index_range, to_int
from .lighting import DirectLighting, ShadowTester
from .scene_needs import SceneNeeds


@dataclass
class RayStats:
    """Rays traced by kind. Device-side counts stay lazy until read."""
    camera: int = 0
    reflection: object = 0
    refraction: object = 0
    passthrough: object = 0
    shadow: object = 0
    #: Hits on analytic proxies made exact (not extra rays).
    refined: object = 0
    generations: int = 0
    batches: int = 0

    KINDS = ("camera", "reflection", "refraction", "passthrough", "shadow")

    def as_dict(self) -> dict:
        counts = {kind: to_int(getattr(self, kind)) for kind in self.KINDS}
        counts["total"] = sum(counts.values())
        counts["refined"] = to_int(self.refined)
        counts["generations"] = self.generations
        counts["batches"] = self.batches
        return counts


#: Codes stored per candidate child; 0 means "no child".
KIND_CODES = {"reflection": 1, "refraction": 2, "passthrough": 3}


class RayBatch:
    """Rays of one generation: origin, direction, throughput, hash key."""

    def __init__(self, o, d, throughput, key):
        self.o, self.d, self.throughput, self.key = o, d, throughput, key

    def __len__(self) -> int:
        return dr.width(self.key)

    def take(self, index: mi.UInt32) -> "RayBatch":
        return RayBatch(dr.gather(mi.Point3f, self.o, index),
                        dr.gather(mi.Vector3f, self.d, index),
                        dr.gather(mi.Color3f, self.throughput, index),
                        dr.gather(mi.UInt32, self.key, index))

    def fields(self):
        return self.o, self.d, self.throughput, self.key


@dataclass
class TreeSettings:
    max_depth: int          # Mitsuba's convention, already mapped from -1
    min_throughput: float
    hide_emitters: bool
    wavefront_size: int


class RayTreeTracer:
    """Traces batches of camera rays to radiance, generation by generation."""

    def __init__(self, scene: mi.Scene, needs: SceneNeeds, settings: TreeSettings,
                 lighting: DirectLighting, intersect, refiner=None):
        self.scene = scene
        self.needs = needs
        self.settings = settings
        self.lighting = lighting
        self.intersect = intersect
        self.refiner = refiner
        self.components = [("delta", c) for c in needs.delta_components]
        if needs.null_surfaces:
            self.components.append(("null", None))
        self.stats = RayStats()

    @property
    def fan_out(self) -> int:
        return len(self.components)

    def trace(self, rays: RayBatch):
        """Radiance and alpha (primary hit) of each camera ray."""
        self.stats.camera += len(rays)
        return self._trace(rays, 0)

    def _trace(self, rays: RayBatch, generation: int):
        self.stats.batches += 1
        self.stats.generations = max(self.stats.generations, generation + 1)
        local, alpha, children, slots = self._shade(rays, generation)
        if children is None:
            return local, alpha
        folded = dr.zeros(mi.Color3f, len(rays) * self.fan_out)
        step = self.settings.wavefront_size
        for start in range(0, len(children), step):
            part = index_range(start, min(start + step, len(children)))
            radiance, _ = self._trace(children.take(part), generation + 1)
            dr.scatter(folded, radiance, dr.gather(mi.UInt32, slots, part))
        return local + self._sum_children(folded, len(rays)), alpha

    def _sum_children(self, folded: mi.Color3f, parents: int) -> mi.Color3f:
        base = dr.arange(mi.UInt32, parents) * self.fan_out
        total = dr.gather(mi.Color3f, folded, base)
        for k in range(1, self.fan_out):
            total += dr.gather(mi.Color3f, folded, base + k)
        return total

    def _shade(self, rays: RayBatch, generation: int):
        """Local radiance of one generation and its compacted children.

        Everything a generation computes (radiance, alpha, the children's
        buffers, the per-lane ray counts) is evaluated in one kernel; the
        counts are reduced afterwards from evaluated arrays, so nothing is
        traced twice."""
        depth = self.settings.max_depth
        ray = mi.Ray3f(rays.o, rays.d)
        si = self.intersect(ray, mi.Bool(True))
        hit = si.is_valid()
        local = mi.Color3f(0)
        if generation + 1 <= depth and not (generation == 0 and self.settings.hide_emitters):
            local += si.emitter(self.scene).eval(si)
        outputs = {"alpha": mi.Float(hit)}
        if self.refiner is not None:
            outputs["refined"] = self.refiner.on_proxy(si, hit)
        children = None
        if generation + 2 <= depth:
            bsdf = si.bsdf(ray)
            radiance, outputs["shadow"] = self.lighting.radiance(si, bsdf, rays.key, hit)
            local += radiance
            if self.fan_out:
                children = self._spawn(si, bsdf, ray, rays, hit)
        local *= rays.throughput
        pending = [local, *outputs.values()]
        if children is not None:
            pending += [*children[0], children[1]]
        dr.eval(*pending)
        self._count_lanes(outputs, children)
        if children is None:
            return local, outputs["alpha"], None, None
        return (local, outputs["alpha"]) + self._compact(*children)

    def _spawn(self, si, bsdf, ray, rays: RayBatch, active):
        """Every candidate child, in (parent, component) order, and a code
        per slot: 0 none (or pruned), else the kind of ray (KIND_CODES)."""
        n, k = len(rays), self.fan_out
        width = n * k
        buffers = [dr.empty(mi.Point3f, width), dr.empty(mi.Vector3f, width),
                   dr.empty(mi.Color3f, width), dr.empty(mi.UInt32, width)]
        codes = dr.empty(mi.UInt32, width)
        slot0 = dr.arange(mi.UInt32, n) * k
        for index, (kind, component) in enumerate(self.components):
            weight, direction, ok, code = self._child(kind, component, si, bsdf, ray, active)
            throughput = rays.throughput * weight
            ok &= dr.max(throughput) > max(self.settings.min_throughput, 0.0)
            child = si.spawn_ray(direction)
            key = mi.sample_tea_32(rays.key, mi.UInt32(index + 1))[0]
            for buffer, value in zip(buffers, (child.o, child.d, throughput, key)):
                dr.scatter(buffer, value, slot0 + index)
            dr.scatter(codes, dr.select(ok, code, 0), slot0 + index)
        return buffers, codes

    def _compact(self, buffers, codes):
        slots = dr.compress(codes != 0)
        if dr.width(slots) == 0:
            return None, None
        return RayBatch(*buffers).take(slots), slots

    def _child(self, kind, component, si, bsdf, ray, active):
        """Weight, direction, validity and kind code of one delta child."""
        if kind == "null":
            weight = bsdf.eval_null_transmission(si, active)
            return weight, ray.d, active & dr.any(weight > 0), mi.UInt32(KIND_CODES["passthrough"])
        ctx = mi.BSDFContext(mi.TransportMode.Radiance, mi.BSDFFlags.Delta, component)
        bs, weight = bsdf.sample(ctx, si, 0.5, mi.Point2f(0.5), active)
        ok = (active & (bs.pdf > 0) & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
              & dr.any(weight > 0))
        reflected = mi.has_flag(bs.sampled_type, mi.BSDFFlags.DeltaReflection)
        code = dr.select(reflected, KIND_CODES["reflection"], KIND_CODES["refraction"])
        return weight, si.to_world(bs.wo), ok, mi.UInt32(code)

    def _count_lanes(self, outputs: dict, children) -> None:
        """Add this generation's ray counts to the statistics (lazily: the
        reductions run on arrays that are already evaluated)."""
        if "shadow" in outputs:
            self.stats.shadow = self.stats.shadow + dr.sum(outputs["shadow"])
        if "refined" in outputs:
            self.stats.refined = self.stats.refined + dr.count(outputs["refined"])
        if children is not None:
            codes = children[1]
            for kind, code in KIND_CODES.items():
                if self._may_spawn(kind):
                    setattr(self.stats, kind, getattr(self.stats, kind) + dr.count(codes == code))

    def _may_spawn(self, kind: str) -> bool:
        if kind == "passthrough":
            return self.needs.null_surfaces
        return bool(self.needs.delta_components)
