"""What a fresh process costs: the whole ``mitsuba-whitted render`` of a
scene, with the kernel cache as it is or empty, and the peak memory of a
process that renders it."""

from __future__ import annotations

import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from ..system import proc_field, program_command

#: Longest a child render may take before the bench gives up on it.
CHILD_TIMEOUT_S = 1800


def peak_rss_mib() -> float:
    """Peak resident memory of this process so far.

    Linux's ``VmHWM`` belongs to the process's own memory map, while
    ``ru_maxrss`` also keeps what its parent had resident when it started
    this process (Linux carries the larger over fork and exec): a child of
    the benchmark would read the benchmark's own peak whatever it
    rendered."""
    high_water = proc_field("/proc/self/status", "VmHWM")  # "1234 kB"
    if high_water is not None:
        return int(high_water.split()[0]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux


@dataclass
class ProcessTiming:
    """A render in a process of its own: the whole process's wall time,
    and the render time the command reports."""
    process_seconds: float
    render_seconds: float


def fresh_process_render(scene_path: Path, defines: dict, empty_cache: bool) -> ProcessTiming:
    """Run ``mitsuba-whitted render`` in a child process, on the scene as
    a user renders it (``defines`` as ``-D``, no other settings); its wall
    time and the render time it reports. An empty kernel cache is a fresh
    HOME."""
    env = dict(os.environ)
    with tempfile.TemporaryDirectory() as tmp:
        if empty_cache:
            env["HOME"] = tmp
            env["XDG_CACHE_HOME"] = os.path.join(tmp, "cache")
        out = os.path.join(tmp, "bench.exr")
        args = [sys.executable, "-m", "mitsuba_whitted.cli", "render", str(scene_path), "-o", out]
        for name, value in defines.items():
            args += ["-D", f"{name}={value}"]
        start = time.perf_counter()
        result = _run_child(args, env=env)
        wall = time.perf_counter() - start
    render = float(re.findall(r" rendered and written in ([0-9.]+) s", result.stdout)[-1])
    return ProcessTiming(wall, render)


def child_peak_memory(scene_path: Path, defines: dict, settings: dict,
                      work: str = "render") -> float:
    """Peak RSS (MiB) of a child process that loads the scene (with
    ``settings``, see :func:`~mitsuba_whitted.overrides.load_with`) and
    renders it, or takes one gradient of it (``work``); the child runs
    :mod:`~mitsuba_whitted.programs.peak_memory`."""
    result = _run_child(program_command("peak_memory", str(scene_path), json.dumps(defines),
                                         json.dumps(settings), work))
    # Mitsuba's log shares stdout (with colour codes): find our own line.
    return float(re.findall(r"peak_rss_mib ([0-9.]+)", result.stdout)[-1])


def _run_child(args: list, env=None) -> subprocess.CompletedProcess:
    result = subprocess.run(args, capture_output=True, text=True, env=env,
                            timeout=CHILD_TIMEOUT_S)
    if result.returncode != 0:
        raise RuntimeError(f"mitsuba-whitted bench: the child render failed: "
                           f"{result.stderr.strip()}")
    return result
