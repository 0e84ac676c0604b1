"""Depth of field through a thin lens, against closed forms and ``path``.

A thin lens of aperture radius A focused at distance F blurs a plane at
distance D (perpendicular to the axis) by a uniform disk of radius
rho = A |1 - D / F| on that plane (the rays of one film point meet at the
focus plane, and an aperture point moves its ray's hit on the plane
affinely). So, for a plane of radiance 1/2 + 1/2 cos(k x) seen by a film
pixel whose footprint on the plane is [x0, x1]:

    pixel = 1/2 + 1/2 (sin(k x1) - sin(k x0)) / (k (x1 - x0)) jinc(k rho),

with jinc(z) = 2 J1(z) / z, over the footprint [x0, x1]; and for a plane that is white where x < e, the pixel is the mean
over its footprint of the share of the disk left of e,
(z sqrt(1 - z^2) + asin z + pi/2) / pi with z = (e - x) / rho.
"""

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from scipy import integrate, special

from conftest import assert_finite, limit_whitted
from mitsuba_whitted.compare import equivalence_test
from mitsuba_whitted.integrators import whitted as whitted_module
from validation.scenes import integrator, scene

SIZE, FOV, DISTANCE = 32, 30.0, 10.0
#: Width of a pixel's footprint on the plane at DISTANCE.
PIXEL = 2 * DISTANCE * math.tan(math.radians(FOV / 2)) / SIZE
WAVENUMBER = 2 * math.pi / (5 * PIXEL)


class CosinePlane(mi.Texture):
    """1/2 + 1/2 cos(k x) on world x (a test texture)."""

    def __init__(self, props):
        mi.Texture.__init__(self, props)

    def eval(self, si, active=True):
        return mi.Color3f(self.eval_1(si, active))

    def eval_1(self, si, active=True):
        return 0.5 + 0.5 * dr.cos(WAVENUMBER * si.p.x)

    def eval_3(self, si, active=True):
        return self.eval(si, active)

    def mean(self):
        return 0.5

    def is_spatially_varying(self):
        return True

    def to_string(self):
        return "CosinePlane[]"


def thin_lens(aperture, focus, size=SIZE):
    return {"type": "thinlens", "fov": FOV, "aperture_radius": aperture,
            "focus_distance": focus,
            "to_world": mi.ScalarTransform4f().look_at([0, 0, 0], [0, 0, -1], [0, 1, 0]),
            "film": {"type": "hdrfilm", "width": size, "height": size,
                     "rfilter": {"type": "box"}}}


def plane(radiance, left=-50.0, right=50.0):
    """An emitting rectangle at z = -DISTANCE covering left <= x <= right."""
    T = mi.ScalarTransform4f
    centre, half = (left + right) / 2, (right - left) / 2
    return {"type": "rectangle",
            "to_world": T().translate([centre, 0, -DISTANCE]) @ T().scale([half, 50, 1]),
            "emitter": {"type": "area", "radiance": radiance}}


def cosine_scene(sensor):
    return mi.load_dict(scene(sensor=sensor, plane=plane(CosinePlane(mi.Properties()))))


def footprints(sensor_dict) -> np.ndarray:
    """(left, right) x of each pixel column's footprint on the plane, from
    the pinhole rays of a perspective camera with the same view."""
    pinhole = mi.load_dict({**{k: v for k, v in sensor_dict.items()
                               if k not in ("aperture_radius", "focus_distance")},
                            "type": "perspective"})
    edges = dr.arange(mi.Float, SIZE + 1) / SIZE
    ray, _ = pinhole.sample_ray(0, 0.5, mi.Point2f(edges, 0.5), mi.Point2f(0.5))
    x = np.array(ray.o.x + (-DISTANCE - ray.o.z) / ray.d.z * ray.d.x, dtype=np.float64)
    return np.stack([np.minimum(x[:-1], x[1:]), np.maximum(x[:-1], x[1:])], axis=1)


def mean_cosine(sensor_dict, wavenumber: float, rho: float) -> np.ndarray:
    """Each pixel column's mean of cos(k x) over its footprint and the blur
    disk (see the module's docstring)."""
    left, right = footprints(sensor_dict).T
    over_pixel = (np.sin(wavenumber * right) - np.sin(wavenumber * left)) / (
        wavenumber * (right - left))
    jinc = 1.0 if rho == 0 else 2 * special.j1(wavenumber * rho) / (wavenumber * rho)
    return over_pixel * jinc


def cosine_closed_form(sensor_dict, rho: float) -> tuple:
    """Each pixel column's value, and the variance of the radiance over the
    pixel and the lens: with c = cos(k x), E[(1/2 + c/2)^2] =
    1/4 + E[c]/2 + (1 + E[cos(2 k x)]) / 8."""
    mean = mean_cosine(sensor_dict, WAVENUMBER, rho)
    square = 0.25 + 0.5 * mean + (1 + mean_cosine(sensor_dict, 2 * WAVENUMBER, rho)) / 8
    value = 0.5 + 0.5 * mean
    return value, square - value * value


def render(loaded, **settings):
    whitted = mi.load_dict(integrator(**settings))
    image = np.array(mi.render(loaded, integrator=whitted))
    assert_finite(image)
    return image, whitted


ANTI_ALIASING = {
    "grid 16 x 16": dict(aa="grid", aa_samples=16, aa_budget=256),
    "contrast 16 x 16": dict(aa="contrast", aa_samples=16, aa_threshold=0.0, aa_budget=257),
    "adaptive to level 3": dict(aa="adaptive", aa_max_depth=3, aa_threshold=0.0,
                                aa_budget=340),
}



def assert_rows_match(image: np.ndarray, expected: np.ndarray, bias: float) -> None:
    """Every row of the image should hold ``expected``. Each pixel pairs
    its film and lens strata through permutations and places its lens
    points by hashes of its own, so its error is one draw of a randomised
    quadrature whose mean is the exact value up to ``bias`` (what the
    film's strata centres leave): a column's mean over the rows must lie
    within 5 standard errors of the closed form (p ~ 6e-7 per column),
    plus that bias."""
    rows = image[:, :, 0].astype(np.float64)
    error = rows.mean(axis=0) - expected
    standard_error = rows.std(axis=0, ddof=1) / math.sqrt(len(rows))
    assert (np.abs(error) <= 5 * standard_error + bias).all(), (
        f"worst column {np.argmax(np.abs(error) - 5 * standard_error)}: error "
        f"{np.abs(error).max():.2e}, standard error {standard_error.max():.2e}")


def assert_stratified(image: np.ndarray, expected: np.ndarray, variance: np.ndarray,
                      samples: int, gain: float) -> None:
    """The pixels' RMS error is at most ``gain`` times what ``samples``
    independent uniform samples would give, sqrt(variance / samples).
    Jittered strata that pair fully in every two coordinates make the error
    fall as N^-1/2 - 1/(2 d) for an integrand ruled by d coordinates at a
    time, so ``gain`` is N^-1/(2 d): a smooth blur of a film coordinate
    with a lens coordinate, d = 2; an edge, whose blur couples a film
    coordinate with both lens coordinates (through the map of the square
    onto the aperture disk) and is discontinuous, d = 3."""
    error = image[:, :, 0] - expected
    rms = math.sqrt(np.mean(np.square(error)))
    random_rms = math.sqrt(np.mean(np.broadcast_to(variance, error.shape)) / samples)
    assert rms <= gain * random_rms, (rms, random_rms)


@pytest.mark.parametrize("settings", ANTI_ALIASING.values(), ids=ANTI_ALIASING.keys())
@pytest.mark.parametrize("focus", [DISTANCE, DISTANCE / 2], ids=["in focus", "out of focus"])
def test_a_cosine_plane_is_blurred_by_the_circle_of_confusion(settings, focus):
    """Out of focus, the aperture (0.4, so rho = 0.4 and jinc(k rho) =
    0.27) takes out three quarters of the cosine's amplitude; a pinhole
    would keep it all. The rows' mean is within its statistical bound (16
    film columns per pixel leave a bias of (k s / 16)^2 / 24 of the
    amplitude, below 2e-4), and the pixels' error is that of stratified
    samples."""
    sensor = thin_lens(0.4, focus)
    image, _ = render(cosine_scene(sensor), **settings)
    expected, variance = cosine_closed_form(sensor, 0.4 * abs(1 - DISTANCE / focus))
    assert_rows_match(image, expected, bias=2e-4)
    assert_stratified(image, expected, variance, 256, gain=256 ** (-1 / 4))


def disk_share_left_of(z: np.ndarray) -> np.ndarray:
    """Share of a unit disk where x < z."""
    z = np.clip(z, -1.0, 1.0)
    return (z * np.sqrt(1 - z * z) + np.arcsin(z) + math.pi / 2) / math.pi


def edge_closed_form(sensor_dict, edge: float, rho: float) -> np.ndarray:
    """Each column's value for a plane white left of x = edge."""
    values = []
    for left, right in footprints(sensor_dict):
        if rho == 0:
            share = np.clip((edge - left) / (right - left), 0, 1)
        else:
            share = integrate.quad(lambda x: disk_share_left_of((edge - x) / rho), left, right,
                                   points=[edge - rho, edge + rho], limit=200)[0] / (right - left)
        values.append(share)
    return np.array(values)


def test_an_edge_is_sharp_on_the_focus_plane():
    """Contrast refinement's 256 Hammersley points place a vertical edge to
    1/256 of a pixel, through a thin lens as through a pinhole."""
    edge = 0.37 * PIXEL
    sensor = thin_lens(0.5, DISTANCE)
    image, _ = render(edge_scene(sensor, edge), aa="contrast", aa_samples=16,
                      aa_threshold=0.01, aa_budget=257)
    np.testing.assert_allclose(image[:, :, 0], np.broadcast_to(
        edge_closed_form(sensor, edge, 0.0), (SIZE, SIZE)), atol=1 / 256 + 1e-6)


def test_an_edge_off_the_focus_plane_is_blurred_by_the_circle_of_confusion():
    """Out of focus (rho = 0.5, three pixels) the blur moves pixels by up to
    0.5 from the sharp edge; with a 16 x 16 grid the rows' mean is within
    its statistical bound and the pixels' error that of stratified samples
    (a pixel's radiance is 0 or 1: its variance is m (1 - m))."""
    edge = 0.37 * PIXEL
    sensor = thin_lens(0.5, DISTANCE / 2)
    image, _ = render(edge_scene(sensor, edge), aa="grid", aa_samples=16, aa_budget=256)
    expected = edge_closed_form(sensor, edge, 0.5)
    assert np.abs(expected - edge_closed_form(sensor, edge, 0.0)).max() > 0.3
    assert_rows_match(image, expected, bias=1e-4)
    assert_stratified(image, expected, expected * (1 - expected), 256, gain=256 ** (-1 / 6))


def edge_scene(sensor, edge):
    return mi.load_dict(scene(sensor=sensor, plane=plane({"type": "rgb", "value": 1.0},
                                                         right=edge)))


def test_a_thin_lens_image_equals_path_in_expectation():
    """The statistical equivalence test (Welch t per pixel, family-wise
    false-alarm rate 1e-3) against 32 batches of 64 spp of Mitsuba's own
    ``path`` through the same thin lens."""
    sensor = thin_lens(0.4, DISTANCE / 2, size=16)
    loaded = cosine_scene(sensor)
    image, _ = render(loaded, aa="grid", aa_samples=16, aa_budget=256)
    path = mi.load_dict({"type": "path", "max_depth": 2})
    batches = np.stack([np.array(mi.render(loaded, integrator=path, spp=64, seed=batch))
                        .reshape(-1, 3) for batch in range(32)])
    result = equivalence_test(image.reshape(1, -1, 3), batches)
    assert result.passed, result.summary()
    pinhole, _ = render(cosine_scene(thin_lens(0.0, DISTANCE / 2, size=16)), aa="grid",
                        aa_samples=16, aa_budget=256)
    assert not equivalence_test(pinhole.reshape(1, -1, 3), batches).passed


@pytest.mark.parametrize("settings", ANTI_ALIASING.values(), ids=ANTI_ALIASING.keys())
def test_depth_of_field_is_deterministic_and_does_not_depend_on_bands(settings, monkeypatch):
    """Bands of four rows of 16 pixels, each allowed all its samples."""
    loaded = cosine_scene(thin_lens(0.4, DISTANCE / 2, size=16))
    whole, _ = render(loaded, **settings)
    np.testing.assert_array_equal(render(loaded, **settings)[0], whole)
    per_pixel = 1 if settings["aa"] == "grid" else settings["aa_budget"]
    limit_whitted(monkeypatch, typical_samples=settings["aa_budget"],
                  band_samples=4 * 16 * per_pixel)
    banded, whitted = render(loaded, **settings)
    assert whitted.last_stats["bands"] > 1
    np.testing.assert_array_equal(banded, whole)


def test_pixel_centres_through_a_thin_lens_are_a_pinhole_and_say_so(monkeypatch):
    warnings = []
    monkeypatch.setattr(whitted_module, "_warn", warnings.append)
    sensor = thin_lens(0.4, DISTANCE / 2, size=16)
    thin, _ = render(cosine_scene(sensor), aa="none")
    pinhole, _ = render(cosine_scene(thin_lens(1e-9, DISTANCE / 2, size=16)), aa="none")
    np.testing.assert_array_equal(thin, pinhole)
    assert len(warnings) == 1 and "no depth of field" in warnings[0]
