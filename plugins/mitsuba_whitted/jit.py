"""Small Dr.Jit helpers shared by the wavefront code.

Python numbers that change from call to call (offsets, sizes, levels) are
passed as *opaque* values: a literal would be baked into the kernel and
every new value would compile a new kernel.
"""

from __future__ import annotations

import time

import drjit as dr
import mitsuba as mi


def index_range(start: int, stop: int) -> "mi.UInt32":
    """``start, start + 1, ..., stop - 1`` without baking ``start`` into a kernel."""
    return dr.arange(mi.UInt32, stop - start) + dr.opaque(mi.UInt32, start)


def opaque_float(value: float) -> "mi.Float":
    return dr.opaque(mi.Float, value)


def sum_blocks(values, block: int):
    """Sum of each run of ``block`` consecutive entries, in a fixed order
    (deterministic, unlike atomic scatter-adds). ``dr.block_sum`` compiles
    in constant time, where an unrolled sum of ``block`` gathers took 0.4 s
    to compile at 64 and 41 s at 1024."""
    # A component broadcast from width 1 would be returned unsummed:
    # adding full-width zeros gives every component the full width.
    return dr.block_sum(values + dr.zeros(type(values), dr.width(values)), block)


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
