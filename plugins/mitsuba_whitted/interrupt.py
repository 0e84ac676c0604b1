"""Ctrl-C (or a plain ``kill``, a closed terminal, Ctrl-\\) on the command
line: the process stops within about a second, says so in one line, exits
with 128 plus the signal's number (130 for SIGINT, 143 for SIGTERM, 129
for SIGHUP, 131 for SIGQUIT) and leaves no partial file. These are the
signals a terminal or a job runner sends to stop a command; SIGPIPE is
left to Python, which ignores it and raises ``BrokenPipeError`` at the
write instead (see ``command.run_command``).

A command whose last file is in place has succeeded: a signal that comes
after the rename that put it there no longer stops it, and one that came
before stops it before that rename (:func:`last_write`).

Python raises ``KeyboardInterrupt`` only when its main thread runs Python
code, and a Dr.Jit launch, an LLVM compilation or a render of Mitsuba's
own integrators keeps it in C++ for as long as they take (tens of seconds
for a large one). So a watcher thread hears the signal at once, through
``signal.set_wakeup_fd``, and gives the main thread :data:`GRACE` seconds
to unwind (its ``finally`` blocks remove temporary files); if it is still
busy then, the watcher removes the temporaries itself and ends the process.

Either way the process ends with ``os._exit``: at a normal exit Dr.Jit
would first finish the launches already queued, and report the arrays the
interrupted frames still hold as leaks.
"""

from __future__ import annotations

import io
import os
import signal
import sys
import tempfile
import threading
import time
from contextlib import contextmanager, suppress

from .startup import STOPPING, exit_code

#: Seconds the main thread has to unwind before the watcher ends the process.
GRACE = 0.5
#: Seconds before a signal that came during an import is sent again.
RETRY = 0.02


class InterruptGuard:
    """While active, a signal of :data:`STOPPING` raises
    ``KeyboardInterrupt`` once in the main thread (once an import under way
    is over) and ends the process (:meth:`stop`) at the latest
    :data:`GRACE` seconds later, unless the command has put its last file
    in place (:meth:`commit`). ``last_words(signum)`` removes what a
    stopped process must not leave behind and says that it stopped."""

    #: The guard of the command that runs now, if any.
    active: "InterruptGuard | None" = None

    def __init__(self, last_words):
        self.last_words = last_words
        self.requested = threading.Event()
        #: The signal that stopped the command (Ctrl-C's, for a
        #: ``KeyboardInterrupt`` that came from elsewhere).
        self.received = signal.SIGINT
        self._raised = False
        #: Set once the command's last file is in place.
        self.committed = False
        self._stopping = threading.Lock()

    def __enter__(self) -> "InterruptGuard":
        self._read, self._write = os.pipe()
        os.set_blocking(self._write, False)
        # Held off: a signal that comes while the guard is set up is raised
        # in the guarded block, not out of this method.
        with held_off():
            self._previous_fd = signal.set_wakeup_fd(self._write, warn_on_full_buffer=False)
            self._previous_handlers = {signum: signal.signal(signum, self._raise_once)
                                       for signum in STOPPING}
            threading.Thread(target=self._watch, name="interrupt watcher", daemon=True).start()
            InterruptGuard.active = self
        return self

    def __exit__(self, *exc) -> None:
        InterruptGuard.active = None
        for signum, handler in self._previous_handlers.items():
            signal.signal(signum, handler)
        signal.set_wakeup_fd(self._previous_fd)
        os.close(self._write)  # the watcher reads the end of the pipe and returns

    def _raise_once(self, signum, frame) -> None:
        # A second signal must not break off the clean-up the first started,
        # and none may fail a command that has succeeded.
        if self._raised or self.committed:
            return
        self._note(signum)
        # An import broken off leaves a module half made, and inside an
        # extension's initialisation (nanobind making OpenImageIO's enums)
        # the exception ends the process in a fatal error: the signal is
        # sent again a moment later, until the import (or a block that
        # holds signals off) is over.
        if _held_off or _importing(frame):
            threading.Timer(RETRY, os.kill, (os.getpid(), signum)).start()
            return
        self._raised = True
        raise KeyboardInterrupt

    def _note(self, signum: int) -> None:
        """Keep the first signal that asked the command to stop."""
        if not self.requested.is_set():
            self.received = signum
            self.requested.set()

    def _watch(self) -> None:
        try:
            while True:
                signals = os.read(self._read, 64)
                if not signals:
                    return
                stopping = [signum for signum in signals if signum in STOPPING]
                if stopping:
                    # The main thread, busy in C++, may not have run the
                    # handler that notes the signal.
                    self._note(stopping[0])
                    time.sleep(GRACE)
                    self.stop()
        finally:
            os.close(self._read)

    def stop(self) -> None:
        """``last_words(signum)``, then end the process with the signal's
        exit code; nothing once the command has committed. Called from
        both threads; the first call ends the process and the second waits
        for that."""
        with self._stopping:
            if self.committed:
                return
            # A block that keeps stderr back must not take the last line.
            _give_stderr_back()
            self.last_words(self.received)
            _flush(sys.stdout)
            _flush(sys.stderr)
            os._exit(exit_code(self.received))

    def commit(self, action) -> None:
        """``action()``, the step that completes the command (the rename of
        its last file), unless a signal has already ended the process;
        afterwards signals no longer stop it. Held off, so that no
        ``KeyboardInterrupt`` comes between the step and the commitment."""
        with held_off(), self._stopping:
            action()
            self.committed = True


#: How many :func:`held_off` blocks are running.
_held_off = 0


@contextmanager
def held_off():
    """A block that a signal does not break off (it is raised once the
    block is over): for steps that must not stop half done, such as making
    a file and noting it for removal."""
    global _held_off
    _held_off += 1
    try:
        yield
    finally:
        _held_off -= 1


#: Whether the block that writes the command's last file is running.
_last_write = False


@contextmanager
def last_write():
    """The block that writes the command's last file: the rename that puts
    it in place (:func:`put_in_place`) completes the command
    (:meth:`InterruptGuard.commit`)."""
    global _last_write
    _last_write = True
    try:
        yield
    finally:
        _last_write = False


def put_in_place(source, target) -> None:
    """``os.replace(source, target)``; in a :func:`last_write` block of a
    command, also the command's commitment."""
    guard = InterruptGuard.active
    if _last_write and guard is not None:
        guard.commit(lambda: os.replace(source, target))
    else:
        os.replace(source, target)


def _importing(frame) -> bool:
    """Whether ``frame`` runs inside an import."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


#: Descriptor 2 as it was before the :func:`stderr_kept_back` block that
#: runs now (``None`` outside one), and the lock of its exchanges.
_stderr_before: int | None = None
_stderr_exchange = threading.Lock()


@contextmanager
def stderr_kept_back():
    """What is written on descriptor 2 during the block, by C++ libraries as
    by Python, goes into a temporary file instead of the terminal; the
    ``io.StringIO`` yielded holds it once the block is over. A signal that stops
    the command gives the descriptor back before the last line."""
    caught = io.StringIO()
    with tempfile.TemporaryFile() as file:
        # The exchanges held off: a KeyboardInterrupt between a dup and its
        # note would leave stderr in the file (the watcher's stop takes the
        # lock and gives it back).
        try:
            with held_off():
                _take_stderr(file.fileno())
            yield caught
        finally:
            with held_off():
                _give_stderr_back()
        file.seek(0)
        caught.write(file.read().decode(errors="replace"))


def _take_stderr(descriptor: int) -> None:
    global _stderr_before
    with _stderr_exchange:
        _flush(sys.stderr)
        _stderr_before = os.dup(2)
        os.dup2(descriptor, 2)


def _give_stderr_back() -> None:
    """Descriptor 2 as before :func:`stderr_kept_back` (nothing outside one)."""
    global _stderr_before
    with _stderr_exchange:
        if _stderr_before is None:
            return
        _flush(sys.stderr)
        os.dup2(_stderr_before, 2)
        os.close(_stderr_before)
        _stderr_before = None


def _flush(stream) -> None:
    # Gone with the terminal (SIGHUP), or closed: nothing to keep.
    with suppress(AttributeError, OSError, ValueError):
        stream.flush()
