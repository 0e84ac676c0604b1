"""Whitted's gradients beside Mitsuba's ``prb`` on the same camera rays.

On a scene where Whitted and path tracing agree in expectation (see
:mod:`.equivalence`), the derivative of Whitted's image equals the
expectation of ``prb``'s derivative estimate. Both are taken here of the
sum of the radiance along the pixel-centre rays of the scene's first
sensor: Whitted's exactly (its ``aa = "none"`` image), ``prb``'s as the
mean of ``spp`` paths per ray, batch by batch with independent seeds, so
that :func:`.equivalence.equivalence_test` can compare them as it compares
images.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..camera import camera_rays, pixel_centres
from .equivalence import _repeat_rays


def gradient_values(params, keys) -> np.ndarray:
    """The gradients of ``params[key]`` for ``keys``, (len(keys), 3) in
    float64, cleared afterwards."""
    values = np.array([np.asarray(dr.grad(params[key]), dtype=np.float64).ravel()
                       for key in keys])
    for key in keys:
        dr.clear_grad(params[key])
    return values


def whitted_gradient(scene: mi.Scene, params, keys) -> np.ndarray:
    """Derivative of the sum of the scene's image (its integrator must be a
    ``whitted`` that traces pixel centres) with respect to ``keys``."""
    image = mi.render(scene, params)
    dr.backward(dr.sum(image[..., :3], axis=None))
    return gradient_values(params, keys)


def prb_gradient_batches(scene: mi.Scene, params, keys, batches: int, spp: int,
                         max_depth: int, seed: int = 0) -> np.ndarray:
    """(batches, len(keys), 3): per batch, ``prb``'s estimate of the
    derivative of the summed radiance along the pixel-centre rays, each ray
    the mean of ``spp`` paths."""
    integrator = mi.load_dict({"type": "prb", "max_depth": max_depth, "rr_depth": 1 << 20})
    sensor = scene.sensors()[0]
    ray, _ = camera_rays(sensor, pixel_centres(sensor.film()))
    rays = _repeat_rays(mi.Ray3f(dr.detach(ray.o), dr.detach(ray.d), ray.time, ray.wavelengths),
                        spp)
    count = dr.width(rays.o)
    result = np.empty((batches, len(keys), 3))
    sampler = mi.load_dict({"type": "independent"})
    for batch in range(batches):
        sampler.seed(seed * 1_000_003 + batch, count)
        # As prb's own render_backward: the replay of the same paths
        # resumes differentiation where it needs it.
        with dr.suspend_grad():
            _, _, _, state = integrator.sample(
                dr.ADMode.Primal, scene, sampler.clone(), rays, None, None, mi.Bool(True))
            integrator.sample(dr.ADMode.Backward, scene, sampler, rays,
                              dr.full(mi.Spectrum, 1.0 / spp, count), state, mi.Bool(True))
            dr.eval()
        result[batch] = gradient_values(params, keys)
    return result
