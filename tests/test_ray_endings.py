"""A command on Ray that a signal stops ends as it does without Ray: in the
package's one line and exit code, with nothing of Ray's before it (its C++
core's stack dump on SIGTERM, its log of a join under way)."""

import contextlib
import importlib.util
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mitsuba_whitted.startup import exit_code, interrupted_line
from validation.scenes import ROOT

if importlib.util.find_spec("ray") is None:
    pytest.skip("Ray is not installed (pip install 'mitsuba-whitted[cluster]')",
                allow_module_level=True)

GLASS = ROOT / "scenes" / "cases" / "glass_spheres.xml"
#: Seconds any command of these tests may take.
COMMAND_SECONDS = 300


@contextlib.contextmanager
def _running(*args):
    """``mitsuba-whitted *args`` in a process of its own, its stderr in a
    pipe; killed at the end of the block if it still runs."""
    env = dict(os.environ)
    env.pop("RAY_ADDRESS", None)
    job = subprocess.Popen([sys.executable, "-m", "mitsuba_whitted.cli", *args], cwd=ROOT,
                           env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, text=True)
    try:
        yield job
    finally:
        if job.poll() is None:
            job.kill()
            job.wait()


def _wait_for_a_render_task(job: subprocess.Popen) -> None:
    """Until a worker of the local Ray that ``job`` started runs a render
    task (Ray titles a worker's process with the function it runs)."""
    import psutil

    deadline = time.monotonic() + COMMAND_SECONDS
    while job.poll() is None and time.monotonic() < deadline:
        for process in psutil.Process(job.pid).children(recursive=True):
            with contextlib.suppress(psutil.Error):
                if " ".join(process.cmdline()).startswith("ray::render_remote"):
                    return
        time.sleep(0.05)
    pytest.fail("no render task was seen running")


def _wait_for_stderr_kept_back(job: subprocess.Popen) -> None:
    """Until ``job``'s descriptor 2 is no longer the pipe it was started
    with (Linux names it in /proc). The pipe is named from this end: read
    from ``job``'s side, it may already be kept back."""
    stderr = Path(f"/proc/{job.pid}/fd/2")
    started_with = f"pipe:[{os.fstat(job.stderr.fileno()).st_ino}]"
    deadline = time.monotonic() + COMMAND_SECONDS
    while job.poll() is None and time.monotonic() < deadline:
        with contextlib.suppress(OSError):
            if os.readlink(stderr) != started_with:
                return
        time.sleep(0.05)
    pytest.fail("the command's stderr was not seen kept back")


def _stopped(job: subprocess.Popen, signum: int) -> str:
    """Send ``signum`` to ``job``; all it wrote on stderr until it ended."""
    job.send_signal(signum)
    return job.communicate(timeout=60)[1]


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP],
                         ids=["SIGTERM", "SIGINT", "SIGHUP"])
def test_a_signal_during_a_job_on_a_local_ray_ends_in_one_line(tmp_path, signum):
    """Ray's C++ core, once this process has joined, handles SIGTERM itself
    (a stack dump, then the signal passed on); the command takes the
    signals that stop it back."""
    with _running("compare", str(GLASS), "--quick", "-D", "res=16", "--reference-spp", "4000000",
                  "--out", str(tmp_path / "out"), "--workers", "2") as job:
        _wait_for_a_render_task(job)
        stderr = _stopped(job, signum)
    assert job.returncode == exit_code(signum), stderr
    assert stderr == interrupted_line("mitsuba-whitted", signum)


def test_ctrl_c_while_joining_a_cluster_ends_in_one_line(tmp_path):
    """While the command joins a cluster, stderr is kept from the terminal
    (Ray's C++ core logs each attempt there); Ctrl-C then, while Ray holds
    the main thread in C++, still ends in the command's line, on the
    terminal. The address accepts connections and answers nothing, as a
    server that is not Ray's."""
    with socket.create_server(("127.0.0.1", 0)) as silent:
        silent.settimeout(COMMAND_SECONDS)
        address = f"127.0.0.1:{silent.getsockname()[1]}"
        with _running("render-many", str(GLASS), "--out", str(tmp_path / "out"),
                      "--cluster", address) as job:
            silent.accept()[0].close()  # the command's check that the address answers
            _wait_for_stderr_kept_back(job)
            stderr = _stopped(job, signal.SIGINT)
    assert job.returncode == exit_code(signal.SIGINT), stderr
    assert stderr == interrupted_line("mitsuba-whitted")
    assert not (tmp_path / "out").exists()
