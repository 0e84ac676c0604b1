"""Running a function as a command: its warnings as plain lines on stderr,
any error as one sentence, Ctrl-C and other signals as one line with the
shell's exit code, no partial file either way. ``mitsuba-whitted`` and the
validation scripts share it, with the argument parser and the argument
types below."""

from __future__ import annotations

import argparse
import re
import select
import signal
import sys
import warnings
from contextlib import contextmanager, suppress

import mitsuba as mi

from . import files
from .errors import caused_by, one_sentence
from .interrupt import InterruptGuard
from .startup import exit_code, interrupted_line
from .system import to_null


class CommandParser(argparse.ArgumentParser):
    """Bad arguments in one line (argparse prints its usage first)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: {message}; '{self.prog} --help' lists the options.\n")


def count(text: str) -> int:
    """An argument's type: a whole number of at least 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number of at least 1, got '{text}'")
    return value


def add_cluster_options(parser: argparse.ArgumentParser) -> None:
    """Where the tasks run: in this process unless one of these is given."""
    parser.add_argument("--workers", type=count, metavar="N",
                        help="run the tasks on N Ray workers (a local Ray unless --cluster "
                        "or $RAY_ADDRESS)")
    parser.add_argument("--cluster", metavar="ADDRESS",
                        help="run the tasks on the Ray cluster at ADDRESS (HOST:PORT; "
                        "default $RAY_ADDRESS)")


def run_command(function, *args, program: str = "mitsuba-whitted") -> int:
    """``function(*args)`` as a command: its warnings on stderr in plain
    lines, any error as one sentence (exit code 2), Ctrl-C as one line and
    exit code 130 (143 for SIGTERM, ...; see :mod:`.interrupt`), no partial
    file either way. Output into a pipe that its reader has closed ends
    the command quietly with 141, as SIGPIPE would."""
    def last_words(signum):
        files.discard_pending()
        _say(erase_line(sys.stderr) + interrupted_line(program, signum))

    with InterruptGuard(last_words) as guard:
        try:
            with plain_warnings():
                code = function(*args)
            sys.stdout.flush()  # a closed pipe shows here, not at the exit
            return code
        except SystemExit:
            raise
        except BaseException as error:
            if guard.requested.is_set() or caused_by(error, KeyboardInterrupt):
                guard.stop()
            if caused_by(error, BrokenPipeError) and _silence_closed_pipes():
                return exit_code(signal.SIGPIPE)
            _say(one_sentence(error) + "\n")
    return 2


def erase_line(stream) -> str:
    """What erases a progress line on a terminal (nothing elsewhere)."""
    return "\r" + " " * 79 + "\r" if stream.isatty() else ""


def _say(text: str) -> None:
    """``text`` on stderr, if anything still reads it (a terminal that hung
    up, a closed pipe: the command ends all the same)."""
    with suppress(OSError, ValueError):
        sys.stderr.write(text)
        sys.stderr.flush()


def _silence_closed_pipes() -> bool:
    """Whether stdout or stderr is a pipe whose reader has gone; each such
    stream then writes to /dev/null, so that nothing more fails on it
    (Python flushes them at the exit)."""
    closed = [stream.fileno() for stream in (sys.stdout, sys.stderr) if _reader_gone(stream)]
    for descriptor in closed:
        to_null(descriptor)
    return bool(closed)


def _reader_gone(stream) -> bool:
    """Whether ``stream`` is a pipe or socket without a reader: the system
    then reports an error condition on it."""
    try:
        poller = select.poll()
        poller.register(stream.fileno(), select.POLLOUT)
        return any(events & select.POLLERR for _, events in poller.poll(0))
    except (AttributeError, OSError, ValueError):
        return False


@contextmanager
def plain_warnings():
    """Mitsuba's log and Python's warnings as plain lines on stderr."""
    logger = mi.logger()
    appenders = [logger.appender(i) for i in range(logger.appender_count())]
    formatter = logger.formatter()
    logger.clear_appenders()
    logger.add_appender(_StderrAppender())
    logger.set_formatter(_PlainFormatter())
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        try:
            yield
        finally:
            logger.clear_appenders()
            for appender in appenders:
                logger.add_appender(appender)
            logger.set_formatter(formatter)


class _PlainFormatter(mi.Formatter):
    """"warning: MESSAGE", without the date, thread and source location."""

    #: Mitsuba's ``mi.Log`` puts the calling Python function before the message.
    CALLER = re.compile(r"^[\w<>]+(?:\(\))?: ")

    def format(self, level, class_name, file_name, line, message):
        if file_name.endswith(".py"):
            message = self.CALLER.sub("", message)
        word = "warning" if level == mi.LogLevel.Warn else level.name.lower()
        return f"{word}: {message}"


class _StderrAppender(mi.Appender):
    """Log lines on stderr (Mitsuba's own appender writes them to stdout,
    in colour even where it is not a terminal)."""

    #: Logged by Mitsuba's own integrators on Ctrl-C; the command says
    #: that it was interrupted in a line of its own.
    WINDING_DOWN = "Received interrupt signal, winding down"

    def append(self, level, text):
        if self.WINDING_DOWN not in text:
            sys.stderr.write(text + "\n")
            sys.stderr.flush()

    def log_progress(self, progress, name, formatted, eta, ptr=None):
        pass  # the commands show their own progress


def _show_warning(message, category, filename, lineno, file=None, line=None):
    sys.stderr.write(f"warning: {message}\n")
