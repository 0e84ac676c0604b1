"""What one Whitted hit computes: its local radiance and its delta children.

Both tracers share this: the wavefront tracer (``raytree``) calls it once
per generation with Python flags that leave unneeded work out of the kernel,
the stack tracer (``stacktree``) calls it inside its loop with per-lane
masks, since lanes there are at different depths of their trees.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from .lighting import DirectLighting
from .offsets import spawn_ray
from .scene_needs import SceneNeeds

#: Codes stored per candidate child; 0 means "no child".
KIND_CODES = {"reflection": 1, "refraction": 2, "passthrough": 3}


@dataclass
class TreeSettings:
    max_depth: int          # Mitsuba's convention, already mapped from -1
    min_throughput: float
    hide_emitters: bool
    wavefront_size: int


@dataclass(frozen=True)
class HitWork:
    """What a hit computes: each is ``False`` (left out of the kernel),
    ``True`` or a per-lane mask. With Python flags it serves as a key."""
    emit: object = False
    light: object = False
    spawn: object = False

    def any(self) -> bool:
        return any(part is not False for part in (self.emit, self.light, self.spawn))


@dataclass
class Child:
    """A candidate child ray of each lane; ``code`` 0 where there is none."""
    o: mi.Point3f
    d: mi.Vector3f
    throughput: mi.Color3f
    key: mi.UInt32
    code: mi.UInt32


def component_table(scene: mi.Scene, kind: str, component) -> "mi.Bool":
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


class HitShader:
    """Local radiance and delta children of hits."""

    def __init__(self, scene: mi.Scene, needs: SceneNeeds, settings: TreeSettings,
                 lighting: DirectLighting):
        self.scene = scene
        self.needs = needs
        self.settings = settings
        self.lighting = lighting
        self.components = [("delta", c) for c in needs.delta_components]
        if needs.null_surfaces:
            self.components.append(("null", None))

    @property
    def fan_out(self) -> int:
        return len(self.components)

    def tables(self) -> tuple:
        """Per component, which BSDFs have it: JIT data the kernels read,
        so it must reach a frozen kernel as an argument."""
        return tuple(component_table(self.scene, kind, component)
                     for kind, component in self.components)

    def spawning_generations(self) -> int:
        """How many generations (0, 1, ...) can have children: the ones
        whose ``work`` may spawn."""
        return sum(1 for generation in range(self.settings.max_depth)
                   if self.work(generation).spawn)

    def work(self, generation) -> HitWork:
        """What a hit of ``generation`` computes (an int, or per lane)."""
        depth = self.settings.max_depth
        direct = generation + 2 <= depth
        emit = self.needs.hittable_emitters and (generation + 1 <= depth)
        if self.settings.hide_emitters and emit is not False:
            emit = emit & (generation > 0)
        return HitWork(
            emit=emit,
            light=self.needs.smooth_surfaces and direct,
            # Children are worth tracing if they can see emission or shade.
            spawn=self.fan_out > 0 and direct & (self.needs.hittable_emitters
                                                 | (generation + 3 <= depth)))

    def shade(self, si, ray, throughput, key, tables, work: HitWork):
        """Radiance (times ``throughput``, ``None`` if nothing adds any),
        shadow rays cast per lane (``None`` without lights) and one
        :class:`Child` per component."""
        hit = si.is_valid()
        local = shadow = None
        children = []
        if work.emit is not False:
            # Misses see the environment emitter, if any.
            local = si.emitter(self.scene).eval(si, mi.Bool(work.emit))
        if work.light is not False or work.spawn is not False:
            bsdf = si.bsdf(ray)
        if work.light is not False:
            radiance, shadow = self.lighting.radiance(si, bsdf, key, hit & work.light)
            local = radiance if local is None else local + radiance
        if work.spawn is not False:
            bsdf_id = dr.reinterpret_array(mi.UInt32, bsdf)
            active = hit & work.spawn
            for index, (kind, component) in enumerate(self.components):
                # Only lanes whose BSDF has this component call into it.
                has = dr.gather(mi.Bool, tables[index], bsdf_id, active)
                children.append(self._candidate(index, kind, component, si, bsdf, ray,
                                                throughput, key, active & has))
        if local is not None:
            local = local * throughput
        return local, shadow, children

    def _candidate(self, index, kind, component, si, bsdf, ray, throughput, key, active):
        weight, direction, ok, code = self._child(kind, component, si, bsdf, ray, active)
        child_throughput = throughput * weight
        ok &= dr.max(child_throughput) > max(self.settings.min_throughput, 0.0)
        child = spawn_ray(si, direction, self.needs.scale)
        child_key = mi.sample_tea_32(key, mi.UInt32(index + 1))[0]
        return Child(child.o, child.d, child_throughput, child_key, dr.select(ok, code, 0))

    @staticmethod
    def _child(kind, component, si, bsdf, ray, active):
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
