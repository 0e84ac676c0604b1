"""A progress bar on the terminal, with the rate and the time left (tqdm)."""

from __future__ import annotations

import os
import sys

from tqdm import tqdm

#: The size tqdm is given for a terminal that does not say its own (a new
#: pseudo-terminal has none until one is set; tqdm would hide the bar below
#: its zero rows).
DEFAULT_SIZE = {"ncols": 80, "nrows": 24}


class Progress:
    """Called as ``progress(done, total, what)``; a new bar starts when the
    total changes or the count goes back. Silent when the stream is not a
    terminal."""

    def __init__(self, stream=None, min_interval: float = 0.1):
        self.stream = stream or sys.stderr
        self.min_interval = min_interval
        self.bar = None

    def __call__(self, done: int, total: int, what: str) -> None:
        if self.bar is None or total != self.bar.total or done < self.bar.n:
            self.finish()
            size = {} if _sized(self.stream) else DEFAULT_SIZE
            self.bar = tqdm(total=total, desc=what, file=self.stream, leave=False,
                            dynamic_ncols=not size, mininterval=self.min_interval,
                            disable=not self.stream.isatty(), **size)
        self.bar.set_description_str(what, refresh=False)
        self.bar.update(done - self.bar.n)

    def finish(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def _sized(stream) -> bool:
    """Whether the terminal says how large it is."""
    try:
        size = os.get_terminal_size(stream.fileno())
    except (AttributeError, OSError, ValueError):
        return False
    return size.columns > 0 and size.lines > 0
