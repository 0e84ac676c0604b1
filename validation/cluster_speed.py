"""How a path reference scales over Ray workers on this machine, and what a
task costs on Ray beyond its render (``python -m validation.cluster_speed``;
needs ``pip install 'mitsuba-whitted[cluster]'``).

1. Speed-up: the same reference (the report's scene, 16 passes) rendered
   in this process and on a local Ray with 1, 2 and 4 workers (one Dr.Jit
   thread each), in ``--rounds`` rounds (see :func:`speedup`). On each Ray
   the first run (which starts the workers, imports Mitsuba in each,
   compiles the kernel and loads the scene) is reported apart.
2. Overhead per task: on one warm worker, jobs of :data:`TASKS` tasks of
   1 to 256 spp on the reference's film. A task's own time is what Ray's
   timeline records as its execution in the worker (loading nothing, the
   scene is the worker's last); the job's wall time per task beyond it is
   Ray's cost: scheduling, passing the task and its image between
   processes, this process's wait. The task size at which that cost falls
   below 5% of the task's time is read off a line fitted to the tasks'
   times (seconds = a + b * samples).
"""

from __future__ import annotations

import json
import logging
import statistics
import sys
import time

import numpy as np

import mitsuba_whitted
from mitsuba_whitted.command import CommandParser, count, run_command
from mitsuba_whitted.compare.reference import path_settings, reference_tasks, render_reference
from mitsuba_whitted.files import check_writable, write_text
from mitsuba_whitted.jit import timed
from mitsuba_whitted.system import machine
from mitsuba_whitted.distributed import InProcess, SceneSource, run_job
from validation.scenes import REPORT_SCENE

#: Tasks per job when measuring the overhead, and their samples per pixel.
TASKS, TASK_SPP = 16, (1, 4, 16, 64, 256)
#: The overhead's share of a task's render that counts as small.
SMALL_SHARE = 0.05
#: Seconds for the workers' task events to reach Ray's timeline.
TIMELINE_FLUSH_SECONDS = 3


def job(backend, source, spp: int, passes: int):
    tasks = reference_tasks(source.digest, spp, passes, path_settings())
    return lambda: run_job(backend, tasks, {source.digest: source}, lambda index, image: None)


def speedup(source, spp: int, workers_list, rounds: int) -> dict:
    """Each round times the reference once in this process and once on a
    fresh local Ray per number of workers (after an untimed first run);
    the figures are medians over the rounds, the speed-ups medians of each
    round's own ratios (so a stretch of load from elsewhere on the machine
    weighs on both sides of a ratio)."""
    from mitsuba_whitted.distributed.ray_backend import RayBackend

    reference = lambda backend: lambda: render_reference(source, spp, backend=backend)  # noqa: E731
    in_process = reference(InProcess())
    in_process()
    runs = {"in-process": []}
    for _ in range(rounds):
        runs["in-process"].append({"seconds": timed(in_process, 1)[1][0]})
        for workers in workers_list:
            started = time.perf_counter()
            with RayBackend.start(workers, None) as backend:
                ready = time.perf_counter() - started
                # The first run starts the workers, imports Mitsuba in each,
                # compiles and loads the scene.
                cold = timed(reference(backend), 1)[1][0]
                runs.setdefault(f"{workers} workers", []).append(
                    {"seconds": timed(reference(backend), 1)[1][0], "ray_start_seconds": ready,
                     "first_run_seconds": cold})
    base = [run["seconds"] for run in runs.get(f"{workers_list[0]} workers", [])]
    rows = {}
    for name, measured in runs.items():
        rows[name] = {key: statistics.median(run[key] for run in measured) for key in measured[0]}
        rows[name]["rounds"] = [run["seconds"] for run in measured]
        rows[name]["speedup_over_fewest_workers"] = statistics.median(
            first / run["seconds"] for first, run in zip(base, measured)) if base else None
    return rows


def overhead(source, repeats: int) -> dict:
    """Ray's cost per task on one warm worker, for tasks of each size in
    :data:`TASK_SPP`: the job's wall time per task against the time the
    worker spent running the task (Ray's timeline)."""
    from mitsuba_whitted.distributed.ray_backend import RayBackend

    film = source.load().sensors()[0].film().crop_size()
    pixels = int(film[0]) * int(film[1])
    windows = []  # (spp, wall seconds per task, start and end of the job)
    with RayBackend.start(1, None) as backend:
        for spp in TASK_SPP:
            run = job(backend, source, spp * TASKS, TASKS)
            run()
            for _ in range(repeats):
                since = time.time()
                wall = timed(run, 1)[1][0] / TASKS
                windows.append((spp, wall, since, time.time()))
        executed = execute_spans()
    rows = []
    for spp in TASK_SPP:
        walls = [wall for size, wall, _, _ in windows if size == spp]
        spans = [seconds for size, _, since, until in windows if size == spp
                 for start, seconds in executed if since <= start <= until]
        wall, run = statistics.median(walls), statistics.median(spans)
        rows.append({"spp": spp, "samples": spp * pixels, "task_seconds": run,
                     "wall_seconds_per_task": wall, "overhead_seconds": wall - run,
                     "overhead_share": (wall - run) / run})
    cost = statistics.median(row["overhead_seconds"] for row in rows)
    slope, intercept = np.polyfit([row["samples"] for row in rows],
                                  [row["task_seconds"] for row in rows], 1)
    small = max(0.0, (cost / SMALL_SHARE - intercept) / slope)
    return {"pixels": pixels, "tasks_per_job": TASKS, "rows": rows,
            "overhead_per_task_seconds": cost,
            "task_seconds_fit": {"a": intercept, "b_per_sample": slope},
            "small_overhead_samples": small, "small_overhead_spp": small / pixels,
            "small_overhead_task_seconds": cost / SMALL_SHARE}


def execute_spans() -> list[tuple[float, float]]:
    """(start, seconds) of every task a worker ran, from Ray's timeline."""
    import ray

    time.sleep(TIMELINE_FLUSH_SECONDS)
    logging.getLogger("ray._private.state").setLevel(logging.ERROR)
    return [(event["ts"] / 1e6, event["dur"] / 1e6) for event in ray.timeline()
            if event.get("name") == "task:execute"]


def table(speed: dict, cost: dict) -> str:
    lines = ["| run | reference (s): median (rounds) | speed-up over the fewest workers | "
             "Ray start (s) | first run (s) |",
             "|---|---|---|---|---|"]
    for name, row in speed.items():
        cells = [f"{row['seconds']:.2f} ({', '.join(f'{t:.2f}' for t in row['rounds'])})",
                 f"{row['speedup_over_fewest_workers']:.2f}x"
                 if row["speedup_over_fewest_workers"] else ""]
        cells += [f"{row[key]:.1f}" if key in row else ""
                  for key in ("ray_start_seconds", "first_run_seconds")]
        lines.append(f"| {name} | {' | '.join(cells)} |")
    lines += ["", "| spp per task | samples | task in the worker (s) | wall per task (s) | "
              "overhead (ms) | overhead / task |", "|---|---|---|---|---|---|"]
    for row in cost["rows"]:
        lines.append(f"| {row['spp']} | {row['samples']} | {row['task_seconds']:.4f} | "
                     f"{row['wall_seconds_per_task']:.4f} | {1000 * row['overhead_seconds']:.1f} | "
                     f"{100 * row['overhead_share']:.1f}% |")
    lines += ["", f"Overhead per task (median): {1000 * cost['overhead_per_task_seconds']:.1f} ms; below "
              f"{100 * SMALL_SHARE:.0f}% from tasks of {cost['small_overhead_task_seconds']:.2f} s "
              f"({cost['small_overhead_samples'] / 1e6:.1f} M samples, "
              f"{cost['small_overhead_spp']:.0f} spp at {cost['pixels']} pixels)."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = CommandParser(prog="validation.cluster_speed",
                           description=__doc__.splitlines()[0])
    parser.add_argument("--res", type=count, default=128, help="film width and height")
    parser.add_argument("--spp", type=count, default=1024,
                        help="samples per pixel of the reference")
    parser.add_argument("--workers", type=count, nargs="+", default=[1, 2, 4])
    parser.add_argument("--rounds", type=count, default=3,
                        help="rounds of the speed-up; repeats of each overhead job")
    parser.add_argument("--json", help="also write the figures to this file")
    args = parser.parse_args(argv)
    if args.json:
        check_writable(args.json)  # before minutes of measuring, not after
    mitsuba_whitted.set_variant("llvm_ad_rgb")
    source = SceneSource(REPORT_SCENE, {"res": str(args.res)})
    source.scene = source.load()
    speed = speedup(source, args.spp, args.workers, args.rounds)
    cost = overhead(source, args.rounds)
    print(f"{REPORT_SCENE.name} at {args.res}x{args.res}, path reference of {args.spp} spp in "
          f"16 passes; {machine()}\n")
    print(table(speed, cost))
    if args.json:
        write_text(args.json, json.dumps({"speedup": speed, "overhead": cost}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(run_command(main, program="validation.cluster_speed"))
