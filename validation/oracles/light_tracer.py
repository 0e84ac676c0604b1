"""The light-tracer oracle: Mitsuba's ``ptracer``, averaged over passes, as
the reference where ``path`` is wrong.

``path`` never samples light that leaves a delta light (point, spot,
directional) and reaches a smooth surface through delta surfaces (mirrors,
glass): a caustic. ``ptracer`` follows light from the lights, through the
delta surfaces, and connects each smooth vertex to the camera, so it sees
caustics; the connection is what it cannot make through a delta surface,
and a pixel is right only where the camera sees a smooth surface first
(:func:`smooth_first_mask`). Light on its way to that surface is followed
through every surface it meets, by sampling the surface's BSDF, so a
dielectric of index 1 lets it straight through (no shadow), where
``path``'s shadow rays stop.

The reference is ``passes`` renders of different seeds, their float64 mean
and the standard error of that mean from the spread of the passes, built
with the path references' machinery (``compare.reference``) and cached
under a key that names the integrator, so a second run reads it back.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsuba_whitted import load_file
from mitsuba_whitted.camera import camera_rays
from mitsuba_whitted.compare import ReferenceCache, cache_key
from mitsuba_whitted.compare.reference import REFERENCE_SEED, PassSums
from mitsuba_whitted.compare.sweep import scene_whitted_settings
from mitsuba_whitted.distributed import InProcess, SceneSource, Task, in_order, run_job
from mitsuba_whitted.scene_digest import scene_without_integrator_digest

#: Whitted's own default depth, which a scene without ``max_depth`` renders at.
WHITTED_DEFAULT_DEPTH = 10
#: Seeds of the light-tracer passes: apart from the path references'
#: (``REFERENCE_SEED`` + pass) so that the two are independent, and a
#: ``seed`` apart from each other by more passes than any reference has.
LIGHT_SEED = 2 * REFERENCE_SEED
SEED_STRIDE = 10_000


@dataclass
class LightTracerReference:
    image: np.ndarray    # (height, width, 3) float64 mean of the passes
    stderr: np.ndarray   # (height, width, 3) standard error of that mean
    spp: int             # light paths per pixel, all passes together
    passes: int
    seconds: float       # wall time of the render (when it was made)
    cached: bool

    @property
    def variance(self) -> np.ndarray:
        return self.stderr ** 2


def _whitted_settings(scene_or_description) -> dict:
    if isinstance(scene_or_description, dict):
        integrator = scene_or_description.get("integrator") or {}
        return integrator if integrator.get("type") == "whitted" else {}
    return scene_whitted_settings(scene_or_description)


def ptracer_settings(scene_or_description) -> dict:
    """``ptracer``'s settings for a scene (a description or a loaded
    scene): the depth and emitter visibility of the scene's ``whitted``.
    Both integrators count ``max_depth`` in segments of the whole path
    (1: lights seen directly, 2: direct light), so the same number bounds
    the same paths."""
    whitted = _whitted_settings(scene_or_description)
    return {"type": "ptracer", "max_depth": int(whitted.get("max_depth", WHITTED_DEFAULT_DEPTH)),
            "hide_emitters": bool(whitted.get("hide_emitters", False))}


def _source(scene, defines: dict):
    """(the loaded scene, its SceneSource, what names it in a cache key)."""
    if isinstance(scene, (str, Path)):
        path = Path(scene)
        loaded = load_file(path, **defines)
        return (loaded, SceneSource(path, dict(defines), loaded),
                scene_without_integrator_digest(path, defines))
    loaded = mi.load_dict(scene)
    return loaded, SceneSource.loaded(loaded), scene


def _render_passes(source: SceneSource, spp: int, passes: int, seed: int,
                   settings: dict) -> dict:
    per_pass = max(1, -(-spp // passes))
    first = LIGHT_SEED + seed * SEED_STRIDE
    tasks = [Task(source.digest, first + index, per_pass, settings) for index in range(passes)]
    sums = PassSums()
    started = time.perf_counter()
    run_job(InProcess(), tasks, {source.digest: source}, in_order(sums.add), None,
            f"light-tracer passes of {per_pass} spp")
    dr.sync_thread()
    mean = sums.total / passes
    # Sample variance of the passes (n - 1 in the denominator) over n.
    variance = np.maximum(sums.square / passes - mean ** 2, 0) / (passes - 1)
    return {"image": mean, "stderr": np.sqrt(variance), "spp": np.array(per_pass * passes),
            "seconds": np.array(time.perf_counter() - started)}


def ptracer_reference(scene: dict | str | Path, spp: int, passes: int = 16, seed: int = 0,
                      cache: ReferenceCache | None = None,
                      defines: dict | None = None) -> LightTracerReference:
    """The mean of ``passes`` ``ptracer`` renders of ``ceil(spp / passes)``
    light paths per pixel each (seeds from ``seed``), and the standard error
    of that mean per pixel and channel, from the spread of the passes.

    ``scene`` is a description for ``mi.load_dict`` or a scene file (loaded
    with ``defines``, e.g. ``{"res": "128"}``); its ``whitted`` sets the
    depth (:func:`ptracer_settings`). With ``cache``, the reference is
    rendered once per key: the scene as ``ptracer`` sees it (the
    description, or the file's digest without its integrator), the
    settings, ``spp``, ``passes`` and ``seed``."""
    if passes < 2:
        raise ValueError("a light-tracer reference needs at least 2 passes for its noise")
    defines = dict(defines or {})
    loaded, source, identity = _source(scene, defines)
    settings = ptracer_settings(scene if isinstance(scene, dict) else loaded)
    compute = lambda: _render_passes(source, spp, passes, seed, settings)  # noqa: E731
    if cache is None:
        arrays, cached = compute(), False
    else:
        hits = cache.hits
        key = cache_key(kind="light tracer", integrator=settings, scene=identity, spp=spp,
                        passes=passes, seed=seed)
        arrays = cache.get_or_compute(key, compute)
        cached = cache.hits > hits
    return LightTracerReference(arrays["image"], arrays["stderr"], int(arrays["spp"]), passes,
                                float(arrays["seconds"]), cached)


def sub_pixel_positions(film: mi.Film, sub: int) -> mi.Point2f:
    """A ``sub`` x ``sub`` grid of points in every pixel of the crop window
    (cell centres), pixel by pixel in row-major order, in pixel units."""
    width, height = film.crop_size()
    per_pixel = sub * sub
    index = dr.arange(mi.UInt32, width * height * per_pixel)
    pixel, cell = index // per_pixel, index % per_pixel
    x = mi.Float(pixel % width) + (mi.Float(cell % sub) + 0.5) / sub
    y = mi.Float(pixel // width) + (mi.Float(cell // sub) + 0.5) / sub
    return mi.Point2f(x, y)


def smooth_first_mask(scene: mi.Scene, sub: int = 4) -> np.ndarray:
    """(height, width) bool: True where every one of the pixel's ``sub`` x
    ``sub`` camera rays (spread over the box filter's footprint, the pixel)
    first hits a surface whose BSDF has a smooth component and neither a
    delta nor a pass-through one.

    Those are the pixels ``ptracer`` renders right: it reaches the camera
    only from smooth vertices, with a visibility test that any surface
    stops, so a pixel that sees a mirror or glass, sees through a
    pass-through surface or sees the background gets no (or not all) of
    its light; a pixel only partly covered by such a surface is left out
    too."""
    sensor = scene.sensors()[0]
    film = sensor.film()
    width, height = film.crop_size()
    ray, _ = camera_rays(sensor, sub_pixel_positions(film, sub))
    si = scene.ray_intersect(ray)
    flags = si.bsdf(ray).flags()
    smooth = (si.is_valid() & mi.has_flag(flags, mi.BSDFFlags.Smooth)
              & ~mi.has_flag(flags, mi.BSDFFlags.Delta) & ~mi.has_flag(flags, mi.BSDFFlags.Null))
    smooth = np.array(smooth, dtype=bool).reshape(height, width, sub * sub)
    return smooth.all(axis=2)


def masked_rel_mse(image: np.ndarray, reference: np.ndarray, mask: np.ndarray,
                   eps: float = 1e-2) -> float:
    """relMSE, ``(x - y)^2 / (y^2 + eps)``, over the mask's pixels."""
    error = (image[..., :3] - reference[..., :3]) ** 2 / (reference[..., :3] ** 2 + eps)
    return float(error[mask].mean())


def masked_noise_rel_mse(variance: np.ndarray, reference: np.ndarray, mask: np.ndarray,
                         eps: float = 1e-2) -> float:
    """The relMSE that noise of per-pixel ``variance`` alone causes, over
    the mask's pixels: what to subtract from a relMSE to leave its bias."""
    return float((variance[..., :3] / (reference[..., :3] ** 2 + eps))[mask].mean())


def agreement_z(a: np.ndarray, a_stderr: np.ndarray, b: np.ndarray, b_stderr: np.ndarray,
                mask: np.ndarray) -> np.ndarray:
    """Per masked pixel-channel, the difference of two independent estimates
    in units of its standard error (Welch's statistic); 0 where both are
    exactly 0."""
    scale = np.sqrt(a_stderr ** 2 + b_stderr ** 2)[mask]
    difference = (a - b)[mask]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(scale > 0, difference / np.where(scale > 0, scale, 1),
                        np.where(difference == 0, 0.0, math.inf))
