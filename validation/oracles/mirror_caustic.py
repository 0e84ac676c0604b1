"""Float64 closed form for a caustic: a point light under a planar mirror
over a diffuse floor.

The floor is the plane y = 0 (diffuse, albedo ``rho``), the point light of
intensity ``I`` is at height ``h``, and a rectangular perfect mirror facing
down hangs at height ``H > h`` over part of the floor. What the mirror sends
to the floor is the light of the light's image in it, the virtual source at
height ``2H - h`` straight above the light, restricted to the floor points
whose segment to the virtual source crosses the mirror's rectangle. So the
floor's irradiance is

    E(x) = I cos(theta) / d^2  +  [x in the footprint] I R cos(theta') / d'^2

(``d``, ``theta``: distance to the light and incidence angle; ``d'``,
``theta'``: the same for the virtual source; ``R``: the mirror's
reflectance, 1 for Mitsuba's ``conductor`` with ``material`` "none"), and
its radiance ``rho / pi * E(x)``.

The scene's depth is 3: Mitsuba's ``max_depth`` (and ``whitted``'s) counts
the segments of the whole path, camera included, so camera -> floor ->
light is 2 and camera -> floor -> mirror -> light is 3. At 3 the light
that leaves the floor, bounces off the mirror and comes back to the floor
(4 segments) is left out, so the closed form is the whole answer. ``path``
samples the direct part exactly (a point light's shadow ray) and never the
mirror's, since no sampled direction from the floor hits a point light:
it renders the direct part alone. The camera hangs below the mirror and
looks down, so no camera ray meets it.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsuba_whitted.camera import camera_rays, pixel_centres
from validation import scenes

#: The scene: floor albedo, the light (position, intensity), the mirror
#: (height, centre in x and z, half sizes in x and z).
RHO = 0.6
LIGHT, INTENSITY = (0.2, 1.5, -0.1), 10.0
MIRROR_HEIGHT, MIRROR_CENTRE, MIRROR_HALF = 2.0, (0.1, -0.2), (0.16, 0.12)
#: Segments of the longest path counted (see the module docstring).
DEPTH = 3
#: Sub-pixel grid of the edge test: points per side, corners included.
EDGE_GRID = 5


def mirror_caustic_scene(size: int = 64, with_mirror: bool = True) -> dict:
    """The floor, the light and (``with_mirror``) the mirror, seen from
    below the mirror by a box-filtered ``size`` x ``size`` camera; its
    ``whitted`` has ``max_depth`` 3."""
    floor = scenes.floor(y=0.0, size=8.0, bsdf=scenes.diffuse(RHO, RHO, RHO))
    sensor = scenes.camera(origin=(0.0, 1.8, 2.2), target=(0.0, 0.0, -0.1), fov=45, size=size)
    named = {"floor": floor, "lamp": scenes.point_light(LIGHT, INTENSITY)}
    if with_mirror:
        placement = (mi.ScalarTransform4f()
                     .translate([MIRROR_CENTRE[0], MIRROR_HEIGHT, MIRROR_CENTRE[1]])
                     .rotate([1, 0, 0], 90).scale([MIRROR_HALF[0], MIRROR_HALF[1], 1]))
        named["mirror"] = {"type": "rectangle", "to_world": placement,
                           "bsdf": {"type": "conductor", "material": "none"}}
    return scenes.scene(sensor=sensor, whitted=scenes.integrator(max_depth=DEPTH), **named)


def virtual_source() -> np.ndarray:
    """The light mirrored in the mirror's plane."""
    x, h, z = LIGHT
    return np.array([x, 2 * MIRROR_HEIGHT - h, z])


def in_footprint(points: np.ndarray) -> np.ndarray:
    """Whether each floor point's (N, 3) segment to the virtual source
    crosses the mirror's rectangle."""
    source = virtual_source()
    along = MIRROR_HEIGHT / source[1]    # where the segment reaches the mirror's height
    crossing = points + along * (source - points)
    return ((np.abs(crossing[:, 0] - MIRROR_CENTRE[0]) <= MIRROR_HALF[0])
            & (np.abs(crossing[:, 2] - MIRROR_CENTRE[1]) <= MIRROR_HALF[1]))


def point_irradiance(points: np.ndarray, source: np.ndarray, intensity: float) -> np.ndarray:
    """Irradiance on the floor (normal +y) at (N, 3) ``points`` from a point
    source above it: I cos(theta) / d^2 = I (height) / d^3."""
    offset = source - points
    distance = np.linalg.norm(offset, axis=1)
    return intensity * offset[:, 1] / distance ** 3


def floor_radiance(points: np.ndarray, reflectance: float = 1.0) -> dict:
    """Float64 radiance of the floor at (N, 3) ``points``: ``direct``,
    ``mirror`` and their sum ``total`` (grey, one value per point)."""
    direct = point_irradiance(points, np.array(LIGHT, dtype=np.float64), INTENSITY)
    mirror = np.where(in_footprint(points),
                      point_irradiance(points, virtual_source(), INTENSITY * reflectance), 0.0)
    scale = RHO / math.pi
    return {"direct": scale * direct, "mirror": scale * mirror, "total": scale * (direct + mirror)}


def floor_points(sensor: mi.Sensor, positions: mi.Point2f) -> np.ndarray:
    """Where the camera rays through ``positions`` meet the plane y = 0,
    in float64 from the rays Mitsuba makes."""
    ray, _ = camera_rays(sensor, positions)
    o = np.array(ray.o, dtype=np.float64).T
    d = np.array(ray.d, dtype=np.float64).T
    if not (d[:, 1] < 0).all():
        raise ValueError("a camera ray of the mirror caustic scene does not go down to the floor")
    return o + (-o[:, 1] / d[:, 1])[:, None] * d


def _grid_positions(film: mi.Film, points_per_side: int) -> mi.Point2f:
    """A grid of points per pixel, its corners on the pixel's corners."""
    width, height = film.crop_size()
    per_pixel = points_per_side ** 2
    index = dr.arange(mi.UInt32, width * height * per_pixel)
    pixel, cell = index // per_pixel, index % per_pixel
    step = 1.0 / (points_per_side - 1)
    return mi.Point2f(mi.Float(pixel % width) + mi.Float(cell % points_per_side) * step,
                      mi.Float(pixel // width) + mi.Float(cell // points_per_side) * step)


def exact_image(scene: mi.Scene, reflectance: float = 1.0) -> dict:
    """Float64 (height, width) arrays of the floor's radiance at the pixel
    centres (``direct``, ``mirror``, ``total``, as ``aa`` none renders), and
    ``valid``: False where the footprint's edge crosses the pixel (a grid of
    ``EDGE_GRID`` points per side, the pixel's corners among them, is
    neither all inside nor all outside): elsewhere the light is smooth across
    the pixel, so its box-filtered mean differs from the centre's value by
    the light's curvature over a pixel only; ``footprint``: True where the
    whole pixel is inside."""
    sensor = scene.sensors()[0]
    film = sensor.film()
    width, height = film.crop_size()
    values = floor_radiance(floor_points(sensor, pixel_centres(film)), reflectance)
    image = {name: value.reshape(height, width) for name, value in values.items()}
    inside = in_footprint(floor_points(sensor, _grid_positions(film, EDGE_GRID)))
    inside = inside.reshape(height, width, EDGE_GRID ** 2)
    image["valid"] = inside.all(axis=2) | ~inside.any(axis=2)
    image["footprint"] = inside.all(axis=2)
    return image
