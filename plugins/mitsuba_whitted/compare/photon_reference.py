"""A reference with every light of the scene: ``path``, plus the light
``path`` cannot find, from Whitted's photons.

Mitsuba's ``path`` never samples light that leaves a delta light (point,
spot, directional) and reaches a smooth surface through delta or null
surfaces: caustics through glass and mirrors, and the light that passes a
surface of index 1 or a null one, where ``path``'s shadow rays stop. In a
scene with such a light and such a surface (:func:`needs_photons`), the
reference is ``path``'s plus ``whitted.photon_light(..., complement="path")``,
progressive photon mapping of exactly that light, gathered at the smooth
hits that the camera reaches through delta surfaces and at the vertices
of paths from them (a caustic lighting a wall is in it). In every other
scene
the reference is ``path`` alone, cached under the same key as ever.

The photon part is the mean of :attr:`PhotonSettings.runs` independent runs
(seeds of their own), each of ``passes`` passes of ``photons`` photons
whose gather radius shrinks from the integrator's first radius (a fraction
of a pixel's footprint). The spread of the runs gives its noise, added to
``path``'s. Its bias is not in that noise: every pass blurs the light over
a disc of its radius, from the first radius down to the last pass's
(about ``passes ** -1/6`` of it), so a caustic's sharp edge is softened
by less than a pixel, below the blur of the box filter that ``path``'s
pixels already have. It falls as the passes grow, slowly.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from ..integrators.photons.emission import bending_spheres
from .cache import ReferenceCache, cache_key, package_digest
from .reference import PATH_DEPTH, REFERENCE_SEED, Reference, rgb_pixels

#: Seeds of the photon runs: apart from the path passes' and the light
#: tracer's, so that the parts are independent.
PHOTON_SEED = 3 * REFERENCE_SEED
#: relMSE's ``eps``, as :mod:`.metrics`.
EPS = 1e-2


@dataclass(frozen=True)
class PhotonSettings:
    """How the photon part converges: ``photons`` per pass, ``passes`` per
    run, ``runs`` independent runs (at least 2, for the spread)."""

    photons: int
    passes: int
    runs: int

    def whitted(self) -> dict:
        """The ``whitted`` settings of a run: path's depth, one jittered
        point of every pixel per pass (the box-filtered pixel)."""
        return {"type": "whitted", "max_depth": PATH_DEPTH, "aa": "grid", "aa_samples": 1,
                "photons": self.photons, "photon_passes": self.passes}

    @property
    def label(self) -> str:
        return f"{self.photons} photons x {self.passes} passes"


#: A comparison's photon part, and the one ``--quick`` takes.
#: A run costs about as many seconds as its photons in millions on two
#: cores, so that the full part takes about as long as a 4096-spp ``path``
#: reference of a 128 x 128 film.
PHOTON_SETTINGS = PhotonSettings(photons=500_000, passes=16, runs=4)
QUICK_PHOTON_SETTINGS = PhotonSettings(photons=100_000, passes=8, runs=4)


def needs_photons(scene: mi.Scene) -> bool:
    """Whether ``path`` misses light in ``scene``: it has a delta light and
    a shape whose BSDF has a delta or null lobe."""
    delta_light = any(mi.has_flag(emitter.flags(), mi.EmitterFlags.Delta)
                      for emitter in scene.emitters())
    return delta_light and bool(bending_spheres(scene))


@dataclass
class PhotonPart:
    """The photon part of a reference: its mean image, the variance of
    that mean, how it was made, and the radii of a run's first and last
    passes (in scene units)."""

    image: np.ndarray
    variance: np.ndarray
    settings: PhotonSettings
    seconds: float
    cached: bool
    radius_first: float
    radius_last: float


def render_photons(scene: mi.Scene, settings: PhotonSettings) -> dict:
    """The arrays of a :class:`PhotonPart`: ``runs`` photon renders of the
    path complement, their float64 mean and the variance of that mean."""
    if settings.runs < 2:
        raise ValueError(f"compare: the photon reference's runs must be at least 2, for its "
                         f"noise (got {settings.runs}).")
    integrator = mi.load_dict(settings.whitted())
    total = square = None
    started = time.perf_counter()
    for run in range(settings.runs):
        image = rgb_pixels(integrator.photon_light(scene, sensor=0, seed=PHOTON_SEED + run,
                                                   complement="path"))
        total = image if total is None else total + image
        square = image ** 2 if square is None else square + image ** 2
    dr.sync_thread()
    stats = integrator.last_stats
    mean = total / settings.runs
    # Sample variance of the runs (n - 1 in the denominator) over n.
    variance = np.maximum(square / settings.runs - mean ** 2, 0) / (settings.runs - 1)
    return {"image": mean, "variance": variance,
            "seconds": np.array(time.perf_counter() - started),
            "radius_first": np.array(stats["photon_radius_first"]),
            "radius_last": np.array(stats["photon_radius_last"])}


def photon_key(scene_identity, settings: PhotonSettings) -> str:
    """The photon part's cache key: the scene (as ``path`` sees it), the
    settings, and the package's code, which renders it."""
    return cache_key(kind="photon complement", scene=scene_identity,
                     integrator=settings.whitted(), runs=settings.runs, seed=PHOTON_SEED,
                     code=package_digest())


def cached_photons(cache: ReferenceCache, scene_identity, scene: mi.Scene,
                   settings: PhotonSettings) -> PhotonPart:
    """:func:`render_photons` through the cache: rendered once per key."""
    hits = cache.hits
    arrays = cache.get_or_compute(photon_key(scene_identity, settings),
                                  lambda: render_photons(scene, settings))
    return PhotonPart(arrays["image"], arrays["variance"], settings, float(arrays["seconds"]),
                      cache.hits > hits, float(arrays["radius_first"]),
                      float(arrays["radius_last"]))


def with_photons(path: Reference, photons: PhotonPart) -> Reference:
    """``path``'s reference completed by ``photons``: their sum, their
    variances added (the parts are independent)."""
    return replace(path, image=path.image + photons.image,
                   variance=path.variance + photons.variance,
                   seconds=path.seconds + photons.seconds,
                   cached=path.cached and photons.cached, photons=photons, path_only=path)


def full_reference(cache: ReferenceCache, scene_identity, scene: mi.Scene, path: Reference,
                   settings: PhotonSettings) -> Reference:
    """``path`` alone where it is right, else ``path`` plus the cached
    photon part of ``settings``."""
    if not needs_photons(scene):
        return path
    return with_photons(path, cached_photons(cache, scene_identity, scene, settings))


def reference_name(reference: Reference) -> str:
    """Which the reference is: ``path`` or ``path + photons (N photons x P
    passes)``."""
    if reference.photons is None:
        return "path"
    return f"path + photons ({reference.photons.settings.label})"


def path_floor(reference: Reference) -> float:
    """``path``'s own error floor against ``reference``: the relMSE of
    ``path`` alone, less what the photon part's noise adds to it (0 where
    the reference is ``path`` alone). ``path`` alone differs from the full
    reference by the photon part exactly, so only that part's noise is in
    the difference."""
    if reference.photons is None:
        return 0.0
    denominator = reference.image ** 2 + EPS
    photons = reference.photons
    return max(float(np.mean((photons.image ** 2 - photons.variance) / denominator)), 0.0)
