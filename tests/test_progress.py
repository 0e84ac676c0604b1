"""The progress bar on terminals that do and do not say their size."""

import os
import pty

from mitsuba_whitted.progress import Progress


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
        shown = os.read(terminal, 4096).decode()
        progress.finish()
        stream.close()
    finally:
        os.close(terminal)
    assert "camera samples" in shown and "3/10" in shown
