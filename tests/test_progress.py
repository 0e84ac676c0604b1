"""The progress bar on terminals, with and without a size, and off them."""

import io
import os
import pty
import select

from mitsuba_whitted.progress import Progress


def shown_on(terminal: int, awaited: str, seconds: float = 10.0) -> str:
    """What the pseudo-terminal ``terminal`` shows, read until ``awaited``
    appears or ``seconds`` pass: the kernel hands a write on to the other
    end a moment after it returns."""
    shown = ""
    while awaited not in shown and select.select([terminal], [], [], seconds)[0]:
        shown += os.read(terminal, 4096).decode()
    return shown


def test_a_terminal_without_a_size_still_shows_the_bar():
    """A new pseudo-terminal has 0 x 0 cells until someone sets a size;
    tqdm then hid its bar below the zero rows and wrote nothing."""
    terminal, child_end = pty.openpty()
    try:
        stream = os.fdopen(child_end, "w", buffering=1)
        assert os.get_terminal_size(child_end).lines == 0
        progress = Progress(stream, min_interval=0)
        progress(3, 10, "camera samples")
        stream.flush()
        shown = shown_on(terminal, "3/10")
        progress.finish()
        stream.close()
    finally:
        os.close(terminal)
    assert "camera samples" in shown and "3/10" in shown


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_progress_bar_shows_the_count_and_the_time_left():
    stream = _Terminal()
    progress = Progress(stream, min_interval=0)
    for done in range(1, 4):
        progress(done, 8, "reference passes")
    progress.finish()
    text = stream.getvalue()
    assert "reference passes" in text and "3/8" in text
    assert "<" in text  # elapsed<remaining


def test_progress_bar_is_silent_off_a_terminal():
    stream = io.StringIO()
    progress = Progress(stream)
    progress(1, 2, "passes")
    progress.finish()
    assert stream.getvalue() == ""
