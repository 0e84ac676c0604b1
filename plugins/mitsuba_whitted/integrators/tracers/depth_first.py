"""Whitted ray trees traced whole, one kernel per batch of camera rays.

Each lane walks its own tree depth first: it intersects and shades a ray,
adds the radiance, goes on with the ray's last child that passes the
``min_throughput`` pruning and leaves the earlier ones on a small stack in
local memory; a ray without children pops the stack instead. The loop ends
when a lane has no ray left. Nothing leaves the kernel between generations,
so there is no compaction, no fold-back and one frozen replay per batch; the
wavefront tracer (:mod:`.wavefront`) stays the reference and serves what a
stack cannot (trees deeper than :data:`MAX_STACK` allows, capturing each
generation's rays).

Stack traffic is the kernel's own overhead, so it is kept off the common
paths: the ray traced next stays in registers, and pushes and pops sit in
symbolic branches that a packet skips when none of its lanes needs them (a
camera ray ending on a diffuse wall touches the stack not at all).

The stack holds at most ``1 + G x (fan-out - 1)`` rays, where G is the
number of generations that may spawn children (``max_depth - 1`` with
emitters a ray can hit, else ``max_depth - 2``): a pop frees one slot,
and the ray in registers needs none.

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

from ...camera import camera_rays
from ..bsdf_query import KIND_CODES
from ..shading import MAX_TREE_RAYS, HitShader
from .base import RayBatch, Tracer
from .frozen import FrozenKernel

#: Most rays one lane's stack holds; deeper trees use the wavefront tracer.
MAX_STACK = 32
#: Camera samples per launch, in units of ``wavefront_size``: outside its
#: kernel a sample holds only its position, key and result (28 bytes), a
#: small share of what a ray of a wavefront generation holds, so launches
#: this much wider stay within the wavefront tracer's memory, and a large
#: anti-aliasing level takes one launch instead of several.
LAUNCH_FACTOR = 8
#: Per-lane counts a kernel returns (``RayStats`` fields).
COUNTED = ("reflection", "refraction", "passthrough", "shadow", "shadow_march", "refined",
           "cut", "indirect", "indirect_shadow")


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

    @dr.syntax
    def push(self, size: mi.UInt32, values: tuple, active: mi.Bool) -> mi.UInt32:
        """Store ``values`` on top where ``active``; the new size. A packet
        none of whose lanes pushes skips the stores (a symbolic branch)."""
        if active:
            for slot, value in zip(self.slots, values):
                for k in range(len(slot)):
                    slot.write(value, k, active & (size == k))
        return dr.select(active, size + 1, size)

    @dr.syntax
    def pop(self, size: mi.UInt32, values: tuple, active: mi.Bool):
        """Take the top entry where ``active`` (``values`` elsewhere): the
        values, the new size and ``active``. Skipped by a packet none of
        whose lanes pops."""
        if active:
            values = select_all(active, self.read(size - 1), values)
        return values, dr.select(active, size - 1, size), active

    def queue(self, size: mi.UInt32, current: tuple, candidates: list):
        """Of ``candidates`` (pairs of a mask and an entry, in order), the
        last one each lane has goes to registers and the earlier ones wait
        on the stack (the order of a plain depth-first walk, without
        storing the entry taken next): the new size, the entry in registers
        (``current`` where a lane has none) and whether a lane had one."""
        queued = mi.Bool(False)
        for valid, entry in candidates:
            # An earlier candidate is superseded by this one: it waits.
            size = self.push(size, current, queued & valid)
            current = select_all(valid, entry, current)
            queued |= valid
        return size, current, queued

    def read(self, index: mi.UInt32) -> list:
        """The entries at ``index`` (per lane), read slot by slot."""
        values = []
        for slot in self.slots:
            value = slot.read(0)
            for k in range(1, len(slot)):
                value = dr.select(index == k, slot.read(k), value)
            values.append(value)
        return values


def select_all(mask: mi.Bool, chosen, others) -> tuple:
    """Per lane, ``chosen`` where ``mask`` else ``others`` (entry by entry)."""
    return tuple(dr.select(mask, a, b) for a, b in zip(chosen, others))


class DepthFirstTracer(Tracer):
    """Traces batches of camera rays to radiance, each tree in one loop."""

    def __init__(self, shader: HitShader, intersect, refiner=None,
                 wavefront_size: int = 1 << 18):
        super().__init__(shader, intersect, refiner, wavefront_size)
        self.capacity = stack_capacity(shader.spawning_generations(), shader.fan_out)
        self._kernel = FrozenKernel(self._trace_kernel, "depth-first tracer",
                                    undo=self._restore_totals)
        self._camera_kernel = FrozenKernel(
            self._trace_camera_kernel, "depth-first tracer", undo=self._restore_totals,
            fallback=(self._trace_camera_rays, "the depth-first tracer makes this sensor's camera "
                      "rays outside its kernel, which Dr.Jit cannot freeze with them inside"))
        self._saved_totals = None

    @staticmethod
    def supports(shader: HitShader) -> bool:
        return stack_capacity(shader.spawning_generations(), shader.fan_out) <= MAX_STACK

    @property
    def camera_batch(self) -> int:
        return LAUNCH_FACTOR * self.wavefront_size

    def _start(self) -> None:
        super()._start()
        # Ray counts (``COUNTED``) and the deepest generation, kept on the
        # device and added to inside the kernels, rather than summed from
        # per-lane counts after each launch (a reduction per kind and
        # launch). Opaque from the start: zeros would be a literal in the
        # first launch and memory in the next, and Dr.Jit records a frozen
        # kernel anew when an input changes so.
        self._counts = dr.opaque(mi.UInt32, 0, len(COUNTED))
        self._deepest = dr.opaque(mi.UInt32, 0, 1)

    def trace(self, rays: RayBatch):
        """Radiance and alpha (primary hit) of each ray, and with indirect
        light its gathered part (see ``Tracer.trace``)."""
        self._count_batch(len(rays))
        return self._launch_ray_kernel(self.shader.scene, self.kernel_inputs,
                                       *rays.fields(), rays.paths)

    def trace_camera(self, sensor: mi.Sensor, positions: mi.Point2f, keys: mi.UInt32,
                     lens: mi.Point2f = None, paths: mi.Float = None):
        """``trace`` of camera rays through ``positions`` from ``lens`` (see
        ``camera_rays``), made inside the kernel (no ray arrays go through
        memory) where Dr.Jit can freeze the sensor's ray generation."""
        self._count_batch(dr.width(keys))
        self._save_totals(self._camera_kernel)
        return self._camera_kernel(dr.width(keys), self.shader.scene, sensor,
                                   self.kernel_inputs, self._counts, self._deepest,
                                   positions, keys, lens, paths)

    def _trace_camera_rays(self, scene, sensor, inputs, counts, deepest, positions, keys,
                           lens, paths):
        """The camera kernel's result, its rays made outside the kernel and
        passed in through memory (for the sensors whose members Mitsuba
        3.9.1 does not expose to ``dr.freeze``: orthographic, thin lens)."""
        ray, weight = camera_rays(sensor, positions, lens)
        return self._launch_ray_kernel(scene, inputs, ray.o, ray.d, mi.Color3f(weight), keys,
                                       paths)

    def _launch_ray_kernel(self, scene, inputs, o, d, throughput, key, paths):
        self._save_totals(self._kernel)
        return self._kernel(dr.width(key), scene, inputs, self._counts, self._deepest,
                            o, d, throughput, key, paths)

    def _count_batch(self, rays: int) -> None:
        self.stats.camera += rays
        self.stats.batches += 1

    def _save_totals(self, kernel: FrozenKernel) -> None:
        """While ``kernel`` may still fail to freeze, keep the totals it is
        about to add to (two copies of a few integers)."""
        if kernel.enabled:
            self._saved_totals = dr.copy(self._counts), dr.copy(self._deepest)

    def _restore_totals(self) -> None:
        """Take back what a failed frozen call added to the totals."""
        for total, saved in zip((self._counts, self._deepest), self._saved_totals):
            dr.scatter(total, saved, dr.arange(mi.UInt32, dr.width(total)))
        dr.eval(self._counts, self._deepest)

    def statistics(self) -> dict:
        counts = self._counts.numpy()
        for kind, count in zip(COUNTED, counts):
            setattr(self.stats, kind, int(count))
        self.stats.generations = int(self._deepest[0]) + 1 if self.stats.camera else 0
        return super().statistics()

    def _trace_camera_kernel(self, scene, sensor, inputs, counts, deepest, positions, keys,
                             lens, paths):
        ray, weight = camera_rays(sensor, positions, lens)
        return self._trace_kernel(scene, inputs, counts, deepest, ray.o, ray.d,
                                  mi.Color3f(weight), keys, paths)

    @dr.syntax
    def _trace_kernel(self, scene, inputs, total_counts, total_deepest, o, d, throughput, key,
                      paths):
        """Radiance and alpha of each ray, and the gathered part of its
        radiance where the tree gathers indirect light (``paths`` per hit,
        per lane; ``None``: the integrator's count); adds its tree's rays by
        kind to ``total_counts`` and its deepest generation to
        ``total_deepest``."""
        stack = LaneStack.allocate(
            (mi.Point3f, mi.Vector3f, mi.Color3f, mi.UInt32, mi.UInt32), self.capacity)
        size = mi.UInt32(0)
        ray = (o, d, throughput, key, mi.UInt32(0))
        live = mi.Bool(True)
        radiance = mi.Color3f(0)
        gathered = mi.Color3f(0)
        alpha = mi.Float(0)
        counts = {kind: mi.UInt32(0) for kind in COUNTED}
        deepest = mi.UInt32(0)
        visited = mi.UInt32(0)
        while live:
            size, ray, live, radiance, gathered, alpha, counts, deepest = self._visit(
                stack, size, ray, radiance, gathered, alpha, counts, deepest, paths)
            # A tree stops at MAX_TREE_RAYS rays; what is still pending is
            # left untraced and counted.
            visited += 1
            full = live & (visited >= MAX_TREE_RAYS)
            counts["cut"] += dr.select(full, size + 1, 0)
            live &= ~full
        # Integer sums and maxima: the same totals in any order.
        for index, kind in enumerate(COUNTED):
            dr.scatter_reduce(dr.ReduceOp.Add, total_counts, counts[kind], mi.UInt32(index))
        dr.scatter_reduce(dr.ReduceOp.Max, total_deepest, deepest, mi.UInt32(0))
        return (radiance, alpha) + ((gathered,) if self.shader.indirect is not None else ())

    def _visit(self, stack, size, ray, radiance, gathered, alpha, counts, deepest, paths):
        """Trace ``ray``: add its radiance, and go on with its last child
        while the others wait on the stack (the order of a plain depth-first
        walk, without storing the ray that is traced next); a lane with no
        child pops the stack. The loop state afterwards."""
        ray_o, ray_d, weight, key, generation = ray
        traced = mi.Ray3f(ray_o, ray_d)
        si = self.intersect(traced, mi.Bool(True), coherent=True)
        hit = si.is_valid()
        alpha = dr.select(generation == 0, mi.Float(hit), alpha)
        deepest = dr.maximum(deepest, generation)
        counts = dict(counts)
        if self.refiner is not None:
            counts["refined"] += mi.UInt32(self.refiner.on_proxy(si, hit))
        shaded = self.shader.shade(si, traced, weight, key, self.shader.work(generation),
                                   generation, paths)
        if shaded.local is not None:
            radiance = radiance + shaded.local
        if shaded.gathered is not None:
            radiance = radiance + shaded.gathered
            gathered = gathered + shaded.gathered
        if shaded.shadow is not None:
            counts["shadow"] += shaded.shadow.tested
            counts["shadow_march"] += shaded.shadow.marched
        if shaded.indirect_rays is not None:
            counts["indirect"] += shaded.indirect_rays.traced
            counts["indirect_shadow"] += shaded.indirect_rays.shadow
        size, ray, live = stack.queue(
            size, ray, [(child.code != 0, (child.o, child.d, child.throughput, child.key,
                                           generation + 1)) for child in shaded.children])
        for child in shaded.children:
            for kind, code in KIND_CODES.items():
                counts[kind] += mi.UInt32(child.code == code)
        ray, size, popped = stack.pop(size, ray, ~live & (size > 0))
        return size, ray, live | popped, radiance, gathered, alpha, counts, deepest
