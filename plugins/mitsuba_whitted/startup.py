"""What the ``mitsuba-whitted`` command does first, before the package
imports Dr.Jit, LLVM and Mitsuba (about half a second, and most of the
address space the command needs).

This is the package's first import: ``mitsuba-whitted`` imports
``mitsuba_whitted.cli``, Python runs the package's ``__init__`` before that
module, and its first statement imports this one. In a command, importing
it makes Ctrl-C end the process with one line (exit code 130) at once;
:func:`start`, called next, refuses an address-space limit (``ulimit -v``)
below what the imports map and turns any error that escapes before a
command takes over (one raised by an import) into one sentence.

It imports only what Python has loaded before it runs any script:
``signal`` would import ``enum``, ``functools`` and more, some 20 ms in
which Ctrl-C ends in a traceback. ``_signal`` is the part of ``signal``
built into the interpreter. A signal that comes earlier still, while
Python starts or finds the package, ends the process as Python ends it.
"""

import _signal
import os
import sys

#: The signals that stop a command, and what it says when one does.
STOPPING = {_signal.SIGINT: "interrupted", _signal.SIGTERM: "terminated",
            _signal.SIGHUP: "hung up", _signal.SIGQUIT: "quit"}

#: Address space that importing Dr.Jit, LLVM, Mitsuba, OpenImageIO and
#: NumPy maps before a command can run, besides :data:`THREAD_ADDRESS_SPACE`
#: per processor; measured on Linux x86-64 with LLVM 19 (a render of 32 x
#: 32 pixels needs 722 MiB on 2 processors), with a margin.
BASE_ADDRESS_SPACE = 768 << 20
#: Address space per processor: Dr.Jit starts a thread on each, with its
#: stack and its share of the allocator's arenas (measured: 10 to 35 MiB).
THREAD_ADDRESS_SPACE = 32 << 20


def exit_code(signum: int) -> int:
    """What shells report for a process that a signal stopped."""
    return 128 + signum


def interrupted_line(program: str, signum: int = _signal.SIGINT) -> str:
    """What a command says, and all it says, when Ctrl-C (or ``signum``)
    ends it."""
    return f"{program}: {STOPPING[signum]}.\n"


def started_as(module: str, script: str) -> bool:
    """Whether this process is a command: ``script`` (a console script) or
    ``python -m module``."""
    argv = sys.orig_argv
    return (os.path.basename(sys.argv[0]) == script
            or (module in argv and argv[argv.index(module) - 1] == "-m"))


def start() -> None:
    """The rest of the command's start-up, once Ctrl-C is handled: the
    standard streams, the address-space limit and the errors of the
    start-up (see the module's docstring)."""
    # Imported here, after Ctrl-C is handled: they import much of the
    # standard library.
    from . import system
    from .errors import one_sentence

    system.open_standard_streams()
    sys.excepthook = lambda kind, error, traceback: end_with(one_sentence(error), 2)
    check_address_space(PROGRAM)


def end_quietly_on_ctrl_c(program: str) -> None:
    """Until a command's :class:`~.interrupt.InterruptGuard` takes over,
    Ctrl-C ends the process at once with one line: nothing is written yet,
    and a ``KeyboardInterrupt`` raised while Python imports Dr.Jit and
    Mitsuba ends in a traceback (or in a half-imported module's
    ``NameError``)."""
    def end(signum, frame):
        os.write(2, interrupted_line(program).encode())
        os._exit(exit_code(_signal.SIGINT))

    _signal.signal(_signal.SIGINT, end)


def end_with(sentence: str, code: int) -> None:
    """Say ``sentence`` on stderr and end the process with ``code`` at once:
    Python's own exit would finalise a Dr.Jit whose import failed half-way,
    which ends in a fatal error."""
    try:
        sys.stderr.write(sentence + "\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        pass  # stderr is gone: the exit code still tells
    os._exit(code)


def check_address_space(program: str) -> None:
    """End the process with one sentence and exit code 2 if its
    address-space limit is below what the imports need (see
    :data:`BASE_ADDRESS_SPACE`). Checked before the imports, because they
    fail under such a limit in ways no ``try`` can catch: the loader's
    "failed to map segment" half-way through Dr.Jit's initialisation ends
    the process in a fatal error, OpenBLAS aborts when it cannot map its
    buffers, a thread's ``std::bad_alloc`` terminates the process."""
    from .system import address_space_limit, describe_limit, size_text

    limit = address_space_limit()
    processors = os.cpu_count() or 1
    needed = BASE_ADDRESS_SPACE + THREAD_ADDRESS_SPACE * processors
    if limit is not None and limit < needed:
        end_with(f"{program}: {describe_limit(limit)} is below the {size_text(needed)} that "
                 f"Dr.Jit, LLVM and Mitsuba map when they load on {processors} processors; "
                 "raise the limit or remove it.", 2)


PROGRAM = "mitsuba-whitted"
#: Whether this process is the ``mitsuba-whitted`` command.
COMMAND = started_as("mitsuba_whitted.cli", PROGRAM)
if COMMAND:
    end_quietly_on_ctrl_c(PROGRAM)
