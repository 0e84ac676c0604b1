"""The project's own scenes for the validation report.

``EQUIVALENCE`` lists scenes where the Whitted model and path tracing agree
in expectation (light reaches the camera only along delta paths from delta
lights, or through the sampled direct light of a small area light), and two
broken cases the test must reject. ``SPEED`` lists the scene files of the
speed-against-error section.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import mitsuba as mi

ROOT = Path(__file__).resolve().parent.parent
REPORT_SCENE = ROOT / "scenes" / "cosc363.xml"
SPEED = [ROOT / "scenes" / "cosc363.xml", ROOT / "scenes" / "cases" / "glass_spheres.xml",
         ROOT / "scenes" / "cases" / "mirror_chain.xml", ROOT / "scenes" / "cases" / "cylinder.xml"]

#: Image side of the equivalence scenes (pixel-centre rays).
SIZE = 32
#: Seeds averaged by Whitted where area lights make it an estimate.
SAMPLED_SEEDS = tuple(range(16))
#: The "blend" case: this diffuse colour blended with a perfect mirror.
BLEND_DIFFUSE, BLEND_WEIGHT = (0.7, 0.2, 0.2), 0.6


@dataclass
class EquivalenceCase:
    name: str
    checks: str
    whitted_scene: dict
    path_scene: dict | None = None   # default: the same scene
    seeds: tuple = (0,)
    expect_agree: bool = True
    settings: dict = field(default_factory=dict)


def _rgb(*value):
    return {"type": "rgb", "value": list(value)}


def _camera(origin=(0, 0, 5), target=(0, 0, 0), fov=40):
    return {"type": "perspective", "fov": fov,
            "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=target, up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": SIZE, "height": SIZE,
                     "rfilter": {"type": "box"}}}


def _scene(*objects, sensor=None, **named):
    description = {"type": "scene", "sensor": sensor or _camera()}
    description.update({f"object_{i}": obj for i, obj in enumerate(objects)})
    description.update(named)
    return description


def _sphere(center, radius, bsdf):
    return {"type": "sphere", "center": list(center), "radius": radius, "bsdf": bsdf}


def _diffuse(*colour):
    return {"type": "diffuse", "reflectance": _rgb(*colour)}


def _point(position, intensity=20.0):
    return {"type": "point", "position": list(position), "intensity": _rgb(intensity, intensity,
                                                                            intensity)}


def _floor(size=3.0):
    return {"type": "rectangle", "bsdf": _diffuse(0.6, 0.6, 0.6),
            "to_world": mi.ScalarTransform4f().translate([0, -1, 0]).rotate([1, 0, 0], -90)
            .scale(size)}


def _backdrop(z=-3.0):
    """An emitting checkerboard behind the scene, seen through glass."""
    radiance = {"type": "checkerboard", "color0": _rgb(0.2, 0.4, 1.0),
                "color1": _rgb(1.0, 0.8, 0.3), "to_uv": mi.ScalarTransform4f().scale([8, 8, 1])}
    return {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, z]).scale(4),
            "emitter": {"type": "area", "radiance": radiance}, "bsdf": _diffuse(0, 0, 0)}


def _sky():
    return {"type": "constant", "radiance": _rgb(0.5, 0.5, 0.5)}


def _glass(reflection=1.0):
    """Fresnel glass; ``reflection`` < 1 scales its reflected part (wrong)."""
    return {"type": "dielectric", "int_ior": 1.5,
            "specular_reflectance": _rgb(reflection, reflection, reflection)}


def _mirror_chain():
    silver = {"type": "conductor", "material": "Ag"}
    facing = mi.ScalarTransform4f().translate([0, 0, 1.5]).rotate([0, 1, 0], 180)
    return _scene(
        {"type": "rectangle", "bsdf": silver,
         "to_world": mi.ScalarTransform4f().translate([0, 0, -1.5]).scale([2, 1.5, 1])},
        {"type": "rectangle", "bsdf": silver, "to_world": facing.scale([2, 1.5, 1])},
        _sphere((-0.3, 0, 0), 0.4, _diffuse(0.8, 0.3, 0.2)), _point((0, 1.2, 0.3), 6.0),
        sensor=_camera(origin=(0.3, 2.0, 1.9), target=(-0.2, -0.2, -1.5), fov=50))


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


def _cylinders():
    """The exact capped cylinder (Whitted) and Mitsuba's cylinder with two
    disks (path): the same solid."""
    material = _diffuse(0.7, 0.6, 0.2)
    transform = mi.ScalarTransform4f().translate([0, -0.8, 0]).scale([0.8, 1.4, 0.8])
    sensor, light = _camera(origin=(2, 2.5, 4)), _point((2, 3, 3))
    capped = {"type": "capped_cylinder", "center": [0, -0.8, 0], "radius": 0.8,
              "height": 1.4, "segments": 10, "bsdf": material}
    return (_scene(capped, light, sensor=sensor),
            _scene(light, sensor=sensor, **builtin_cylinder(transform, material)))


def blend_scene(diffuse=BLEND_DIFFUSE) -> dict:
    """A sphere of ``diffuse`` blended with a perfect mirror (weight
    BLEND_WEIGHT) under a point light, before an emitting backdrop."""
    blend = {"type": "blendbsdf", "weight": BLEND_WEIGHT, "bsdf_0": _diffuse(*diffuse),
             "bsdf_1": {"type": "conductor"}}
    return _scene(_sphere((0, 0, 0), 1, blend), _point((2, 3, 4)), _backdrop(z=-2.5))


def _cornell_box():
    box = mi.cornell_box()
    box["sensor"]["film"].update(width=SIZE, height=SIZE)
    box.pop("integrator")
    return box


def equivalence_cases() -> list[EquivalenceCase]:
    spot = {"type": "spot", "intensity": _rgb(30, 30, 30), "cutoff_angle": 25, "beam_width": 15,
            "to_world": mi.ScalarTransform4f().look_at(origin=[1, 3, 1], target=[0, -1, 0],
                                                       up=[0, 0, 1])}
    sun = {"type": "directional", "direction": [-1, -2, -0.5], "irradiance": _rgb(0.6, 0.5, 0.4)}
    phong = {"type": "phong", "diffuse_reflectance": _rgb(0.6, 0.3, 0.1),
             "specular_reflectance": _rgb(0.3, 0.3, 0.3), "exponent": 20.0}
    tartan = {"type": "phong", "exponent": 40.0,
              "diffuse_reflectance": {"type": "tartan", "frequency": 6.0}}
    plastic = {"type": "plastic", "diffuse_reflectance": _rgb(0.2, 0.3, 0.8)}
    lamp = {"type": "sphere", "center": [0.5, 1.0, 0.5], "radius": 0.2,
            "emitter": {"type": "area", "radiance": _rgb(15, 15, 15)}}
    capped, builtin = _cylinders()
    glass = _scene(_sphere((0, 0, 0), 1, _glass()), _backdrop(), _sky())
    return [
        EquivalenceCase("diffuse + point light", "direct light, hard shadow edge of the sphere",
                        _scene(_sphere((0, 0, 0), 1, _diffuse(0.8, 0.5, 0.2)), _point((2, 3, 4)))),
        EquivalenceCase("Phong", "the normalized Phong lobe under two point lights",
                        _scene(_sphere((0, 0, 0), 1, phong), _point((2, 3, 4)),
                               _point((-3, 1, 4), 8.0))),
        EquivalenceCase("tartan texture", "procedural texture inside Phong",
                        _scene(_sphere((0, 0, 0), 1, tartan), _point((2, 3, 4)))),
        EquivalenceCase("mirror chain", "two facing silver mirrors, many bounces",
                        _mirror_chain(), settings={"max_depth": 24}),
        EquivalenceCase("Fresnel glass", "Fresnel split into reflection and refraction",
                        glass),
        EquivalenceCase("plastic", "Fresnel-weighted coating over diffuse",
                        _scene(_sphere((0, 0, 0), 1, plastic), _point((2, 3, 4)),
                               _point((-3, 1, 4), 8.0))),
        EquivalenceCase("blend", "blendbsdf of diffuse and conductor", blend_scene(),
                        seeds=SAMPLED_SEEDS),
        EquivalenceCase("capped cylinder", "exact capped cylinder (Whitted) against Mitsuba's "
                        "cylinder + 2 disks (path)", capped, builtin),
        EquivalenceCase("spot + directional", "spot cone and falloff, directional light",
                        _scene(_floor(), spot, sun, sensor=_camera(origin=(0, 3, 4)))),
        EquivalenceCase("small area light", "area light through 16 shadow rays per hit",
                        _scene(_floor(), lamp, sensor=_camera(origin=(0, 3, 4))),
                        seeds=SAMPLED_SEEDS),
        EquivalenceCase("broken: glass reflecting 50%", "Whitted's glass reflects half what "
                        "Fresnel says; path renders correct glass",
                        _scene(_sphere((0, 0, 0), 1, _glass(0.5)), _backdrop(), _sky()),
                        glass, expect_agree=False),
        EquivalenceCase("broken: Cornell box", "interreflection, which Whitted leaves out",
                        _cornell_box(), seeds=SAMPLED_SEEDS, expect_agree=False),
    ]
