"""Whitted ray trees traced whole, one kernel per batch of camera rays.

Each lane walks its own tree depth first: it pops a ray from a small stack
in local memory, intersects and shades it, adds the radiance, and pushes
the children that pass the ``min_throughput`` pruning. The loop ends when
every stack is empty. Nothing leaves the kernel between generations, so
there is no compaction, no fold-back and one frozen replay per batch; on
the report's scene this is about 1.5 times as fast as the wavefront tracer
(``raytree``), which stays the reference and serves what a stack cannot
(trees deeper than :data:`MAX_STACK` allows, capturing each generation's
rays).

The stack holds at most ``1 + G x (fan-out - 1)`` rays, where G is the
number of generations that may spawn children (``max_depth - 1`` with
emitters a ray can hit, else ``max_depth - 2``): a pop frees one slot.

Determinism: each lane sums its tree in a fixed order, so the same input
gives the same bits. The order differs from the wavefront tracer's, so the
two agree to float rounding, not bit for bit.

Dr.Jit 1.5 (LLVM) reads and writes local memory at a per-lane index wrongly
when the lanes of a packet are at different stack heights (measured against
a plain-Python stack: other slots come back); :class:`LaneStack` therefore
touches every slot at a uniform index, with a mask or a select per lane,
which is exact and costs a few operations per slot.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from .frozen import FrozenKernel
from .raytree import RayBatch, Tracer
from .bsdf_query import KIND_CODES
from .shading import HitShader

#: Most rays one lane's stack holds; deeper trees use the wavefront tracer.
MAX_STACK = 32
#: Per-lane counts a kernel returns (``RayStats`` fields).
COUNTED = ("reflection", "refraction", "passthrough", "shadow", "refined")


def stack_capacity(spawning_generations: int, fan_out: int) -> int:
    """Most rays pending at once in a depth-first walk of a ray tree: a pop
    frees one slot, each generation that spawns adds at most fan-out."""
    return 1 + spawning_generations * max(fan_out - 1, 0)


@dataclass
class LaneStack:
    """A stack per lane of Dr.Jit values of the given types. A dataclass,
    so that a symbolic loop finds its local memory among its state (a loop
    that cannot see it never ends)."""

    slots: list

    @classmethod
    def allocate(cls, types: tuple, capacity: int) -> "LaneStack":
        return cls([dr.alloc_local(kind, capacity) for kind in types])

    def push(self, size: mi.UInt32, values: tuple, active: mi.Bool) -> mi.UInt32:
        """Store ``values`` on top where ``active``; the new size."""
        for slot, value in zip(self.slots, values):
            for k in range(len(slot)):
                slot.write(value, k, active & (size == k))
        return dr.select(active, size + 1, size)

    def read(self, index: mi.UInt32) -> list:
        """The entries at ``index`` (per lane), read slot by slot."""
        values = []
        for slot in self.slots:
            value = slot.read(0)
            for k in range(1, len(slot)):
                value = dr.select(index == k, slot.read(k), value)
            values.append(value)
        return values


class StackTreeTracer(Tracer):
    """Traces batches of camera rays to radiance, each tree in one loop."""

    def __init__(self, shader: HitShader, intersect, refiner=None):
        super().__init__(shader, intersect, refiner)
        self.capacity = stack_capacity(shader.spawning_generations(), shader.fan_out)
        self._kernel = FrozenKernel(self._trace_kernel, "stack tracer")

    @staticmethod
    def supports(shader: HitShader) -> bool:
        return stack_capacity(shader.spawning_generations(), shader.fan_out) <= MAX_STACK

    def trace(self, rays: RayBatch):
        """Radiance and alpha (primary hit) of each camera ray."""
        self.stats.camera += len(rays)
        self.stats.batches += 1
        radiance, alpha, counts, deepest = self._kernel(
            len(rays), self.shader.scene, self._kernel_inputs, *rays.fields())
        for kind, count in counts.items():
            setattr(self.stats, kind, getattr(self.stats, kind) + dr.sum(count))
        # Kept on the device: reading it here would wait for the kernel.
        self.stats.generations = dr.maximum(self.stats.generations, dr.max(deepest) + 1)
        return radiance, alpha

    @dr.syntax
    def _trace_kernel(self, scene, inputs, o, d, throughput, key):
        """Radiance, alpha, per-lane ray counts by kind and the deepest
        generation of each lane's tree."""
        stack = LaneStack.allocate(
            (mi.Point3f, mi.Vector3f, mi.Color3f, mi.UInt32, mi.UInt32), self.capacity)
        size = stack.push(mi.UInt32(0), (o, d, throughput, key, mi.UInt32(0)), mi.Bool(True))
        radiance = mi.Color3f(0)
        alpha = mi.Float(0)
        counts = {kind: mi.UInt32(0) for kind in COUNTED}
        deepest = mi.UInt32(0)
        while size > 0:
            size, radiance, alpha, counts, deepest = self._visit(
                stack, size - 1, radiance, alpha, counts, deepest)
        return radiance, alpha, counts, deepest

    def _visit(self, stack, size, radiance, alpha, counts, deepest):
        """Trace the ray on top of the stack (at ``size``): add its
        radiance, push its children; the loop state afterwards."""
        ray_o, ray_d, weight, key, generation = stack.read(size)
        ray = mi.Ray3f(ray_o, ray_d)
        si = self.intersect(ray, mi.Bool(True))
        hit = si.is_valid()
        alpha = dr.select(generation == 0, mi.Float(hit), alpha)
        deepest = dr.maximum(deepest, generation)
        counts = dict(counts)
        if self.refiner is not None:
            counts["refined"] += mi.UInt32(self.refiner.on_proxy(si, hit))
        local, shadow, children = self.shader.shade(si, ray, weight, key,
                                                    self.shader.work(generation))
        if local is not None:
            radiance = radiance + local
        if shadow is not None:
            counts["shadow"] += shadow
        for child in children:
            push = (child.code != 0) & (size < self.capacity)
            size = stack.push(size, (child.o, child.d, child.throughput, child.key,
                                     generation + 1), push)
            for kind, code in KIND_CODES.items():
                counts[kind] += mi.UInt32(push & (child.code == code))
        return size, radiance, alpha, counts, deepest
