"""Small Dr.Jit helpers shared by the wavefront code.

Python numbers that change from call to call (offsets, sizes, levels) are
passed as *opaque* values: a literal would be baked into the kernel and
every new value would compile a new kernel.
"""

from __future__ import annotations

import gc
import sys
import time

import drjit as dr
import mitsuba as mi
import numpy as np


def index_range(start: int, stop: int) -> "mi.UInt32":
    """``start, start + 1, ..., stop - 1`` without baking ``start`` into a kernel."""
    return dr.arange(mi.UInt32, stop - start) + dr.opaque(mi.UInt32, start)


def in_launches(total: int, launch: int, run, done=None) -> tuple:
    """The arrays ``run`` gives (radiance, alpha, ...) for ``total`` items,
    at most ``launch`` at a time: ``run(start, stop, part)`` gives those of
    items ``start`` to ``stop - 1``, ``part`` being their indices
    (``index_range(start, stop)``), or ``None`` where all the items fit in
    one launch, which then needs no copies in and out. Launch by launch,
    the parts are scattered into arrays of the whole, and ``done(stop)``
    is called after each."""
    if total <= launch:
        return run(0, total, None)
    wholes = None
    for start in range(0, total, launch):
        stop = min(start + launch, total)
        part = index_range(start, stop)
        parts = run(start, stop, part)
        if wholes is None:
            wholes = tuple(dr.empty(type(value), total) for value in parts)
        for whole, value in zip(wholes, parts):
            dr.scatter(whole, value, part)
        if done is not None:
            done(stop)
    return wholes


def unit_pair(value: "mi.UInt32", salt, rounds: int = 4) -> tuple:
    """Two floats in [0, 1) from a TEA hash, of ``rounds`` rounds, of
    ``value`` and ``salt`` (an ``mi.UInt32`` or a number)."""
    a, b = mi.sample_tea_32(value, mi.UInt32(salt), rounds)
    scale = 2.0 ** -32
    return mi.Float(a) * scale, mi.Float(b) * scale


def opaque_float(value: float) -> "mi.Float":
    return dr.opaque(mi.Float, value)


#: Blocks up to this size are read as packets and summed in the kernel that
#: uses the sums; larger ones by ``dr.block_sum``.
GATHERED_BLOCK = 16


def sum_blocks(values, block: int):
    """Sum of each run of ``block`` consecutive entries, in a fixed order
    (deterministic, unlike atomic scatter-adds).

    ``dr.block_sum`` evaluates its input and runs a reduction of its own, on
    one thread. A small block is read instead as one packet per run (a
    gather into a dynamically sized array reads consecutive entries
    together, far cheaper than one gather per entry), and its sum becomes
    part of whatever kernel uses it. Large blocks stay with
    ``dr.block_sum``, which compiles in constant time, where the compile
    time of an unrolled sum grows steeply with the block."""
    values = full_width(values)
    if block > GATHERED_BLOCK:
        return dr.block_sum(values, block)
    if dr.depth_v(values) > 1:
        return type(values)(*[_sum_runs(component, block) for component in values])
    return _sum_runs(values, block)


def full_width(values, width: int | None = None):
    """``values`` with every component ``width`` wide (default: as wide as
    the widest). A component broadcast from width 1 (``Color3f(x, y,
    0.5)``, or all of them where a scene has nothing to shade) would be read
    out of bounds by a gather and returned unsummed by ``dr.block_sum``;
    adding full-width zeros widens it, and leaves a full-width one as it
    is."""
    return values + dr.zeros(type(values), dr.width(values) if width is None else width)


def concat(parts: list):
    """The entries of ``parts`` (arrays of one type, flat or nested such as
    ``Point2f``) one after another."""
    if dr.depth_v(parts[0]) > 1:
        return type(parts[0])(*[dr.concat([part[axis] for part in parts])
                                for axis in range(len(parts[0]))])
    return dr.concat(parts)


#: The dynamically sized array of each flat type: its gathers read a packet.
_PACKET_TYPES = {dr.VarType.Float32: "ArrayXf", dr.VarType.Float64: "ArrayXf64",
                 dr.VarType.UInt32: "ArrayXu", dr.VarType.Int32: "ArrayXi"}


def read_runs(flat, block: int) -> list:
    """The runs of ``block`` consecutive entries of a flat array, each read
    as one packet: entry ``k`` of every run, for k = 0 ... block - 1."""
    runs = dr.width(flat) // block
    packet_type = getattr(sys.modules[type(flat).__module__], _PACKET_TYPES[dr.type_v(flat)])
    parts = dr.gather(packet_type, flat, dr.arange(mi.UInt32, runs), shape=(block, runs))
    return [parts[offset] for offset in range(block)]


def _sum_runs(flat, block: int):
    """``sum_blocks`` of a flat array, each run summed from its first entry
    to its last."""
    parts = read_runs(flat, block)
    total = parts[0]
    for part in parts[1:]:
        total = total + part
    return total


#: The alignment of Dr.Jit's own allocations (``posix_memalign(64)``).
ALIGNMENT = 64

#: NumPy element type of each flat Dr.Jit array type.
_NUMPY_TYPES = {dr.VarType.Float32: np.float32, dr.VarType.Float64: np.float64,
                dr.VarType.UInt32: np.uint32, dr.VarType.Int32: np.int32,
                dr.VarType.Bool: np.bool_}


def device_array(array_type, values: np.ndarray):
    """A flat Dr.Jit array holding ``values``, in memory Dr.Jit allocated.

    On the LLVM backend, ``array_type(values)`` maps NumPy's memory instead
    of copying it, and a plugin must not keep such an array:

    - a frozen kernel recognises an array it reads through a virtual call
      (a mesh's vertices, a texture's placement) only if Dr.Jit allocated
      it; a mapped one is recorded as a fixed address, so a replay after a
      parameter update reads the old buffer, or freed memory;
    - the buffer is aligned only as NumPy happened to allocate it, and
      Dr.Jit emits other code for an unaligned one, so kernels would differ
      from process to process and miss the kernel cache.

    The copy is a gather, whose code does not depend on the source's
    alignment; its index is opaque, as Dr.Jit elides a gather by a plain
    ``arange``. The caller may change ``values`` once this returns."""
    flat = np.ascontiguousarray(values, dtype=_NUMPY_TYPES[dr.type_v(array_type)]).ravel()
    mapped = array_type(flat)
    owned = dr.gather(array_type, mapped, index_range(0, len(flat)))
    dr.eval(owned)
    dr.sync_thread()  # the copy runs asynchronously; ``flat`` must outlive it
    return owned


def to_int(value) -> int:
    """A count kept lazily on the device (size-1 array) or on the host."""
    return int(value[0]) if dr.is_array_v(value) else int(value)


def timed(function, repeats: int):
    """The last result of ``repeats`` calls of ``function`` and the wall time
    of each call; the clock stops only after ``dr.sync_thread()``, since a
    call may return before the work it launched has run."""
    result, times = None, []
    for _ in range(repeats):
        start = time.perf_counter()
        result = function()
        dr.sync_thread()
        times.append(time.perf_counter() - start)
    return result, times


def release_scenes() -> None:
    """Free the scenes measured so far, and the memory cached for them.

    Every call of a frozen kernel traverses all live instances of the
    scene's plugin types, not only the scene's own, and the virtual calls
    of Mitsuba's own integrators reach every live instance too, so scenes
    kept alive (a cycle of references holds one until the collector runs)
    would slow every later measurement; so would the memory cached from a
    large render."""
    gc.collect()
    dr.flush_malloc_cache()
