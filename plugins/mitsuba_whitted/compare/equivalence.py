"""Comparing the Whitted integrator with Mitsuba's path tracer.

The equivalence test asks whether Whitted and ``path`` agree *in
expectation* on the very same camera rays (pixel centres), given that path
tracing is noisy: for every pixel and channel, the path tracer's estimate is
split into ``batches`` independent batch means (each the mean of
``spp`` samples, so close to normal by the central limit theorem), and
Welch's t statistic compares them with Whitted's value (itself averaged over
render seeds when the scene has area lights, deterministic otherwise).

A pixel is rejected when |t| passes the two-sided Student-t quantile at the
Bonferroni-corrected level ``alpha / tests``, so ``alpha`` is the chance
that a correct integrator fails the whole image (the false-alarm rate).
Float32 pipelines never agree to the last bit, so a relative floor
``rel_floor`` (default 1e-4, about 1000 float32 ulps) is added to the
standard error; it is far below any modelling difference worth finding.
"""

from __future__ import annotations

from dataclasses import dataclass
from statistics import NormalDist

import drjit as dr
import mitsuba as mi
import numpy as np


def t_quantile(p: float, dof):
    """Upper ``p`` quantile of Student's t with ``dof`` degrees of freedom
    (Abramowitz & Stegun 26.7.5; ``dof`` may be a numpy array). Checked
    against scipy in the tests: within 2% for p >= 1e-9 and dof >= 15."""
    x = NormalDist().inv_cdf(1.0 - p)
    x2 = x * x
    g1 = (x2 + 1) * x / 4
    g2 = ((5 * x2 + 16) * x2 + 3) * x / 96
    g3 = (((3 * x2 + 19) * x2 + 17) * x2 - 15) * x / 384
    g4 = ((((79 * x2 + 776) * x2 + 1482) * x2 - 1920) * x2 - 945) * x / 92160
    return x + g1 / dof + g2 / dof ** 2 + g3 / dof ** 3 + g4 / dof ** 4


@dataclass
class EquivalenceResult:
    tests: int            # pixel-channels tested
    rejected: int         # how many passed the corrected threshold
    max_abs_t: float      # |t| of the pixel-channel closest to rejection
    threshold: float      # its threshold (it depends on the Welch dof)
    alpha: float          # family-wise false-alarm rate
    whitted: np.ndarray   # (pixels, 3) Whitted means
    path: np.ndarray      # (pixels, 3) path means
    t: np.ndarray         # (pixels, 3) t statistics

    @property
    def passed(self) -> bool:
        return self.rejected == 0

    @property
    def noise_multiple(self) -> float:
        """Mean of t squared: the squared difference of the two means as a
        multiple of its variance (their own noise, plus the float32 floor),
        about 1 when the difference is noise and nothing else."""
        return float(np.mean(self.t ** 2))

    def summary(self) -> str:
        verdict = "agree" if self.passed else "DIFFER"
        return (f"{verdict}: {self.rejected}/{self.tests} pixel-channels rejected, "
                f"max |t| = {self.max_abs_t:.2f} (threshold {self.threshold:.2f}, "
                f"family-wise alpha = {self.alpha:g})")


def _welch_dof(w_var, p_var, w_n: int, p_n: int):
    """Welch-Satterthwaite degrees of freedom of the difference of means."""
    w_term = w_var ** 2 / (w_n - 1) if w_n > 1 else 0.0
    p_term = p_var ** 2 / (p_n - 1)
    total = (w_var + p_var) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        dof = np.where(w_term + p_term > 0, total / (w_term + p_term), np.inf)
    return np.maximum(dof, min(p_n - 1, w_n - 1 if w_n > 1 else p_n - 1))


def equivalence_test(whitted: np.ndarray, path: np.ndarray, alpha: float = 1e-3,
                     rel_floor: float = 1e-4) -> EquivalenceResult:
    """Welch t test per pixel-channel between batch means.

    ``whitted`` and ``path`` have shape (batches, pixels, 3); a single
    Whitted batch means a deterministic estimate (zero variance).
    """
    w_n, p_n = whitted.shape[0], path.shape[0]
    w_mean, p_mean = whitted.mean(axis=0), path.mean(axis=0)
    w_var = whitted.var(axis=0, ddof=1) / w_n if w_n > 1 else np.zeros_like(w_mean)
    p_var = path.var(axis=0, ddof=1) / p_n
    floor = rel_floor * np.maximum(np.abs(p_mean), 1e-3)
    t = (w_mean - p_mean) / np.sqrt(w_var + p_var + floor ** 2)
    tests = t.size
    dof = np.minimum(_welch_dof(w_var, p_var, w_n, p_n), 1e6)
    threshold = t_quantile(alpha / (2 * tests), dof)
    excess = np.abs(t) / threshold
    worst = np.unravel_index(int(excess.argmax()), excess.shape)
    return EquivalenceResult(tests, int((excess > 1).sum()), float(np.abs(t)[worst]),
                             float(threshold[worst]), alpha, w_mean, p_mean, t)


def _repeat_rays(ray: mi.Ray3f, count: int) -> mi.RayDifferential3f:
    index = dr.arange(mi.UInt32, dr.width(ray.o) * count) // count
    return mi.RayDifferential3f(mi.Ray3f(dr.gather(mi.Point3f, ray.o, index),
                                         dr.gather(mi.Vector3f, ray.d, index),
                                         ray.time, ray.wavelengths))


def path_batches(scene: mi.Scene, integrator: mi.SamplingIntegrator, ray,
                 batches: int, spp: int, seed: int = 0) -> np.ndarray:
    """(batches, rays, 3) means of ``spp`` path samples per ray and batch."""
    rays = dr.width(ray.o)
    repeated = _repeat_rays(ray, spp)
    result = np.empty((batches, rays, 3))
    sampler = mi.load_dict({"type": "independent"})
    for batch in range(batches):
        sampler.seed(seed * 1_000_003 + batch, rays * spp)
        radiance, _, _ = integrator.sample(scene, sampler, repeated, None, True)
        means = dr.block_sum(mi.Color3f(radiance), spp) / spp if spp > 1 else mi.Color3f(radiance)
        result[batch] = np.array(means).T
    return result


def whitted_batches(scene: mi.Scene, integrator, ray, seeds=(0,)) -> np.ndarray:
    """(len(seeds), rays, 3) Whitted radiance along ``ray``."""
    result = np.empty((len(seeds), dr.width(ray.o), 3))
    for index, seed in enumerate(seeds):
        radiance, _ = integrator.trace_rays(scene, ray, seed)
        result[index] = np.array(radiance).T
    return result
