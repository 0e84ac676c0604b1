"""The reference with every light (``compare.photon_reference``): where a
delta light reaches a smooth surface through glass, ``path`` plus the
photons of what it misses, which agrees with the light tracer; where
``path`` is right, ``path`` alone under its old key; the photon part
cached under a key of its own.
"""

import mitsuba as mi
import numpy as np
import pytest

from mitsuba_whitted.compare import ReferenceCache, cache_key, cached_reference, path_settings
from mitsuba_whitted.compare.photon_reference import (PhotonSettings, full_reference,
                                                      needs_photons, path_floor, photon_key,
                                                      reference_name)
from mitsuba_whitted.compare.scene_report import REFERENCE_PASSES, reference_key
from mitsuba_whitted.scene_digest import scene_without_integrator_digest
from validation import scenes
from validation.oracles import light_tracer
from validation.reference_errors import at_path_depth

#: Few photons in enough runs that their spread is a fair noise estimate
#: per pixel.
PHOTONS = PhotonSettings(photons=50_000, passes=4, runs=6)


def _path(cache, description, spp=256, passes=16):
    scene = mi.load_dict(description)
    key = cache_key(kind="test", scene=description, spp=spp, passes=passes)
    return scene, cached_reference(cache, key, scene, spp, passes)


def test_a_caustic_reference_is_path_plus_photons_and_agrees_with_ptracer(tmp_path):
    """The glass ball's caustic: path alone lacks it (far from ptracer on
    the mask), the full reference matches ptracer within the noise of
    both, and path's floor is about path's error against ptracer."""
    description = at_path_depth(scenes.glass_ball_caustic(size=32))
    cache = ReferenceCache(tmp_path)
    scene, path = _path(cache, description)
    assert needs_photons(scene)
    reference = full_reference(cache, description, scene, path, PHOTONS)
    assert reference_name(reference) == "path + photons (50000 photons x 4 passes)"
    assert reference.path_alone() is path and reference.photons.image.max() > 0
    np.testing.assert_array_equal(reference.image, path.image + reference.photons.image)
    assert (reference.variance >= path.variance).all()

    light = light_tracer.ptracer_reference(description, spp=8192, passes=32)
    mask = light_tracer.smooth_first_mask(scene)
    full = light_tracer.agreement_z(light.image, light.stderr, reference.image,
                                    np.sqrt(reference.variance), mask)
    alone = light_tracer.agreement_z(light.image, light.stderr, path.image,
                                     np.sqrt(path.variance), mask)
    assert np.mean(full ** 2) < 1.5, np.mean(full ** 2)
    assert np.mean(alone ** 2) > 20
    bias = {name: light_tracer.masked_rel_mse(image, light.image, mask)
            - light_tracer.masked_noise_rel_mse(variance + light.variance, light.image, mask)
            for name, image, variance in (("path", path.image, path.variance),
                                          ("full", reference.image, reference.variance))}
    assert bias["full"] < 0.05 * bias["path"]
    floor = path_floor(reference)
    assert 0.5 * bias["path"] < floor < 1.5 * bias["path"]


def test_a_scene_where_path_is_right_keeps_the_path_reference_and_its_key(tmp_path):
    """No delta light, or no delta or null surface: the reference is the
    path reference itself, nothing else rendered or cached, and a scene
    file's key is the one path references have always had."""
    diffuse_ball = scenes.caustic_ball_scene(scenes.diffuse(0.8, 0.4, 0.2), size=16)
    area_lit_glass = scenes.caustic_ball_scene(
        {"type": "dielectric"}, scenes.small_sphere_lamp(scenes.CAUSTIC_LAMP, 20.0, 0.1),
        size=16)
    cache = ReferenceCache(tmp_path)
    for description in (diffuse_ball, area_lit_glass):
        scene, path = _path(cache, description, spp=16, passes=2)
        assert not needs_photons(scene)
        misses = cache.misses
        reference = full_reference(cache, description, scene, path, PHOTONS)
        assert reference is path and reference_name(reference) == "path"
        assert path_floor(reference) == 0.0 and cache.misses == misses
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        f"{cache_key(kind='test', scene=d, spp=16, passes=2)}.npz"
        for d in (diffuse_ball, area_lit_glass))
    scene_file = scenes.SPEED[1]
    assert reference_key(scene_file, {}, 64) == cache_key(
        scene=scene_without_integrator_digest(scene_file, {}), spp=64,
        passes=REFERENCE_PASSES, integrator=path_settings())


def test_the_photon_part_is_cached_and_keyed_on_its_settings(tmp_path):
    description = at_path_depth(scenes.index_matched_shadow(size=16))
    cache = ReferenceCache(tmp_path)
    scene, path = _path(cache, description, spp=16, passes=2)
    settings = PhotonSettings(photons=10_000, passes=2, runs=2)
    first = full_reference(cache, description, scene, path, settings)
    second = full_reference(cache, description, scene, path, settings)
    assert (first.photons.cached, second.photons.cached) == (False, True)
    np.testing.assert_array_equal(first.image, second.image)
    np.testing.assert_array_equal(first.variance, second.variance)
    # The index-1 ball's shadow is light path lacks: the photons bring it.
    assert path_floor(first) > 0
    keys = {photon_key(description, s) for s in
            (settings, PhotonSettings(20_000, 2, 2), PhotonSettings(10_000, 3, 2),
             PhotonSettings(10_000, 2, 3))}
    assert len(keys) == 4
    with pytest.raises(ValueError, match="runs must be at least 2"):
        full_reference(cache, description, scene, path, PhotonSettings(10_000, 2, 1))
