"""Derivatives of a ``whitted`` image with respect to the scene's parameters.

``mi.render(scene, params)`` hands the derivative of its image to the
integrator's ``render_forward`` (a tangent image from the parameters'
tangents) and ``render_backward`` (the parameters' gradients from an
adjoint image). A Whitted image is a deterministic function of the scene, so
both are exact: no samples, no noise.

How it is computed, band by band as ``render`` renders:

1. The camera samples are placed by the render's own anti-aliasing, so
   that its choices (which cells to split, which pixels to refine) are
   those of the image. It decides by the radiance the render traced, which
   the render kept (:mod:`.kept_launches`), or else traces the samples
   again with its frozen tracer. Each launch of samples comes back as a
   fresh AD leaf: once its choices are made, a sampler combines samples
   into pixels linearly (block means, refined cells replacing their
   parents), and Dr.Jit differentiates that combination. Backward, the
   band's adjoint pixels give each sample's adjoint; forward, each sample's
   tangent gives the band's tangent pixels.
2. Each sample's ray tree is replayed for its derivative, tile by tile, by
   one of two :class:`Replay` kinds (the integrator's ``gradient_replay``):

   - :class:`TreeReplay`, where the depth-first tracer serves: frozen
     kernels walk each tree again and differentiate one hit at a time
     (:mod:`.tracers.tree_replay`), as Mitsuba's ``prb`` replays a path.
     Nothing of a derivative outlives its hit, so a tile is a render's
     launch.
   - :class:`GraphReplay`: the wavefront tracer unfrozen, the whole trace of
     a tile recorded by Dr.Jit's AD and differentiated at once, in tiles of
     ``TILE_FACTOR x wavefront_size`` samples (memory follows the tile). It
     serves trees too deep for the stacks, takes over where Dr.Jit refuses
     to record the tree replay's kernels, and is its oracle in the tests.

   Either way the gradient flows through the whole ray tree: Fresnel
   weights, transmittances, the shading, the lights, and the shadow rays'
   crossings of glass.

The parameters being differentiated are replaced for the length of the
derivative by fresh AD leaves of the same value (:class:`StandIns`), so
that what plugins derive from a parameter on an update (a bitmap's
texture) is derived again inside the scope in which ``mi.render`` runs the
derivative; their gradients are then added to the parameters' in one step.

Dr.Jit 1.5 sets the graph replay's modes. Reverse-mode AD goes through
symbolic loops only by replaying stored iterations, which on the LLVM
backend mis-compiles a stored mask and fails on a state variable of width
one and on nested loops: loops and branches are traced in evaluated mode.
Forward mode evaluates calls too, as its traversal may not cross from a
symbolic call's recording into the variables it read; reverse mode keeps
them symbolic, as its evaluated form counts the derivative of a gather at
one index (a texture's transform) once per lane. The tree replay never
differentiates across a loop's iterations, and keeps its loops symbolic.

What is not differentiated: changes of visibility. A silhouette, the edge of
a shadow, the edge of total internal reflection or of a texture's pattern
that moves when a parameter changes moves a discontinuity, whose derivative
is a Dirac delta that only edge sampling or reparameterisation captures (as
in Mitsuba's ``prb`` without them). The parameters that move geometry (a
shape's vertices or placement, the sensor) are refused with one sentence.

Determinism: Dr.Jit traverses a graph in the order in which it was built,
and the tiles are summed in order. What remains is the scatter-adds into
the parameters' gradients (every lane that reads a texel or a constant adds
to its gradient): with several threads they land in a different order every
run, so the kernels that scatter (the tree replay's backward, the graph
replay's backward pass) run on one thread, where they land in lane order.
The same scene and adjoint give the same gradient bit for bit.
"""

from __future__ import annotations

import dataclasses
from contextlib import contextmanager
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..camera import camera_rays
from ..errors import ParameterError, VariantError, check
from ..jit import concat, index_range
from .camera_shader import CameraShader
from .render_plan import Demand
from .settings import PLUGIN_NAME
from .tracers import DepthFirstTracer, RayBatch
from .tracers.tree_replay import TreeWalk

#: A shape's parameters whose change moves its surface.
GEOMETRY = ("vertex_positions", "to_world", "center", "radius", "height")
#: Camera samples traced at once, in units of ``wavefront_size``: tracing a
#: tile again with AD costs a fixed time for each generation of its trees,
#: so tiles are wider than a primal launch.
TILE_FACTOR = 4
#: Bytes of a tile's AD graph per camera sample, with some margin (about
#: 900 on the report's scene).
TILE_SAMPLE_BYTES = 1280
#: Bytes per camera sample of a tile of the tree replay: its ray, adjoint
#: and radiance.
TREE_SAMPLE_BYTES = 96
_NOT_GEOMETRY = ("which whitted does not differentiate (silhouettes would move); "
                 "differentiate materials, textures, lights or the ambient term")


def require_differentiable(indirect_samples: int, photons: int = 0) -> None:
    """One sentence where the active variant has no automatic
    differentiation, or the integrator gathers indirect light or photons."""
    if not dr.is_diff_v(mi.Float):
        raise VariantError(
            "gradients need a variant with automatic differentiation such as 'llvm_ad_rgb' "
            f"(the active variant is '{mi.variant()}').", PLUGIN_NAME)
    check(indirect_samples == 0, PLUGIN_NAME, "indirect_samples",
          f"is {indirect_samples}, and the indirect light is not differentiated: "
          "set it to 0 for gradients")
    check(photons == 0, PLUGIN_NAME, "photons",
          f"is {photons}, and the photons' light is not differentiated: set it to 0 for "
          "gradients")


def tile_demand(demand: Demand, replay: "Replay") -> Demand:
    """What a render's ``demand`` becomes where ``replay`` traces a tile
    of camera samples again beside it."""
    return dataclasses.replace(demand, launch_samples=replay.tile,
                               launch_sample_bytes=replay.sample_bytes)


def replay_of(tracer, sensor: mi.Sensor) -> "Replay":
    """The replay of camera samples that differentiates ``tracer``'s
    traces (built ``differentiable``)."""
    if isinstance(tracer, DepthFirstTracer):
        return TreeReplay(tracer, sensor)
    return GraphReplay(tracer, sensor)


def primal_seed(seed: int, last_seed: int) -> int:
    """The seed whose image is differentiated. ``mi.render`` passes its
    differential phase a seed of its own, a hash of the primal one
    (``sample_tea_32(seed, 1)``): that hash of the last render's seed
    (``last_seed``) is taken back to it, so that the derivative is that of
    the image ``mi.render`` returned."""
    return last_seed if seed == _differential_seed(last_seed) else seed


def _differential_seed(seed: int) -> int:
    """The seed ``mi.render`` derives for the differential phase from ``seed``."""
    return int(mi.sample_tea_32(mi.UInt32(seed), mi.UInt32(1))[0][0])


def differentiated(params) -> list:
    """The keys of ``params`` (``mi.SceneParameters``, or ``None``) whose
    values have their gradients enabled, after refusing those whitted does
    not differentiate: a shape's geometry or placement, and a sensor's."""
    if params is None:
        return []
    found = []
    for key in params.keys():
        node = params.properties[key][2]
        if not _grad_enabled(params[key]):
            continue
        name = key.rsplit(".", 1)[-1]
        if isinstance(node, mi.Shape) and name in GEOMETRY:
            raise ParameterError(PLUGIN_NAME, key, "moves a shape, " + _NOT_GEOMETRY)
        if isinstance(node, mi.Sensor):
            raise ParameterError(PLUGIN_NAME, key, "belongs to the sensor, " + _NOT_GEOMETRY)
        found.append(key)
    return found


class StandIns:
    """For the length of a ``with`` block, each differentiated parameter of
    ``params`` is replaced in the scene by a fresh AD leaf of the same
    value (its ``stand_in``), carrying the parameter's tangent, and the
    plugins are updated; afterwards the parameters come back, each with the
    gradient of its stand-in added to its own.

    The derivatives are so taken on a graph of their own: values the
    plugins derive from a parameter when it is updated (a bitmap's texture
    from its data) are derived again from the stand-in, inside the
    differentiation that ``mi.render`` runs in a scope of its own, which
    Dr.Jit's forward mode cannot leave; and every gradient is complete,
    and evaluated, when the block ends."""

    def __init__(self, params, keys: list, tangents: bool):
        self.view = params.copy() if keys else None
        #: Forward mode: the parameters' gradients are tangents, and the
        #: stand-ins' gradients are not added back.
        self.tangents = tangents
        #: The parameters as they were: copies that share their variables.
        self.originals = {key: _alias(params[key]) for key in keys}
        self.stand_ins = {}

    def __enter__(self) -> "StandIns":
        for key, original in self.originals.items():
            # A copy (Mitsuba takes a value with the parameter's own
            # variable for no change at all).
            leaf = dr.copy(dr.detach(original))
            dr.make_opaque(leaf)
            dr.enable_grad(leaf)
            self.stand_ins[key] = leaf
        self._install(self.stand_ins)
        return self

    def tangents_of(self) -> list:
        """``(stand-in, tangent)`` of each parameter, the tangent being the
        parameter's gradient (forward mode)."""
        return [(leaf, dr.detach(dr.grad(self.originals[key])))
                for key, leaf in self.stand_ins.items()]

    def __exit__(self, *error) -> None:
        gradients = {key: dr.detach(dr.grad(leaf)) for key, leaf in self.stand_ins.items()}
        self._install(self.originals)
        if error[0] is None and not self.tangents:
            for key, gradient in gradients.items():
                dr.accum_grad(self.originals[key], gradient)

    def leaves(self) -> list:
        """The stand-ins."""
        return list(self.stand_ins.values())

    def _install(self, values: dict) -> None:
        if self.view is None:
            return
        for key, value in values.items():
            self.view[key] = value
        self.view.update()


def _alias(value):
    """A new handle on the same variables as ``value`` (an array, a tensor
    or a transform): assigning through one leaves the other as it was."""
    return type(value)(value)


def _grad_enabled(value) -> bool:
    """Whether ``value`` (an array, a transform, or a plain number) has its
    gradient enabled."""
    try:
        return dr.grad_enabled(value)
    except TypeError:
        return False


@contextmanager
def _evaluated(reverse: bool):
    """Loops and branches traced in evaluated mode, and calls too for the
    forward mode (see the module's docstring)."""
    with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, False), \
            dr.scoped_set_flag(dr.JitFlag.SymbolicConditionals, False), \
            dr.scoped_set_flag(dr.JitFlag.SymbolicCalls, reverse):
        yield


@contextmanager
def _one_thread():
    """Kernels run on one thread: scatter-adds land in lane order.

    Dr.Jit's LLVM backend gives a scatter-add onto a small array one copy of
    it per thread, laid out for the thread count of the moment the
    operation is recorded: whatever is recorded under one count must run
    under it. Scatters are side effects, which ``dr.eval()`` runs (all of
    them, those into gradients Dr.Jit keeps out of reach included), so the
    block starts and ends with one; its caller evaluates what it reads."""
    count = dr.thread_count()
    _flush()
    dr.set_thread_count(1)
    try:
        yield
    finally:
        _flush()
        dr.set_thread_count(count)


def _flush() -> None:
    """Run every computation recorded so far, side effects included."""
    dr.eval()
    dr.sync_thread()


@dataclass
class _Launch:
    """Camera samples a sampler asked for at once, and their radiance as an
    AD leaf (its gradient: each sample's adjoint or tangent)."""
    positions: mi.Point2f
    keys: mi.UInt32
    lens: object
    radiance: mi.Color3f


class Replay:
    """The camera samples of a render traced again for their derivative,
    tile by tile: ``tile`` samples at a time, each holding
    ``sample_bytes`` while it is traced."""

    #: ``"tree"`` or ``"graph"``, the integrator's ``gradient_replay``.
    kind: str
    tile: int
    sample_bytes: int

    def __init__(self, tracer, sensor: mi.Sensor):
        self.tracer = tracer
        self.sensor = sensor
        #: Rays of the last derivative by kind, where the replay counts them.
        self.rays = {}

    def start(self) -> None:
        """Ready for another derivative."""
        self.tracer.reload()

    def _rays(self, positions, keys, lens, part) -> RayBatch:
        """The camera rays of the samples ``part``, without derivative."""
        with dr.suspend_grad():
            ray, weight = camera_rays(self.sensor, dr.gather(mi.Point2f, positions, part),
                                      None if lens is None else dr.gather(type(lens), lens, part))
            return RayBatch(ray.o, ray.d, mi.Color3f(weight), dr.gather(mi.UInt32, keys, part))

    def _parts(self, count: int):
        for start in range(0, count, self.tile):
            yield index_range(start, min(start + self.tile, count))


class TreeReplay(Replay):
    """Each sample's ray tree replayed in frozen kernels that differentiate
    it a hit at a time (:mod:`.tracers.tree_replay`): no derivative graph
    outlives a hit, so a tile is as wide as a render's launch."""

    kind = "tree"
    sample_bytes = TREE_SAMPLE_BYTES

    def __init__(self, tracer, sensor: mi.Sensor):
        super().__init__(tracer, sensor)
        self.tile = tracer.camera_batch
        self.walk = TreeWalk(tracer)

    def start(self) -> None:
        """Ready for another derivative: its ray counts start at 0 (the
        rays its backward walks trace, and those traced again)."""
        super().start()
        self.rays = {"walked": 0, "walked again": 0}

    def tangent(self, positions, keys, lens, sources: list) -> mi.Color3f:
        """The samples' radiance tangent, from ``sources``: pairs of a
        stand-in of a parameter and its tangent.

        The tangents are first carried to the values the plugins derived
        from the stand-ins (a bitmap's texels), and the edges between them
        dropped: the kernel's derivatives start from the arrays it reads,
        since a frozen function's may not leave it. The kernel adds nothing
        outside its own lanes, so it runs on every thread."""
        count = dr.width(keys)
        tangent = dr.empty(mi.Color3f, count)
        leaves = [leaf for leaf, _ in sources]
        with dr.resume_grad():
            for leaf, value in sources:
                dr.set_grad(leaf, value)
            dr.enqueue(dr.ADMode.Forward, leaves)
            dr.traverse(dr.ADMode.Forward, flags=dr.ADFlag.ClearEdges)
            for part in self._parts(count):
                rays = self._rays(positions, keys, lens, part)
                dr.scatter(tangent, self.walk.forward(rays, leaves), part)
                dr.eval(tangent)
            for leaf in leaves:
                dr.clear_grad(leaf)
        return tangent

    def backward(self, positions, keys, lens, adjoint: mi.Color3f, parameters: list) -> None:
        """Add to the gradients of ``parameters`` that of the samples'
        radiance weighed by ``adjoint``."""
        for part in self._parts(dr.width(keys)):
            rays = self._rays(positions, keys, lens, part)
            part_adjoint = dr.gather(mi.Color3f, adjoint, part)
            dr.eval(rays.fields(), part_adjoint)
            with dr.resume_grad(), _one_thread():
                walked = self.walk.backward(rays, part_adjoint, parameters)
                dr.eval([dr.grad(parameter) for parameter in parameters])
            self.rays["walked"] += _total(walked.visited)
            self.rays["walked again"] += _total(walked.revisited)


class GraphReplay(Replay):
    """The samples' radiance traced again with AD enabled by the wavefront
    tracer unfrozen, for the trees too deep for :class:`TreeReplay`'s
    stacks; only one tile's AD graph is kept (see the module's
    docstring)."""

    kind = "graph"
    sample_bytes = TILE_SAMPLE_BYTES

    def __init__(self, tracer, sensor: mi.Sensor):
        super().__init__(tracer, sensor)
        self.tile = tracer.camera_batch * TILE_FACTOR

    def _radiance(self, positions, keys, lens, part, reverse: bool) -> mi.Color3f:
        """Radiance of the samples ``part`` of ``positions``, to be
        differentiated in reverse mode or (``reverse`` false) forward."""
        rays = self._rays(positions, keys, lens, part)
        with dr.resume_grad(), _evaluated(reverse):
            radiance, _ = self.tracer.trace(rays)
        return radiance

    def tangent(self, positions, keys, lens, sources: list) -> mi.Color3f:
        """The samples' radiance tangent, from ``sources``: pairs of a
        stand-in of a parameter and its tangent.

        Each tile's traversal keeps its edges for the next tile, and goes
        only along paths that end in the tile's radiance: a value derived
        from a stand-in and kept, which this tile does not read (a bitmap's
        texels padded to four channels for packet gathers), would otherwise
        keep the tangent it was given and pass it on a second time to the
        first tile that reads it. The stand-ins hold their tangents only
        meanwhile, since the frozen kernels take them as inputs, and a
        frozen call records anew for each new kind of input."""
        count = dr.width(keys)
        tangent = dr.empty(mi.Color3f, count)
        for part in self._parts(count):
            radiance = self._radiance(positions, keys, lens, part, reverse=False)
            with dr.resume_grad():
                for leaf, value in sources:
                    dr.set_grad(leaf, value)
                dr.forward_to(radiance, flags=dr.ADFlag.ClearInterior | dr.ADFlag.AllowNoGrad)
                dr.scatter(tangent, dr.detach(dr.grad(radiance)), part)
                for leaf, _ in sources:
                    dr.clear_grad(leaf)
            dr.eval(tangent)
        return tangent

    def backward(self, positions, keys, lens, adjoint: mi.Color3f, parameters: list) -> None:
        """Add to the gradients of ``parameters`` that of the samples'
        radiance weighed by ``adjoint``."""
        for part in self._parts(dr.width(keys)):
            radiance = self._radiance(positions, keys, lens, part, reverse=True)
            dr.eval(radiance)
            with dr.resume_grad(), _one_thread():
                dr.set_grad(radiance, dr.gather(mi.Color3f, adjoint, part))
                dr.enqueue(dr.ADMode.Backward, radiance)
                # Edges are kept: derived values the tiles share (a texture's
                # transform) lead each tile's gradient on to the parameters.
                dr.traverse(dr.ADMode.Backward, flags=dr.ADFlag.ClearVertices)
                dr.eval([dr.grad(parameter) for parameter in parameters])
            del radiance


class RecordingShader(CameraShader):
    """A camera shader that hands each launch's radiance out as an AD leaf.
    Given a ``tangent``, the leaf's gradient is ``tangent(positions, keys,
    lens)`` and nothing else is kept: the band's pixels, made of the
    leaves, keep them in their AD graph until the band's tangent is taken.
    Without one (reverse mode), each launch (:class:`_Launch`) is kept in
    ``launches`` until the caller has the band's adjoints and empties it.
    ``read``, where given, reads each launch's radiance and alpha from the
    render's kept launches (:mod:`.kept_launches`) instead of tracing."""

    def __init__(self, tracer, sensor, progress=None, indirect_samples=0, tangent=None,
                 read=None):
        super().__init__(tracer, sensor, progress, indirect_samples)
        self.tangent = tangent
        self.read = read
        self.launches = []

    def __call__(self, positions, keys, lens=None, share=1):
        if self.read is None:
            radiance, alpha = super().__call__(positions, keys, lens, share)
        else:
            radiance, alpha = self.read(keys)
            self._report(dr.width(keys), dr.width(keys))
        leaf = mi.Color3f(radiance)
        dr.enable_grad(leaf)
        if self.tangent is not None:
            dr.set_grad(leaf, self.tangent(positions, keys, lens))
        else:
            self.launches.append(_Launch(positions, keys, lens, leaf))
        return leaf, alpha


def _total(counts: mi.UInt32) -> int:
    return int(counts.numpy().sum(dtype=np.int64))


def sample_adjoints(launches: list, radiance: mi.Color3f, adjoint: mi.Color3f):
    """The camera samples of ``launches`` (positions, keys, lens points or
    ``None``) and each one's adjoint, from the ``adjoint`` of the band's
    pixel ``radiance`` that the sampler made of them."""
    with dr.resume_grad():
        dr.set_grad(radiance, adjoint)
        dr.enqueue(dr.ADMode.Backward, radiance)
        dr.traverse(dr.ADMode.Backward)
        adjoints = [dr.detach(dr.grad(launch.radiance)) for launch in launches]
    lens = None if launches[0].lens is None else concat([l.lens for l in launches])
    samples = (concat([l.positions for l in launches]), concat([l.keys for l in launches]),
               lens, concat(adjoints))
    # Evaluated here, with the threads that recorded the scatter-adds of
    # this traversal (see ``_one_thread``).
    dr.eval(samples)
    return samples


def band_tangent(radiance: mi.Color3f) -> mi.Color3f:
    """The tangent of a band's pixel ``radiance`` from those of its samples."""
    with dr.resume_grad():
        dr.forward_to(radiance)
        return dr.detach(dr.grad(radiance))
