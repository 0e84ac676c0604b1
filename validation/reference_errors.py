"""Where the reference is wrong: scenes in which Mitsuba 3.9.1's own answer,
the reference of the rest of the validation report, is not the right one.

Each case has a closed-form or float64 value, what Mitsuba and Whitted give,
and a scene for an image; the report (``validation/run.py``) names the cause
in Mitsuba's source. ``tests/test_reference_errors.py`` checks that Mitsuba
is still wrong in the known way, so that a Mitsuba that fixes a case makes
the test say so, and that this package is right.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mitsuba as mi
import numpy as np

from mitsuba_whitted.camera import camera_rays, pixel_centres
from mitsuba_whitted.compare import cache_key, cached_reference, luminance, path_batches
from mitsuba_whitted.compare.photon_reference import (PHOTON_SETTINGS, full_reference,
                                                      path_floor, reference_name)
from mitsuba_whitted.compare.reference import PATH_DEPTH, path_settings
from mitsuba_whitted.integrators.settings import is_whitted
from validation import scenes
from validation.oracles import light_tracer
from validation.stability import cylinder
from validation.stability.common import SEED, float32_rays, unit_rows

# --- blendbsdf with a delta lobe ----------------------------------------------

#: The known case: a black diffuse lobe (weight 0.65) blended with a
#: perfect mirror (weight 0.35).
MIRROR_WEIGHT = 0.35
BLACK = (0.0, 0.0, 0.0)
#: Incidence cosines of the ray bundles.
COSINES = (1.0, 0.75, 0.5, 0.2)
#: Path samples of the bundles: batches of a few samples per ray each.
BLEND_BATCHES, BLEND_SPP = 16, 256


def blend_bsdf(diffuse=BLACK, weight=MIRROR_WEIGHT) -> dict:
    """A diffuse lobe blended with a perfect mirror of weight ``weight``."""
    return {"type": "blendbsdf", "weight": weight,
            "bsdf_0": scenes.diffuse(*diffuse),
            "bsdf_1": {"type": "conductor", "material": "none"}}


def blend_plane_scene(diffuse=BLACK, weight=MIRROR_WEIGHT, size: int = 128) -> dict:
    """The plane y = 0 of the blend under a uniform sky of radiance 1, seen
    obliquely from above (incidence cosines from 0.3 to 0.95)."""
    return {"type": "scene", "sensor": scenes.camera((0, 2, 3), (0, 0, -1), fov=60, size=size),
            "plane": scenes.floor(y=0.0, size=40, bsdf=blend_bsdf(diffuse, weight)),
            "sky": scenes.sky(1)}


def mirror_factor(cos, diffuse, weight):
    """What Mitsuba's ``blendbsdf.sample`` makes of the mirror's share of the
    light from the mirror direction, at incidence ``cos``.

    It picks the mirror with probability ``weight`` and then divides
    ``weight x 1 + (1 - weight) f_d`` (the mirror's value, taken as 1, plus
    the diffuse lobe's) by ``weight x 1 + (1 - weight) p_d`` (the mirror's
    probability 1 plus the diffuse density p_d = cos / pi), mixing a discrete
    probability with a density. The true factor is 1."""
    diffuse = np.asarray(diffuse, dtype=np.float64)
    density = np.asarray(cos, dtype=np.float64)[..., None] / np.pi
    return (weight + (1 - weight) * diffuse * density) / (weight + (1 - weight) * density)


def blend_expected(cos, diffuse=BLACK, weight=MIRROR_WEIGHT):
    """(true, Mitsuba's) radiance of the plane under the sky of radiance 1:
    ``weight + (1 - weight) rho``, and the same with the mirror's share
    scaled by :func:`mirror_factor` (the diffuse lobe's own samples are
    right)."""
    diffuse = np.asarray(diffuse, dtype=np.float64)
    true = weight + (1 - weight) * diffuse
    return true, weight * mirror_factor(cos, diffuse, weight) + (1 - weight) * diffuse


def parallel_rays(cos: float, count: int = 64) -> mi.Ray3f:
    """``count`` parallel rays meeting the plane y = 0 at incidence ``cos``."""
    direction = np.tile([math.sqrt(1 - cos * cos), -cos, 0.0], (count, 1))
    origin = np.c_[np.linspace(-1, 1, count), np.ones(count), np.zeros(count)]
    return float32_rays(origin, direction)


@dataclass
class BlendRow:
    cos: float
    true: np.ndarray       #: closed form, per channel
    mitsuba: np.ndarray    #: closed form of Mitsuba's expectation
    path: np.ndarray       #: path's mean
    path_error: np.ndarray  #: its standard error
    whitted: np.ndarray    #: whitted's mean
    whitted_error: float   #: whitted's largest deviation from ``true``


def blend_delta_lobe(diffuse=BLACK, weight=MIRROR_WEIGHT, cosines=COSINES, seed: int = 0):
    """Path and Whitted on ray bundles at each incidence of ``cosines``."""
    scene = mi.load_dict(blend_plane_scene(diffuse, weight, size=8))
    path = mi.load_dict({"type": "path", "max_depth": 3})
    whitted = mi.load_dict({"type": "whitted"})
    rows = []
    for cos in cosines:
        ray = parallel_rays(cos)
        batches = path_batches(scene, path, ray, BLEND_BATCHES, BLEND_SPP, seed).mean(axis=1)
        traced, _ = whitted.trace_rays(scene, ray)
        traced = np.array(traced, dtype=np.float64).T
        true, mitsuba = blend_expected(cos, diffuse, weight)
        rows.append(BlendRow(cos, true, mitsuba, batches.mean(axis=0),
                             batches.std(axis=0, ddof=1) / math.sqrt(len(batches)),
                             traced.mean(axis=0), float(np.abs(traced - true).max())))
    return rows


def blend_bias(scene: mi.Scene, shape, mirror_part: np.ndarray, ray: mi.Ray3f, diffuse,
               weight) -> np.ndarray:
    """Per ray, what Mitsuba's ``blendbsdf.sample`` adds to the right value
    where ``ray`` hits ``shape`` (made of the blend): ``mirror_part`` (the
    light through the mirror lobe, ``weight x L``, as Whitted gives it)
    times :func:`mirror_factor` - 1 at that hit's incidence."""
    si = scene.ray_intersect(ray)
    cos = np.abs(np.sum(np.array(si.n, dtype=np.float64) * np.array(ray.d), axis=0))
    on_blend = np.array(si.is_valid() & (si.shape == mi.ShapePtr(shape)))
    return np.where(on_blend[:, None], mirror_part * (mirror_factor(cos, diffuse, weight) - 1), 0)


# --- Mitsuba's cylinder --------------------------------------------------------

#: Distances (in radii) of the far-away bundles.
CYLINDER_DISTANCES = (10.0, 1e3, 1e4)
#: A rotation about the non-unit axis (1, 1, 0): Mitsuba's ``rotate`` does
#: not normalise it, so the matrix shears and scales the solid.
NON_UNIT_ROTATION = ((1.0, 1.0, 0.0), 35.0)


@dataclass
class CylinderRow:
    label: str
    rays: int
    reference_hits: int
    mitsuba_hits: int
    mitsuba_disagreements: int   #: hit/miss against float64, outside the band
    mitsuba_t: float             #: largest |t - t_float64| where both hit (nan: none)
    capped_disagreements: int
    capped_t: float


def _disagreements(ref: dict, hit: np.ndarray, t: np.ndarray):
    """Hit/miss disagreements with the float64 reference outside its band,
    and the largest error in t where both hit."""
    near = ref["margin"] < cylinder.CYLINDER_BAND
    both = hit & ref["hit"]
    worst = float(np.abs(t[both] - ref["t"][both]).max()) if both.any() else math.nan
    return int(((hit != ref["hit"]) & ~near).sum()), worst


def builtin_hits(to_world, o: np.ndarray, d: np.ndarray):
    """Mitsuba's cylinder and disks on the canonical solid placed by
    ``to_world``: hit and t of the rays."""
    scene = mi.load_dict({"type": "scene", **scenes.builtin_cylinder(to_world)})
    si = scene.ray_intersect(float32_rays(o, d))
    return np.array(si.is_valid()), np.array(si.t, dtype=np.float64)


def compare_cylinders(label: str, o: np.ndarray, d: np.ndarray, to_world=None) -> CylinderRow:
    """Mitsuba's cylinder and the exact capped cylinder (as Whitted sees
    it) on the same float32 rays, against the float64 reference."""
    to_world = to_world or mi.ScalarTransform4f()
    capped = cylinder.cylinder_scene(to_world=to_world)
    ref = cylinder.cylinder_reference(capped, o, d)
    hit, t, _, _ = cylinder.exact_cylinder_hits(capped, o, d)
    builtin_hit, builtin_t = builtin_hits(to_world, o, d)
    return CylinderRow(label, len(o), int(ref["hit"].sum()), int(builtin_hit.sum()),
                       *_disagreements(ref, builtin_hit, builtin_t), *_disagreements(ref, hit, t))


def cylinder_far_away(distance: float, rays: int = 4096) -> CylinderRow:
    o, d = cylinder.far_bundle(rays, np.random.default_rng(SEED), distance)
    return compare_cylinders(f"from {distance:g} radii", o, d)


def non_unit_rotation() -> mi.ScalarTransform4f:
    axis, angle = NON_UNIT_ROTATION
    return mi.ScalarTransform4f().rotate(list(axis), angle)


def cylinder_rotated(rays: int = 4096) -> CylinderRow:
    """The bundle from 10 radii, solid and rays placed by the rotation about
    a non-unit axis; the float64 reference and the capped cylinder invert
    its matrix, Mitsuba's cylinder and disks use the inverse ``rotate``
    stored with it (its transpose)."""
    to_world = non_unit_rotation()
    o, d = cylinder.far_bundle(rays, np.random.default_rng(SEED), 10.0)
    matrix = np.array(to_world.matrix, dtype=np.float64)
    o = o @ matrix[:3, :3].T + matrix[:3, 3]
    d = unit_rows(d @ matrix[:3, :3].T)
    return compare_cylinders("rotated about (1, 1, 0)", o, d, to_world)


def cylinder_scene(capped: bool, to_world, eye, target, fov: float, size: int = 128) -> dict:
    """The solid placed by ``to_world`` (the capped cylinder, or Mitsuba's
    cylinder and disks) seen from ``eye``, lit by a point light beside the
    eye whose intensity grows with the square of the distance."""
    material = scenes.diffuse(0.7, 0.6, 0.2)
    solid = ({"solid": {"type": "capped_cylinder", "to_world": to_world, "bsdf": material}}
             if capped else scenes.builtin_cylinder(to_world, material))
    eye, target = np.asarray(eye, dtype=np.float64), np.asarray(target, dtype=np.float64)
    distance = float(np.linalg.norm(eye - target))
    light = eye + distance * np.array([0.4, 0.6, 0.0])
    return {"type": "scene", **solid,
            "sensor": scenes.camera(list(eye), list(target), fov=fov, size=size,
                                    far_clip=10 * distance),
            "light": scenes.point_light(light, 8 * distance ** 2)}


def far_views(distance: float = CYLINDER_DISTANCES[-1]):
    """(Mitsuba's solid, the capped cylinder) seen from ``distance`` radii,
    from where the far bundle starts."""
    fov = 2 * math.degrees(math.atan(1.6 / distance))
    return tuple(cylinder_scene(capped, mi.ScalarTransform4f(), (0.3, 0.9, distance),
                                (0, 0.5, 0), fov) for capped in (False, True))


def rotated_views():
    """(Mitsuba's solid, the capped cylinder) placed by the rotation about a
    non-unit axis, and the camera with them."""
    to_world = non_unit_rotation()
    eye, target = (to_world @ mi.ScalarPoint3f(p) for p in ((3, 2.5, 4), (0, 0.5, 0)))
    return tuple(cylinder_scene(capped, to_world, list(eye), list(target), 40.0)
                 for capped in (False, True))


def reference_mask(scene: mi.Scene) -> np.ndarray:
    """Float64: which pixel-centre rays of ``scene``'s camera hit the solid
    of the capped cylinder in ``scene`` (white) or miss it."""
    sensor = scene.sensors()[0]
    ray, _ = camera_rays(sensor, pixel_centres(sensor.film()))
    o, d = np.array(ray.o, dtype=np.float64).T, np.array(ray.d, dtype=np.float64).T
    hit = cylinder.cylinder_reference(scene, o, d)["hit"]
    width, height = sensor.film().crop_size()
    return np.repeat(hit.reshape(height, width, 1).astype(np.float64), 3, axis=2)


# --- shadow rays through surfaces that let light straight through ------------

#: Surfaces that let light through without bending it, each with the share
#: of a point light's light that passes its two crossings on a straight
#: line through the centre (at normal incidence).
_THIN_R0 = ((1.5 - 1) / (1.5 + 1)) ** 2
PASS_THROUGH = {
    "null": ({"type": "null"}, 1.0),
    "mask, opacity 0.5": ({"type": "mask", "opacity": 0.5,
                           "bsdf": {"type": "diffuse"}}, 0.5 ** 2),
    "thin dielectric, index 1.5": ({"type": "thindielectric", "int_ior": 1.5,
                                    "ext_ior": 1.0}, (1 - 2 * _THIN_R0 / (1 + _THIN_R0)) ** 2),
    "index-matched dielectric, transmittance 0.8": (
        {"type": "dielectric", "int_ior": 1.0, "ext_ior": 1.0,
         "specular_transmittance": scenes.rgb(0.8, 0.8, 0.8)}, 0.8 ** 2),
}
LAMP_HEIGHT, BALL_HEIGHT, BALL_RADIUS, BALL_SPACING = 6.0, 1.5, 0.35, 1.0


def ball_positions() -> list:
    return [((index - 1.5) * BALL_SPACING, BALL_HEIGHT, 0.0) for index in range(len(PASS_THROUGH))]


def pass_through_scene(with_balls: bool = True, size: int = 128) -> dict:
    """A floor lit by a point light above a row of balls, one of each of
    the ``PASS_THROUGH`` surfaces."""
    scene = {"type": "scene", "sensor": scenes.camera((0, 2.0, 6.0), fov=45, size=size),
             "floor": scenes.floor(y=0.0),
             "lamp": scenes.point_light((0, LAMP_HEIGHT, 0), 40)}
    if with_balls:
        for index, ((bsdf, _), centre) in enumerate(zip(PASS_THROUGH.values(), ball_positions())):
            scene[f"ball_{index}"] = scenes.sphere(centre, BALL_RADIUS, bsdf)
    return scene


def shadow_centre_rays() -> mi.Ray3f:
    """Rays falling straight onto the floor where the line from the lamp
    through each ball's centre meets it."""
    stretch = LAMP_HEIGHT / (LAMP_HEIGHT - BALL_HEIGHT)
    x = np.array([centre[0] * stretch for centre in ball_positions()])
    origin = np.c_[x, np.full_like(x, 0.1), np.zeros_like(x)]
    return mi.Ray3f(mi.Point3f(*origin.astype(np.float32).T),
                    mi.Vector3f(0, -1, 0))


def pass_through_shares(integrators: dict, batches: int = 8, spp: int = 16) -> dict:
    """Per integrator, the share of the lamp's light at each shadow centre
    (the radiance there over the radiance without the balls), and its
    standard error."""
    ray = shadow_centre_rays()
    shaded, lit = (mi.load_dict(pass_through_scene(balls, size=8)) for balls in (True, False))
    shares = {}
    for name, integrator in integrators.items():
        if is_whitted(integrator):     # one exact value
            values = [np.array(integrator.trace_rays(s, ray)[0], dtype=np.float64).T[None]
                      for s in (shaded, lit)]
        else:
            values = [path_batches(s, integrator, ray, batches, spp) for s in (shaded, lit)]
        ratio = (values[0] / values[1].mean(axis=0)).mean(axis=2)
        error = (ratio.std(axis=0, ddof=1) / math.sqrt(len(ratio)) if len(ratio) > 1
                 else np.zeros(ratio.shape[1]))
        shares[name] = (ratio.mean(axis=0), error)
    return shares


# --- delta lights through delta and null surfaces ------------------------------

#: Light paths per pixel of the light tracer's reference of these cases, in
#: passes; and path's samples per pixel.
LIGHT_SPP, LIGHT_PASSES, MISSING_PATH_SPP = 16384, 32, 1024


def at_path_depth(description: dict) -> dict:
    """``description`` with its ``whitted`` at path's depth, which the light
    tracer takes for its own, so that all three count the same paths."""
    integrator = dict(description.get("integrator") or {"type": "whitted"},
                      max_depth=PATH_DEPTH)
    return dict(description, integrator=integrator)


@dataclass
class MissingLight:
    """Path, the full reference (path + photons) and the light tracer on a
    scene where path misses light: relMSE against the light tracer on the
    pixels it renders right (``mask``), less the noise of both, and the
    share of the light tracer's light there that path lacks."""

    mask: np.ndarray
    path: np.ndarray
    reference: np.ndarray
    light: np.ndarray
    reference_name: str
    path_error: float
    reference_error: float
    light_noise: float
    missing_share: float
    path_floor: float


def missing_light_case(cache, name: str, description: dict, photons=None) -> MissingLight:
    """The figures of :class:`MissingLight` for ``description`` (taken at
    path's depth), every render cached in ``cache``."""
    description = at_path_depth(description)
    scene = mi.load_dict(description)
    settings = path_settings()
    key = cache_key(kind="reference error", name=name, scene=description,
                    spp=MISSING_PATH_SPP, integrator=settings)
    path = cached_reference(cache, key, scene, MISSING_PATH_SPP, settings=settings)
    reference = full_reference(cache, description, scene, path, photons or PHOTON_SETTINGS)
    light = light_tracer.ptracer_reference(description, LIGHT_SPP, LIGHT_PASSES, cache=cache)
    mask = light_tracer.smooth_first_mask(scene)

    def bias(image, variance):
        return (light_tracer.masked_rel_mse(image, light.image, mask)
                - light_tracer.masked_noise_rel_mse(variance + light.variance, light.image,
                                                    mask))

    found = luminance(light.image)[mask].sum()
    return MissingLight(mask, path.image, reference.image, light.image,
                        reference_name(reference), bias(path.image, path.variance),
                        bias(reference.image, reference.variance),
                        light_tracer.masked_noise_rel_mse(light.variance, light.image, mask),
                        float(1 - luminance(path.image)[mask].sum() / found),
                        path_floor(reference))
