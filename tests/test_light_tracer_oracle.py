"""The oracles for caustics (``validation/oracles/light_tracer.py`` and
``mirror_caustic.py``): ``ptracer`` agrees with ``path`` where ``path`` is
right, the mask keeps only the pixels ``ptracer`` renders right, and on a
mirror's caustic the closed form, ``ptracer`` and ``path`` say what they
should: ``ptracer`` the whole light, ``path`` the direct part alone.
"""

import math

import mitsuba as mi
import numpy as np
import pytest

from mitsuba_whitted.camera import camera_rays, pixel_centres
from mitsuba_whitted.compare import ReferenceCache, path_batches, render_reference
from validation import scenes
from validation.oracles import light_tracer, mirror_caustic

#: Passes of every light-tracer estimate: its light per pixel comes from few
#: paths, so that a pass's value is skewed, and with few passes the spread
#: of the passes underestimates the noise of the dark ones.
PASSES = 32


def chi_square_ok(z: np.ndarray, bound: float) -> str:
    """A message unless the mean square of the z values is near 1 and no
    value lies beyond ``bound``."""
    mean_square, worst = float(np.mean(z ** 2)), float(np.max(np.abs(z)))
    if 0.7 < mean_square < 1.3 and worst < bound:
        return ""
    return f"mean z^2 {mean_square:.3f}, max |z| {worst:.2f} over {z.size} values"


def test_ptracer_agrees_with_path_without_caustics():
    """A diffuse ball on a diffuse floor under a point light: no delta
    surface, so ``path`` is right, and the two agree on the mask's pixels
    within their noises."""
    description = scenes.caustic_ball_scene(scenes.diffuse(0.8, 0.4, 0.2), size=32)
    scene = mi.load_dict(description)
    mask = light_tracer.smooth_first_mask(scene)
    assert 0.6 < mask.mean() < 0.99
    # Enough light paths that every pass reaches the shadow's darkest
    # pixels (lit only from the ball and the floor): a pixel no pass
    # reaches has no noise estimate.
    light = light_tracer.ptracer_reference(description, spp=8192, passes=PASSES)
    settings = {"type": "path", "max_depth": scenes.CAUSTIC_DEPTH}
    path = render_reference(scene, spp=512, passes=PASSES, settings=settings)
    z = light_tracer.agreement_z(light.image, light.stderr, path.image,
                                 np.sqrt(path.variance), mask)
    message = chi_square_ok(z, bound=6.0)
    assert not message, message
    # Not an agreement of noise alone: path 5% brighter is told apart.
    brighter = light_tracer.agreement_z(light.image, light.stderr, 1.05 * path.image,
                                        np.sqrt(path.variance), mask)
    assert np.mean(brighter ** 2) > 2


def test_light_tracer_reference_is_cached_under_its_own_key(tmp_path):
    cache = ReferenceCache(tmp_path)
    description = scenes.glass_ball_caustic(size=16)
    first = light_tracer.ptracer_reference(description, spp=64, passes=4, cache=cache)
    second = light_tracer.ptracer_reference(description, spp=64, passes=4, cache=cache)
    other_seed = light_tracer.ptracer_reference(description, spp=64, passes=4, seed=1,
                                                cache=cache)
    assert (first.cached, second.cached, other_seed.cached) == (False, True, False)
    assert np.array_equal(first.image, second.image)
    assert not np.array_equal(first.image, other_seed.image)
    assert light_tracer.ptracer_settings(description) == {
        "type": "ptracer", "max_depth": scenes.CAUSTIC_DEPTH, "hide_emitters": False}


def test_mask_keeps_smooth_surfaces_seen_first():
    """A mirror ball and a diffuse ball against the background: the mirror's
    pixels, the background and the diffuse ball's silhouette are left out,
    its inside kept."""
    size = 16
    description = scenes.scene(
        scenes.sphere((-1.0, 0, 0), 0.8, {"type": "conductor"}),
        scenes.sphere((1.0, 0, 0), 0.8, scenes.diffuse(0.5, 0.5, 0.5)),
        scenes.point_light((0, 3, 3)), sensor=scenes.camera(size=size))
    scene = mi.load_dict(description)
    mask = light_tracer.smooth_first_mask(scene)
    assert mask.shape == (size, size)
    assert not mask[8, 4]          # inside the mirror ball
    assert mask[8, 11]             # inside the diffuse ball
    assert not mask[0, 0]          # background
    # Pixels whose centre sees the diffuse ball but whose corner does not.
    sensor = scene.sensors()[0]
    ray, _ = camera_rays(sensor, pixel_centres(sensor.film()))
    centre_hits = np.array(scene.ray_intersect(ray).is_valid()).reshape(size, size)
    right_half = np.zeros_like(mask)
    right_half[:, size // 2:] = True
    assert mask.sum() < (centre_hits & right_half).sum()
    assert not (mask & ~(centre_hits & right_half)).any()


def test_perfect_mirror_reflects_everything():
    """The closed form's R = 1: Mitsuba's conductor with material "none"."""
    bsdf = mi.load_dict({"type": "conductor", "material": "none"})
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(math.sin(0.7), 0, math.cos(0.7))
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    _, weight = bsdf.sample(mi.BSDFContext(), si, 0.3, mi.Point2f(0.5, 0.5))
    assert np.allclose(np.array(weight), 1.0, rtol=1e-6)


@pytest.fixture(scope="module")
def mirror_scene():
    scene = mi.load_dict(mirror_caustic.mirror_caustic_scene())
    return scene, mirror_caustic.exact_image(scene)


def _path_at_centres(scene, description) -> np.ndarray:
    """Path's radiance along the pixel-centre rays of ``scene``'s camera
    (in the scene ``description``), as an image."""
    sensor = scene.sensors()[0]
    ray, _ = camera_rays(sensor, pixel_centres(sensor.film()))
    width, height = sensor.film().crop_size()
    batches = path_batches(mi.load_dict(description),
                           mi.load_dict({"type": "path", "max_depth": mirror_caustic.DEPTH}),
                           ray, batches=2, spp=4)
    # A point light's shadow ray is the only light at this depth: no noise.
    assert np.array_equal(batches[0], batches[1])
    return batches[0].reshape(height, width, 3)


def test_closed_form_direct_light_is_paths(mirror_scene):
    """With the mirror taken away, path's radiance at every pixel centre is
    the closed form's direct part, to float32 rounding."""
    scene, exact = mirror_scene
    path = _path_at_centres(scene, mirror_caustic.mirror_caustic_scene(with_mirror=False))
    assert np.allclose(path, exact["direct"][..., None], rtol=2e-5, atol=0)
    assert exact["footprint"].mean() > 0.05
    assert (exact["mirror"][exact["footprint"]] > 0.3 * exact["direct"][exact["footprint"]]).all()


def test_ptracer_sees_the_mirror_caustic_path_misses(mirror_scene):
    """With the mirror: ptracer matches the closed form (direct and mirror
    light) within its noise on every masked pixel; path renders the direct
    light alone, far from the closed form inside the mirror's footprint."""
    scene, exact = mirror_scene
    mask = light_tracer.smooth_first_mask(scene) & exact["valid"]
    assert mask.mean() > 0.9
    total = np.repeat(exact["total"][..., None], 3, axis=2)
    light = light_tracer.ptracer_reference(mirror_caustic.mirror_caustic_scene(), spp=4096,
                                           passes=PASSES)
    z = light_tracer.agreement_z(light.image, light.stderr, total, np.zeros_like(total), mask)
    message = chi_square_ok(z, bound=6.0)
    assert not message, message
    inside = mask & exact["footprint"]
    ratio = light.image[inside].mean() / total[inside].mean()
    assert abs(ratio - 1) < 0.01, ratio

    path = _path_at_centres(scene, mirror_caustic.mirror_caustic_scene())
    assert np.allclose(path, exact["direct"][..., None], rtol=2e-5, atol=0)
    missing = (total - path)[inside] / total[inside]
    assert missing.min() > 0.2, missing.min()


def test_ptracer_casts_no_shadow_under_index_matched_glass():
    """A dielectric ball of index 1 bends and reflects nothing: ptracer's
    floor is the floor without the ball, and path's shadow rays stop at the
    ball, leaving it black."""
    description = scenes.index_matched_shadow(size=32)
    scene = mi.load_dict(description)
    mask = light_tracer.smooth_first_mask(scene)
    without_ball = {name: value for name, value in description.items() if name != "object_1"}
    # The floor's direct light from a point light, which path gets exactly
    # at each point: its only noise is where in the pixel it looks.
    truth = np.asarray(mi.render(mi.load_dict(without_ball), spp=1024,
                                 integrator=mi.load_dict({"type": "path", "max_depth": 2})),
                       dtype=np.float64)[..., :3]
    path = np.asarray(mi.render(scene, spp=4, integrator=mi.load_dict(
        {"type": "path", "max_depth": scenes.CAUSTIC_DEPTH})), dtype=np.float64)[..., :3]
    shadow = mask & (path.mean(axis=2) < 0.05 * truth.mean(axis=2))
    assert shadow.sum() >= 10
    light = light_tracer.ptracer_reference(description, spp=8192, passes=PASSES)
    z = light_tracer.agreement_z(light.image, light.stderr, truth, np.zeros_like(truth), mask)
    message = chi_square_ok(z, bound=6.0)
    assert not message, message
    ratio = light.image[shadow].sum() / truth[shadow].sum()
    assert abs(ratio - 1) < 0.03, ratio
