"""Converged path-traced references, with their own noise.

A reference is the mean of ``passes`` independent ``path`` renders; the
spread between the passes estimates its noise (the per-pixel variance of
the mean), so a report can say how much of any error is the reference's.
Where ``path`` misses light, :mod:`.photon_reference` adds it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..distributed import InProcess, SceneSource, Task, in_order, run_job
from .cache import ReferenceCache

#: Longest reference path: long enough for glass and mirror chains, bounded
#: so that facing perfect mirrors (never stopped by Russian roulette) end.
PATH_DEPTH = 32
#: Reference seeds start here, far from the seeds the sweep uses, so the
#: reference is independent of every image compared against it.
REFERENCE_SEED = 1_000_000


def path_settings(max_depth: int = PATH_DEPTH) -> dict:
    return {"type": "path", "max_depth": max_depth}


@dataclass
class Reference:
    image: np.ndarray     # (height, width, 3) mean of the passes
    variance: np.ndarray  # (height, width, 3) variance of that mean
    spp: int
    seconds: float        # wall time of the render (when it was made)
    cached: bool
    #: The photon part (:class:`.photon_reference.PhotonPart`) where the
    #: reference adds the light ``path`` misses, and ``path``'s alone.
    photons: object = None
    path_only: "Reference | None" = None

    def path_alone(self) -> "Reference":
        """The ``path`` part of the reference: itself unless it has photons."""
        return self if self.path_only is None else self.path_only


def rgb_pixels(image) -> np.ndarray:
    """The colour channels of a rendered image as float64 numpy."""
    return np.asarray(image, dtype=np.float64)[..., :3]


def reference_tasks(scene: str, spp: int, passes: int, settings: dict) -> list[Task]:
    """One task per pass: ``ceil(spp / passes)`` samples per pixel each,
    from the pass's own seed."""
    per_pass = max(1, -(-spp // passes))
    return [Task(scene, REFERENCE_SEED + index, per_pass, settings) for index in range(passes)]


class PassSums:
    """float64 sums of the passes' colours and of their squares, each pass
    added in turn (the job's order, so the sums come out the same bits
    whoever rendered the passes and when)."""

    def __init__(self):
        self.total = self.square = None

    def add(self, image) -> None:
        image = rgb_pixels(image)
        self.total = image if self.total is None else self.total + image
        self.square = image ** 2 if self.square is None else self.square + image ** 2


def render_reference(scene: mi.Scene | SceneSource, spp: int, passes: int = 16,
                     settings: dict | None = None, progress=None, backend=None) -> Reference:
    """Mean and variance of the mean of ``passes`` path renders of
    ``ceil(spp / passes)`` samples per pixel each, rendered by ``backend``
    (default: in this process; other backends need the scene's file, a
    :class:`SceneSource`)."""
    source = scene if isinstance(scene, SceneSource) else SceneSource.loaded(scene)
    tasks = reference_tasks(source.digest, spp, passes, settings or path_settings())
    sums = PassSums()
    started = time.perf_counter()
    run_job(backend or InProcess(), tasks, {source.digest: source}, in_order(sums.add),
            progress, f"reference passes of {tasks[0].spp} spp")
    dr.sync_thread()
    mean = sums.total / passes
    # Sample variance of the passes (n - 1 in the denominator) over n.
    variance = np.maximum(sums.square / passes - mean ** 2, 0) / (passes - 1)
    return Reference(mean, variance, tasks[0].spp * passes, time.perf_counter() - started, False)


def cached_reference(cache: ReferenceCache, key: str, scene: mi.Scene | SceneSource, spp: int,
                     passes: int = 16, settings: dict | None = None,
                     progress=None, backend=None) -> Reference:
    """``render_reference`` through the cache: rendered once per key."""
    def compute():
        made = render_reference(scene, spp, passes, settings, progress, backend)
        return {"image": made.image, "variance": made.variance,
                "spp": np.array(made.spp), "seconds": np.array(made.seconds)}

    hits = cache.hits
    arrays = cache.get_or_compute(key, compute)
    return Reference(arrays["image"], arrays["variance"], int(arrays["spp"]),
                     float(arrays["seconds"]), cache.hits > hits)
