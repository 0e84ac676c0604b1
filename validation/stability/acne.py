"""Self-intersection (acne) in rendered images: the ``whitted`` integrator
on the same scene at scales 1e-3 and 1e3, against the scene at scale 1, and
a plane lit at a grazing angle, against its closed form."""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from mitsuba_whitted.camera import camera_rays, pixel_centres
from mitsuba_whitted.integrators.offsets import scene_scale
from mitsuba_whitted.integrators.scene_needs import analyse
from validation.scenes import camera, diffuse, point_light, sphere
from validation.scenes import scene as scene_dict
from validation.stability.common import CaseResult
from validation.stability.glass import IOR

SCALES = (1e-3, 1.0, 1e3)
#: Images of the same scene at another scale, with ray offsets of the same
#: size relative to the scene: float32 positions round differently, which
#: moves shading by ~1e-6 relative; acne moves a pixel by tens of percent.
#: 1e-3 sits between the two.
SCALE_TOLERANCE = 1e-3
#: A pixel whose 3x3 neighbourhood in the reference varies by more than
#: this (relative) lies on an edge, where a float32 pixel-centre ray may
#: legitimately land on the other side.
EDGE_CONTRAST = 0.05


def _whitted():
    return mi.load_dict({"type": "whitted", "max_depth": 8})


def _camera(scale, size, origin, target, up=(0, 1, 0), fov=35.0):
    return camera([scale * c for c in origin], [scale * c for c in target], up, fov, size,
                  near_clip=1e-2 * scale, far_clip=1e3 * scale)


def scaled_glass_scene(scale: float, size: int) -> mi.Scene:
    """A diffuse sphere, a glass sphere and a glass capped cylinder on a
    floor, seen from just above the floor (grazing), lit by a point light;
    every length times ``scale`` and the intensity times scale^2, so the
    image is the same at every scale."""
    glass = {"type": "dielectric", "int_ior": IOR}

    def at(*v):
        return [scale * c for c in v]

    floor = mi.ScalarTransform4f().scale(scale).rotate([1, 0, 0], -90).scale(5)
    wall = mi.ScalarTransform4f().scale(scale).translate([0, 0, -3]).scale(5)
    return mi.load_dict(scene_dict(
        sensor=_camera(scale, size, (0, 0.3, 6), (0, 0.4, 0)),
        floor={"type": "rectangle", "to_world": floor, "bsdf": diffuse(0.6, 0.6, 0.6)},
        wall={"type": "rectangle", "to_world": wall, "bsdf": diffuse(0.4, 0.4, 0.4)},
        matte=sphere(at(-1.2, 0.5, 0), 0.5 * scale, diffuse(0.7, 0.7, 0.7)),
        ball=sphere(at(0.1, 0.5, 0.4), 0.5 * scale, glass),
        rod={"type": "capped_cylinder", "center": at(1.2, 0, -0.3), "radius": 0.4 * scale,
             "height": scale, "bsdf": glass},
        light=point_light(at(2, 1.5, 3), 10 * scale ** 2)))


def render(scene: mi.Scene) -> np.ndarray:
    return np.array(mi.render(scene, integrator=_whitted()), dtype=np.float64)


def render_with_offsets(scene: mi.Scene, length: float) -> np.ndarray:
    """What ``render`` gives (pixel centres), with ``length`` in place of
    the scene's own absolute term of the ray offsets (``offsets.py``)."""
    needs = analyse(scene)
    needs.scale = length
    sensor = scene.sensors()[0]
    ray, _ = camera_rays(sensor, pixel_centres(sensor.film()))
    radiance, _ = _whitted().trace_rays(scene, ray, needs=needs)
    width, height = sensor.film().crop_size()
    return np.array(radiance, dtype=np.float64).T.reshape(height, width, 3)


def edge_band(image: np.ndarray) -> np.ndarray:
    """Pixels whose 3x3 neighbourhood varies by more than EDGE_CONTRAST."""
    value = image.mean(axis=2)
    padded = np.pad(value, 1, mode="edge")
    h, w = value.shape
    stack = np.stack([padded[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
                      for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
    return stack.max(axis=0) - stack.min(axis=0) > EDGE_CONTRAST * np.maximum(value, 1e-2 * value.mean())


def judge_scaled(name: str, image: np.ndarray, reference: np.ndarray) -> CaseResult:
    """Pixels of ``image`` against the scale-1 ``reference``: outside the
    edge band each must agree within SCALE_TOLERANCE (relative, with a
    floor of 1% of the mean for black pixels)."""
    floor = 1e-2 * reference.mean()
    error = (np.abs(image - reference) / np.maximum(reference, floor)).max(axis=2)
    finite = np.isfinite(image).all(axis=2) & np.isfinite(reference).all(axis=2)
    edge = edge_band(reference)
    differ = ~finite | (error > SCALE_TOLERANCE)
    flat_error = np.where(finite & ~edge, error, 0)
    worst = float(flat_error.max())
    return CaseResult(
        name=name, measures="whitted render (mi.render), glass + diffuse, grazing view",
        reference="the scene at scale 1, offsets of the same relative size",
        samples=int(error.size),
        nonfinite=int((~np.isfinite(image)).sum() + (~np.isfinite(reference)).sum()),
        disagreements=int((differ & ~edge).sum()), excused=int((differ & edge).sum()),
        band=f"edge pixels (3x3 contrast > {EDGE_CONTRAST:g})", worst_error=worst,
        unit="relative radiance (flat pixels)", bound=SCALE_TOLERANCE,
        passed=bool(finite.all() and not (differ & ~edge).any()))


def acne_at_scale(size: int, scale: float, unscaled: np.ndarray) -> CaseResult:
    """Self-intersection at another scene scale: Mitsuba offsets spawned
    rays by ~1e-7 (1 + |p|) — absolute near the origin, so relatively 1000x
    larger in a 1e-3 scene — and the capped cylinder by 1e-4 of its own
    canonical size. Acne (a ray hitting the surface it leaves) shows as
    dark or wrong pixels in flat regions, which must match the scale-1
    image within SCALE_TOLERANCE.

    The scale-1 image is rendered with offsets of the same size relative to
    the scene as the scaled one's: their absolute term, min(1, scene size),
    is Mitsuba's 1 unit in scenes larger than a unit (so that Whitted traces
    the very rays Mitsuba's integrators trace, which the equivalence tests
    rely on), and that is no fixed share of the scene. With each scene's own
    offsets, the scaled images differ from ``unscaled`` where rays bounce
    inside the glass cylinder (its refracted and reflected rays start
    offset across the surface, and each bounce inside a circle turns an
    offset into a larger change of direction) until a weak ray lands on the
    other side of a shadow edge: that comparison is reported in the notes."""
    scaled = scaled_glass_scene(scale, size)
    image = render(scaled)
    length = scene_scale(scaled) / scale
    result = judge_scaled(f"acne: glass and diffuse at scale {scale:g}", image,
                          render_with_offsets(scaled_glass_scene(1.0, size), length))
    own = judge_scaled("", image, unscaled)
    result.details = (f"scale-1 image rendered with offset term {length:g} (its own: "
                      f"{scene_scale(scaled_glass_scene(1.0, 8)):g}); against the scale-1 image with "
                      f"its own offsets, flat pixels over the bound: {own.disagreements}, worst "
                      f"{own.worst_error:.2g}")
    return result


#: The lit plane's radiance is a float32 product of a few terms (~1e-6
#: relative); shadow acne blacks a pixel out. 1e-3 is far from both.
PLANE_TOLERANCE = 1e-3


def plane_scene(scale: float, size: int, light) -> mi.Scene:
    floor = mi.ScalarTransform4f().scale(scale).rotate([1, 0, 0], -90).scale(20)
    return mi.load_dict(scene_dict(
        sensor=_camera(scale, size, (0, 4, 0), (0, 0, 0), up=(0, 0, -1), fov=30),
        floor={"type": "rectangle", "to_world": floor, "bsdf": diffuse(0.5, 0.5, 0.5)},
        light=point_light([scale * c for c in light], 50 * scale ** 2)))


def lit_plane_closed_form(scene: mi.Scene, light, albedo=0.5, intensity=50.0, scale=1.0):
    """rho/pi * I cos(theta) / d^2 at each pixel centre's hit on y = 0, in
    float64 from the camera's own float32 rays."""
    sensor = scene.sensors()[0]
    ray, _ = camera_rays(sensor, pixel_centres(sensor.film()))
    o = np.array(ray.o, dtype=np.float64).T
    d = np.array(ray.d, dtype=np.float64).T
    p = o - (o[:, 1] / d[:, 1])[:, None] * d
    to_light = scale * np.asarray(light) - p
    distance = np.linalg.norm(to_light, axis=1)
    cos_theta = to_light[:, 1] / distance
    radiance = albedo / np.pi * intensity * scale ** 2 * cos_theta / distance ** 2
    width, height = sensor.film().crop_size()
    return radiance.reshape(height, width)


def shadow_acne_plane(size: int) -> CaseResult:
    """A diffuse plane lit by a point light 0.25 above it and 6 away
    (cos θ ~ 0.04, the regime where a shadow ray leaving the plane may
    re-hit it), at every scale: every pixel (all lie on the flat plane)
    must be within PLANE_TOLERANCE of the closed form; a speckle of shadow
    acne would be black."""
    light = (-6.0, 0.25, 0.0)
    worst, bad, pixels, nonfinite = 0.0, 0, 0, 0
    for scale in SCALES:
        scene = plane_scene(scale, size, light)
        image = render(scene)
        expected = lit_plane_closed_form(scene, light, scale=scale)
        error = np.abs(image - expected[..., None]).max(axis=2) / expected
        nonfinite += int((~np.isfinite(image)).sum())
        bad += int((~(error <= PLANE_TOLERANCE)).sum())
        worst = max(worst, float(np.nanmax(error)))
        pixels += error.size
    return CaseResult(
        name="shadow acne: lit plane, grazing light", measures="whitted render, scales 1e-3, 1, 1e3",
        reference="closed form rho/pi I cos(theta)/d^2 (float64)", samples=pixels,
        nonfinite=nonfinite, disagreements=bad, excused=0, band="none (every pixel is flat)",
        worst_error=worst, unit="relative radiance", bound=PLANE_TOLERANCE,
        passed=bool(nonfinite == 0 and bad == 0 and worst <= PLANE_TOLERANCE))
