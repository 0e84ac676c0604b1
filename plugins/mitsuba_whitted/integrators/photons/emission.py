"""Where a pass's photons start: each emitter's share of them, and for
lights at a point (point, spot) directions aimed at what can bend light.

Light from a point light reaches a caustic only through a surface with a
delta lobe (a mirror, glass) or a pass-through part. Emitted uniformly,
most photons land where the shadow rays already lit the scene, and are
wasted where only the light that bends is wanted. Aimed emission draws a
direction from a mixture of cones, one around each such shape's bounding
sphere, and of the uniform sphere with weight ``uniform_share``; each
photon carries the light's intensity over the mixture's exact density, so
the estimate stays unbiased for every direction the mixture can draw
(with ``uniform_share`` 0, every direction that meets such a shape first).

Emitters of every other kind (area, environment, directional) start
photons by their own ``sample_ray``, whose weight is their power over
its density. Each emitter takes a share of the pass's photons in
proportion to its power (estimated from a fixed set of its own samples,
so that the split is the same on every run), at least one photon.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from ..sequence import PaddedSobol

#: Samples of each emitter's ``sample_ray`` that estimate its power.
POWER_SAMPLES = 4096
#: Fixed seed of the power estimate's points.
_POWER_SEED = 0x2545F491


@dataclass
class Cone:
    """Directions from a light towards a sphere: the unit ``axis`` and the
    cosine of the half angle (-1: the light is inside, every direction)."""
    axis: tuple
    cos_max: float

    @property
    def solid_angle(self) -> float:
        return 2 * math.pi * (1 - self.cos_max)


@dataclass
class EmitterShare:
    """One emitter's photons in a pass: how many, and for a light at a
    point, its position and the cones its directions are aimed at."""
    emitter: mi.Emitter
    count: int
    position: tuple = None
    cones: list = field(default_factory=list)
    uniform_share: float = 1.0

    @property
    def aimed(self) -> bool:
        return self.position is not None


def bending_spheres(scene: mi.Scene) -> list:
    """``(centre, radius)`` of the bounding sphere of every shape whose BSDF
    has a delta lobe or lets light pass: what can bend or pass light from a
    point light."""
    spheres = []
    for shape in scene.shapes():
        bsdf = shape.bsdf()
        if bsdf is None or not mi.has_flag(bsdf.flags(), mi.BSDFFlags.Delta | mi.BSDFFlags.Null):
            continue
        box = shape.bbox()
        centre = np.array(box.center(), dtype=np.float64)
        extents = np.array(box.extents(), dtype=np.float64)
        # A sphere fills the sphere inscribed in its box; others, at most
        # the one about the box.
        radius = 0.5 * float(extents.max() if shape.shape_type() == int(mi.ShapeType.Sphere)
                             else np.linalg.norm(extents))
        spheres.append((centre, max(radius, 1e-6)))
    return spheres


def cones_towards(position: np.ndarray, spheres: list) -> list:
    """The cone of directions from ``position`` onto each sphere."""
    cones = []
    for centre, radius in spheres:
        offset = centre - position
        distance = float(np.linalg.norm(offset))
        if distance <= radius * (1 + 1e-6):
            return [Cone((0.0, 0.0, 1.0), -1.0)]
        cos_max = math.sqrt(max(1.0 - (radius / distance) ** 2, 0.0))
        cones.append(Cone(tuple(float(c) for c in offset / distance), cos_max))
    return cones


def light_position(emitter: mi.Emitter) -> tuple | None:
    """Where a light at a point sits (point and spot lights), else ``None``."""
    if not mi.has_flag(emitter.flags(), mi.EmitterFlags.DeltaPosition):
        return None
    it = dr.zeros(mi.Interaction3f)
    it.p = mi.Point3f(0, 0, 0)
    ds, _ = emitter.sample_direction(it, mi.Point2f(0.5))
    return tuple(float(c[0]) for c in ds.p)


def emitter_power(emitter: mi.Emitter) -> float:
    """The emitter's power (luminance), the mean weight of a fixed set of
    its own emitted rays."""
    sequence = PaddedSobol(mi.UInt32(_POWER_SEED))
    index = dr.arange(mi.UInt32, POWER_SAMPLES)
    u1, u2 = sequence.point(index, 0), sequence.point(index, 1)
    _, weight = emitter.sample_ray(0.0, u1.x, u1, u2)
    luminance = mi.luminance(mi.Color3f(weight))
    return float(dr.mean(dr.select(dr.isfinite(luminance), luminance, 0), axis=None)[0])


def plan_emission(scene: mi.Scene, photons: int, delta_only: bool,
                  uniform_share: float) -> list:
    """Each emitter's share of ``photons`` (``delta_only``: lights at a
    point or in a direction alone, whose light a path tracer cannot find
    through a delta chain). Lights at a point aim at the shapes that bend
    light, keeping ``uniform_share`` of their photons uniform; where no
    shape bends light and ``uniform_share`` is 0, they start none."""
    emitters = [e for e in scene.emitters()
                if not delta_only or mi.has_flag(e.flags(), mi.EmitterFlags.Delta)]
    spheres = bending_spheres(scene)
    powers = [emitter_power(e) for e in emitters]
    total = sum(powers)
    shares = []
    if total <= 0 or photons <= 0:
        return shares
    for emitter, power in zip(emitters, powers):
        if power <= 0:
            continue
        count = max(1, int(round(photons * power / total)))
        position = light_position(emitter)
        if position is None:
            shares.append(EmitterShare(emitter, count))
            continue
        cones = cones_towards(np.array(position), spheres)
        uniform = 1.0 if not cones else uniform_share
        if not cones and uniform_share == 0:
            continue
        shares.append(EmitterShare(emitter, count, position, cones, uniform))
    return shares


def emitted_rays(share: EmitterShare, index: mi.UInt32, sequence: PaddedSobol):
    """The rays and powers (over the photon count) of photons ``index`` of
    ``share``: pairs 0 and 1 of ``sequence`` place them."""
    u1, u2 = sequence.point(index, 0), sequence.point(index, 1)
    if not share.aimed:
        ray, weight = share.emitter.sample_ray(0.0, u1.x, u1, u2)
        # A uniform emitter's weight is one value for all its rays: made
        # as wide as they are, so that each photon has its own.
        power = mi.Color3f(weight) / share.count + dr.zeros(mi.Color3f, dr.width(index))
        return mi.Ray3f(ray), power
    origin = mi.Point3f(*share.position)
    d = _aimed_direction(share, u1.x, u2)
    it = dr.zeros(mi.Interaction3f, dr.width(index))
    it.p = origin + d
    ds, intensity = share.emitter.sample_direction(it, mi.Point2f(0.5))
    # At unit distance the light's weight towards ``it`` is its intensity.
    power = mi.Color3f(intensity) / (aimed_pdf(share, d) * share.count)
    return mi.Ray3f(origin, d), dr.select(dr.isfinite(power), power, 0)


def _aimed_direction(share: EmitterShare, u_choice, u_dir: mi.Point2f):
    """A direction of the mixture: uniform with probability
    ``uniform_share``, else in one of the cones, each as likely."""
    cones = share.cones
    direction = mi.warp.square_to_uniform_sphere(u_dir)
    cone_part = 1.0 - share.uniform_share
    if not cones or cone_part <= 0:
        return direction
    pick = (u_choice - share.uniform_share) / cone_part
    in_cones = u_choice >= share.uniform_share
    for k, cone in enumerate(cones):
        chosen = in_cones & (pick * len(cones) >= k) & (pick * len(cones) < k + 1)
        local = mi.warp.square_to_uniform_cone(u_dir, cone.cos_max)
        frame = mi.Frame3f(mi.Vector3f(*cone.axis))
        direction = dr.select(chosen, frame.to_world(local), direction)
    return direction


def aimed_pdf(share: EmitterShare, d: mi.Vector3f) -> mi.Float:
    """The mixture's density of direction ``d`` (per steradian)."""
    pdf = mi.Float(share.uniform_share / (4 * math.pi))
    cone_part = 1.0 - share.uniform_share
    for cone in share.cones:
        inside = dr.dot(d, mi.Vector3f(*cone.axis)) >= cone.cos_max
        pdf += dr.select(inside, cone_part / (len(share.cones) * cone.solid_angle), 0)
    return pdf
