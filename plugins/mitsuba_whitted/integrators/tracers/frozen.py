"""Kernels frozen with ``dr.freeze``, and traced anew if freezing fails.

A frozen function replays the kernels it recorded without running its
Python code again, which for a tracer's thousands of operations is most of
the time of a small launch. Dr.Jit 1.5 can still refuse to record some
constructions or, if misused, replay arrays of a wrong width; either way the
kernel warns once and from then on runs its function unfrozen (slower, same
result).
"""

from __future__ import annotations

import gc
import weakref
from contextlib import contextmanager

import drjit as dr
import mitsuba as mi

from ...errors import caused_by, one_sentence


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


def widths_match(outputs, width: int) -> bool:
    """Every array in ``outputs`` (nested lists, tuples, dicts, dataclasses; ``None``
    allowed) is ``width`` wide or a single value."""
    if outputs is None:
        return True
    if isinstance(outputs, dict):
        return widths_match(list(outputs.values()), width)
    if isinstance(outputs, (list, tuple)):
        return all(widths_match(item, width) for item in outputs)
    if hasattr(outputs, "__dataclass_fields__"):
        return widths_match([getattr(outputs, name) for name in outputs.__dataclass_fields__],
                            width)
    return dr.width(outputs) in (width, 1)


class FrozenKernel:
    """``kernel(width, *args, **kwargs)``: the outputs of ``method(*args,
    *fixed, **kwargs)``, which must be ``width`` wide. JIT data the method
    reads must come in through its arguments (a frozen function sees
    nothing else).

    ``method`` is a bound method of the object that keeps this kernel, held
    weakly: a strong reference back would make a cycle, which only Python's
    cycle collector frees, at whatever moment it happens to run, and
    Mitsuba objects freed in the middle of another render's tracing crash
    the process. Without the cycle, a scene and its tracer go as soon as
    the last reference to them does."""

    def __init__(self, method, name: str, *fixed, undo=None, fallback=None):
        weak = weakref.WeakMethod(method)

        def function(*args, **kwargs):
            return weak()(*args, *fixed, **kwargs)

        self.function = function
        self.name = name
        self.frozen = dr.freeze(function)
        self.enabled = True
        #: A bound method too (held weakly, for the same reason), called
        #: after a frozen call failed and before the method runs unfrozen: a
        #: failed recording has already run the kernels, so whatever they
        #: add to their arguments must be taken back first.
        self.undo = weakref.WeakMethod(undo) if undo is not None else None
        #: ``(bound method, what it does)``: run with the same arguments
        #: instead of the method unfrozen, once freezing failed.
        self.fallback = None
        if fallback is not None:
            self.fallback = (weakref.WeakMethod(fallback[0]), fallback[1])

    def __call__(self, width: int, *args, **kwargs):
        if self.enabled:
            try:
                with _no_garbage_collection():
                    outputs = self.frozen(*args, **kwargs)
                if widths_match(outputs, width):
                    return outputs
                problem = "a replay returned arrays of the wrong width"
            except RuntimeError as error:
                # Ctrl-C during a recording reaches here wrapped by Dr.Jit:
                # it stops the render, and freezing stays on.
                if caused_by(error, KeyboardInterrupt):
                    raise
                problem = one_sentence(error).rstrip(".")
            self._disable(problem)
        if self.fallback is not None:
            return self.fallback[0]()(*args, **kwargs)
        return self.function(*args, **kwargs)

    def _disable(self, problem: str) -> None:
        """Stop freezing, say so, and take back what the failed call added.
        A kernel with a fallback planned for the failure (a sensor Dr.Jit
        cannot freeze) says so as information; any other failure is a
        warning: the render goes on, slower."""
        self.enabled = False
        if self.fallback is not None:
            mi.Log(mi.LogLevel.Info, f"whitted: {self.fallback[1]} ({problem}).")
        else:
            mi.Log(mi.LogLevel.Warn, f"whitted: tracing without frozen kernels in the "
                                     f"{self.name}, which is slower ({problem}).")
        if self.undo is not None:
            self.undo()()
