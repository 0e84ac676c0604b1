"""Progressive photon mapping in ``whitted`` (``photons``): checked against
oracles that are right where ``path`` is not.

- the float64 closed form of a point light's caustic under a planar mirror
  (``validation/oracles/mirror_caustic.py``), and the rate at which the
  error falls as passes grow;
- Mitsuba's ``ptracer`` on the pixels whose every sub-ray sees a smooth
  surface first, for a glass ball, a mirror ball and the report's scene;
- Mitsuba's ``path`` where it is right: the small-light limit of the glass
  ball's caustic, and scenes where no delta light reaches a smooth surface
  through a delta chain, where nothing changes;
- the house rules: the same bits per seed, one sentence for bad values and
  for gradients, memory checked before it is spent.
"""

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsuba_whitted import ParameterError
from mitsuba_whitted.compare import render_reference
from mitsuba_whitted.integrators.photons.emission import (EmitterShare, aimed_pdf,
                                                          cones_towards, emitted_rays)
from mitsuba_whitted.integrators.photons.progressive import radii
from mitsuba_whitted.integrators.sequence import PaddedSobol
from validation import scenes
from validation.oracles import light_tracer, mirror_caustic
from validation.scenes import REPORT_SCENE

from conftest import assert_finite

#: Passes of every light-tracer reference (its per-pass values are skewed:
#: with few passes their spread underestimates the noise).
LIGHT_PASSES = 32
#: Seeds of each whitted estimate whose spread gives its own noise.
SEEDS = (0, 1, 2)


def with_photons(description: dict, **settings) -> dict:
    """``description`` rendered by its whitted with ``settings`` added."""
    return dict(description, integrator=dict(description["integrator"], **settings))


def rendered(description, seed: int = 0, integrator: dict | None = None) -> np.ndarray:
    """whitted's image of ``description`` (or of a loaded scene, rendered
    by ``integrator``)."""
    scene = description if isinstance(description, mi.Scene) else mi.load_dict(description)
    other = None if integrator is None else mi.load_dict(integrator)
    image = np.array(mi.render(scene, integrator=other, seed=seed), dtype=np.float64)
    assert_finite(image)
    return image[..., :3]


def estimate(description, integrator: dict | None = None) -> tuple:
    """The mean over ``SEEDS`` of whitted's image, and its variance."""
    images = np.array([rendered(description, seed, integrator) for seed in SEEDS])
    return images.mean(axis=0), images.var(axis=0, ddof=1) / len(SEEDS)


def against_light_tracer(scene: mi.Scene, reference, whitted: dict, photons: dict) -> dict:
    """relMSEs on the light tracer's mask: the ``whitted`` integrator
    with ``photons`` settings and without, and the noise of each
    estimate."""
    mask = light_tracer.smooth_first_mask(scene)
    assert mask.sum() > 100
    image, variance = estimate(scene, dict(whitted, **photons))
    without = rendered(scene, integrator=whitted)
    error = lambda x: light_tracer.masked_rel_mse(x, reference.image, mask)  # noqa: E731
    noise = lambda v: light_tracer.masked_noise_rel_mse(v, reference.image, mask)  # noqa: E731
    return {"with": error(image), "without": error(without),
            "reference noise": noise(reference.stderr ** 2),
            "noise": noise(reference.stderr ** 2) + noise(variance)}


def assert_agrees(result: dict, bias_share: float) -> None:
    """Whitted with photons is within the noises of both estimates, and
    the error left besides noise is at most ``bias_share`` of the light
    that whitted without photons lacks."""
    assert result["with"] < 1.3 * result["noise"], result
    left = max(result["with"] - result["noise"], 0.0)
    assert left < bias_share * (result["without"] - result["reference noise"]), result


def test_a_mirror_caustic_equals_its_closed_form():
    """A point light under a planar mirror: whitted without photons is the
    direct light alone (the closed form's direct part); with them, the
    mirror's light too, within 1% over its footprint, where it lacked a
    fifth or more of the light."""
    description = mirror_caustic.mirror_caustic_scene(size=32)
    exact = mirror_caustic.exact_image(mi.load_dict(description))
    inside = exact["valid"] & exact["footprint"]
    assert inside.sum() > 50
    plain = rendered(description).mean(axis=-1)
    lit = rendered(with_photons(description, photons=40000, photon_passes=16)).mean(axis=-1)
    assert np.allclose(plain[exact["valid"]], exact["direct"][exact["valid"]], rtol=1e-4)
    missing = 1 - plain[inside] / exact["total"][inside]
    assert missing.min() > 0.15
    ratio = lit[inside] / exact["total"][inside]
    assert abs(ratio.mean() - 1) < 0.01, ratio.mean()
    outside = exact["valid"] & ~exact["footprint"]
    assert np.allclose(lit[outside], exact["total"][outside], rtol=2e-2, atol=1e-4)


def test_the_error_falls_at_the_rate_of_the_radius_schedule():
    """With alpha 2/3 the mean squared error falls as passes^(-2/3): over
    1 to 64 passes of the mirror caustic, against its closed form, each
    fourfold of the passes lowers the relMSE, and the fitted slope lies
    near -2/3 (a radius that did not shrink would flatten at its blur; no
    progress at all would give 0)."""
    description = mirror_caustic.mirror_caustic_scene(size=32)
    exact = mirror_caustic.exact_image(mi.load_dict(description))
    valid = exact["valid"]
    passes = [1, 4, 16, 64]
    errors = []
    for count in passes:
        image = rendered(with_photons(description, photons=20000, photon_passes=count))
        errors.append(float((((image.mean(axis=-1) - exact["total"]) / exact["total"]) ** 2)
                            [valid].mean()))
    assert all(later < earlier for earlier, later in zip(errors, errors[1:])), errors
    slope = np.polyfit(np.log(passes), np.log(errors), 1)[0]
    assert -1.0 < slope < -0.5, (slope, errors)


def test_the_radius_shrinks_by_alpha():
    first, *rest = radii(1.0, 4, alpha=2 / 3)
    assert first == 1.0
    expected = [math.sqrt(math.prod((i + 2 / 3) / (i + 1) for i in range(1, k + 1)))
                for k in range(1, 4)]
    assert np.allclose(rest, expected)


#: Anti-aliasing of the whitted renders compared with the light tracer,
#: whose pixels are box-filtered: a 4 x 4 grid leaves little of the
#: direct light's edges to tell apart.
GRID = {"aa": "grid", "aa_samples": 4}


@pytest.mark.parametrize("builder", [scenes.glass_ball_caustic, scenes.mirror_ball_caustic])
def test_caustics_of_a_ball_agree_with_the_light_tracer(builder):
    """On the pixels the light tracer renders right, whitted with photons
    agrees with it within their noises; without photons it lacks the
    caustic, many times that error."""
    description = builder(size=32)
    reference = light_tracer.ptracer_reference(description, spp=8192, passes=LIGHT_PASSES)
    result = against_light_tracer(mi.load_dict(description), reference,
                                  dict(description["integrator"], **GRID),
                                  dict(photons=100000, photon_passes=12, photon_radius=0.02))
    assert_agrees(result, 0.2)


def test_with_indirect_paths_photons_carry_only_what_the_paths_miss():
    """With ``indirect_samples``, the paths carry the light between
    diffuse surfaces and the photons the caustic, including what the
    paths' vertices see of it: together they agree with the light tracer
    where the paths alone lack the caustic."""
    description = scenes.glass_ball_caustic(size=32)
    reference = light_tracer.ptracer_reference(description, spp=8192, passes=LIGHT_PASSES)
    whitted = dict(description["integrator"], **GRID, indirect_samples=16)
    result = against_light_tracer(mi.load_dict(description), reference, whitted,
                                  dict(photons=100000, photon_passes=8, photon_radius=0.02))
    assert_agrees(result, 0.2)


def ceiling_over_a_caustic(size: int = 32) -> dict:
    """A spot light whose whole cone passes a glass ball onto a floor, and
    a camera that sees only the ceiling above: the ceiling's light is the
    caustic, seen through the floor's diffuse bounce, and nothing else."""
    transform = mi.ScalarTransform4f()
    ceiling = {"type": "rectangle", "bsdf": scenes.diffuse(0.8, 0.8, 0.8),
               "to_world": transform.translate([0, 2.5, 0]).rotate([1, 0, 0], 90).scale(3)}
    spot = {"type": "spot", "intensity": scenes.rgb(30, 30, 30), "cutoff_angle": 18,
            "beam_width": 17,
            "to_world": transform.look_at(origin=[0, 2.2, 0], target=[0, 0, 0], up=[0, 0, 1])}
    ball = scenes.sphere((0, 0.6, 0), 0.5, {"type": "dielectric", "int_ior": 1.5})
    floor = scenes.floor(y=0.0, size=3.0, bsdf=scenes.diffuse(0.8, 0.8, 0.8))
    camera = scenes.camera(origin=(0, 1.0, 2.0), target=(0, 2.5, -0.3), size=size, fov=60)
    return scenes.scene(floor, ceiling, ball, spot, sensor=camera,
                        whitted=scenes.integrator(max_depth=8))


def test_the_paths_gather_the_caustic_a_diffuse_bounce_sees():
    """With indirect paths the photons end on the floor; the ceiling sees
    their light only through the paths' vertices there. Its light, summed
    over the ceiling, equals the light tracer's within the noise of the
    seeds; the paths alone (and the path tracer) find none of it."""
    description = ceiling_over_a_caustic()
    scene = mi.load_dict(description)
    mask = light_tracer.smooth_first_mask(scene)
    assert mask.sum() > 500
    reference = light_tracer.ptracer_reference(description, spp=4096, passes=LIGHT_PASSES)
    whitted = dict(description["integrator"], aa="grid", indirect_samples=4)
    sums = [rendered(scene, seed, dict(whitted, photons=20000, photon_passes=8))[mask].sum()
            for seed in range(4)]
    theirs = reference.image[mask].sum()
    sigma = math.hypot(np.std(sums, ddof=1) / 2, math.sqrt((reference.stderr[mask] ** 2).sum()))
    assert abs(np.mean(sums) - theirs) < 4 * sigma, (sums, theirs, sigma)
    assert theirs > 20 * sigma
    assert rendered(scene, integrator=whitted)[mask].sum() == 0


def test_the_report_scene_comes_close_to_the_light_tracer():
    """``scenes/cosc363.xml`` at 32 x 32, with the settings under which
    its light is the physical one the light tracer renders (no ambient
    term, physical shadows): photons add its caustics, its index-1
    sphere's shadow light and its interreflections, and take away more
    than four fifths of the error beyond noise that whitted has without
    them. (What is left, about 0.4 of the noise here, is not yet
    explained; the two balls above agree within it.)"""
    import mitsuba_whitted
    scene = mitsuba_whitted.load_file(str(REPORT_SCENE), res="32")
    reference = light_tracer.ptracer_reference(REPORT_SCENE, spp=4096, passes=LIGHT_PASSES,
                                               defines={"res": "32"})
    whitted = dict(type="whitted", max_depth=6, ambient=0.0, shadows="physical", **GRID)
    result = against_light_tracer(scene, reference, whitted,
                                  dict(photons=100000, photon_passes=6))
    left = max(result["with"] - result["noise"], 0.0)
    assert left < 0.2 * (result["without"] - result["reference noise"]), result


def test_the_small_light_limit_agrees_with_path():
    """The glass ball's caustic from a small sphere light, which ``path``
    finds too: whitted gathers it from photons (indirect_samples 0), and
    its light over the caustic's pixels equals a converged ``path``'s
    within their noises (a sum, since ``path``'s rare bright samples make
    its per-pixel spread a poor estimate of its noise), where without
    photons it lacks most of it."""
    description = scenes.glass_ball_small_light(size=32)
    scene = mi.load_dict(description)
    mask = light_tracer.smooth_first_mask(scene)
    settings = {"type": "path", "max_depth": description["integrator"]["max_depth"]}
    reference = render_reference(scene, spp=4096, passes=16, settings=settings)
    image, variance = estimate(with_photons(description, **GRID, photons=100000,
                                            photon_passes=8))
    without = rendered(with_photons(description, **GRID))
    caustic = mask[..., None] & (image - without > 0.2 * without)
    assert caustic.sum() > 10
    ours, theirs, lacking = (image[caustic].sum(), reference.image[caustic].sum(),
                             without[caustic].sum())
    sigma = math.sqrt(variance[caustic].sum() + reference.variance[caustic].sum())
    assert abs(ours - theirs) < 4 * sigma, (ours, theirs, sigma)
    assert theirs - lacking > 8 * sigma, (lacking, theirs, sigma)


def test_nothing_changes_where_no_delta_chain_reaches_a_smooth_surface():
    """With indirect paths, photons carry only what they cannot find; a
    scene of diffuse surfaces and a point light has none of it, and its
    image is the same bits as without photons."""
    description = scenes.caustic_ball_scene(scenes.diffuse(0.8, 0.4, 0.2), size=16)
    plain = rendered(with_photons(description, indirect_samples=4))
    lit = rendered(with_photons(description, indirect_samples=4, photons=10000))
    assert np.array_equal(plain, lit)


def test_photons_give_the_same_bits_for_a_seed():
    description = with_photons(scenes.glass_ball_caustic(size=16), aa="grid", photons=20000,
                               photon_passes=3)
    first, again = rendered(description, seed=3), rendered(description, seed=3)
    assert np.array_equal(first, again)
    assert not np.array_equal(first, rendered(description, seed=4))


def test_the_mixture_of_cones_has_its_density():
    """The aimed directions' density integrates to 1 over the sphere, and
    the photons' powers sum to the light's power (4 pi I)."""
    position = np.array([0.0, 3.0, 0.0])
    spheres = [(np.array([0.0, 0.5, 0.0]), 0.5), (np.array([2.0, 0.0, 1.0]), 0.3)]
    at = tuple(float(c) for c in position)
    share = EmitterShare(None, 1, at, cones_towards(position, spheres), 0.25)
    sequence = PaddedSobol(mi.UInt32(7))
    count = 1 << 18
    u = sequence.point(dr.arange(mi.UInt32, count), 0)
    directions = mi.warp.square_to_uniform_sphere(u)
    assert abs(float(dr.mean(aimed_pdf(share, directions))[0]) * 4 * math.pi - 1) < 5e-3
    light = mi.load_dict({"type": "point", "position": list(position),
                          "intensity": {"type": "rgb", "value": [2.0, 2.0, 2.0]}})
    share = EmitterShare(light, count, at, share.cones, 0.25)
    _, power = emitted_rays(share, dr.arange(mi.UInt32, count), sequence)
    assert abs(float(dr.sum(power.x)[0]) / (4 * math.pi * 2.0) - 1) < 1e-2


@pytest.mark.parametrize("name, value, words", [
    ("photons", -1, "must be between 0"),
    ("photon_passes", 0, "must be between 1"),
    ("photon_radius", -0.5, "must be >= 0"),
    ("photon_radius", float("nan"), "photon_radius"),
])
def test_bad_photon_settings_get_one_sentence(name, value, words):
    with pytest.raises(ParameterError, match=words) as caught:
        mi.load_dict({"type": "whitted", name: value})
    assert "whitted" in str(caught.value) and name in str(caught.value)


def test_a_refused_update_of_photons_changes_nothing():
    scene = mi.load_dict(with_photons(scenes.glass_ball_caustic(size=8), photons=1000))
    params = mi.traverse(scene)
    params["integrator.photons"] = -5
    with pytest.raises(ParameterError, match="photons"):
        params.update()
    assert scene.integrator().photons == 1000


def test_gradients_with_photons_get_one_sentence():
    scene = mi.load_dict(with_photons(scenes.glass_ball_caustic(size=8), photons=1000))
    params = mi.traverse(scene)
    key = "integrator.ambient"
    dr.enable_grad(params[key])
    with pytest.raises(ParameterError, match="photons.*not differentiated"):
        image = mi.render(scene, params)
        dr.backward(dr.sum(image, axis=None))


def test_photons_beyond_memory_are_refused_before_they_are_traced():
    scene = mi.load_dict(with_photons(scenes.glass_ball_caustic(size=8), photons=1 << 30))
    with pytest.raises(ParameterError, match="photons.*more than this machine"):
        mi.render(scene)
