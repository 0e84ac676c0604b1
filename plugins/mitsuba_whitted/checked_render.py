"""``mi.render`` that raises what the user must read.

Mitsuba's ``mi.render`` runs the integrator inside a Dr.Jit custom
operation, which wraps whatever the integrator raises in a
``RuntimeError`` whose own message only points at it
("drjit.custom(...): error while performing a custom differentiable
operation. (see above)"): a user who catches a refusal of ``whitted``
would read that, and Ctrl-C would arrive as a ``RuntimeError``. Before its
operation, ``mi.render`` fails with nanobind's ``TypeError`` on a seed
that 32 bits do not hold, and with a bare ``AssertionError`` on a scene
loaded in another variant.

Importing the package puts :func:`render` in ``mi.render``'s place: it
checks the scene and the seeds first, and raises this package's errors and
``KeyboardInterrupt`` themselves, unwrapped. Everything else passes
through as Mitsuba raises it. One render runs at a time
(:mod:`.render_lock`): calls from other threads wait for their turn.
"""

from __future__ import annotations

import functools
import inspect
import signal
import sys

import mitsuba as mi

from .errors import ParameterError, VariantError, own_error, raising_own
from .parameters import check_seed
from .render_lock import one_at_a_time

#: The seeds ``mi.render`` takes, which it hashes as 32-bit integers.
SEEDS = ("seed", "seed_grad")


def checked(mitsuba_render):
    """:func:`render` around Mitsuba's ``mitsuba_render``."""
    signature = inspect.signature(mitsuba_render)

    @functools.wraps(mitsuba_render)
    @one_at_a_time
    def render(*args, **kwargs):
        arguments = signature.bind(*args, **kwargs).arguments
        _check_scene(arguments.get("scene"))
        for name in SEEDS:
            if name in arguments:
                check_seed(arguments[name], "mi.render", name)
        try:
            with raising_own(own_error):
                return mitsuba_render(*args, **kwargs)
        finally:
            _interrupt_waits_again()

    return render


def _interrupt_waits_again() -> None:
    """Let Ctrl-C interrupt the waits of Python's locks again (a thread's
    ``join``, a render waiting for its turn): the render of one of
    Mitsuba's own integrators installs its own SIGINT handler and puts
    Python's back with ``signal()``, whose SA_RESTART resumes a wait that
    the signal interrupted, so ``KeyboardInterrupt`` came only once the
    wait ended."""
    signal.siginterrupt(signal.SIGINT, True)


def _check_scene(scene) -> None:
    """Refuse a scene of another variant (Mitsuba's classes are made anew
    for each, all named ``mitsuba.Scene``), in a sentence that names both."""
    if isinstance(scene, mi.Scene):
        return
    variant = next((name for name in mi.variants()
                    if getattr(sys.modules.get(f"mitsuba.{name}"), "Scene", None) is type(scene)),
                   None)
    if variant is not None:
        raise VariantError(
            f"the scene was loaded in variant '{variant}', and the active variant is "
            f"'{mi.variant()}'; load it again, or call mi.set_variant('{variant}') first.",
            "mi.render")
    raise ParameterError("mi.render", "scene", f"must be a mi.Scene of variant "
                         f"'{mi.variant()}' (got a {type(scene).__name__})")
