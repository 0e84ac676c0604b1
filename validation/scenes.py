"""The project's scene library: small scenes as dictionaries for
``mi.load_dict``, which the test suite and the validation report both build
from, and the scene files of the report.

Every builder returns plain data, so that a description is also the cache
key of its path reference (``compare.cache_key`` hashes its JSON): a builder
adds a parameter to a description only when it is given, and keeps its
defaults, or every cached reference built from it would be rendered anew.
"""

from __future__ import annotations

import math
from pathlib import Path

import mitsuba as mi

ROOT = Path(__file__).resolve().parent.parent
REPORT_SCENE = ROOT / "scenes" / "cosc363.xml"
#: A closed box with glass, a mirror and a point light: mostly indirect light.
GLASS_BOX = ROOT / "scenes" / "cases" / "glass_box.xml"
#: :func:`glass_ball_caustic` as a scene file, for the speed section.
GLASS_BALL = ROOT / "scenes" / "cases" / "glass_ball_caustic.xml"
SPEED = [ROOT / "scenes" / "cosc363.xml", ROOT / "scenes" / "cases" / "glass_spheres.xml",
         ROOT / "scenes" / "cases" / "mirror_chain.xml", ROOT / "scenes" / "cases" / "cylinder.xml",
         GLASS_BOX, GLASS_BALL]


def camera(origin=(0, 0, 5), target=(0, 0, 0), up=(0, 1, 0), fov=40, size=24, crop=None,
           **clip):
    """A perspective camera with a square box-filtered film of ``size``
    pixels; ``crop`` updates the film (``crop_width`` ...), ``clip`` sets
    ``near_clip`` and ``far_clip``."""
    film = {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"}}
    if crop is not None:
        film.update(crop)
    return {"type": "perspective", "fov": fov, **clip,
            "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=target, up=up),
            "film": film}


def rgb(*value):
    return {"type": "rgb", "value": list(value)}


def sphere(center, radius, bsdf):
    return {"type": "sphere", "center": list(center), "radius": radius, "bsdf": bsdf}


def diffuse(*color):
    return {"type": "diffuse", "reflectance": rgb(*color)}


def point_light(position, intensity=20.0):
    return {"type": "point", "position": list(position),
            "intensity": rgb(intensity, intensity, intensity)}


def integrator(**settings):
    return {"type": "whitted", **settings}


def scene(*objects, sensor=None, whitted=None, **named):
    """A scene of ``objects`` (named ``object_0``, ...) and ``named`` ones,
    seen by ``sensor`` (default: :func:`camera`), rendered by ``whitted``
    when given."""
    description = {"type": "scene", "sensor": sensor or camera()}
    if whitted is not None:
        description["integrator"] = whitted
    for index, obj in enumerate(objects):
        description[f"object_{index}"] = obj
    description.update(named)
    return description


def floor(y=-1.0, size=4.0, bsdf=None):
    """A square of half-side ``size`` in the plane at height ``y``, facing up."""
    transform = (mi.ScalarTransform4f().translate([0, y, 0])
                 .rotate([1, 0, 0], -90).scale(size))
    return {"type": "rectangle", "to_world": transform, "bsdf": bsdf or diffuse(0.6, 0.6, 0.6)}


def wall(z=-2.0, size=4.0, bsdf=None):
    """A square of half-side ``size`` in the plane at depth ``z``, facing +z."""
    transform = mi.ScalarTransform4f().translate([0, 0, z]).scale(size)
    return {"type": "rectangle", "to_world": transform, "bsdf": bsdf or diffuse(0.5, 0.5, 0.5)}


def backdrop(z=-3.0):
    """An emitting checkerboard wall, black itself, to be seen through glass
    and in mirrors."""
    radiance = {"type": "checkerboard", "color0": rgb(0.2, 0.4, 1.0),
                "color1": rgb(1.0, 0.8, 0.3), "to_uv": mi.ScalarTransform4f().scale([8, 8, 1])}
    return dict(wall(z, bsdf=diffuse(0, 0, 0)), emitter={"type": "area", "radiance": radiance})


def sky(radiance=0.5):
    """A uniform environment light."""
    return {"type": "constant", "radiance": rgb(radiance, radiance, radiance)}


def builtin_cylinder(to_world: mi.ScalarTransform4f, bsdf: dict | None = None) -> dict:
    """Mitsuba's cylinder (axis z, open) and two disks, placed on the solid
    that ``to_world`` makes of the capped cylinder's canonical one (axis y,
    0 <= y <= 1, radius 1)."""
    up = mi.ScalarTransform4f().rotate([1, 0, 0], -90)
    parts = {"side": to_world @ up,
             "bottom": to_world @ mi.ScalarTransform4f().rotate([1, 0, 0], 90),
             "top": to_world @ mi.ScalarTransform4f().translate([0, 1, 0]) @ up}
    return {name: {"type": "cylinder" if name == "side" else "disk", "to_world": placement,
                   **({"bsdf": bsdf} if bsdf else {})}
            for name, placement in parts.items()}


def glass_scene(size=48):
    """A mirror ball, a glass ball, a floor, a small area light and a point light."""
    mirror_ball = sphere((-0.8, 0, 0), 0.6, {"type": "conductor"})
    glass = sphere((0.7, 0, 0.3), 0.6, {"type": "dielectric"})
    lamp = {"type": "sphere", "center": [0, 2, 2], "radius": 0.3,
            "emitter": {"type": "area", "radiance": rgb(10, 10, 10)}}
    return scene(floor(), mirror_ball, glass, lamp, point_light((1, 3, 3)),
                 sensor=camera(origin=(0, 1, 5), size=size))


# --- caustics and pass-through shadows -----------------------------------------
#
# Scenes where Mitsuba's ``path`` is wrong or slow: a delta light seen by a
# smooth surface through delta surfaces (a caustic, which ``path`` never
# samples from a point light), and a shadow cast by a surface that bends no
# light. ``validation.oracles.light_tracer`` gives their reference.

#: Whitted settings of the caustic scenes: deep enough for the ball's
#: internal reflections.
CAUSTIC_DEPTH = 8
#: The caustic scenes' ball (resting on the floor at y = 0) and lamp: the
#: lamp is low enough to the side that the focused light lands on the floor
#: beside the ball, in view.
CAUSTIC_BALL_CENTRE, CAUSTIC_BALL_RADIUS = (0.0, 0.5, 0.0), 0.5
CAUSTIC_LAMP, CAUSTIC_INTENSITY = (-2.5, 2.2, 0.0), 20.0


def caustic_ball_scene(ball_bsdf: dict, lamp: dict | None = None, size=128) -> dict:
    """A ball of ``ball_bsdf`` on a diffuse floor (y = 0), lit by ``lamp``
    (default: the caustic point light), seen from the front and above with
    a box-filtered film of ``size`` pixels (default 128)."""
    sensor = camera(origin=(0.6, 2.4, 3.6), target=(0.6, 0.2, 0.0), fov=40,
                    size=size)
    return scene(floor(y=0.0, size=6.0), sphere(CAUSTIC_BALL_CENTRE, CAUSTIC_BALL_RADIUS,
                                               ball_bsdf),
                 lamp or point_light(CAUSTIC_LAMP, CAUSTIC_INTENSITY), sensor=sensor,
                 whitted=integrator(max_depth=CAUSTIC_DEPTH))


def glass_ball_caustic(size=128) -> dict:
    """A glass ball (index 1.5) focusing a point light onto the floor."""
    return caustic_ball_scene({"type": "dielectric", "int_ior": 1.5}, size=size)


def mirror_ball_caustic(size=128) -> dict:
    """A perfect mirror ball reflecting a point light onto the floor."""
    return caustic_ball_scene({"type": "conductor", "material": "none"}, size=size)


def small_sphere_lamp(position, intensity: float, radius: float) -> dict:
    """A sphere area light with the radiant intensity of a point light of
    ``intensity``: seen from any direction it shows pi r^2 of radiance
    ``intensity / (pi r^2)``. As ``radius`` shrinks its light tends to the
    point light's, and ``path`` samples the caustic (by BSDF sampling
    through the ball, hitting the lamp) however slowly."""
    radiance = intensity / (math.pi * radius ** 2)
    return {"type": "sphere", "center": list(position), "radius": radius,
            "emitter": {"type": "area", "radiance": rgb(radiance, radiance, radiance)}}


def glass_ball_small_light(radius=0.05, size=128) -> dict:
    """:func:`glass_ball_caustic` with its point light replaced by a small
    sphere of the same power (the small-light limit, where ``path``
    converges too)."""
    return caustic_ball_scene({"type": "dielectric", "int_ior": 1.5},
                              small_sphere_lamp(CAUSTIC_LAMP, CAUSTIC_INTENSITY, radius),
                              size=size)


def index_matched_shadow(size=128) -> dict:
    """A dielectric ball whose index equals its surroundings' (eta 1: it
    bends and reflects nothing) over a diffuse floor under a point light.
    The truth is no shadow; ``path``'s shadow rays stop at the ball."""
    ball = sphere((0.0, 0.8, 0.0), 0.5, {"type": "dielectric", "int_ior": 1.0,
                                          "ext_ior": 1.0})
    sensor = camera(origin=(0.0, 2.4, 3.6), target=(0.0, 0.3, 0.0), fov=40,
                    size=size)
    return scene(floor(y=0.0, size=6.0), ball, point_light((0.6, 3.5, 0.4), CAUSTIC_INTENSITY),
                 sensor=sensor, whitted=integrator(max_depth=CAUSTIC_DEPTH))
