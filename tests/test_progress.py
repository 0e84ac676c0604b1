"""The progress bar on terminals, with and without a size, and off them;
a render's one count, whatever its bands and levels."""

import io
import os
import pty
import re
import select
import threading
import time

import mitsuba as mi

from conftest import cli, limit_whitted
from mitsuba_whitted.progress import LINE_INTERVAL_VARIABLE, Progress
from validation.scenes import (REPORT_SCENE, camera, diffuse, floor, integrator, point_light,
                               scene, sphere)


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
    assert lines and all(re.fullmatch(r"rendering: \d+/\d+ \(\d+%\), .* elapsed, .* left",
                                      line) for line in lines), result.stderr


def banded_adaptive_render(monkeypatch, progress) -> dict:
    """Adaptive anti-aliasing of spheres' silhouettes over a 24 x 24 film
    in bands of a few rows (as in test_render_plan), reported to
    ``progress``: the render's statistics."""
    limit_whitted(monkeypatch, band_samples=2000)
    loaded = mi.load_dict(scene(floor(), sphere((-0.6, 0, 0), 0.5, diffuse(0.8, 0.3, 0.2)),
                                sphere((0.7, 0, 0.3), 0.6, {"type": "dielectric"}),
                                point_light((1, 3, 3)), sensor=camera(origin=(0, 1, 5))))
    whitted = mi.load_dict(integrator(aa="adaptive", aa_max_depth=4, aa_threshold=0.05,
                                      aa_budget=16))
    whitted.progress = progress
    mi.render(loaded, integrator=whitted)
    return whitted.last_stats


def test_a_render_in_bands_and_levels_is_one_count_that_only_grows(monkeypatch):
    """Each band's first level and each of its refinement levels is a call
    of its own to the shader; the display hears one count over the whole
    render, from 0 to a total that does not change."""
    reports = []
    stats = banded_adaptive_render(monkeypatch, lambda *report: reports.append(report))
    assert stats["bands"] > 3 and stats["aa_levels"] > 1
    total = reports[0][1]
    assert {(report[1], report[2]) for report in reports} == {(total, "rendering")}
    done = [report[0] for report in reports]
    assert done == sorted(done) and done[0] == 0 and done[-1] == total


def test_a_render_in_bands_shows_one_bar_on_a_terminal(monkeypatch):
    """The bar a terminal shows of that render: one label, one total, a
    count that only grows to it, and the time left."""
    terminal, child_end = pty.openpty()
    shown = []
    reader = threading.Thread(target=read_until_closed, args=(terminal, shown))
    reader.start()
    try:
        with os.fdopen(child_end, "w", buffering=1) as stream:
            progress = Progress(stream, min_interval=0)
            banded_adaptive_render(monkeypatch, progress)
            progress.finish()
        reader.join(timeout=10)
    finally:
        os.close(terminal)
    text = b"".join(shown).decode()
    counts = [(int(done), int(total)) for done, total in re.findall(r"(\d+)/(\d+) \[", text)]
    assert counts and {total for _, total in counts} == {counts[0][1]}
    assert [done for done, _ in counts] == sorted(done for done, _ in counts)
    assert counts[-1][0] == counts[0][1]
    assert set(re.findall(r"(\w[\w ]*): +\d+%", text)) == {"rendering"}
    assert re.search(r"\[\d\d:\d\d<\d\d:\d\d", text)  # elapsed<remaining


def read_until_closed(terminal: int, shown: list) -> None:
    """Keep what the pseudo-terminal ``terminal`` shows in ``shown`` until
    its other end is closed, reading as it comes so that a full buffer
    never holds up the writer."""
    while True:
        try:
            chunk = os.read(terminal, 4096)
        except OSError:  # EIO: the other end is closed
            return
        if not chunk:
            return
        shown.append(chunk)
