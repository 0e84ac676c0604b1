"""Image error metrics and energy accounting, on linear RGB numpy images.

``rel_mse`` is the relative MSE of the rendering literature: the squared
error over the squared reference plus ``eps``, so dark pixels do not
dominate. FLIP (Andersson et al. 2020, the ``flip-evaluator`` package) is a
perceptual difference in [0, 1]; its HDR variant takes linear images.
"""

from __future__ import annotations

import functools
import math
import pickle
import subprocess

import numpy as np

from ..system import program_command

#: Each metric of :func:`error_maps` as the reports name it.
METRIC_NAMES = {"relmse": "relMSE", "flip": "FLIP"}
#: Side of the square tiles, in pixels, in which each metric's per-pixel
#: errors are drawn together by the bootstrap (:mod:`.intervals`): wide
#: enough that errors in different tiles go their own ways. A path image's
#: per-pixel squared errors are independent from pixel to pixel; FLIP
#: filters the images before it compares them, with filters about 19
#: pixels across at its default 67 pixels per degree.
TILE_SIDES = {"relmse": 8, "flip": 16}
#: Rec. 709 luminance weights, as Mitsuba's ``luminance()``.
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])


def rel_mse(image: np.ndarray, reference: np.ndarray, eps: float = 1e-2) -> float:
    """Relative mean squared error, (x - y)^2 / (y^2 + eps), averaged."""
    return float(np.mean(rel_squared_error(image, reference, eps)))


def rel_squared_error(image: np.ndarray, reference: np.ndarray, eps: float = 1e-2) -> np.ndarray:
    """Per-pixel relative squared error, averaged over the colour channels."""
    error = (image[..., :3] - reference[..., :3]) ** 2 / (reference[..., :3] ** 2 + eps)
    return error.mean(axis=-1)


def error_maps(image: np.ndarray, reference: np.ndarray) -> dict:
    """Per-pixel error of each metric whose mean is its image error:
    ``relmse`` (:func:`rel_squared_error`) and, where the package is
    installed, ``flip`` (HDR-FLIP)."""
    maps = {"relmse": rel_squared_error(image, reference)}
    flip_map = flip_error(image, reference)[1]
    if flip_map is not None:
        maps["flip"] = flip_map.astype(np.float64)
    return maps


def rmse(image: np.ndarray, reference: np.ndarray) -> float:
    return float(math.sqrt(np.mean((image - reference) ** 2)))


def noise_rel_mse(variance: np.ndarray, reference: np.ndarray, eps: float = 1e-2) -> float:
    """Expected relMSE of an unbiased estimate with per-pixel ``variance``
    against its own expectation: the relMSE its noise alone causes."""
    return float(np.mean(variance[..., :3] / (reference[..., :3] ** 2 + eps)))


def luminance(image: np.ndarray) -> np.ndarray:
    return image[..., :3] @ LUMINANCE


def missing_light(image: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per-pixel luminance the reference has and ``image`` lacks (the
    positive part of reference minus image)."""
    return np.maximum(luminance(reference) - luminance(image), 0.0)


def missing_energy_share(image: np.ndarray, reference: np.ndarray) -> float:
    """Share of the reference's total luminance that ``image`` lacks."""
    return float(missing_light(image, reference).sum() / luminance(reference).sum())


def flip_available() -> bool:
    try:
        import flip_evaluator  # noqa: F401
    except ImportError:
        return False
    return True


def flip_error(image: np.ndarray, reference: np.ndarray):
    """(mean, per-pixel map) of HDR-FLIP, or (nan, None) when the
    ``flip-evaluator`` package is not installed.

    Computed in a worker process: FLIP's C++ keeps Python's global lock
    for the whole of its run (seconds for a 600 x 600 image), and with it
    a Ctrl-C (see ``interrupt.py``)."""
    if not flip_available():
        return math.nan, None
    reference, image = (np.ascontiguousarray(np.maximum(x[..., :3], 0), dtype=np.float32)
                        for x in (reference, image))
    return _flip_worker()(reference, image)


class _FlipWorker:
    """A process running :mod:`~mitsuba_whitted.programs.flip_worker`, in a session of its own (a
    Ctrl-C at the terminal is for its parent); it ends when its parent
    does, however that ends."""

    def __init__(self):
        self.process = subprocess.Popen(program_command("flip_worker"),
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        stderr=subprocess.PIPE, start_new_session=True)

    def __call__(self, reference: np.ndarray, image: np.ndarray):
        try:
            pickle.dump((reference, image), self.process.stdin, protocol=5)
            self.process.stdin.flush()
            return pickle.load(self.process.stdout)
        except (OSError, EOFError, pickle.UnpicklingError):
            problem = self.process.stderr.read().decode(errors="replace").strip()
            raise RuntimeError(f"FLIP's worker process failed: "
                               f"{problem.splitlines()[-1] if problem else 'it gave no reason'}")


@functools.cache
def _flip_worker() -> _FlipWorker:
    return _FlipWorker()
