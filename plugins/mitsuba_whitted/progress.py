"""Where long work is: a progress bar on a terminal, with the rate and the
time left (tqdm), and elsewhere (a log, a CI job) a plain line at
intervals, so that a long command is not silent for minutes."""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass

from tqdm import tqdm

#: The size tqdm is given for a terminal that does not say its own (a new
#: pseudo-terminal has none until one is set; tqdm would hide the bar below
#: its zero rows).
DEFAULT_SIZE = {"ncols": 80, "nrows": 24}
#: A plain line, as tqdm formats it.
LINE_FORMAT = "{desc}: {n_fmt}/{total_fmt} ({percentage:.0f}%), {elapsed} elapsed, {remaining} left"
#: Seconds between plain lines unless this environment variable says
#: otherwise (a log read live may want them more often, a CI log less).
LINE_INTERVAL_VARIABLE = "MITSUBA_WHITTED_PROGRESS_SECONDS"
DEFAULT_LINE_INTERVAL = 10.0


@dataclass
class _Task:
    """The task that plain lines report on."""
    total: int
    done: int
    started: float


class Progress:
    """Called as ``progress(done, total, what)``; a new task starts when
    the total changes or the count goes back. On a terminal, a bar; on any
    other stream, a line at most every ``line_interval`` seconds, the first
    one ``line_interval`` seconds after this object is made, so that short
    work says nothing (by default :data:`LINE_INTERVAL_VARIABLE` or 10 s).
    The interval runs across tasks: work made of many short tasks is not
    silent either."""

    def __init__(self, stream=None, min_interval: float = 0.1,
                 line_interval: float | None = None):
        self.stream = stream or sys.stderr
        self.min_interval = min_interval
        self.line_interval = default_line_interval() if line_interval is None else line_interval
        self.bar = None
        self.task = None
        self.written = time.monotonic()

    def __call__(self, done: int, total: int, what: str) -> None:
        if self.stream.isatty():
            self._show_bar(done, total, what)
        else:
            self._write_line(done, total, what)

    def _show_bar(self, done: int, total: int, what: str) -> None:
        if self.bar is None or _starts_anew(done, total, self.bar.n, self.bar.total):
            self.finish()
            size = {} if _sized(self.stream) else DEFAULT_SIZE
            # Every update may redraw (at most every ``min_interval``): tqdm's
            # own guess of the updates to skip, from the last jump, would
            # let a render's first pass hide the single steps of the
            # refinement levels after it.
            self.bar = tqdm(total=total, desc=what, file=self.stream, leave=False,
                            dynamic_ncols=not size, mininterval=self.min_interval, miniters=1,
                            **size)
        self.bar.set_description_str(what, refresh=False)
        self.bar.update(done - self.bar.n)

    def _write_line(self, done: int, total: int, what: str) -> None:
        now = time.monotonic()
        if self.task is None or _starts_anew(done, total, self.task.done, self.task.total):
            self.task = _Task(total, done, started=now)
        self.task.done = done
        if now - self.written >= self.line_interval:
            self.written = now
            line = tqdm.format_meter(done, total, now - self.task.started, prefix=what,
                                     bar_format=LINE_FORMAT)
            print(line, file=self.stream, flush=True)

    def finish(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
        self.task = None


def default_line_interval() -> float:
    """Seconds between plain lines: :data:`LINE_INTERVAL_VARIABLE`, or
    :data:`DEFAULT_LINE_INTERVAL` where it is not set."""
    return float(os.environ.get(LINE_INTERVAL_VARIABLE) or DEFAULT_LINE_INTERVAL)


def _starts_anew(done: int, total: int, previous_done: int, previous_total: int) -> bool:
    """Whether a report begins a new task rather than going on with the last."""
    return total != previous_total or done < previous_done


def _sized(stream) -> bool:
    """Whether the terminal says how large it is."""
    try:
        size = os.get_terminal_size(stream.fileno())
    except (AttributeError, OSError, ValueError):
        return False
    return size.columns > 0 and size.lines > 0
