"""Ctrl-C: every command stops within two seconds, at any size and in any
anti-aliasing mode, says so in one line, exits with 130 and leaves no
partial file.

Each command runs as a user runs it, its stderr on a terminal (a pty); the
signal is sent 1 s after its first output there (the progress display, or
the first progress line), so that the work, not Python's start-up, is what
is interrupted."""

import fcntl
import hashlib
import os
import pty
import re
import select
import signal
import subprocess
import sys
import termios
import time
import tty
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsuba_whitted.integrators.tracers.frozen import FrozenKernel
from mitsuba_whitted.compare.scene_report import FOLDER_MARK
from mitsuba_whitted.interrupt import STOPPING
from validation.scenes import REPORT_SCENE, ROOT



def interrupted(args, started_after: float = 1.0, signum: int = signal.SIGINT, env=None):
    """Run ``python args`` with stderr on a pty; SIGINT (or ``signum``)
    ``started_after`` seconds after its first output there. (exit code,
    seconds from the signal to the exit, all it wrote on stderr)."""
    terminal, child_end = pty.openpty()
    tty.setraw(child_end)  # the bytes as written: no "\r\n" for "\n"
    process = subprocess.Popen([sys.executable, *args], stdin=subprocess.DEVNULL,
                               stdout=subprocess.DEVNULL, stderr=child_end, cwd=ROOT, env=env)
    os.close(child_end)
    try:
        output = _read(terminal, until_any=True, seconds=300)
        assert output, "the command wrote nothing within 300 s"
        output += _read(terminal, seconds=started_after)
        assert process.poll() is None, "the command ended before it could be interrupted"
        sent = time.monotonic()
        process.send_signal(signum)
        code = process.wait(timeout=60)
        seconds = time.monotonic() - sent
        output += _read(terminal, seconds=0.5)
    finally:
        if process.poll() is None:
            process.kill()
        os.close(terminal)
    return code, seconds, output.decode(errors="replace")


def _read(terminal: int, seconds: float, until_any: bool = False) -> bytes:
    data = b""
    deadline = time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0 and not (until_any and data):
        if select.select([terminal], [], [], left)[0]:
            try:
                chunk = os.read(terminal, 65536)
            except OSError:  # the command ended and closed the terminal
                break
            if not chunk:
                break
            data += chunk
    return data


def last_line(output: str) -> str:
    """The last line as a terminal shows it (progress updates overwrite
    each other with carriage returns)."""
    return output.rstrip("\n").split("\n")[-1].split("\r")[-1]


def assert_stopped(code, seconds, output, program="mitsuba-whitted", signum=signal.SIGINT):
    assert code == 128 + signum, output
    assert seconds < 2, f"{seconds:.2f} s from the signal to the end"
    assert last_line(output) == f"{program}: {STOPPING[signum]}."
    assert "Traceback" not in output and "leak" not in output, output


@pytest.fixture
def samples_scene(tmp_path):
    """The report's scene with its anti-aliasing samples as defaults too."""
    text = REPORT_SCENE.read_text().replace("../textures/", f"{ROOT}/textures/")
    text = text.replace('<default name="res" value="600"/>',
                        '<default name="res" value="600"/>'
                        '<default name="aa_samples" value="2"/>')
    text = text.replace('<integer name="aa_max_depth" value="$aa_max_depth"/>',
                        '<integer name="aa_max_depth" value="$aa_max_depth"/>'
                        '<integer name="aa_samples" value="$aa_samples"/>')
    path = tmp_path / "scene.xml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("defines", [
    ["res=6000", "aa=none"],
    ["res=1200", "aa=grid", "aa_samples=6"],
    ["res=2000", "aa=adaptive", "aa_threshold=0.02"],
    ["res=2000", "aa=contrast", "aa_samples=8", "aa_threshold=0.05"],
], ids=["none", "grid", "adaptive", "contrast"])
def test_ctrl_c_stops_a_render(tmp_path, samples_scene, defines):
    out = tmp_path / "out"
    args = ["-m", "mitsuba_whitted.cli", "render", str(samples_scene), "-o", str(out / "x.png")]
    for define in defines:
        args += ["-D", define]
    code, seconds, output = interrupted(args)
    assert_stopped(code, seconds, output)
    assert output.count("\n") == 1, output
    assert not out.exists()


@pytest.mark.parametrize("kernels", ["cached", "compiling"])
def test_kill_stops_a_render_as_ctrl_c_does(tmp_path, samples_scene, kernels):
    """SIGTERM, as ``kill`` and job schedulers send it: exit code 143, one
    line, the user's old image as it was and no temporary beside it; also
    while Dr.Jit compiles (an empty kernel cache), when the main thread is
    in C++ and the watcher ends the process."""
    target = tmp_path / "out" / "x.png"
    target.parent.mkdir()
    target.write_bytes(b"the user's image")
    env = None
    if kernels == "compiling":
        env = dict(os.environ, HOME=str(tmp_path / "home"), XDG_CACHE_HOME=str(tmp_path / "cache"))
    code, seconds, output = interrupted(
        ["-m", "mitsuba_whitted.cli", "render", str(samples_scene), "-o", str(target),
         "-D", "res=6000", "-D", "aa=none"], signum=signal.SIGTERM, env=env)
    assert_stopped(code, seconds, output, signum=signal.SIGTERM)
    assert output.count("\n") == 1, output
    assert target.read_bytes() == b"the user's image"
    assert [p.name for p in target.parent.iterdir()] == ["x.png"]


@pytest.mark.parametrize("suffix", ["png", "exr"])
@pytest.mark.parametrize("signum", [signal.SIGHUP, signal.SIGQUIT], ids=["SIGHUP", "SIGQUIT"])
def test_a_hang_up_or_ctrl_backslash_stops_a_render_as_kill_does(tmp_path, samples_scene,
                                                                  signum, suffix):
    """SIGHUP (the terminal closed, its SSH session lost) and SIGQUIT
    (Ctrl-\\) ended the process at once and left the hidden temporary
    beside the image: now the exit code is 128 plus the signal's number,
    with one line, and the old image is as it was."""
    target = tmp_path / "out" / f"x.{suffix}"
    target.parent.mkdir()
    target.write_bytes(b"the user's image")
    code, seconds, output = interrupted(
        ["-m", "mitsuba_whitted.cli", "render", str(samples_scene), "-o", str(target),
         "-D", "res=6000", "-D", "aa=none"], signum=signum)
    assert_stopped(code, seconds, output, signum=signum)
    assert target.read_bytes() == b"the user's image"
    assert [p.name for p in target.parent.iterdir()] == [target.name]


def test_a_real_hang_up_ends_the_command_without_its_last_words(tmp_path, samples_scene):
    """The command's terminal closes (its controlling terminal: the system
    sends SIGHUP): the line that would say so cannot be written any more,
    and the command must end all the same, without a temporary."""
    target = tmp_path / "x.exr"
    terminal, child_end = pty.openpty()

    def own_terminal():
        os.setsid()
        fcntl.ioctl(2, termios.TIOCSCTTY, 0)

    process = subprocess.Popen([sys.executable, "-m", "mitsuba_whitted.cli", "render",
                                str(samples_scene), "-o", str(target), "-D", "res=6000",
                                "-D", "aa=none"], stdin=subprocess.DEVNULL,
                               stdout=child_end, stderr=child_end, cwd=ROOT,
                               preexec_fn=own_terminal)
    os.close(child_end)
    try:
        assert _read(terminal, until_any=True, seconds=300), "the command wrote nothing"
        _read(terminal, seconds=1.0)
        assert process.poll() is None, "the command ended before the hang-up"
    finally:
        os.close(terminal)
    assert process.wait(timeout=60) == 128 + signal.SIGHUP
    assert list(tmp_path.iterdir()) == [samples_scene]


#: A command whose last write sends it ``SIGNAL`` ``WHEN`` (while the
#: file is written, or just after the rename that puts it in place), then
#: says that it is done, and takes longer than the watcher's grace.
LAST_WRITE = """
import os, signal, sys, time
from mitsuba_whitted import files, interrupt
from mitsuba_whitted.command import run_command

target, when, signum = sys.argv[1], sys.argv[2], int(sys.argv[3])
replace = os.replace

def replace_then_signal(source, destination):
    replace(source, destination)
    os.kill(os.getpid(), signum)

def write(file):
    file.write(b"new")
    if when == "while writing":
        os.kill(os.getpid(), signum)
        time.sleep(2)

def command():
    if when == "after the rename":
        os.replace = replace_then_signal
    with interrupt.last_write():
        files.write_atomically(target, write)
    print("written")
    time.sleep(1)
    return 0

sys.exit(run_command(command))
"""


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("when", ["while writing", "after the rename"])
def test_a_signal_at_the_last_write_stops_before_the_rename_or_not_at_all(tmp_path, when,
                                                                         signum):
    """Ctrl-C as the image was put in place gave 'rendered and written',
    then 'interrupted.' and exit code 130, with the file replaced. Before
    the rename, the command stops and the old file stays; after it, the
    command has succeeded and ends with 0."""
    target = tmp_path / "x.png"
    target.write_bytes(b"old")
    result = subprocess.run([sys.executable, "-c", LAST_WRITE, str(target), when, str(signum)],
                            capture_output=True, text=True, timeout=60, cwd=ROOT)
    if when == "after the rename":
        assert (result.returncode, result.stdout, result.stderr) == (0, "written\n", "")
        assert target.read_bytes() == b"new"
    else:
        assert (result.returncode, result.stdout) == (128 + signum, "")
        assert result.stderr == f"mitsuba-whitted: {STOPPING[signum]}.\n"
        assert target.read_bytes() == b"old"
    assert list(tmp_path.iterdir()) == [target]


SLOW_STEP = ("import os, signal, time\n"
             "os.kill(os.getpid(), signal.SIGINT)\n"
             "time.sleep(0.2)\n"
             "open(os.environ['FINISHED'], 'w').close()\n")


@pytest.mark.parametrize("step", [
    "    import slow_step\n",
    "    from mitsuba_whitted.interrupt import held_off\n"
    "    with held_off():\n"
    "        exec(open(os.path.join(sys.path[-1], 'slow_step.py')).read())\n",
], ids=["import", "held off"])
def test_a_signal_during_an_import_or_a_held_off_step_lets_it_finish(tmp_path, step):
    """An exception raised in Python code that an extension runs while it
    initialises (nanobind making OpenImageIO's enums on its first import)
    ends the process in a fatal error, and one raised between making a file
    and noting it for removal leaves the file: such steps finish, and the
    command stops after them."""
    (tmp_path / "slow_step.py").write_text(SLOW_STEP)
    command = ("import os, sys, time\n"
               f"sys.path.append({str(tmp_path)!r})\n"
               "from mitsuba_whitted.command import run_command\n"
               "def work():\n" + step +
               "    time.sleep(30)\n"
               "sys.exit(run_command(work))\n")
    finished = tmp_path / "finished"
    result = subprocess.run([sys.executable, "-c", command], capture_output=True, text=True,
                            env=dict(os.environ, FINISHED=str(finished)), timeout=60)
    assert (result.returncode, result.stderr) == (130, "mitsuba-whitted: interrupted.\n")
    assert finished.exists()


@pytest.mark.parametrize("after", [0.15, 0.4])
def test_ctrl_c_while_the_command_starts(tmp_path, after):
    """While Python imports Dr.Jit and Mitsuba (about half a second), before
    the command's own handling is in place."""
    process = subprocess.Popen([sys.executable, "-m", "mitsuba_whitted.cli", "render",
                                str(REPORT_SCENE), "-o", str(tmp_path / "x.png")],
                               stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True, cwd=ROOT)
    time.sleep(after)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, stderr
    assert stderr == "mitsuba-whitted: interrupted.\n"
    assert list(tmp_path.iterdir()) == []


#: Delays (seconds) of SIGINT after the package's first module has loaded.
EARLY = (0, 0.005, 0.01, 0.025, 0.05, 0.1, 0.2)


def interrupted_early(command, delay):
    """Run ``python -X importtime command`` and send SIGINT ``delay``
    seconds after Python reports the first module of the package loaded
    (the first of the package's code has then run); its exit code and its
    stderr without the import times."""
    process = subprocess.Popen([sys.executable, "-X", "importtime", *command], cwd=ROOT,
                               stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE)
    try:
        for line in process.stderr:
            if re.search(rb"\|\s+mitsuba_whitted", line):
                break
        time.sleep(delay)
        process.send_signal(signal.SIGINT)
        _, rest = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    said = [line for line in rest.decode(errors="replace").splitlines(keepends=True)
            if not line.startswith("import time:")]
    return process.returncode, "".join(said)


@pytest.mark.parametrize("form", ["console script", "python -m"])
def test_ctrl_c_in_the_first_milliseconds_is_one_line(tmp_path, form):
    """Ctrl-C while the command starts, from its package's first module on:
    a signal during the package's first imports (``signal``'s ``enum``,
    ``platform``), before the command's handler was in place, ended in a
    traceback and Python's death by SIGINT. A signal before that, while
    Python itself starts, ends as Python ends (README, Reliability)."""
    script = Path(sys.executable).with_name("mitsuba-whitted")
    command = [str(script)] if form == "console script" else ["-m", "mitsuba_whitted.cli"]
    command += ["render", str(REPORT_SCENE), "-D", "res=16", "-o", str(tmp_path / "x.png")]
    endings = {(delay, *interrupted_early(command, delay)) for delay in EARLY for _ in range(3)}
    assert {ending for ending in endings
            if ending[1:] != (130, "mitsuba-whitted: interrupted.\n")} == set()
    assert list(tmp_path.iterdir()) == []


def test_ctrl_c_stops_compare(tmp_path):
    out = tmp_path / "out"
    code, seconds, output = interrupted(["-m", "mitsuba_whitted.cli", "compare", str(REPORT_SCENE),
                                         "--quick", "-D", "res=128", "--out", str(out)])
    assert_stopped(code, seconds, output)
    assert output.count("\n") == 1, output
    # A reference finished before the signal is a whole cache entry; the
    # folder's mark lets the next compare write there.
    for path in (p for p in out.rglob("*") if p.is_file() and p.parent != out):
        assert path.parent.name == "cache" and not path.name.startswith("."), path
        np.load(path)["image"]
    assert [p.name for p in out.iterdir() if p.is_file()] == [FOLDER_MARK]


def test_ctrl_c_stops_bench(tmp_path):
    target = tmp_path / "bench.json"
    code, seconds, output = interrupted(["-m", "mitsuba_whitted.cli", "bench", "--quick",
                                         "--json", str(target)], started_after=3.0)
    assert_stopped(code, seconds, output)
    assert list(tmp_path.iterdir()) == []


def test_ctrl_c_stops_validation_and_keeps_the_old_report():
    report = ROOT / "validation" / "report"

    def contents():
        return {p.relative_to(report): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in report.rglob("*") if p.is_file()}

    before = contents()
    code, seconds, output = interrupted(["-m", "validation.run"], started_after=3.0)
    assert_stopped(code, seconds, output, program="validation.run")
    assert contents() == before
    assert sorted(p.name for p in report.parent.iterdir() if p.name.startswith(".report")) == []


class _Tracer:
    """Whose frozen kernel is interrupted by Ctrl-C while it records."""

    def __init__(self):
        self.calls = 0
        self.kernel = FrozenKernel(self.trace, "test tracer")

    def trace(self, value):
        self.calls += 1
        if self.calls == 1:
            raise KeyboardInterrupt
        return value + 1


def test_ctrl_c_while_a_kernel_is_frozen_is_not_swallowed():
    """Dr.Jit wraps the KeyboardInterrupt in a RuntimeError, which a
    frozen kernel took for a failure to freeze: it warned, stopped
    freezing and ran the function again."""
    tracer = _Tracer()
    value = dr.arange(mi.Float, 8)
    with pytest.raises(BaseException) as raised:
        tracer.kernel(8, value)
    assert isinstance(raised.value, KeyboardInterrupt) or isinstance(
        raised.value.__cause__, KeyboardInterrupt)
    assert tracer.calls == 1 and tracer.kernel.enabled
    assert dr.all(tracer.kernel(8, value) == value + 1)
