"""Small scenes, as dictionaries, shared by the tests."""

from __future__ import annotations

import mitsuba as mi


def camera(origin=(0, 0, 5), target=(0, 0, 0), up=(0, 1, 0), fov=40, size=24, crop=None,
           far_clip=1e4):
    film = {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"}}
    if crop is not None:
        film.update(crop)
    return {
        "type": "perspective", "fov": fov, "far_clip": far_clip,
        "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=target, up=up),
        "film": film,
    }


def rgb(*value):
    return {"type": "rgb", "value": list(value)}


def sphere(center, radius, bsdf):
    return {"type": "sphere", "center": list(center), "radius": radius, "bsdf": bsdf}


def diffuse(*color):
    return {"type": "diffuse", "reflectance": rgb(*color)}


def point_light(position, intensity=20.0):
    return {"type": "point", "position": list(position), "intensity": rgb(intensity, intensity, intensity)}


def integrator(**settings):
    return {"type": "whitted", **settings}


def scene(*objects, sensor=None, whitted=None, **named):
    description = {"type": "scene", "sensor": sensor or camera()}
    if whitted is not None:
        description["integrator"] = whitted
    for index, obj in enumerate(objects):
        description[f"object_{index}"] = obj
    description.update(named)
    return description


def floor(y=-1.0, size=4.0, bsdf=None):
    transform = (mi.ScalarTransform4f().translate([0, y, 0])
                 .rotate([1, 0, 0], -90).scale(size))
    return {"type": "rectangle", "to_world": transform, "bsdf": bsdf or diffuse(0.6, 0.6, 0.6)}


def wall(z=-2.0, size=4.0, bsdf=None):
    transform = mi.ScalarTransform4f().translate([0, 0, z]).scale(size)
    return {"type": "rectangle", "to_world": transform, "bsdf": bsdf or diffuse(0.5, 0.5, 0.5)}


def glass_scene(size=48):
    """A mirror ball, a glass ball, a floor, a small area light and a point light."""
    mirror_ball = sphere((-0.8, 0, 0), 0.6, {"type": "conductor"})
    glass = sphere((0.7, 0, 0.3), 0.6, {"type": "dielectric"})
    lamp = {"type": "sphere", "center": [0, 2, 2], "radius": 0.3,
            "emitter": {"type": "area", "radiance": rgb(10, 10, 10)}}
    return scene(floor(), mirror_ball, glass, lamp, point_light((1, 3, 3)),
                 sensor=camera(origin=(0, 1, 5), size=size))
