"""Whitted's error in two parts: the sampling error, a setting's image
against a render of the same model whose anti-aliasing has converged, and
the model's bias, that converged render against path's reference.

The converged render samples every pixel on a dense grid of side
:data:`CONVERGED_SIDE`. Unlike adaptive or contrast refinement, a grid
cannot miss detail that the pixel centres do not show (a thin line, a
checkerboard minified in a glass ball's rim); its error at an edge is at
most 1/n of the pixel's coverage; and its n x n camera samples each cast
their own shadow rays towards area lights, so their average converges
too. Every setting that differs only in its anti-aliasing shares one
converged render. A setting with indirect light whose model is path's
(``indirect_samples`` above 0, physical shadows, no ambient term, path's
``max_depth``) converges to path's image, as the equivalence tests show:
its converged render is path's reference, and its model bias 0. A
setting with photons on path's model converges to the whole light, which
the full reference holds (path's, plus the photons' part where path misses
light): its converged render is that reference. Renders are cached like
the references, under a key of the scene, the model's settings and the
package's code.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from .cache import ReferenceCache, cache_key, package_digest
from .metrics import error_maps
from .reference import PATH_DEPTH, Reference, path_settings, rgb_pixels

#: The settings that choose the anti-aliasing, which a converged render
#: replaces.
AA_KEYS = ("aa", "aa_samples", "aa_threshold", "aa_max_depth", "aa_budget")
#: Side of the converged render's grid of samples in each pixel, and the
#: side ``--quick`` takes.
CONVERGED_SIDE, QUICK_SIDE = 32, 16


def model_settings(settings: dict) -> dict:
    """A Whitted setting without its anti-aliasing: what its image
    converges to as the anti-aliasing samples more."""
    return {name: value for name, value in settings.items() if name not in AA_KEYS}


def converged_settings(settings: dict, side: int = CONVERGED_SIDE) -> dict:
    """``settings``'s model with a ``side`` x ``side`` grid in every pixel."""
    return {**model_settings(settings), "aa": "grid", "aa_samples": side,
            "aa_budget": side * side}


def converges_to_path(settings: dict) -> bool:
    """Whether Whitted with ``settings`` has path's expectation: indirect
    light gathered, physical shadows, no ambient term, path's depth."""
    return (settings.get("indirect_samples", 0) > 0
            and settings.get("shadows", "physical") == "physical"
            and not has_ambient(settings) and settings.get("max_depth", 10) == PATH_DEPTH)


def converges_to_reference(settings: dict) -> bool:
    """Whether Whitted with ``settings`` converges to the full reference:
    photons (with or without indirect paths) on path's model."""
    return (settings.get("photons", 0) > 0
            and settings.get("shadows", "physical") == "physical"
            and not has_ambient(settings) and settings.get("max_depth", 10) == PATH_DEPTH)


def has_ambient(settings: dict) -> bool:
    """Whether Whitted's ``settings`` add an ambient term."""
    return any(settings.get("ambient", {}).get("value", [0]))


@dataclass
class Converged:
    """A converged render: its settings, image, render time (when it was
    made) and whether it came from the cache."""

    settings: dict
    image: np.ndarray
    seconds: float
    cached: bool


def converged_renders(scene: mi.Scene, scene_digest: str, whitted: dict,
                      cache: ReferenceCache, side: int = CONVERGED_SIDE,
                      reference: Reference | None = None,
                      full: Reference | None = None) -> dict:
    """The converged render of each labelled Whitted setting of
    ``whitted`` (settings dictionaries without ``type``), by label, one
    render for each distinct model; ``scene_digest`` names the scene in
    the cache. Settings that converge to path's image share ``reference``
    where it is given, and those with photons on path's model ``full``,
    the reference with every light."""
    renders, by_label = {}, {}
    for label, settings in whitted.items():
        target, image_of = converged_settings(settings, side), None
        if full is not None and converges_to_reference(settings):
            target, image_of = {**path_settings(), "light": "every"}, full
        elif reference is not None and converges_to_path(settings):
            target, image_of = path_settings(), reference
        model = json.dumps(target, sort_keys=True, default=str)
        if model not in renders:
            renders[model] = (Converged(target, image_of.image, image_of.seconds,
                                        image_of.cached) if image_of is not None
                              else _cached_render(scene, scene_digest, target, cache))
        by_label[label] = renders[model]
    return by_label


def _cached_render(scene, scene_digest: str, settings: dict, cache: ReferenceCache) -> Converged:
    def compute():
        started = time.perf_counter()
        integrator = mi.load_dict({"type": "whitted", **settings})
        image = rgb_pixels(mi.render(scene, integrator=integrator))
        dr.sync_thread()
        return {"image": image, "seconds": np.array(time.perf_counter() - started)}

    key = cache_key(kind="converged whitted", scene=scene_digest, integrator=settings,
                    code=package_digest())
    hits = cache.hits
    arrays = cache.get_or_compute(key, compute)
    return Converged(settings, arrays["image"], float(arrays["seconds"]), cache.hits > hits)


def mean_errors(image: np.ndarray, reference: np.ndarray) -> dict:
    """Each metric's error of ``image`` against ``reference``."""
    return {metric: float(np.mean(values))
            for metric, values in error_maps(image, reference).items()}
