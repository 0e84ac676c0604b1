"""Lights anywhere: at the world origin, on an axis, on a surface, for
every kind of light whitted shades (point, spot, directional, area).

Oracle: Mitsuba's ``path`` (max_depth 2: direct light) on the very
pixel-centre rays whitted's ``aa = "none"`` traces, through the
equivalence test of :mod:`mitsuba_whitted.compare` (Welch's t per pixel
and channel, family-wise false-alarm rate 1e-3). Over diffuse surfaces,
a delta light's path estimate is its light sample alone, the same in every
sample, so whitted must agree to float rounding (the test's floor, 1e-4
of the value); an area light is sampled by both, and they agree within
their noise.
"""

import mitsuba as mi
import numpy as np
import pytest

from conftest import assert_finite
from mitsuba_whitted.camera import camera_rays, pixel_centres
from mitsuba_whitted.compare.equivalence import equivalence_test, path_batches
from validation.scenes import camera, diffuse, floor, integrator, rgb, scene, sphere

T = mi.ScalarTransform4f
#: A diffuse ball in front of the world origin, on a floor at y = -1.
BALL = (0.0, 0.0, -3.0)
SIZE = 16
#: Path batches per pixel and samples per batch; whitted's seeds for
#: area lights (each seed turns their sample pattern).
BATCHES, SPP, SEEDS = 16, 16, 16
#: Where a light sits: the origin, on an axis, on the floor's surface.
PLACES = {"origin": (0.0, 0.0, 0.0), "axis": (0.0, 2.5, 0.0), "surface": (1.5, -1.0, -2.0)}


def point(position):
    return {"type": "point", "position": list(position), "intensity": rgb(8, 8, 8)}


def spot(position):
    return {"type": "spot", "cutoff_angle": 40, "intensity": rgb(8, 8, 8),
            "to_world": T().look_at(origin=list(position), target=list(BALL), up=[0, 1, 0])}


def directional(axis):
    return {"type": "directional", "direction": list(axis), "irradiance": rgb(2, 2, 2)}


def area(position):
    """A square lamp centred at ``position``, facing the ball."""
    return {"type": "rectangle", "emitter": {"type": "area", "radiance": rgb(20, 20, 20)},
            "to_world": T().look_at(origin=list(position), target=list(BALL), up=[0, 1, 0])
            @ T().scale(0.3), "bsdf": diffuse(0, 0, 0)}


LIGHTS = {
    **{f"point at the {place}": point(at) for place, at in PLACES.items()},
    **{f"spot at the {place}": spot(at) for place, at in PLACES.items()},
    "directional along -z": directional((0, 0, -1)),
    "directional along -y": directional((0, -1, 0)),
    "area lamp at the origin": area(PLACES["origin"]),
    "area lamp on an axis": area(PLACES["axis"]),
}


def lit_ball(light):
    return mi.load_dict(scene(floor(), sphere(BALL, 1.0, diffuse(0.7, 0.6, 0.5)), light,
                              sensor=camera(origin=(0, 1, 4), target=(0, -0.3, -2), size=SIZE),
                              whitted=integrator(aa="none", max_depth=2, emitter_samples=16)))


def whitted_pixels(loaded, seeds) -> np.ndarray:
    """(len(seeds), pixels, 3) whitted images, through ``mi.render``."""
    images = []
    for seed in seeds:
        image = np.array(mi.render(loaded, seed=seed))
        assert_finite(image)
        images.append(image[..., :3].reshape(-1, 3))
    return np.stack(images)


@pytest.mark.parametrize("light", LIGHTS.values(), ids=LIGHTS.keys())
def test_a_light_anywhere_renders_as_path_renders_it(light):
    loaded = lit_ball(light)
    sampled = light["type"] == "rectangle"
    whitted = whitted_pixels(loaded, range(SEEDS) if sampled else (0,))
    sensor = loaded.sensors()[0]
    ray, _ = camera_rays(sensor, pixel_centres(sensor.film()))
    path = path_batches(loaded, mi.load_dict({"type": "path", "max_depth": 2}), ray,
                        BATCHES, SPP)
    assert path.max() > 0.05, "the light must reach what the camera sees"
    result = equivalence_test(whitted, path)
    assert result.passed, result.summary()
