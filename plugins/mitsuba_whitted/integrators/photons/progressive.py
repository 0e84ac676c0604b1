"""Progressive photon mapping: passes of photons, gathered at the smooth
hits of the ray tree, with a radius that shrinks from pass to pass.

Each pass traces ``photons`` photons from the lights (:mod:`.tracing`),
puts them in a hashed grid (:mod:`.grid`), and walks each pixel's ray tree
once more from a point of the pixel (and of the lens) jittered anew each
pass where anti-aliasing or an aperture is on. At every smooth hit of the
tree the photons within the pass's radius give a density estimate of the
light that reaches it, times the tree's throughput to the hit: the tree's
smooth hits are the visible points.

The radius shrinks as in stochastic progressive photon mapping (Hachisuka
and Jensen 2009), in its probabilistic form (Knaus and Zwicker 2011): pass
i gathers with r_i, where r_(i+1)^2 = r_i^2 (i + alpha) / (i + 1), and a
pixel's estimate is the mean of its passes' estimates. Each pass's blur
shrinks with r_i^2 while its noise grows only as 1 / r_i^2, so with alpha
in (0, 1) both the bias and the variance of the mean vanish as passes grow
(for alpha 2/3, the mean squared error falls as passes^(-2/3)).

The first radius, unless the scene gives ``photon_radius``, is half the
width of a pixel at the median distance of the camera's first hits.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from ...camera import camera_rays
from ...errors import ParameterError
from ...system import available_memory
from ..lens import pixel_seed
from ..sequence import mix, to_unit
from ..settings import PLUGIN_NAME
from .emission import plan_emission
from .grid import PhotonGrid
from .tracing import PHOTON_BYTES, TRAVELLING_BYTES, PhotonKinds, PhotonTracer, Photons

#: The radius reduction of every pass (Hachisuka and Jensen's alpha).
ALPHA = 2.0 / 3.0
#: The first radius, in pixel widths at the camera's typical distance.
FOOTPRINT_PIXELS = 0.5
#: Pixels per side of the grid of camera rays that measures the footprint.
FOOTPRINT_PROBES = 64
#: Of the memory left, the share a pass's photons may take.
MEMORY_SHARE = 0.25
#: The gather radius at the vertices of paths, in radii of the tree's hits:
#: a caustic seen through a diffuse bounce is blurred by the bounce anyway,
#: and a wider radius gathers many more photons at each vertex.
PATH_RADIUS_FACTOR = 4.0
#: Shares of an aimed light's photons left uniform where it also lights
#: indirect light (which does not need to pass what bends light first).
UNIFORM_SHARE = 0.5
#: R2 sequence steps (Roberts 2018): the jitter of pass i.
_R2 = (0.7548776662466927, 0.5698402909980532)
_LENS_SALT = 0x68E31DA4
_PASS_SALT = 0x1B873593


def radii(first: float, passes: int, alpha: float = ALPHA) -> list:
    """The gather radius of each pass."""
    squared, values = first * first, []
    for i in range(1, passes + 1):
        values.append(math.sqrt(squared))
        squared *= (i + alpha) / (i + 1)
    return values


def kinds_for(indirect_samples: int) -> tuple:
    """Which photons a render needs (:class:`.tracing.PhotonKinds`), and
    whether they come from delta lights alone: without indirect paths,
    every light the tree leaves out; with them, only what their paths
    cannot find, the light of delta lights through delta chains."""
    if indirect_samples:
        return PhotonKinds(straight_bends=False, smooth_bounces=False), True
    return PhotonKinds(straight_bends=False, smooth_bounces=True), False


#: What completes a path tracer: delta light through any delta or null
#: crossing onto a smooth surface (a path tracer's shadow rays stop at every
#: surface and its paths cannot hit a delta light).
PATH_COMPLEMENT = PhotonKinds(straight_bends=True, smooth_bounces=False)


class PhotonLookup:
    """What a photon pass's tracer gathers from: the current pass's grid.
    ``with_paths``: whether the tree's smooth hits also send a path each
    that gathers at its vertices, for photons that end at the first smooth
    surface they meet (whose light a smooth hit sees through other smooth
    surfaces only that way)."""

    def __init__(self, with_paths: bool = False):
        self.with_paths = with_paths
        self.hold(Photons.empty(), 1.0)

    def hold(self, photons: Photons, radius: float) -> None:
        """Gather from ``photons`` within ``radius`` at the tree's hits, and
        within ``PATH_RADIUS_FACTOR`` times that at the paths' vertices."""
        self.grid = PhotonGrid(photons, radius)
        self.far_grid = (PhotonGrid(photons, radius * PATH_RADIUS_FACTOR) if self.with_paths
                         else self.grid)

    def estimate(self, si, bsdf, active, segments):
        """At a hit of the tree."""
        return self.grid.estimate(si, bsdf, active, segments)

    def estimate_far(self, si, bsdf, active, segments):
        """At a vertex of a path, seen through another smooth surface, whose
        blur no pixel shows: a wider radius, for less noise."""
        return self.far_grid.estimate(si, bsdf, active, segments)

    def arrays(self) -> tuple:
        return self.grid.arrays() + (self.far_grid.arrays() if self.with_paths else ())


class ProgressivePhotons:
    """``render(scene, sensor, seed, shade)``: the photons' light of every
    pixel of the sensor's crop window, the mean of ``passes`` passes.

    ``tracer`` is a photon pass's tracer (built with a :class:`PhotonLookup`)
    and ``shade(positions, keys, lens)`` traces camera samples with it."""

    def __init__(self, photons: int, passes: int, radius: float, kinds: PhotonKinds,
                 delta_only: bool, max_depth: int):
        self.photons = photons
        self.passes = passes
        self.radius = radius
        self.kinds = kinds
        self.delta_only = delta_only
        self.max_depth = max_depth
        #: What the last render did: photons emitted and stored, radii.
        self.stats = {}

    def render(self, scene: mi.Scene, sensor: mi.Sensor, seed: int, tracer, shade,
               jitter: bool, lens: bool, on_pass=None) -> mi.Color3f:
        """The mean photon light per pixel; ``jitter``: whether each pass
        takes a new point of each pixel, ``lens`` of the aperture;
        ``on_pass(i, mean)``, if given, hears of each pass's running mean;
        what it raises ends the passes there. Pass i's radius and photons
        depend on i alone, so the mean of the first k passes is the same
        whatever ``passes`` is, as long as it is at least k."""
        lookup = tracer.shader.photons
        shares = plan_emission(scene, self.photons, self.delta_only,
                               UNIFORM_SHARE if self.kinds.smooth_bounces else 0.0)
        width, height = sensor.film().crop_size()
        pixels = width * height
        self._check_memory(pixels)
        photon_tracer = PhotonTracer(tracer.intersect, tracer.shader.needs.scale, self.kinds,
                                     self.max_depth, self._photon_budget())
        first = self.radius or pixel_footprint(scene, sensor, tracer.intersect)
        schedule = radii(first, self.passes)
        total = dr.zeros(mi.Color3f, pixels)
        stats = {"photons_emitted": 0, "photons_stored": 0, "photon_segments": 0,
                 "photon_passes": self.passes, "photon_radius_first": first,
                 "photon_radius_last": schedule[-1] if schedule else first}
        if not shares:
            # No light of the kinds asked for: nothing to trace or gather.
            self.stats = stats
            return total
        base_inputs = tracer.kernel_inputs
        try:
            for i, radius in enumerate(schedule):
                photons, emitted, segments = photon_tracer.trace(shares, pass_salt(seed, i))
                lookup.hold(photons, radius)
                tracer.kernel_inputs = tuple(base_inputs) + lookup.arrays()
                positions, keys, lens_points = pass_samples(width, height, i, seed, jitter, lens)
                radiance = shade(positions, keys, lens_points)[0]
                total = total + radiance
                dr.eval(total)
                stats["photons_emitted"] += emitted
                stats["photons_stored"] += len(photons)
                stats["photon_segments"] += segments
                if on_pass is not None:
                    on_pass(i + 1, total / (i + 1))
        finally:
            # Also where on_pass stops the passes by raising: the tracer
            # is kept for the next render, which starts from its inputs.
            tracer.kernel_inputs = base_inputs
            lookup.hold(Photons.empty(), 1.0)
        self.stats = stats
        return total / max(self.passes, 1)

    def _photon_budget(self) -> int:
        available = available_memory()
        return int(MEMORY_SHARE * available) if available else 1 << 40

    def _check_memory(self, pixels: int) -> None:
        """Refuse, before anything is allocated, a pass whose travelling
        photons and at least one stored photon each would not fit."""
        available = available_memory()
        if available is None:
            return
        needed = self.photons * (TRAVELLING_BYTES + PHOTON_BYTES) + pixels * 64
        if needed > MEMORY_SHARE * available:
            raise ParameterError(
                PLUGIN_NAME, "photons",
                f"is {self.photons:,} photons per pass, which need about "
                f"{needed / 2**20:,.0f} MiB, more than this machine can spare "
                f"({MEMORY_SHARE * available / 2**20:,.0f} MiB); lower 'photons' and raise "
                "'photon_passes'")


def pass_salt(seed: int, index: int) -> int:
    """The seed of pass ``index``'s photons."""
    return int(mix(mi.UInt32((seed * 0x9E3779B1 + index * 0x85EBCA77 + _PASS_SALT)
                             % (1 << 32)))[0])


def pass_samples(width: int, height: int, index: int, seed: int, jitter: bool, lens: bool):
    """Pass ``index``'s camera sample of every pixel (row-major): its
    position, key and lens point. Jittered, pixel by pixel, along an R2
    sequence rotated by a hash of the pixel, so that each pixel's points
    over the passes are well spread over it."""
    pixel = dr.arange(mi.UInt32, width * height)
    x = mi.Float(pixel % width)
    y = mi.Float(pixel // width)
    keys = pixel + dr.opaque(mi.UInt32, (index * width * height) % (1 << 32))
    if not jitter:
        return mi.Point2f(x + 0.5, y + 0.5), keys, None
    seed_value = dr.opaque(mi.UInt32, (seed * 0x27D4EB2F) % (1 << 32))
    rotation = pixel_seed(pixel ^ seed_value)
    offset = _r2_point(index, rotation)
    positions = mi.Point2f(x, y) + offset
    if not lens:
        return positions, keys, None
    return positions, keys, _r2_point(index, mix(rotation ^ _LENS_SALT))


def _r2_point(index: int, rotation: mi.UInt32) -> mi.Point2f:
    """Point ``index`` of the R2 sequence, rotated by a hash per lane."""
    u = to_unit(rotation)
    v = to_unit(mix(rotation))
    step = dr.opaque(mi.Float, index)
    px = u + step * _R2[0]
    py = v + step * _R2[1]
    return mi.Point2f(px - dr.floor(px), py - dr.floor(py))


def pixel_footprint(scene: mi.Scene, sensor: mi.Sensor, intersect) -> float:
    """The width of one pixel at the median distance of the camera's
    first hits: a grid of camera rays, each beside its neighbour one
    pixel to the right."""
    width, height = sensor.film().crop_size()
    n = FOOTPRINT_PROBES
    index = dr.arange(mi.UInt32, n * n)
    x = (mi.Float(index % n) + 0.5) * (width - 1) / n
    y = (mi.Float(index // n) + 0.5) * height / n
    here, _ = camera_rays(sensor, mi.Point2f(x, y))
    beside, _ = camera_rays(sensor, mi.Point2f(x + 1, y))
    si = intersect(mi.Ray3f(here), mi.Bool(True))
    t = si.t
    spread = dr.norm((beside.o + beside.d * t) - (here.o + here.d * t))
    found = spread.numpy()[si.is_valid().numpy()]
    found = found[np.isfinite(found) & (found > 0)]
    if found.size:
        return float(np.median(found)) * FOOTPRINT_PIXELS
    extent = float(np.max(np.array(scene.bbox().extents())))
    return extent / max(width, height) * FOOTPRINT_PIXELS
