"""The whitted integrator: shadows, depth, determinism, film, parameters."""

import gc
import math
import re
import weakref

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import mitsuba_whitted
from conftest import assert_finite
from mitsuba_whitted.errors import ParameterError
from mitsuba_whitted.integrators.scene_needs import analyse
from mitsuba_whitted.integrators.scene_ref import SceneRef
from mitsuba_whitted.integrators.tracers.depth_first import LAUNCH_FACTOR, DepthFirstTracer
from validation.oracles.fresnel import reflectance
from validation.scenes import (camera, diffuse, floor, glass_scene, integrator, point_light, rgb, scene,
                    sphere)
from validation.stability.common import unit_rows

TINT = (0.8, 0.5, 0.3)


def render(description, **settings):
    loaded = mi.load_dict(description)
    whitted = mi.load_dict(integrator(**settings))
    image = mi.render(loaded, integrator=whitted)
    assert_finite(image)
    return np.array(image), whitted


#: The shadow scenes: a point light at height LAMP above a floor at height
#: 0, an occluding ball of radius GLASS_RADIUS centred at height
#: GLASS_CENTRE between them (index GLASS_IOR where it is glass).
LAMP, GLASS_CENTRE, GLASS_RADIUS, GLASS_IOR = 4.0, 2.0, 0.5, 1.5


def shadow_scene(occluder_bsdf=None):
    """A floor lit from straight above; an optional sphere between them.

    The camera looks at the floor's centre from the side, below the
    sphere, so only the shadow ray crosses the sphere."""
    objects = [floor(y=0.0, size=3), point_light((0, LAMP, 0), 30.0)]
    if occluder_bsdf is not None:
        objects.append(sphere((0, GLASS_CENTRE, 0), GLASS_RADIUS, occluder_bsdf))
    return scene(*objects, sensor=camera(origin=(0, 1, 4), target=(0, 0, 0), size=33))


def centre_ratio(occluder_bsdf, shadows):
    lit, _ = render(shadow_scene(), shadows=shadows)
    shaded, _ = render(shadow_scene(occluder_bsdf), shadows=shadows)
    centre = lit.shape[0] // 2
    # The shadow must be there but not reach the floor beyond its umbra.
    return shaded[centre, centre] / lit[centre, centre], shaded[-3, centre] / lit[-3, centre]


def tinted_glass(ior):
    return {"type": "dielectric", "int_ior": ior, "ext_ior": 1.0,
            "specular_transmittance": rgb(*TINT)}


@pytest.mark.parametrize("shadows", ["physical", "tinted"])
def test_index_matched_shadow_is_transmittance_squared(shadows):
    """Two interfaces of an index-matched sphere: the tint, squared."""
    centre, outside = centre_ratio(tinted_glass(1.0), shadows)
    np.testing.assert_allclose(centre, np.square(TINT), rtol=1e-5)
    np.testing.assert_allclose(outside, 1.0, rtol=1e-6)


def test_physical_shadow_behind_refracting_glass_is_black():
    centre, _ = centre_ratio(tinted_glass(1.5), "physical")
    assert np.all(centre == 0)


def test_tinted_shadow_behind_refracting_glass_is_tinted():
    """Normal incidence through the centre: Fresnel transmission
    (1 - F)^2 with F = ((n - 1) / (n + 1))^2, and the tint applies twice."""
    centre, _ = centre_ratio(tinted_glass(1.5), "tinted")
    fresnel = ((1.5 - 1) / (1.5 + 1)) ** 2
    np.testing.assert_allclose(centre, (1 - fresnel) ** 2 * np.square(TINT), rtol=1e-4)


def test_shadow_modes_are_named_only_by_their_names():
    with pytest.raises(ParameterError, match=re.escape(
            "whitted: parameter 'shadows' must be one of 'physical', 'tinted' (got 'seed')")):
        render(shadow_scene(tinted_glass(1.5)), shadows="seed")


def test_opaque_occluder_blocks_in_both_modes():
    for shadows in ("physical", "tinted"):
        centre, _ = centre_ratio(diffuse(0.5, 0.5, 0.5), shadows)
        assert np.all(centre == 0)


#: Radius of the core of the shadow that a tinted glass ball casts on the
#: floor of shadow_scene (in closed form below): the cone from the light
#: that grazes the ball.
CORE = LAMP * math.tan(math.asin(GLASS_RADIUS / (LAMP - GLASS_CENTRE)))


def floor_transmittance(x, z):
    """What reaches the floor points (x, 0, z) from the light through the
    ball in ``tinted`` mode, relative to the floor without the ball: the
    Whitted radiance of rays falling straight onto them, which cross
    nothing but the floor."""
    ray = mi.Ray3f(mi.Point3f(*np.stack([x, np.full_like(x, 0.1), z]).astype(np.float32)),
                   mi.Vector3f(0, -1, 0))
    whitted = mi.load_dict(integrator(shadows="tinted"))
    values = []
    for description in (shadow_scene(), shadow_scene(tinted_glass(GLASS_IOR))):
        radiance, _ = whitted.trace_rays(mi.load_dict(description), ray)
        values.append(np.array(radiance, dtype=np.float64).T)
    lit, shaded = values
    assert np.all(lit > 0)
    return shaded / lit


def _leave(p, n, d):
    """Mitsuba's ray origin leaving ``p`` (normal ``n``) towards ``d``,
    in float64: (1 + max|p|) RayEpsilon along the normal (offsets.py, in a
    scene larger than one unit)."""
    step = (1 + np.abs(p).max(axis=-1, keepdims=True)) * float(mi.math.RayEpsilon)
    return p + n * step * np.sign(np.sum(n * d, axis=-1, keepdims=True))


def tinted_closed_form(x, z):
    """Float64 model of the two segments a shadow ray takes from (x, 0, z)
    through the ball to the light: the one from the floor meets the sphere
    at cos(theta_1), the one from just inside the entry point leaves it at
    cos(theta_2) (equal to cos(theta_1) but for the offsets); each crossing
    passes 1 - F(theta) as seen from outside and the tint T, so the floor
    gets (1 - F(theta_1)) (1 - F(theta_2)) T^2. Also returns the distance
    of the straight segment from the ball's centre over its radius; points
    whose segment misses the ball get 1."""
    start = np.stack([x, np.zeros_like(x), z], axis=-1).astype(np.float32).astype(np.float64)
    light, centre = np.array([0, LAMP, 0.0]), np.array([0, GLASS_CENTRE, 0.0])
    origin = _leave(start, np.array([0, 1.0, 0]), light - start)
    d = unit_rows(light - origin)
    along = np.sum((centre - origin) * d, axis=-1)
    b = np.linalg.norm(origin + along[:, None] * d - centre, axis=-1) / GLASS_RADIUS
    entry = origin + (along - GLASS_RADIUS * np.sqrt(np.clip(1 - b ** 2, 0, 1)))[:, None] * d
    n_entry = (entry - centre) / GLASS_RADIUS
    inside = _leave(entry, n_entry, d)
    d_inside = unit_rows(light - inside)
    along = np.sum((centre - inside) * d_inside, axis=-1)
    gap = np.linalg.norm(inside + along[:, None] * d_inside - centre, axis=-1) / GLASS_RADIUS
    exit_point = inside + (along + GLASS_RADIUS * np.sqrt(np.clip(1 - gap ** 2, 0, 1)))[:, None] * d_inside
    n_exit = (exit_point - centre) / GLASS_RADIUS
    passed = ((1 - reflectance(-np.sum(n_entry * d, axis=-1), 1.0, GLASS_IOR))
              * (1 - reflectance(np.sum(n_exit * d_inside, axis=-1), 1.0, GLASS_IOR)))
    value = np.where((b < 1)[:, None], passed[:, None] * np.square(TINT), 1.0)
    return value, b


def test_tinted_shadow_lights_its_whole_core():
    """No dark ring: every floor point whose straight segment to the light
    crosses the ball gets light (at least 99% of them: float32 may round
    the outermost ones onto the silhouette), as much as the closed form
    says."""
    side = np.linspace(-1.05 * CORE, 1.05 * CORE, 81)
    x, z = (a.ravel() for a in np.meshgrid(side, side))
    measured = floor_transmittance(x, z)
    expected, b = tinted_closed_form(x, z)
    core = b < 1
    assert core.sum() > 4000
    assert np.mean(np.all(measured[core] > 0, axis=1)) >= 0.99
    clear = np.abs(b - 1) > 1e-3
    np.testing.assert_allclose(measured[clear], expected[clear], rtol=1e-5, atol=1e-5)


def test_tinted_shadow_profile_falls_from_its_centre_to_its_edge():
    """Along a radius of the core the light falls monotonically from the
    closed form's centre value, (1 - R0)^2 T^2, to its smallest at the rim:
    no minimum inside the shadow."""
    radius = CORE * np.linspace(0, 0.999, 400)
    profile = floor_transmittance(radius, np.zeros_like(radius))
    r0 = ((GLASS_IOR - 1) / (GLASS_IOR + 1)) ** 2
    np.testing.assert_allclose(profile[0], (1 - r0) ** 2 * np.square(TINT), rtol=1e-6)
    np.testing.assert_allclose(profile, tinted_closed_form(radius, np.zeros_like(radius))[0],
                               rtol=1e-5, atol=1e-5)
    assert np.all(np.diff(profile, axis=0) <= 1e-6 * profile[:-1])
    assert np.all(profile[:-1] > profile[-1])


LIGHT_HEIGHT, BALL_HEIGHT, BALL_RADIUS, EYE_HEIGHT = 10.0, 5.0, 1.0, 20.0
#: Half the width of floor the camera sees, and the film's size: chosen so
#: that no pixel centre lies within 1e-3 of an edge of the ball or of its
#: shadow (which the closed form checks).
VIEW, MARCH_SIZE = 2.5, 34
#: Mitsuba 3.9.1's orthographic sensor does not expose its JIT members to
#: ``dr.freeze``: the depth-first tracer's camera kernel fails to record (after
#: running once) and the tracer makes the camera rays outside it instead.
PROJECTIONS = {"perspective": "camera kernel", "orthographic": "camera kernel not frozen"}


def march_scene(projection):
    """A floor seen from straight above, lit by a point light above an
    index-matched ball: a shadow ray through the ball takes three
    closest-hit queries after its any-hit test (into the ball, out of it,
    on to the light)."""
    view = mi.ScalarTransform4f().look_at(origin=[0, EYE_HEIGHT, 0], target=[0, 0, 0],
                                          up=[0, 0, -1])
    film = {"type": "hdrfilm", "width": MARCH_SIZE, "height": MARCH_SIZE,
            "rfilter": {"type": "box"}}
    if projection == "orthographic":
        sensor = {"type": "orthographic", "to_world": view.scale([VIEW, VIEW, 1]), "film": film}
    else:
        fov = 2 * math.degrees(math.atan(VIEW / EYE_HEIGHT))
        sensor = {"type": "perspective", "fov": fov, "to_world": view, "film": film}
    return scene(floor(y=0.0, size=3), point_light((0, LIGHT_HEIGHT, 0), 30.0),
                 sphere((0, BALL_HEIGHT, 0), BALL_RADIUS, tinted_glass(1.0)), sensor=sensor)


def _distance_to_ball(start, end):
    """Float64: distance from the ball's centre to each segment."""
    centre = np.array([0, BALL_HEIGHT, 0])
    span = end - start
    t = np.clip(np.sum((centre - start) * span, axis=-1) / np.sum(span ** 2, axis=-1), 0, 1)
    return np.linalg.norm(start + t[..., None] * span - centre, axis=-1)


def _distance_to_line(points, start, end):
    """Float64: distance of each point (3 x n) from the line through
    ``start`` and ``end``."""
    span = (end - start).astype(np.float64)
    offset = (points - start).astype(np.float64)
    return np.linalg.norm(np.cross(offset, span, axis=0), axis=0) / np.linalg.norm(span, axis=0)


def expected_shadow_rays(projection):
    """Closed form: the floor points seen at the pixel centres (unless the
    ball is in the way: a hit on the ball casts no shadow ray), and those
    whose segment to the light crosses the ball."""
    offsets = -VIEW + 2 * VIEW * (np.arange(MARCH_SIZE) + 0.5) / MARCH_SIZE
    x, z = np.meshgrid(offsets, offsets)
    floor_points = np.stack([x, np.zeros_like(x), z], axis=-1)
    eyes = floor_points + [0, EYE_HEIGHT, 0] if projection == "orthographic" else \
        np.broadcast_to([0, EYE_HEIGHT, 0], floor_points.shape)
    sight = _distance_to_ball(eyes, floor_points)
    shadow = _distance_to_ball(floor_points, np.broadcast_to([0, LIGHT_HEIGHT, 0],
                                                             floor_points.shape))
    for distance in (sight, shadow):
        assert np.abs(distance - BALL_RADIUS).min() > 1e-3
    floor_seen = sight > BALL_RADIUS
    return int(floor_seen.sum()), int((floor_seen & (shadow < BALL_RADIUS)).sum())


def render_march_scene(projection, capture):
    loaded = mi.load_dict(march_scene(projection))
    whitted = mi.load_dict(integrator(max_depth=2, aa="none"))
    whitted.capture_rays = capture
    assert_finite(mi.render(loaded, integrator=whitted))
    return loaded, whitted


@pytest.mark.parametrize("projection", PROJECTIONS, ids=list(PROJECTIONS.values()))
@pytest.mark.parametrize("capture", [False, True], ids=["depth-first tracer", "wavefront tracer"])
def test_marched_shadow_rays_are_counted(projection, capture):
    """Each tracer counts every shadow ray once, and its marching queries,
    also when a kernel cannot be frozen (its failed recording has run it
    once already)."""
    shadow_rays, blocked = expected_shadow_rays(projection)
    assert 0 < blocked < shadow_rays
    _, whitted = render_march_scene(projection, capture)
    stats = whitted.last_stats
    assert (stats["shadow"], stats["shadow_march"]) == (shadow_rays, 3 * blocked)


def test_a_capturing_render_records_its_shadow_rays(monkeypatch):
    """The shadow test of a capturing render writes down every shadow ray
    it tests, from the floor to the light, and every query that follows a
    blocked one through the index-matched ball: the blocked ray itself,
    then from the ball's near side and from its far side, crossing by
    crossing; and the image is the same, bit for bit, as the same tracer's
    without capturing."""
    shadow_rays, blocked = expected_shadow_rays("perspective")
    loaded, whitted = render_march_scene("perspective", capture=True)
    [batch] = whitted.last_rays
    shadow, queries = batch.shadow, batch.queries
    assert (dr.width(shadow.o), dr.width(queries.o)) == (shadow_rays, 3 * blocked)
    assert (whitted.last_stats["shadow"], whitted.last_stats["shadow_march"]) == \
        (shadow_rays, 3 * blocked)
    light = np.array([[0], [LIGHT_HEIGHT], [0]])
    np.testing.assert_allclose(np.array(shadow.o)[1], 0, atol=1e-3)
    np.testing.assert_allclose(np.array(shadow.o + shadow.d * shadow.maxt), np.broadcast_to(
        light, (3, shadow_rays)), atol=0.02)
    origins = np.array(queries.o)
    np.testing.assert_allclose(origins[1, :blocked], 0, atol=1e-3)
    centre = np.array([[0], [BALL_HEIGHT], [0]])
    np.testing.assert_allclose(np.linalg.norm(origins[:, blocked:] - centre, axis=0),
                               BALL_RADIUS, atol=1e-3)
    # Each blocked ray's crossings lie on its line to the light, in order.
    floor_points, near, far = np.split(origins, 3, axis=1)
    for crossing in (near, far):
        np.testing.assert_allclose(_distance_to_line(crossing, floor_points, light), 0,
                                   atol=1e-3)
    assert np.all(floor_points[1] < near[1]) and np.all(near[1] < far[1])
    np.testing.assert_allclose(np.array(queries.o + queries.d * queries.maxt), np.broadcast_to(
        light, (3, 3 * blocked)), atol=0.02)

    captured = mi.render(loaded, integrator=whitted)
    monkeypatch.setattr(DepthFirstTracer, "supports", staticmethod(lambda shader: False))
    whitted.capture_rays = False
    assert np.array_equal(np.array(mi.render(loaded, integrator=whitted)), np.array(captured))
    assert whitted.last_rays is None


def test_a_capturing_render_records_every_light_sample_in_its_slot():
    """A floor under a point light and an area light sampled four times:
    each floor hit tests five shadow rays, logged light sample by light
    sample (the point light's, then the area light's), each in the order of
    the hits; they end at the point light and on the area light's square."""
    samples, half = 4, 0.5
    lamp = {"type": "rectangle", "emitter": {"type": "area", "radiance": rgb(5, 5, 5)},
            "to_world": mi.ScalarTransform4f().translate([0, 4, 0]).rotate([1, 0, 0], 90)
            .scale(half)}  # facing down
    loaded = mi.load_dict(scene(floor(y=0.0, size=3), point_light((0, 3, 0)), lamp,
                                sensor=camera(origin=(0, 2, 4), size=16)))
    whitted = mi.load_dict(integrator(max_depth=2, emitter_samples=samples))
    whitted.capture_rays = True
    mi.render(loaded, integrator=whitted)
    [batch] = whitted.last_rays
    hits = dr.count(loaded.ray_intersect(mi.Ray3f(batch.rays.o, batch.rays.d)).is_valid())[0]
    assert 0 < hits < 16 * 16
    assert dr.width(batch.shadow.o) == whitted.last_stats["shadow"] == (1 + samples) * hits
    origins = np.split(np.array(batch.shadow.o), 1 + samples, axis=1)
    ends = np.split(np.array(batch.shadow.o + batch.shadow.d * batch.shadow.maxt), 1 + samples,
                    axis=1)
    for slot in range(1, 1 + samples):
        assert np.array_equal(origins[slot], origins[0])
    np.testing.assert_allclose(ends[0], np.broadcast_to([[0], [3], [0]], (3, hits)), atol=0.02)
    on_lamp = np.stack(ends[1:])
    np.testing.assert_allclose(on_lamp[:, 1], 4, atol=0.02)
    assert np.all(np.abs(on_lamp[:, [0, 2]]) <= half + 1e-3)
    assert all(np.all(np.any(on_lamp[i] != on_lamp[j], axis=0))
               for i in range(samples) for j in range(i))


def test_diffuse_point_light_closed_form():
    """Floor radiance under a point light: rho/pi * I cos(theta) / d^2."""
    image, _ = render(shadow_scene())
    centre = image.shape[0] // 2
    expected = 0.6 / np.pi * 30.0 / 4.0 ** 2
    np.testing.assert_allclose(image[centre, centre], expected, rtol=2e-3)


def test_determinism_bit_for_bit():
    settings = dict(aa="adaptive", aa_max_depth=3, aa_threshold=0.05, emitter_samples=4)
    first, _ = render(glass_scene(), **settings)
    second, _ = render(glass_scene(), **settings)
    assert np.array_equal(first, second)


@pytest.mark.parametrize("max_depth, launch_factor", [(10, LAUNCH_FACTOR), (-1, 1)],
                         ids=["depth-first tracer", "wavefront tracer"])
def test_wavefront_size_is_not_an_approximation(max_depth, launch_factor):
    """Splitting camera samples (and, in the wavefront tracer, generations)
    into parts changes which operations Dr.Jit fuses into one kernel, and
    with it float rounding (FMA contraction), but nothing else: pixels
    agree to float32 noise."""
    large, _ = render(glass_scene(), aa="grid", aa_samples=2, max_depth=max_depth)
    small, whitted = render(glass_scene(), aa="grid", aa_samples=2, wavefront_size=1024,
                            max_depth=max_depth)
    # 48 x 48 pixels x 4 samples, in parts of 1024 camera samples (8 times
    # as many in the depth-first tracer): at least 9 launches (2).
    assert whitted.last_stats["batches"] >= math.ceil(48 * 48 * 4 / (1024 * launch_factor)) >= 2
    np.testing.assert_allclose(small, large, rtol=1e-3, atol=1e-5)


def test_max_depth_convention():
    lamp = {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, -1]),
            "emitter": {"type": "area", "radiance": rgb(1, 1, 1)}}
    mirror_ball = sphere((0, 0, 1), 0.5, {"type": "conductor", "material": "none"})
    description = scene(lamp, mirror_ball, floor(), point_light((0, 3, 3)),
                        sensor=camera(origin=(0, 0, 4), size=16))
    emitters_only, _ = render(description, max_depth=1)
    direct, _ = render(description, max_depth=2)
    bounce, _ = render(description, max_depth=3)
    nothing, _ = render(description, max_depth=0)
    assert nothing.max() == 0
    # Depth 1: the lamp around the ball, nothing else (the ball is black).
    assert emitters_only.max() == pytest.approx(1.0) and emitters_only[8, 8].max() == 0
    ball = (emitters_only.max(axis=2) == 0) & (direct.max(axis=2) == 0)
    assert ball.sum() > 10                    # a mirror has no direct term...
    assert bounce[ball].max() > 0             # ...but one bounce shows the lamp


def test_hide_emitters():
    lamp = {"type": "rectangle", "emitter": {"type": "area", "radiance": rgb(2, 2, 2)}}
    description = scene(lamp, sensor=camera(size=8))
    shown, _ = render(description)
    hidden, _ = render(description, hide_emitters=True)
    assert shown.max() == pytest.approx(2.0) and hidden.max() == 0


def test_ambient_scales_diffuse_albedo():
    description = scene(sphere((0, 0, 0), 1, diffuse(0.2, 0.4, 0.6)), sensor=camera(size=9))
    image, _ = render(description, ambient=[0.5, 0.5, 0.5])
    np.testing.assert_allclose(image[4, 4], [0.1, 0.2, 0.3], rtol=1e-6)


def test_film_crop_and_alpha():
    crop = {"crop_offset_x": 4, "crop_offset_y": 2, "crop_width": 6, "crop_height": 5,
            "pixel_format": "rgba"}
    description = scene(sphere((0, 0, 0), 1, diffuse(0.5, 0.5, 0.5)), point_light((1, 2, 3)),
                        sensor=camera(size=16, crop=crop))
    image, _ = render(description)
    assert image.shape == (5, 6, 4)
    full, _ = render(scene(sphere((0, 0, 0), 1, diffuse(0.5, 0.5, 0.5)), point_light((1, 2, 3)),
                           sensor=camera(size=16)))
    # Same rays up to the rounding of crop-relative film positions.
    np.testing.assert_allclose(image[..., :3], full[2:7, 4:10], rtol=1e-5, atol=1e-7)
    assert set(np.unique(image[..., 3])) <= {0.0, 1.0}


def test_traverse_shows_parameters():
    description = scene(sphere((0, 0, 0), 1, diffuse(0.5, 0.5, 0.5)), point_light((1, 2, 3)),
                        whitted=integrator(max_depth=4))
    loaded = mi.load_dict(description)
    params = mi.traverse(loaded)
    assert params["integrator.max_depth"] == 4
    for name in ("aa", "aa_threshold", "shadows", "ambient", "min_throughput"):
        assert f"integrator.{name}" in params


def test_render_writes_like_any_film(tmp_path):
    sensor = camera()
    sensor["film"]["component_format"] = "float32"
    loaded = mi.load_dict(scene(sphere((0, 0, 0), 1, diffuse(0.5, 0.5, 0.5)),
                                point_light((1, 2, 3)), whitted=integrator(), sensor=sensor))
    image = mi.render(loaded)
    loaded.sensors()[0].film().write(str(tmp_path / "out.exr"))
    written = np.array(mi.Bitmap(str(tmp_path / "out.exr")))
    np.testing.assert_array_equal(written[..., :3], np.array(image))


BAD = [
    ({"aa": "supersample"}, "aa"),
    ({"shadows": "soft"}, "shadows"),
    ({"aa_threshold": -0.1}, "aa_threshold"),
    ({"max_depth": -2}, "max_depth"),
    ({"aa_max_depth": 17}, "aa_max_depth"),
    ({"aa_max_depth": -1}, "aa_max_depth"),
    ({"aa_samples": 0}, "aa_samples"),
    ({"emitter_samples": 0}, "emitter_samples"),
    ({"min_throughput": -1.0}, "min_throughput"),
    ({"aa_budget": 1.0}, "aa_budget"),
    ({"ambient": [-1.0, 0.0, 0.0]}, "ambient"),
]


@pytest.mark.parametrize("settings, parameter", BAD)
def test_bad_parameter_names_plugin_and_parameter(settings, parameter):
    with pytest.raises(ParameterError, match=f"^whitted: parameter '{parameter}'"):
        mi.load_dict(integrator(**settings))


def test_scalar_variant_is_refused_clearly():
    try:
        mi.set_variant("scalar_rgb")
        with pytest.raises(RuntimeError, match="whitted: the wavefront integrator needs a JIT"):
            mi.load_dict(integrator())
    finally:
        mitsuba_whitted.set_variant("llvm_ad_rgb")
    assert isinstance(mi.load_dict(integrator()), mi.SamplingIntegrator)


@pytest.mark.parametrize("max_depth", [6, -1], ids=["depth-first tracer", "wavefront tracer"])
def test_falls_back_when_a_frozen_replay_goes_wrong(monkeypatch, max_depth):
    """If Dr.Jit's frozen replay ever returns arrays of a wrong width, the
    tracer warns and traces anew: same image, no crash. (Both tracers
    return radiance first and alpha second.)"""
    expected, _ = render(glass_scene(size=16), max_depth=max_depth)

    def broken_freeze(function):
        def replay(*args, **kwargs):
            radiance, alpha, *rest = function(*args, **kwargs)
            return (radiance, dr.zeros(mi.Float, 3), *rest)
        return replay

    monkeypatch.setattr(dr, "freeze", broken_freeze)
    image, _ = render(glass_scene(size=16), max_depth=max_depth)
    np.testing.assert_array_equal(image, expected)


@pytest.mark.parametrize("shape, skipped", [("rectangle", True), ("disk", True),
                                            ("sphere", True), ("cube", False)])
def test_a_light_skips_its_own_hits_only_where_it_cannot_see_itself(shape, skipped):
    """Flat and spherical lights cannot light their own surface, so their
    samples are skipped there; a mesh (which may be concave) keeps them."""
    from mitsuba_whitted.integrators.lighting import _on_own_shape
    loaded = mi.load_dict({"type": "scene",
                           "light": {"type": shape, "emitter": {"type": "area"}},
                           "other": sphere((0, 0, -5), 0.5, diffuse(0.5, 0.5, 0.5))})
    rays = mi.Ray3f(mi.Point3f(0, 0, 5), mi.Vector3f(0, 0, -1))
    hit_light = loaded.ray_intersect(rays)
    hit_other = loaded.ray_intersect(mi.Ray3f(mi.Point3f(0, 0, -3), mi.Vector3f(0, 0, -1)))
    light = loaded.emitters()[0]
    assert bool(_on_own_shape(light, hit_light)[0]) == skipped
    assert not bool(_on_own_shape(light, hit_other)[0])


class _Switch(mi.BSDF):
    """A test BSDF that is a mirror or a diffuse surface, switched through
    ``mi.traverse``: its flags change after the scene is loaded."""

    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        # Opaque, so that a change does not make Dr.Jit trace anew by itself.
        self.mirror = dr.opaque(mi.Float, props.get("mirror", 0.0))
        self._set_flags()

    def _is_mirror(self) -> bool:
        return bool(self.mirror[0] > 0.5)

    def _set_flags(self):
        flag = mi.BSDFFlags.DeltaReflection if self._is_mirror() else mi.BSDFFlags.DiffuseReflection
        self.m_components = [flag | mi.BSDFFlags.FrontSide]
        self.m_flags = flag | mi.BSDFFlags.FrontSide

    def traverse(self, callback):
        callback.put("mirror", self.mirror, mi.ParamFlags.NonDifferentiable)

    def parameters_changed(self, keys):
        self._set_flags()

    def sample(self, ctx, si, sample1, sample2, active=True):
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo = mi.reflect(si.wi) if self._is_mirror() else mi.warp.square_to_cosine_hemisphere(sample2)
        bs.pdf = 1.0 if self._is_mirror() else mi.warp.square_to_cosine_hemisphere_pdf(bs.wo)
        bs.eta = 1.0
        bs.sampled_type = mi.UInt32(+self.m_flags)
        return bs, mi.Color3f(0.8 if self._is_mirror() else 0.5)

    def eval(self, ctx, si, wo, active=True):
        if self._is_mirror():
            return mi.Color3f(0)
        return mi.Color3f(0.5 * dr.inv_pi * dr.maximum(mi.Frame3f.cos_theta(wo), 0))

    def pdf(self, ctx, si, wo, active=True):
        return mi.Float(0)

    def eval_pdf(self, ctx, si, wo, active=True):
        return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)


def test_a_reused_integrator_follows_a_bsdf_whose_lobes_change():
    """Kernels are specialised to each BSDF's lobes, so an integrator used
    again after a BSDF turned from diffuse into a mirror renders what a
    fresh one does (a conductor elsewhere keeps the scene's delta
    components the same, so only that BSDF's own flags tell)."""
    mi.register_bsdf("test_switch", lambda props: _Switch(props))

    def description(mirror):
        return scene(floor(y=-1.0), point_light((0, 3, 2)),
                     sphere((-0.7, 0, 0), 0.5, {"type": "test_switch", "mirror": mirror}),
                     sphere((0.7, 0, 0), 0.5, {"type": "conductor"}))

    loaded = mi.load_dict(description(0.0))
    whitted = mi.load_dict(integrator(max_depth=4))
    diffuse_image = np.array(mi.render(loaded, integrator=whitted))
    before = analyse(loaded)
    params = mi.traverse(loaded)
    key = next(k for k in params.keys() if k.endswith("mirror"))
    params[key] = dr.opaque(mi.Float, 1.0)
    params.update()
    after = analyse(loaded)
    assert after.delta_components == before.delta_components
    assert after != before, "what the scene needs must tell the lobes changed"
    switched = np.array(mi.render(loaded, integrator=whitted))
    fresh = np.array(mi.render(mi.load_dict(description(1.0)),
                               integrator=mi.load_dict(integrator(max_depth=4))))
    assert not np.allclose(diffuse_image, fresh), "the switch must change the image"
    np.testing.assert_array_equal(switched, fresh)


@pytest.mark.parametrize("max_depth", [10, -1], ids=["depth-first tracer", "wavefront tracer"])
def test_a_reused_integrator_follows_a_plain_number_parameter(max_depth):
    """A dielectric's ``eta`` is a plain number, which a frozen kernel
    records as a constant: updated through ``mi.traverse``, the next render
    is what a scene loaded with that index gives (the kept tracer's kernels
    showed the old index)."""
    def loaded(ior):
        description = glass_scene()
        description["object_2"]["bsdf"].update(int_ior=ior, ext_ior=1.0)
        return mi.load_dict(dict(description, integrator=integrator(max_depth=max_depth)))

    changed = loaded(1.5)
    before = np.array(mi.render(changed))
    params = mi.traverse(changed)
    key = next(k for k in params.keys() if k.endswith("bsdf.eta"))
    params[key] = 1.2
    params.update()
    after = np.array(mi.render(changed))
    assert not np.array_equal(before, after), "the index must change the image"
    np.testing.assert_array_equal(after, np.array(mi.render(loaded(1.2))))


@pytest.mark.parametrize("max_depth", [10, -1], ids=["depth-first tracer", "wavefront tracer"])
def test_a_rendered_scene_is_freed_when_dropped(max_depth):
    """The integrator keeps its tracer for the next render, and the scene
    keeps the integrator: a tracer holding the scene, or its frozen kernels
    holding the tracer, would make a cycle through Mitsuba's references.
    Such a scene stayed alive for good, and every later frozen call paid
    for traversing it; left to Python's cycle collector, a tracer went at an
    arbitrary moment, which crashed another render's tracing. So: dropping
    the scene frees it and its tracer at once, and leaves no object of
    Mitsuba or of this package to the collector."""
    loaded = mi.load_dict(dict(glass_scene(), integrator=integrator(max_depth=max_depth)))
    for _ in range(2):   # the second render replays the kept tracer
        assert_finite(mi.render(loaded))
    kept = weakref.ref(loaded.integrator())
    gc.collect()
    gc.disable()
    gc.set_debug(gc.DEBUG_SAVEALL)
    try:
        del loaded
        freed = kept() is None
        gc.collect()
        # Dr.Jit's freeze makes classes of its own for each frozen function,
        # which only the collector frees; they hold the traced function
        # (and its plain settings), but nothing of a scene.
        left = [type(o).__qualname__ for o in gc.garbage
                if isinstance(o, (mi.Object, SceneRef)) or hasattr(o, "scene_ref")]
    finally:
        gc.set_debug(0)
        gc.garbage.clear()
        gc.enable()
    assert freed and not left, left
