"""One render at a time in a process.

Renders in several Python threads at once are not safe in Mitsuba 3.9.1:
four threads rendering two scenes failed with Dr.Jit's errors in every run
and now and then aborted the process (``jit_var(...): unknown variable!``),
with Mitsuba's own ``path`` as well as with ``whitted``, which also keeps
its last render's tracer (and its frozen kernels) for the next one. So
``mi.render``, as importing the package wraps it, and ``whitted``'s render
methods, which a user may call directly, hold one re-entrant lock: other
threads wait for their turn, and a render inside a render (a progress
callback that renders, the package's own nested renders) goes on in the
thread that holds the lock.

A thread waiting for the lock stays interruptible: Python's lock waits
return when a signal comes (once ``mi.render`` has undone the SA_RESTART
that Mitsuba's own integrators leave, see :mod:`.checked_render`), so
Ctrl-C in the main thread raises ``KeyboardInterrupt`` there at once,
whichever thread renders.

Dr.Jit orders the kernels of all threads in one queue per device, but it
refuses to build a kernel in one thread from arrays that another thread
computed (lazily) in a later "scope" ("the scope ID of predecessors must be
lower"): a scene loaded in a worker thread and rendered in the main thread
failed so. A thread that takes the lock therefore starts a new scope, later
than every array made so far. Its render then gives the same bits as in
any other thread. Dr.Jit's JIT flags belong to the thread that sets them
(``dr.set_flag`` in the main thread does not reach a worker); the renders
set what they need themselves.
"""

from __future__ import annotations

import functools
import threading
from contextlib import contextmanager

import drjit as dr
import mitsuba as mi

_RENDERING = threading.RLock()
#: How deep this thread is in the lock (a render inside a render: 2).
_held = threading.local()


def one_at_a_time(function):
    """``function``, run while this thread holds the render lock."""
    @functools.wraps(function)
    def serialised(*args, **kwargs):
        with _holding():
            return function(*args, **kwargs)

    return serialised


@contextmanager
def _holding():
    with _RENDERING:
        depth = getattr(_held, "depth", 0)
        try:
            _held.depth = depth + 1
            if depth == 0:
                _new_jit_scope()
            yield
        finally:
            _held.depth = depth


def _new_jit_scope() -> None:
    """Let this thread use the arrays every other thread has made."""
    backend = dr.backend_v(mi.Float)
    if backend != dr.JitBackend.Invalid:
        dr.detail.new_scope(backend)
