"""Derivatives of camera samples' radiance, each ray tree replayed depth
first in one frozen kernel that differentiates it node by node.

The radiance of a camera sample is a sum over the nodes of its ray tree,
each node's own radiance (emission, the lights, the ambient term) times
its throughput, the product of the BSDF weights on the way to it. Written
from the root, ``R(n) = own(n) + sum_k w_k(n) R(c_k)`` over the node's
children ``c_k``. A parameter changes ``own`` and the weights ``w``, and
nothing else: the parameters that move rays (geometry, the sensor) are
refused, and so a node's derivative is local,

    dL = sum_n T(n) [d own(n) + sum_k d w_k(n) R(c_k)],

with the throughputs ``T`` and the children's radiances ``R`` held fixed.
This is the replay of Mitsuba's ``prb`` with a tree for a path: the kernel
walks each tree as :mod:`.depth_first` does and, at each node, takes the
derivative of that node's term alone, ``dr.backward_from`` (reverse mode)
or ``dr.forward_to`` (forward mode) inside the loop. No derivative crosses
an iteration, so the loop stays symbolic and the whole replay is one frozen
kernel per tile.

A node's own radiance is differentiated when the walk shades it. Its
children's part needs their radiances, known only once their subtrees are
walked: a node with children opens a *frame* (its ray, throughput, own
radiance and the radiance each child sends back), and when its last child
is done the loop traces that node's ray again, shades it for its
children's weights alone (no lights, no emission), differentiates those,
and sends its radiance up to its parent's frame. A node without children
is done as soon as it is shaded. The rays a tree visits and their order
are the depth-first tracer's, its cut at ``MAX_TREE_RAYS`` included; a
node with children is traced twice.

The open frames wait on a second :class:`LaneStack`, the innermost in
registers. A frame is opened by a node that spawns children, so at most
``spawning_generations`` are open at once.

Determinism: the backward kernel's scatter-adds into the parameters'
gradients land in lane order only on one thread, where it runs (as in
:mod:`..gradients`); the forward kernel adds nothing outside its lanes and
runs on every thread.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ...errors import Error
from ..settings import PLUGIN_NAME
from ..shading import MAX_TREE_RAYS
from .depth_first import DepthFirstTracer, LaneStack, select_all
from .frozen import FrozenKernel

#: A frame holds its node's ray (see ``_ray_types``), the count of children
#: still to finish, the node's own radiance, then the radiance each child
#: sent back.
PENDING = 6
OWN = PENDING + 1
RETURNED = OWN + 1
#: How each node's derivative is taken.
ANY_TERM = dr.ADFlag.Default | dr.ADFlag.AllowNoGrad


@dataclass
class Walked:
    """Per ray: its tree's radiance, summed from the leaves up, the rays the
    walk traced (the tree's, as the depth-first tracer traces them) and
    those it traced again (each node with children, once they were done)."""
    radiance: mi.Color3f
    visited: mi.UInt32
    revisited: mi.UInt32


class ReplayRefused(Error):
    """Dr.Jit could not record (or replay) a kernel of the tree replay: the
    caller takes the derivative another way, dropping what the replay's
    kernels may already have added to the stand-ins' gradients."""

    def __init__(self):
        super().__init__("Dr.Jit could not record the gradient's tree replay.", PLUGIN_NAME)


class TreeWalk:
    """``backward`` and ``forward`` of the radiance of camera rays, traced
    by ``tracer``'s shader and intersection (a :class:`DepthFirstTracer`
    built differentiable). ``sources`` (arguments of the kernels) are the
    arrays the derivative is taken with respect to, besides the scene's."""

    def __init__(self, tracer: DepthFirstTracer):
        self.tracer = tracer
        self.shader = tracer.shader
        self.intersect = tracer.intersect
        self.ray_capacity = tracer.capacity
        self.frame_types = (_ray_types() + (mi.UInt32, mi.Color3f)
                            + (mi.Color3f,) * self.shader.fan_out)
        # Open frames besides the one in registers.
        self.frame_capacity = max(self.shader.spawning_generations() - 1, 1)
        refusal = (self._refuse, "the gradient is taken by the slower unfrozen replay, as "
                                 "Dr.Jit cannot replay this scene's trees a hit at a time")
        self._backward = FrozenKernel(self._backward_kernel, "gradient replay", fallback=refusal)
        self._forward = FrozenKernel(self._forward_kernel, "gradient replay", fallback=refusal)

    def backward(self, rays, adjoint: mi.Color3f, sources: list) -> "Walked":
        """Add to the gradients of the scene's parameters (and of
        ``sources``) that of the rays' radiance weighed by ``adjoint``;
        what the walk found (:class:`Walked`)."""
        return self._backward(len(rays), self.shader.scene, self.tracer.kernel_inputs,
                              sources, *rays.fields(), adjoint)

    def forward(self, rays, sources: list) -> mi.Color3f:
        """The tangent of the rays' radiance along the gradients the
        parameters (and ``sources``) hold."""
        return self._forward(len(rays), self.shader.scene, self.tracer.kernel_inputs,
                             sources, *rays.fields())

    def _refuse(self, *args):
        raise ReplayRefused()

    def _backward_kernel(self, scene, inputs, sources, o, d, throughput, key, adjoint):
        # The loop itself is not differentiated: its body takes each node's
        # derivative in a scope of its own (``_node_term``).
        with dr.suspend_grad():
            radiance, _, visited, revisited = self._walk(o, d, throughput, key, adjoint)
        return Walked(radiance, visited, revisited)

    def _forward_kernel(self, scene, inputs, sources, o, d, throughput, key):
        with dr.suspend_grad():
            _, tangent, _, _ = self._walk(o, d, throughput, key, None)
        return tangent

    @dr.syntax
    def _walk(self, o, d, throughput, key, adjoint):
        """Walk each ray's tree; the radiance, the tangent where ``adjoint``
        is ``None`` (forward mode; else each node's derivative is sent back
        weighed by ``adjoint``), and the rays traced and traced again."""
        rays = LaneStack.allocate(_ray_types(), self.ray_capacity)
        frames = LaneStack.allocate(self.frame_types, self.frame_capacity)
        zero = mi.UInt32(0)
        ray = (o, d, throughput, key, zero, zero)
        frame = ray + (zero,) + (mi.Color3f(0),) * (1 + self.shader.fan_out)
        walk = (mi.UInt32(0),) * 5
        completing = mi.Bool(False)
        cut = mi.Bool(False)
        live = mi.Bool(True)
        radiance = mi.Color3f(0)
        tangent = mi.Color3f(0)
        while live:
            ray, frame, walk, completing, cut, live, radiance, tangent = self._step(
                rays, frames, ray, frame, walk, completing, cut, live, radiance, tangent,
                adjoint)
        return radiance, tangent, walk[3], walk[4]

    def _step(self, rays, frames, ray, frame, walk, completing, cut, live, radiance,
              tangent, adjoint):
        """One node: the next ray of the walk, or (``completing``) the node
        of the frame in registers, whose children are all done. ``walk``:
        sizes of the two stacks, open frames, rays visited and visited
        again (completed frames)."""
        size, frames_size, depth, visited, revisited = walk
        node = select_all(completing, frame[:PENDING], ray)
        own, sent, children, tangent = self._node_term(node, frame, completing, tangent,
                                                       adjoint)
        spawned = mi.UInt32(0)
        for child in children:
            spawned += mi.UInt32(child.code != 0)
        opens = ~completing & (spawned > 0)
        done = ~opens
        visited = dr.select(completing, visited, visited + 1)
        revisited = dr.select(completing, revisited + 1, revisited)
        cut |= visited >= MAX_TREE_RAYS

        # A node with children opens a frame; its last child goes next, the
        # others wait on the stack.
        frames_size = frames.push(frames_size, frame, opens & (depth > 0))
        opened = node + (spawned, own) + (mi.Color3f(0),) * len(children)
        frame = select_all(opens, opened, frame)
        depth = dr.select(opens, depth + 1, depth)
        generation = node[4] + 1
        size, ray, _ = rays.queue(size, ray, [
            (opens & (child.code != 0),
             (child.o, child.d, child.throughput, child.key, generation, mi.UInt32(slot)))
            for slot, child in enumerate(children)])

        # A node done sends its radiance to its parent's frame: the one in
        # registers, or for a completed frame the one under it.
        frame, frames_size, _ = frames.pop(frames_size, frame, completing & (depth > 1))
        depth = dr.select(completing, depth - 1, depth)
        root = done & (depth == 0)
        radiance = dr.select(root, sent, radiance)
        live &= ~root
        delivers = done & (depth > 0)
        frame = _delivered(frame, node[PENDING - 1], sent, delivers)

        # Next: the parent's node once its children are done (or the tree
        # is cut), else the next waiting ray.
        finished = delivers & ((frame[PENDING] == 0) | cut)
        ray, size, _ = rays.pop(size, ray, delivers & ~finished)
        completing = finished | (opens & cut)
        return (ray, frame, (size, frames_size, depth, visited, revisited), completing, cut,
                live, radiance, tangent)

    def _node_term(self, node, frame, completing, tangent, adjoint):
        """Shade ``node`` and take the derivative of its part of the term:
        visited, of its own radiance; ``completing`` (its children's
        radiances in ``frame``), of its children's weights, shaded again
        for those alone (no lights, no emission). Its own radiance and the
        radiance it sends back (where it is done; detached), its children,
        and the tangent with the derivative added (forward mode)."""
        o, d, throughput, key, generation, _ = node
        traced = mi.Ray3f(o, d)
        si = self.intersect(traced, mi.Bool(True), coherent=True)
        visiting = ~completing
        work = self.shader.work(generation)
        work = dataclasses.replace(work, emit=_where(work.emit, visiting),
                                   light=_where(work.light, visiting))
        with dr.resume_grad():
            shaded = self.shader.shade(si, traced, throughput, key, work, generation)
            own = shaded.own if shaded.own is not None else mi.Color3f(0)
            returned = mi.Color3f(0)
            for child, radiance in zip(shaded.children, frame[RETURNED:]):
                returned += dr.select(child.code != 0, child.weight * radiance, 0)
            term = throughput * dr.select(completing, returned, own)
            # Allowed to depend on no parameter: a derivative may ask for
            # parameters that no hit reads.
            if adjoint is None:
                tangent = tangent + dr.forward_to(term, flags=ANY_TERM)
            else:
                dr.backward_from(adjoint * term, flags=ANY_TERM)
        own = dr.detach(own)
        sent = dr.select(completing, frame[OWN] + dr.detach(returned), own)
        children = [_detached(child) for child in shaded.children]
        return own, sent, children, tangent


def _ray_types() -> tuple:
    """A ray waiting on the stack: origin, direction, throughput, key,
    generation, and which of its parent's children it is (its slot)."""
    return mi.Point3f, mi.Vector3f, mi.Color3f, mi.UInt32, mi.UInt32, mi.UInt32


def _where(part, mask: mi.Bool):
    """A part of a hit's work (``False``, or a mask) kept where ``mask``."""
    return False if part is False else part & mask


def _detached(child):
    """A child with no derivative: rays and throughputs the walk holds."""
    child.o, child.d = dr.detach(child.o), dr.detach(child.d)
    child.throughput = dr.detach(child.throughput)
    return child


def _delivered(frame: tuple, slot: mi.UInt32, sent: mi.Color3f, active: mi.Bool) -> tuple:
    """``frame`` with ``sent`` as the radiance of child ``slot`` and one
    child fewer pending, where ``active``."""
    returned = tuple(dr.select(active & (slot == k), sent, value)
                     for k, value in enumerate(frame[RETURNED:]))
    pending = dr.select(active, frame[PENDING] - 1, frame[PENDING])
    return frame[:PENDING] + (pending, frame[OWN]) + returned
