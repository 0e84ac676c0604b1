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

import drjit as dr
import mitsuba as mi

from ...jit import index_range, sum_blocks
from ..bsdf_query import KIND_CODES
from ..shading import MAX_TREE_RAYS, HitShader, HitWork
from .base import CapturedBatch, RayBatch, Tracer
from .frozen import FrozenKernel
from .shadow_log import ShadowLog, no_rays


class WavefrontTracer(Tracer):
    """Traces batches of camera rays to radiance, generation by generation."""

    def __init__(self, shader: HitShader, intersect, refiner=None,
                 wavefront_size: int = 1 << 18, frozen: bool = True):
        super().__init__(shader, intersect, refiner, wavefront_size)
        self.fan_out = shader.fan_out
        #: Whether generations run as frozen kernels; unfrozen, a trace can
        #: be differentiated (``gradients``), which a frozen call cannot.
        self.frozen = frozen
        #: One frozen kernel per combination of work: Dr.Jit 1.5 does not
        #: always record anew when only a Python flag argument changes
        #: (measured: a kernel recorded with children replayed without).
        self._generation = {}

    @property
    def launch_rays(self) -> int:
        # A generation and its compacted children.
        return self.camera_batch * (1 + self.fan_out)

    def trace(self, rays: RayBatch):
        """Radiance and alpha (primary hit) of each camera ray, and the part
        of the radiance gathered as indirect light where there is some
        (``Tracer.trace``).

        Depth first over parts of at most ``wavefront_size`` rays, with the
        generations whose children are still being traced on a list rather
        than on Python's call stack, so any depth can be traced. The trees
        of one call add at most ``MAX_TREE_RAYS - 1`` rays per camera ray;
        a part that would pass that is left untraced (and counted)."""
        self.stats.camera += len(rays)
        rays_left = (MAX_TREE_RAYS - 1) * len(rays)
        pending, result = [], self._visit(rays, 0)
        while True:
            if isinstance(result, _Generation):
                pending.append(result)
            elif not pending:
                return result
            else:
                pending[-1].fold(result)
            part = pending[-1].next_part(self.wavefront_size)
            if part is None:
                result = pending.pop().radiance()
                continue
            children = pending[-1].children.take(part)
            if len(children) > rays_left:
                self.stats.cut += len(children)
                result = (dr.zeros(mi.Color3f, len(children)), None,
                          *self._no_gathering(len(children)))
            else:
                rays_left -= len(children)
                result = self._visit(children, pending[-1].generation + 1)

    def _visit(self, rays: RayBatch, generation: int):
        """Shade a batch: its radiance and alpha if it has no children, else
        a :class:`_Generation` waiting for them."""
        self.stats.batches += 1
        self.stats.generations = max(self.stats.generations, generation + 1)
        log = self._shadow_log(len(rays), generation)
        local, alpha, gathered, children, slots = self._shade(rays, generation, log)
        if self.captured is not None:
            self.captured.append(CapturedBatch(generation, rays, *_logged_rays(log)))
        if children is None:
            return (local, alpha) + gathered
        return _Generation(generation, local, alpha, gathered, children, slots, self.fan_out)

    def _no_gathering(self, lanes: int) -> tuple:
        """The gathered radiance of ``lanes`` rays that gather none: zeros
        where the shader gathers indirect light, else nothing."""
        return () if self.shader.indirect is None else (dr.zeros(mi.Color3f, lanes),)

    def _shadow_log(self, lanes: int, generation: int):
        """Where a capturing render's shadow test writes the rays of a batch
        of ``lanes`` rays of ``generation``; ``None`` if the render does not
        capture or the batch tests no shadows."""
        lighting = self.shader.lighting
        if (self.captured is None or self.shader.work(generation).light is False
                or lighting.shadow_slots == 0):
            return None
        return ShadowLog.for_batch(lanes, lighting.shadow_slots,
                                   marching=not lighting.shadows.opaque)

    def _shade(self, rays: RayBatch, generation: int, log):
        """Local radiance and alpha of one generation, its gathered radiance
        (a tuple: empty without indirect light), its compacted children and
        the slot (parent x fan-out + component) of each child; the shadow
        rays go to ``log`` where it is not ``None``."""
        work = self.shader.work(generation)
        if not work.any() and generation > 0:
            return (dr.zeros(mi.Color3f, len(rays)), None, self._no_gathering(len(rays)),
                    None, None)
        # The generation as an opaque value: the indirect paths' length
        # depends on it, and one frozen kernel serves every generation.
        kernel, arguments = self._kernel(work), (len(rays), self.shader.scene,
                                                 self.kernel_inputs, *rays.fields(),
                                                 rays.paths, dr.opaque(mi.UInt32, generation))
        outputs = kernel(*arguments, log)
        if log is not None and log.make_room():
            # Once more with room for the queries it counted: same rays, same results.
            outputs = kernel(*arguments, log)
        local, gathered, alpha, shadow, indirect, refined, candidates = outputs
        local = dr.zeros(mi.Color3f, len(rays)) if local is None else local
        gathered = self._no_gathering(len(rays)) if gathered is None else (gathered,)
        if shadow is not None:
            tested, marched = shadow
            self.stats.shadow = self.stats.shadow + dr.sum(tested)
            self.stats.shadow_march = self.stats.shadow_march + dr.sum(marched)
        if indirect is not None:
            traced, shadow_rays = indirect
            self.stats.indirect = self.stats.indirect + dr.sum(traced)
            self.stats.indirect_shadow = self.stats.indirect_shadow + dr.sum(shadow_rays)
        if refined is not None:
            self.stats.refined = self.stats.refined + dr.sum(refined)
        if not candidates:
            return local, alpha, gathered, None, None
        children, slots = self._compact(candidates, rays.paths is not None)
        return local, alpha, gathered, children, slots

    def _kernel(self, work: HitWork):
        """``kernel(width, *inputs)``: the generation kernel for ``work``."""
        if not self.frozen:
            return lambda width, *inputs: self._generation_kernel(*inputs, work)
        if work not in self._generation:
            self._generation[work] = FrozenKernel(self._generation_kernel, "wavefront tracer",
                                                  work)
        return self._generation[work]

    def _generation_kernel(self, scene, inputs, o, d, throughput, key, paths, generation, log,
                           work: HitWork):
        """Everything one generation computes, as one traced function of its
        rays: radiance (and the part of it gathered as indirect light, from
        ``paths`` paths per hit), alpha, shadow rays, indirect rays and
        refinements per lane, and one candidate child per delta component
        (which inherits its parent's ``paths``); the shadow test writes its rays
        to ``log`` (filled in place) where it is not ``None``.

        It reads no sizes, so Dr.Jit can freeze it and replay its kernels for
        every later generation, part and anti-aliasing level. Outputs that
        would be constants are returned as ``None``: a constant carries the
        size of the call that recorded it and would come back wrong."""
        ray = mi.Ray3f(o, d)
        si = self.intersect(ray, mi.Bool(True), coherent=True)
        # Materialising the hit first lets the BSDF and emitter calls below
        # dispatch on evaluated pointers, faster than on symbolic ones.
        dr.eval(si)
        hit = si.is_valid()
        refined = None
        if self.refiner is not None:
            refined = mi.UInt32(self.refiner.on_proxy(si, hit))
        with self.shader.lighting.shadows.logging_to(log):
            shaded = self.shader.shade(si, ray, throughput, key, work, generation, paths)
        shadow = indirect = None
        local = shaded.local
        if shaded.gathered is not None:
            local = shaded.gathered if local is None else local + shaded.gathered
        if shaded.shadow is not None:
            shadow = (shaded.shadow.tested, shaded.shadow.marched)
        if shaded.indirect_rays is not None:
            indirect = (shaded.indirect_rays.traced, shaded.indirect_rays.shadow)
        inherited = () if paths is None else (paths,)
        candidates = [(child.o, child.d, child.throughput, child.key, *inherited, child.code)
                      for child in shaded.children]
        return local, shaded.gathered, mi.Float(hit), shadow, indirect, refined, candidates

    def _compact(self, candidates, with_paths: bool):
        """Children of all components in one batch (with their indirect
        paths per hit where ``with_paths``); a child's slot is parent x
        fan-out + component, so folding back is collision free."""
        picks = []
        for component, (*fields, codes) in enumerate(candidates):
            index = dr.compress(codes != 0)
            self._count_children(self.shader.components[component][0], codes, dr.width(index))
            if dr.width(index):
                picks.append((component, index, fields))
        total = sum(dr.width(index) for _, index, _ in picks)
        if total == 0:
            return None, None
        batch = RayBatch(dr.empty(mi.Point3f, total), dr.empty(mi.Vector3f, total),
                         dr.empty(mi.Color3f, total), dr.empty(mi.UInt32, total),
                         dr.empty(mi.Float, total) if with_paths else None)
        buffers = batch.fields() + ((batch.paths,) if with_paths else ())
        slots = dr.empty(mi.UInt32, total)
        offset = 0
        for component, index, fields in picks:
            target = index_range(offset, offset + dr.width(index))
            for buffer, value in zip(buffers, fields):
                dr.scatter(buffer, dr.gather(type(value), value, index), target)
            dr.scatter(slots, index * self.fan_out + component, target)
            offset += dr.width(index)
        dr.eval(*buffers, slots)
        return batch, slots

    def _count_children(self, kind: str, codes, count: int) -> None:
        """Add one component's children to the statistics: a null component
        only passes rays through; a delta one reflects or refracts them."""
        if kind == "null":
            self.stats.passthrough = self.stats.passthrough + count
            return
        reflected = dr.count(codes == KIND_CODES["reflection"])
        self.stats.reflection = self.stats.reflection + reflected
        self.stats.refraction = self.stats.refraction + (count - reflected)


def _logged_rays(log) -> tuple:
    """The shadow rays and queries of ``log``, evaluated so that the log can
    go; none without one."""
    if log is None:
        return no_rays(), no_rays()
    rays = log.shadow_rays(), log.query_rays()
    dr.eval(rays)
    return rays


class _Generation:
    """A shaded batch whose children are traced part by part: each part's
    radiance is folded into its parents' slots (parent x fan-out +
    component), and summed per parent in component order once all are in."""

    def __init__(self, generation: int, local, alpha, gathered: tuple, children: RayBatch,
                 slots, fan_out: int):
        self.generation = generation
        self.local, self.alpha = local, alpha
        #: The gathered part of ``local`` (a tuple: empty without indirect
        #: light), folded back and summed as ``local`` is.
        self.gathered = gathered
        self.children, self.slots = children, slots
        self.fan_out = fan_out
        self.folded = [dr.zeros(mi.Color3f, dr.width(local) * fan_out)
                       for _ in range(1 + len(gathered))]
        self.start = 0
        self.part = None

    def next_part(self, size: int):
        """Indices of the next part of the children, ``None`` after the last."""
        if self.start >= len(self.children):
            return None
        stop = min(self.start + size, len(self.children))
        self.part = index_range(self.start, stop)
        self.start = stop
        return self.part

    def fold(self, result: tuple) -> None:
        """Put the radiance (and gathered radiance) of the current part,
        ``result`` as a visit gives it, into its parents' slots."""
        radiance, _, *gathered = result
        slots = dr.gather(mi.UInt32, self.slots, self.part)
        for folded, value in zip(self.folded, [radiance, *gathered]):
            dr.scatter(folded, value, slots)

    def radiance(self) -> tuple:
        """Radiance, alpha and gathered radiance (where there is some)."""
        totals = [own + sum_blocks(folded, self.fan_out)
                  for own, folded in zip((self.local, *self.gathered), self.folded)]
        return totals[0], self.alpha, *totals[1:]
