"""A task, and what every process that runs one does.

A task is one render of a whole film: a scene (by content hash), a sample
seed and a number of samples per pixel, by a given integrator or the
scene's own. It is the unit a backend schedules, retries and reports
progress on. Films are not split into crops: Mitsuba seeds each sample by
its index within the rendered crop, so a tile's samples are not those the
same pixels get in a render of the whole film, and a reference made of
tiles would differ from the one rendered in one piece (and from every
reference already cached).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from ..errors import ClusterError


@dataclass(frozen=True)
class Task:
    scene: str                      # the scene's content hash (SceneSource.digest)
    seed: int = 0
    spp: int = 0                    # 0: the scene's sampler decides
    integrator: dict | None = None  # a dictionary for mi.load_dict; None: the scene's own

    @property
    def integrator_key(self) -> str:
        return json.dumps(self.integrator, sort_keys=True)


@dataclass(frozen=True)
class Environment:
    """What a worker process must match to render the same bits as the
    process that made the job."""

    variant: str
    mitsuba: str
    package: str

    @classmethod
    def here(cls) -> "Environment":
        import mitsuba as mi

        import mitsuba_whitted

        return cls(mi.variant(), mi.__version__, mitsuba_whitted.__version__)


def prepare_process(environment: Environment, threads: int | None = None) -> None:
    """Register this package's plugins and set the job's variant, before
    any scene is loaded in this process; refuse a process whose Mitsuba or
    package version differs from the job's (its images would too).
    ``threads``: Dr.Jit's worker threads for this process (None: as many
    as the machine has)."""
    import socket

    import drjit as dr
    import mitsuba as mi

    import mitsuba_whitted

    here = (mi.__version__, mitsuba_whitted.__version__)
    if here != (environment.mitsuba, environment.package):
        raise ClusterError(
            f"the worker on {socket.gethostname()} has mitsuba {here[0]} and "
            f"mitsuba-whitted {here[1]}, but the job needs mitsuba {environment.mitsuba} and "
            f"mitsuba-whitted {environment.package}; install the same versions on every node.")
    if mi.variant() != environment.variant:
        mitsuba_whitted.set_variant(environment.variant)
    if threads is not None and dr.thread_count() != threads:
        dr.set_thread_count(threads)


def make_integrator(task: Task):
    import mitsuba as mi

    return None if task.integrator is None else mi.load_dict(task.integrator)


def render_task(scene, integrator, task: Task) -> np.ndarray:
    """The film's image of one task, as Mitsuba renders it (float32)."""
    import mitsuba as mi

    image = mi.render(scene, integrator=integrator, seed=task.seed, spp=task.spp)
    return np.array(image, dtype=np.float32)
