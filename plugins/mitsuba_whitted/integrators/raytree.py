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

import gc
from contextlib import contextmanager
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi

from ..jit import index_range, sum_blocks, to_int
from .lighting import DirectLighting, ShadowTester
from .offsets import spawn_ray
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


@contextmanager
def _no_garbage_collection():
    """Keep Python's cycle collector out of a frozen function's recording:
    if it frees Dr.Jit memory then, Dr.Jit aborts the process
    ("enqueue_host_func(): this function cannot be recorded")."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def _component_table(scene: mi.Scene, kind: str, component) -> "mi.Bool":
    """Per BSDF registry id: whether that BSDF has this delta component
    (``kind == "null"``: whether it lets light pass through unscattered)."""
    bsdfs = {id(shape.bsdf()): shape.bsdf() for shape in scene.shapes() if shape.bsdf()}
    entries = {}
    for bsdf in bsdfs.values():
        index = int(dr.reinterpret_array(mi.UInt32, mi.BSDFPtr(bsdf))[0])
        if kind == "null":
            entries[index] = mi.has_flag(bsdf.flags(), mi.BSDFFlags.Null)
        else:
            entries[index] = (component < bsdf.component_count()
                              and mi.has_flag(bsdf.flags(component), mi.BSDFFlags.Delta)
                              and not mi.has_flag(bsdf.flags(component), mi.BSDFFlags.Null))
    table = [False] * (max(entries, default=0) + 1)
    for index, value in entries.items():
        table[index] = bool(value)
    return mi.Bool(table)


def _widths_match(outputs, width: int) -> bool:
    """Every array in ``outputs`` (nested lists/tuples, ``None`` allowed) is
    ``width`` wide or a single value."""
    if outputs is None:
        return True
    if isinstance(outputs, (list, tuple)):
        return all(_widths_match(item, width) for item in outputs)
    return dr.width(outputs) in (width, 1)


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
        #: When a list, every traced batch is appended to it (benchmarks
        #: replay the very same rays through Mitsuba's own ray casting).
        self.captured = None
        self._generation = dr.freeze(self._generation_kernel)
        self._frozen = True
        # Everything the frozen kernel reads besides the scene and its rays:
        # a frozen function must receive its JIT data as arguments.
        component_tables = tuple(_component_table(scene, kind, component)
                                 for kind, component in self.components)
        self._kernel_inputs = (refiner.tables() if refiner is not None else (),
                               component_tables)

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
        if self.captured is not None:
            self.captured.append(rays)
        local, alpha, children, slots = self._shade(rays, generation)
        if children is None:
            return local, alpha
        folded = dr.zeros(mi.Color3f, len(rays) * self.fan_out)
        step = self.settings.wavefront_size
        for start in range(0, len(children), step):
            part = index_range(start, min(start + step, len(children)))
            radiance, _ = self._trace(children.take(part), generation + 1)
            dr.scatter(folded, radiance, dr.gather(mi.UInt32, slots, part))
        return local + sum_blocks(folded, self.fan_out), alpha

    def _shade(self, rays: RayBatch, generation: int):
        """Local radiance and alpha of one generation, its compacted children
        and the slot (parent x fan-out + component) of each child."""
        depth = self.settings.max_depth
        direct = generation + 2 <= depth
        work = dict(
            emit=(generation + 1 <= depth and self.needs.hittable_emitters
                  and not (generation == 0 and self.settings.hide_emitters)),
            light=direct and self.needs.smooth_surfaces,
            # Children are worth tracing if they can see emission or shade.
            spawn=direct and self.fan_out > 0 and (self.needs.hittable_emitters
                                                  or generation + 3 <= depth))
        if not any(work.values()) and generation > 0:
            return dr.zeros(mi.Color3f, len(rays)), None, None, None
        local, alpha, shadow, refined, candidates = self._run_generation(rays, work)
        local = dr.zeros(mi.Color3f, len(rays)) if local is None else local
        if shadow is not None:
            self.stats.shadow = self.stats.shadow + dr.sum(shadow)
        if refined is not None:
            self.stats.refined = self.stats.refined + dr.sum(refined)
        if not candidates:
            return local, alpha, None, None
        children, slots = self._compact(candidates)
        return local, alpha, children, slots

    def _run_generation(self, rays: RayBatch, work: dict):
        """The frozen generation kernel, or the plain one if freezing fails.

        A frozen replay must return arrays as wide as its rays; if Dr.Jit
        ever refuses to record or replays a wrong width, this tracer falls
        back to tracing every generation anew (slower, same result)."""
        args = (self.scene, self._kernel_inputs, *rays.fields())
        if self._frozen:
            try:
                with _no_garbage_collection():
                    outputs = self._generation(*args, **work)
                if _widths_match(outputs, len(rays)):
                    return outputs
                problem = "a replay returned arrays of the wrong width"
            except RuntimeError as error:
                problem = str(error).splitlines()[0]
            self._frozen = False
            mi.Log(mi.LogLevel.Warn, f"whitted: tracing without frozen kernels ({problem}).")
        return self._generation_kernel(*args, **work)

    def _generation_kernel(self, scene, inputs, o, d, throughput, key,
                           emit: bool, light: bool, spawn: bool):
        """Everything one generation computes, as one traced function of its
        rays: radiance, alpha, shadow rays and refinements per lane, and one
        candidate child per delta component (fields + kind code, 0 = none).

        It reads no sizes, so Dr.Jit can freeze it and replay its kernels for
        every later generation, part and anti-aliasing level. Outputs that
        would be constants are returned as ``None``: a constant carries the
        size of the call that recorded it and would come back wrong."""
        ray = mi.Ray3f(o, d)
        si = self.intersect(ray, mi.Bool(True))
        # Materialising the hit first lets the BSDF and emitter calls below
        # dispatch on evaluated pointers (measured ~30% faster shading).
        dr.eval(si)
        hit = si.is_valid()
        local = shadow = refined = None
        candidates = []
        if self.refiner is not None:
            refined = mi.UInt32(self.refiner.on_proxy(si, hit))
        if emit:
            local = si.emitter(scene).eval(si)
        if light or spawn:
            bsdf = si.bsdf(ray)
        if light:
            radiance, shadow = self.lighting.radiance(si, bsdf, key, hit)
            local = radiance if local is None else local + radiance
        if spawn:
            bsdf_id = dr.reinterpret_array(mi.UInt32, bsdf)
            for index, (kind, component) in enumerate(self.components):
                # Only lanes whose BSDF has this component call into it.
                has = dr.gather(mi.Bool, inputs[1][index], bsdf_id, hit)
                candidates.append(self._candidate(index, kind, component, si, bsdf, ray,
                                                  throughput, key, hit & has))
        if local is not None:
            local = local * throughput
        return local, mi.Float(hit), shadow, refined, candidates

    def _candidate(self, index, kind, component, si, bsdf, ray, throughput, key, active):
        weight, direction, ok, code = self._child(kind, component, si, bsdf, ray, active)
        child_throughput = throughput * weight
        ok &= dr.max(child_throughput) > max(self.settings.min_throughput, 0.0)
        child = spawn_ray(si, direction, self.needs.scale)
        child_key = mi.sample_tea_32(key, mi.UInt32(index + 1))[0]
        return child.o, child.d, child_throughput, child_key, dr.select(ok, code, 0)

    def _compact(self, candidates):
        """Children of all components in one batch; a child's slot is
        parent x fan-out + component, so folding back is collision free."""
        picks = []
        for component, (*fields, codes) in enumerate(candidates):
            index = dr.compress(codes != 0)
            self._count_children(self.components[component][0], codes, dr.width(index))
            if dr.width(index):
                picks.append((component, index, fields))
        total = sum(dr.width(index) for _, index, _ in picks)
        if total == 0:
            return None, None
        batch = RayBatch(dr.empty(mi.Point3f, total), dr.empty(mi.Vector3f, total),
                         dr.empty(mi.Color3f, total), dr.empty(mi.UInt32, total))
        slots = dr.empty(mi.UInt32, total)
        offset = 0
        for component, index, fields in picks:
            target = index_range(offset, offset + dr.width(index))
            for buffer, value in zip(batch.fields(), fields):
                dr.scatter(buffer, dr.gather(type(value), value, index), target)
            dr.scatter(slots, index * self.fan_out + component, target)
            offset += dr.width(index)
        dr.eval(*batch.fields(), slots)
        return batch, slots

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

    def _count_children(self, kind: str, codes, count: int) -> None:
        """Add one component's children to the statistics: a null component
        only passes rays through; a delta one reflects or refracts them."""
        if kind == "null":
            self.stats.passthrough = self.stats.passthrough + count
            return
        reflected = dr.count(codes == KIND_CODES["reflection"])
        self.stats.reflection = self.stats.reflection + reflected
        self.stats.refraction = self.stats.refraction + (count - reflected)
