"""Converged path-traced references, with their own noise.

A reference is the mean of ``passes`` independent ``path`` renders; the
spread between the passes estimates its noise (the per-pixel variance of
the mean), so a report can say how much of any error is the reference's.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

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


def rgb(image) -> np.ndarray:
    """The colour channels of a rendered image as float64 numpy."""
    return np.asarray(image, dtype=np.float64)[..., :3]


def render_reference(scene: mi.Scene, spp: int, passes: int = 16, settings: dict | None = None,
                     progress=None) -> Reference:
    """Mean and variance of the mean of ``passes`` path renders of
    ``ceil(spp / passes)`` samples per pixel each."""
    integrator = mi.load_dict(settings or path_settings())
    per_pass = max(1, -(-spp // passes))
    started = time.perf_counter()
    total = square = None
    for index in range(passes):
        image = rgb(mi.render(scene, integrator=integrator, spp=per_pass,
                              seed=REFERENCE_SEED + index))
        total = image if total is None else total + image
        square = image ** 2 if square is None else square + image ** 2
        if progress is not None:
            progress(index + 1, passes, f"reference passes of {per_pass} spp")
    dr.sync_thread()
    mean = total / passes
    # Sample variance of the passes (n - 1 in the denominator) over n.
    variance = np.maximum(square / passes - mean ** 2, 0) / (passes - 1)
    return Reference(mean, variance, per_pass * passes, time.perf_counter() - started, False)


def cached_reference(cache: ReferenceCache, key: str, scene: mi.Scene, spp: int,
                     passes: int = 16, settings: dict | None = None,
                     progress=None) -> Reference:
    """``render_reference`` through the cache: rendered once per key."""
    def compute():
        made = render_reference(scene, spp, passes, settings, progress)
        return {"image": made.image, "variance": made.variance,
                "spp": np.array(made.spp), "seconds": np.array(made.seconds)}

    hits = cache.hits
    arrays = cache.get_or_compute(key, compute)
    return Reference(arrays["image"], arrays["variance"], int(arrays["spp"]),
                     float(arrays["seconds"]), cache.hits > hits)
