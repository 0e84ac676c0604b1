"""Whitted against Mitsuba's path tracer where both models coincide.

Oracle: Mitsuba's own ``path`` integrator, run on exactly the pixel-centre
rays Whitted traces. The statistical test (``compare.equivalence_test``)
has a family-wise false-alarm rate of 1e-3 per scene; the last test shows
that it does reject a scene where Whitted is known to be wrong.
"""

import mitsuba as mi
import numpy as np

from mitsuba_whitted.camera import camera_rays, pixel_centres
from mitsuba_whitted.compare import (equivalence_test, path_batches, pixel_centre_equivalence,
                                     whitted_batches)

from scenes import (camera, diffuse, floor, integrator, point_light, rgb, scene,
                    sphere, wall)

DEPTH = 12
BATCHES, SPP = 32, 32
#: Seeds for scenes with area or environment lights, where Whitted averages
#: a fixed number of shadow rays and is itself an estimate.
SAMPLED_SEEDS = tuple(range(16))


def textured_backdrop(z=-3.0, size=4.0, scale=3.0):
    """An emitting checkerboard behind the scene, seen through glass."""
    transform = mi.ScalarTransform4f().translate([0, 0, z]).scale(size)
    radiance = {"type": "checkerboard", "color0": rgb(0.2, 0.4, 1.0),
                "color1": rgb(1.0, 0.8, 0.3),
                "to_uv": mi.ScalarTransform4f().scale([8, 8, 1])}
    return {"type": "rectangle", "to_world": transform,
            "emitter": {"type": "area", "radiance": radiance},
            "bsdf": diffuse(0, 0, 0)}


def run(description, seeds=(0,), **whitted_settings):
    loaded = mi.load_dict(description)
    whitted = mi.load_dict(integrator(max_depth=DEPTH, min_throughput=0.0,
                                      emitter_samples=16, **whitted_settings))
    path = mi.load_dict({"type": "path", "max_depth": DEPTH, "rr_depth": 1000})
    result = pixel_centre_equivalence(loaded, whitted, path, BATCHES, SPP, seeds)
    assert np.isfinite(result.whitted).all()
    return result


def assert_agree(result):
    assert result.passed, result.summary()
    # The scene must actually show something, or agreement means nothing.
    assert result.path.max() > 0.05


def test_diffuse_sphere_point_light():
    assert_agree(run(scene(sphere((0, 0, 0), 1, diffuse(0.8, 0.5, 0.2)),
                           point_light((2, 3, 4)))))


def test_mirror_reflects_diffuse_object():
    mirror = wall(z=-1.5, size=3, bsdf={"type": "conductor", "material": "Au"})
    assert_agree(run(scene(mirror, sphere((0.6, 0, 0.5), 0.6, diffuse(0.2, 0.7, 0.3)),
                           point_light((1, 2, 3)),
                           sensor=camera(origin=(-1.5, 0.5, 4)))))


def test_dielectric_sphere_fresnel_split():
    glass = sphere((0, 0, 0), 1, {"type": "dielectric", "int_ior": 1.5})
    assert_agree(run(scene(glass, textured_backdrop())))


def test_plastic_sphere():
    plastic = {"type": "plastic", "diffuse_reflectance": rgb(0.2, 0.3, 0.8)}
    assert_agree(run(scene(sphere((0, 0, 0), 1, plastic), point_light((2, 3, 4)),
                           point_light((-3, 1, 4), 8.0))))


def test_blend_of_diffuse_and_conductor():
    blend = {"type": "blendbsdf", "weight": 0.6, "bsdf_0": diffuse(0.7, 0.2, 0.2),
             "bsdf_1": {"type": "conductor"}}
    assert_agree(run(scene(sphere((0, 0, 0), 1, blend), point_light((2, 3, 4)),
                           textured_backdrop(z=-2.5)), seeds=SAMPLED_SEEDS))


def test_spot_and_directional_lights():
    spot = {"type": "spot", "to_world": mi.ScalarTransform4f().look_at(
        origin=[1, 3, 1], target=[0, -1, 0], up=[0, 0, 1]),
        "intensity": rgb(30, 30, 30), "cutoff_angle": 25, "beam_width": 15}
    sun = {"type": "directional", "direction": [-1, -2, -0.5], "irradiance": rgb(0.6, 0.5, 0.4)}
    assert_agree(run(scene(floor(size=3), spot, sun, sensor=camera(origin=(0, 3, 4)))))


def test_small_sphere_area_light():
    lamp = {"type": "sphere", "center": [0.5, 1.0, 0.5], "radius": 0.2,
            "emitter": {"type": "area", "radiance": rgb(15, 15, 15)}}
    assert_agree(run(scene(floor(size=3), lamp, sensor=camera(origin=(0, 3, 4))),
                     seeds=SAMPLED_SEEDS))


def test_interreflecting_box_is_rejected():
    """Whitted has no indirect diffuse light: the test must notice."""
    box = mi.cornell_box()
    box["sensor"]["film"]["width"] = box["sensor"]["film"]["height"] = 24
    box.pop("integrator")
    result = run(box, seeds=SAMPLED_SEEDS)
    assert not result.passed, result.summary()
    assert result.rejected > 0.2 * result.tests


def test_phong_sphere_point_light():
    phong = {"type": "phong", "diffuse_reflectance": rgb(0.6, 0.3, 0.1),
             "specular_reflectance": rgb(0.3, 0.3, 0.3), "exponent": 20.0}
    assert_agree(run(scene(sphere((0, 0, 0), 1, phong), point_light((2, 3, 4)),
                           point_light((-3, 1, 4), 8.0))))


def test_textured_phong_sphere():
    tartan = {"type": "phong", "exponent": 40.0,
              "diffuse_reflectance": {"type": "tartan", "frequency": 6.0}}
    assert_agree(run(scene(sphere((0, 0, 0), 1, tartan), point_light((2, 3, 4)))))


def test_exact_capped_cylinder_against_builtin_solid():
    """Whitted on the exact capped cylinder vs path on Mitsuba's own
    cylinder and disks: the same solid, so the same image in expectation."""
    material = diffuse(0.7, 0.6, 0.2)
    capped = {"type": "capped_cylinder", "center": [0, -0.8, 0], "radius": 0.8,
              "height": 1.4, "segments": 10, "bsdf": material}
    transform = (mi.ScalarTransform4f().translate([0, -0.8, 0]).scale([0.8, 1.4, 0.8]))
    up = mi.ScalarTransform4f().rotate([1, 0, 0], -90)
    builtin = {"side": {"type": "cylinder", "to_world": transform @ up, "bsdf": material},
               "bottom": {"type": "disk", "bsdf": material,
                          "to_world": transform @ mi.ScalarTransform4f().rotate([1, 0, 0], 90)},
               "top": {"type": "disk", "bsdf": material,
                       "to_world": transform @ mi.ScalarTransform4f().translate([0, 1, 0]) @ up}}
    sensor = camera(origin=(2, 2.5, 4))
    light = point_light((2, 3, 3))
    ours = mi.load_dict(scene(capped, light, sensor=sensor))
    theirs = mi.load_dict(scene(light, sensor=sensor, **builtin))
    whitted = mi.load_dict(integrator(max_depth=DEPTH))
    path = mi.load_dict({"type": "path", "max_depth": DEPTH, "rr_depth": 1000})
    ray, _ = camera_rays(ours.sensors()[0], pixel_centres(ours.sensors()[0].film()))
    result = equivalence_test(whitted_batches(ours, whitted, ray),
                              path_batches(theirs, path, ray, BATCHES, SPP))
    assert_agree(result)
