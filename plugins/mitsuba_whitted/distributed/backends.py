"""Where a job's tasks run, behind one interface.

``backend.run(tasks, scenes, on_result)`` renders every task and calls
``on_result(index, image)`` as each finishes, in whatever order they
finish; :func:`in_order` puts them back in the job's order. An exception
raised by ``on_result`` (a Ctrl-C included) stops the job: tasks still
running are cancelled.

- :class:`InProcess` (the default) renders the tasks one after another in
  this process, with no dependency beyond Mitsuba.
- :class:`.ray_backend.RayBackend` (``pip install mitsuba-whitted[cluster]``)
  runs them on a local Ray started for the job (``--workers N``) or on an
  existing cluster (``--cluster ADDRESS`` or ``RAY_ADDRESS``).
"""

from __future__ import annotations

import contextlib
import os

from ..errors import ClusterError
from .task import make_integrator, render_task


class InProcess:
    """The tasks one after another in this process, Dr.Jit's threads on
    every core. One scene is loaded at a time (scenes kept alive make every
    later frozen kernel call dearer)."""

    description = "in-process"

    def run(self, tasks, scenes, on_result) -> None:
        loaded, integrators = (None, None), {}
        for index, task in enumerate(tasks):
            if loaded[0] != task.scene:
                loaded = (None, None)  # the last scene is freed before the next one loads
                loaded = (task.scene, scenes[task.scene].load())
            if task.integrator_key not in integrators:
                integrators[task.integrator_key] = make_integrator(task)
            on_result(index, render_task(loaded[1], integrators[task.integrator_key], task))


def in_order(consume):
    """``on_result`` for a job whose results must be combined in task
    order: ``consume(image)`` is called for task 0, 1, 2, ... whatever
    order they finish in."""
    waiting, next_index = {}, 0

    def receive(index, image):
        nonlocal next_index
        waiting[index] = image
        while next_index in waiting:
            consume(waiting.pop(next_index))
            next_index += 1

    return receive


def run_job(backend, tasks, scenes, on_result, progress=None, what: str = "tasks") -> None:
    """``backend.run`` with ``progress(done, total, what)`` after each task."""
    done = 0

    def receive(index, image):
        nonlocal done
        on_result(index, image)
        done += 1
        if progress is not None:
            progress(done, len(tasks), what)

    backend.run(tasks, scenes, receive)


@contextlib.contextmanager
def backend(workers: int | None = None, cluster: str | None = None):
    """The backend for ``--workers`` and ``--cluster``: in-process when
    neither is given (nor ``RAY_ADDRESS``), else Ray, which is stopped or
    left when the block ends."""
    if workers is not None and workers < 1:
        raise ClusterError(f"--workers must be at least 1 (got {workers}).")
    address = cluster or os.environ.get("RAY_ADDRESS") or None
    if workers is None and address is None:
        yield InProcess()
        return
    try:
        from .ray_backend import RayBackend
    except ImportError:
        asked = ("--cluster" if cluster else "RAY_ADDRESS" if address else "--workers")
        raise ClusterError(f"{asked} needs Ray, which is not installed: "
                           "pip install 'mitsuba-whitted[cluster]'.") from None
    with RayBackend.start(workers, address) as ray_backend:
        yield ray_backend
