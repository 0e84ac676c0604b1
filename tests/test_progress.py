"""The progress bar on terminals, with and without a size, and off them."""

import io
import os
import pty
import re
import select
import time

from conftest import cli
from mitsuba_whitted.progress import LINE_INTERVAL_VARIABLE, Progress
from validation.scenes import REPORT_SCENE


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


def test_off_a_terminal_short_work_says_nothing():
    stream = io.StringIO()
    progress = Progress(stream)
    progress(1, 2, "passes")
    progress.finish()
    assert stream.getvalue() == ""


def test_off_a_terminal_a_plain_line_at_intervals():
    stream = io.StringIO()
    progress = Progress(stream, line_interval=0.5)
    progress(1, 4, "reference passes")  # at once: no line yet
    time.sleep(0.6)
    progress(2, 4, "reference passes")  # an interval later: a line
    progress(3, 4, "reference passes")  # at once: none
    assert stream.getvalue() == "reference passes: 2/4 (50%), 00:00 elapsed, 00:00 left\n"


def test_a_render_into_a_pipe_says_where_it_is(tmp_path):
    env = dict(os.environ, **{LINE_INTERVAL_VARIABLE: "0.001"})
    result = cli("render", str(REPORT_SCENE), "-o", str(tmp_path / "small.exr"), "-D", "res=32",
                 env=env, check=True)
    lines = result.stderr.splitlines()
    assert lines and all(re.fullmatch(r"camera samples: \d+/\d+ \(\d+%\), .* elapsed, .* left",
                                      line) for line in lines), result.stderr
