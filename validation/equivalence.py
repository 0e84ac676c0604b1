"""The equivalence suite: scenes where the Whitted model and path tracing
agree in expectation (light reaches the camera only along delta paths from
delta lights, or through the sampled direct light of a small area light),
scenes full of indirect light where Whitted agrees once it gathers it
(``indirect_samples``), and broken cases the test must reject: among them
the same scenes rendered by classic Whitted, which leaves that light out.

The test suite (``tests/test_equivalence.py``) and the validation report
(section 1) run these very cases through :func:`run_equivalence`; the
report draws more path samples per ray. The oracle is Mitsuba's own
``path`` integrator on exactly the pixel-centre rays Whitted traces
(``compare.equivalence_test``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import mitsuba as mi
import numpy as np

from mitsuba_whitted import load_file
from mitsuba_whitted.camera import camera_rays, pixel_centres
from mitsuba_whitted.compare import (EquivalenceResult, ReferenceCache, cache_key,
                                     equivalence_test, path_batches, whitted_batches)
from mitsuba_whitted.scene_digest import scene_without_integrator_digest
from validation.scenes import (GLASS_BOX, backdrop, builtin_cylinder, camera, diffuse, floor,
                               point_light, rgb, scene, sky, sphere, wall)

#: Image side of the equivalence scenes (pixel-centre rays).
SIZE = 32
#: Seeds averaged by Whitted where area lights make it an estimate.
SAMPLED_SEEDS = tuple(range(16))
#: The "blend" case: this diffuse colour blended with a perfect mirror.
BLEND_DIFFUSE, BLEND_WEIGHT = (0.7, 0.2, 0.2), 0.6
#: Path depth, unless a case sets ``max_depth``; Whitted gets the same.
DEPTH = 12
#: Paths of indirect light per hit in the cases that gather it (averaged
#: over ``SAMPLED_SEEDS``: fewer seeds underestimate the spread of its
#: skewed estimates, and a correct case fails now and then).
INDIRECT_SAMPLES = 16

#: Family-wise false-alarm rate of each case's test.
ALPHA = 1e-3


@dataclass
class EquivalenceCase:
    name: str
    checks: str
    whitted_scene: dict | Path       # a description, or a scene file
    path_scene: dict | Path | None = None   # default: the same scene
    seeds: tuple = (0,)
    expect_agree: bool = True
    settings: dict = field(default_factory=dict)


def _camera(origin=(0, 0, 5), target=(0, 0, 0), fov=40):
    return camera(origin, target, fov=fov, size=SIZE)


def _glass(reflection=1.0):
    """Fresnel glass; ``reflection`` < 1 scales its reflected part (wrong)."""
    return {"type": "dielectric", "int_ior": 1.5,
            "specular_reflectance": rgb(reflection, reflection, reflection)}


def _mirror_chain():
    silver = {"type": "conductor", "material": "Ag"}
    facing = mi.ScalarTransform4f().translate([0, 0, 1.5]).rotate([0, 1, 0], 180)
    return scene(
        {"type": "rectangle", "bsdf": silver,
         "to_world": mi.ScalarTransform4f().translate([0, 0, -1.5]).scale([2, 1.5, 1])},
        {"type": "rectangle", "bsdf": silver, "to_world": facing.scale([2, 1.5, 1])},
        sphere((-0.3, 0, 0), 0.4, diffuse(0.8, 0.3, 0.2)), point_light((0, 1.2, 0.3), 6.0),
        sensor=_camera(origin=(0.3, 2.0, 1.9), target=(-0.2, -0.2, -1.5), fov=50))


def _cylinders():
    """The exact capped cylinder (Whitted) and Mitsuba's cylinder with two
    disks (path): the same solid."""
    material = diffuse(0.7, 0.6, 0.2)
    transform = mi.ScalarTransform4f().translate([0, -0.8, 0]).scale([0.8, 1.4, 0.8])
    sensor, light = _camera(origin=(2, 2.5, 4)), point_light((2, 3, 3))
    capped = {"type": "capped_cylinder", "center": [0, -0.8, 0], "radius": 0.8,
              "height": 1.4, "segments": 10, "bsdf": material}
    return (scene(capped, light, sensor=sensor),
            scene(light, sensor=sensor, **builtin_cylinder(transform, material)))


def blend_scene(diffuse_colour=BLEND_DIFFUSE) -> dict:
    """A sphere of ``diffuse_colour`` blended with a perfect mirror (weight
    BLEND_WEIGHT) under a point light, before an emitting backdrop."""
    blend = {"type": "blendbsdf", "weight": BLEND_WEIGHT, "bsdf_0": diffuse(*diffuse_colour),
             "bsdf_1": {"type": "conductor"}}
    return scene(sphere((0, 0, 0), 1, blend), point_light((2, 3, 4)), backdrop(z=-2.5),
                 sensor=_camera())


def _cornell_box():
    box = mi.cornell_box()
    box["sensor"]["film"].update(width=SIZE, height=SIZE)
    box.pop("integrator")
    return box


def _lit_by_area_light():
    """A diffuse ball on a floor before a wall, under a small spherical
    lamp and a dim point light: the floor and the wall light the ball and
    each other."""
    lamp = {"type": "sphere", "center": [-0.6, 1.6, 0.8], "radius": 0.25,
            "emitter": {"type": "area", "radiance": rgb(12, 12, 12)}}
    return scene(floor(size=3.0, bsdf=diffuse(0.7, 0.7, 0.7)),
                 wall(z=-1.2, size=3.0, bsdf=diffuse(0.2, 0.6, 0.3)),
                 sphere((0.2, -0.4, 0), 0.6, diffuse(0.8, 0.4, 0.2)), lamp,
                 point_light((1.5, 2.0, 1.5), 3.0), sensor=_camera(origin=(0, 1.2, 4)))


def _on_sphere(bsdf, *lights):
    return scene(sphere((0, 0, 0), 1, bsdf), *lights, sensor=_camera())


def equivalence_cases() -> list[EquivalenceCase]:
    spot = {"type": "spot", "intensity": rgb(30, 30, 30), "cutoff_angle": 25, "beam_width": 15,
            "to_world": mi.ScalarTransform4f().look_at(origin=[1, 3, 1], target=[0, -1, 0],
                                                       up=[0, 0, 1])}
    sun = {"type": "directional", "direction": [-1, -2, -0.5], "irradiance": rgb(0.6, 0.5, 0.4)}
    phong = {"type": "phong", "diffuse_reflectance": rgb(0.6, 0.3, 0.1),
             "specular_reflectance": rgb(0.3, 0.3, 0.3), "exponent": 20.0}
    tartan = {"type": "phong", "exponent": 40.0,
              "diffuse_reflectance": {"type": "tartan", "frequency": 6.0}}
    plastic = {"type": "plastic", "diffuse_reflectance": rgb(0.2, 0.3, 0.8)}
    lamp = {"type": "sphere", "center": [0.5, 1.0, 0.5], "radius": 0.2,
            "emitter": {"type": "area", "radiance": rgb(15, 15, 15)}}
    two_lights = point_light((2, 3, 4)), point_light((-3, 1, 4), 8.0)
    capped, builtin = _cylinders()
    glass = _on_sphere(_glass(), backdrop(), sky())
    return [
        EquivalenceCase("diffuse + point light", "direct light, hard shadow edge of the sphere",
                        _on_sphere(diffuse(0.8, 0.5, 0.2), point_light((2, 3, 4)))),
        EquivalenceCase("Phong", "the normalized Phong lobe under two point lights",
                        _on_sphere(phong, *two_lights)),
        EquivalenceCase("tartan texture", "procedural texture inside Phong",
                        _on_sphere(tartan, point_light((2, 3, 4)))),
        EquivalenceCase("mirror chain", "two facing silver mirrors, many bounces",
                        _mirror_chain(), settings={"max_depth": 24}),
        EquivalenceCase("Fresnel glass", "Fresnel split into reflection and refraction",
                        glass),
        EquivalenceCase("plastic", "Fresnel-weighted coating over diffuse",
                        _on_sphere(plastic, *two_lights)),
        EquivalenceCase("blend", "blendbsdf of diffuse and conductor", blend_scene(),
                        seeds=SAMPLED_SEEDS),
        EquivalenceCase("capped cylinder", "exact capped cylinder (Whitted) against Mitsuba's "
                        "cylinder + 2 disks (path)", capped, builtin),
        EquivalenceCase("spot + directional", "spot cone and falloff, directional light",
                        scene(floor(size=3.0), spot, sun, sensor=_camera(origin=(0, 3, 4)))),
        EquivalenceCase("small area light", "area light through 16 shadow rays per hit",
                        scene(floor(size=3.0), lamp, sensor=_camera(origin=(0, 3, 4))),
                        seeds=SAMPLED_SEEDS),
        EquivalenceCase("broken: glass reflecting 50%", "Whitted's glass reflects half what "
                        "Fresnel says; path renders correct glass",
                        _on_sphere(_glass(0.5), backdrop(), sky()),
                        glass, expect_agree=False),
        *_indirect_cases(),
        EquivalenceCase("broken: Cornell box", "interreflection, which Whitted leaves out",
                        _cornell_box(), seeds=SAMPLED_SEEDS, expect_agree=False),
    ]


def _indirect_cases() -> list[EquivalenceCase]:
    """Scenes lit mostly by indirect light: Whitted gathering it agrees with
    ``path`` (no ambient term, physical shadows); classic Whitted, which
    leaves it out, is rejected (the Cornell box's classic case is the
    suite's last)."""
    gathering = {"indirect_samples": INDIRECT_SAMPLES}
    scenes = {"Cornell box": _cornell_box(),
              "glass and mirror box, point light": GLASS_BOX,
              "area and point lights": _lit_by_area_light()}
    cases = [EquivalenceCase(f"indirect: {name}", "indirect light gathered by path tracing "
                             "from every smooth hit", description, seeds=SAMPLED_SEEDS,
                             settings=gathering)
             for name, description in scenes.items()]
    cases += [EquivalenceCase("broken: glass and mirror box without indirect light",
                              "the light classic Whitted leaves out", GLASS_BOX,
                              expect_agree=False),
              EquivalenceCase("broken: area and point lights without indirect light",
                              "the light classic Whitted leaves out",
                              scenes["area and point lights"], seeds=SAMPLED_SEEDS,
                              expect_agree=False)]
    return cases


def load_case_scene(description: dict | Path) -> mi.Scene:
    """A case's scene: a description, or a scene file at the suite's size."""
    if isinstance(description, Path):
        return load_file(description, res=str(SIZE))
    return mi.load_dict(description)


def _cache_description(description: dict | Path):
    """What identifies a case's scene in a cache key: the description, or
    the digest of the scene file without its integrator (path's own
    settings replace it) and the files it names."""
    if isinstance(description, Path):
        return scene_without_integrator_digest(description, {"res": str(SIZE)})
    return description


def equivalence_rays(case: EquivalenceCase):
    """The Whitted integrator of a case, its scene and pixel-centre rays."""
    settings = {"max_depth": DEPTH, "min_throughput": 0.0, "emitter_samples": 16, **case.settings}
    whitted_scene = load_case_scene(case.whitted_scene)
    sensor = whitted_scene.sensors()[0]
    ray, _ = camera_rays(sensor, pixel_centres(sensor.film()))
    return mi.load_dict({"type": "whitted", **settings}), whitted_scene, ray


def equivalence_path(case: EquivalenceCase, ray, batches: int, spp: int,
                     cache: ReferenceCache | None = None) -> np.ndarray:
    """(batches, rays, 3) path batch means of a case along ``ray``, from
    ``cache`` when given (keyed by the path scene's description)."""
    depth = {"max_depth": DEPTH, **case.settings}["max_depth"]
    path_settings = {"type": "path", "max_depth": depth, "rr_depth": 1000}
    scene_description = case.path_scene or case.whitted_scene

    def render():
        return {"batches": path_batches(load_case_scene(scene_description),
                                        mi.load_dict(path_settings), ray, batches, spp)}

    if cache is None:
        return render()["batches"]
    key = cache_key(kind="equivalence", scene=_cache_description(scene_description),
                    batches=batches, spp=spp, integrator=path_settings)
    return cache.get_or_compute(key, render)["batches"]


def run_equivalence(case: EquivalenceCase, batches: int, spp: int,
                    cache: ReferenceCache | None = None) -> EquivalenceResult:
    """The equivalence test of one case against ``batches`` path batch
    means of ``spp`` samples per ray."""
    whitted, whitted_scene, ray = equivalence_rays(case)
    return equivalence_test(whitted_batches(whitted_scene, whitted, ray, case.seeds),
                            equivalence_path(case, ray, batches, spp, cache), ALPHA)
