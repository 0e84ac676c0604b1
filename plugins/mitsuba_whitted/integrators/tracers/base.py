"""What the two ray-tree tracers share.

A tracer turns camera samples into radiance: ``trace(rays)`` walks the
Whitted ray tree of each ray (:mod:`.shading` says what a hit computes).
Two implementations stand side by side over the base here:

- :mod:`.depth_first`: each camera sample's whole tree in one frozen
  kernel, depth first, with a small per-lane stack: the fast one;
- :mod:`.wavefront`: one generation of rays at a time for the whole batch,
  compacted between generations: any depth, and every ray it casts can be
  kept (``captured``) for the bench to replay.

:func:`.build.build_tracer` assembles a tracer for a scene and picks the
implementation.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ...camera import camera_rays
from ...jit import to_int
from ..shading import HitShader


@dataclass
class RayStats:
    """Rays traced by kind. Device-side counts stay lazy until read."""
    camera: int = 0
    reflection: object = 0
    refraction: object = 0
    passthrough: object = 0
    shadow: object = 0
    #: Closest-hit queries of shadow rays through pass-through surfaces.
    shadow_march: object = 0
    #: Hits on analytic proxies made exact (not extra rays).
    refined: object = 0
    #: Rays of the kinds above (counted when spawned) left untraced because
    #: their tree reached ``MAX_TREE_RAYS``.
    cut: object = 0
    #: Closest-hit rays of the indirect paths (:mod:`.indirect`), and
    #: their shadow rays.
    indirect: object = 0
    indirect_shadow: object = 0
    generations: object = 0
    batches: int = 0

    KINDS = ("camera", "reflection", "refraction", "passthrough", "shadow", "shadow_march",
             "indirect", "indirect_shadow")

    def as_dict(self) -> dict:
        counts = {kind: to_int(getattr(self, kind)) for kind in self.KINDS}
        counts["total"] = sum(counts.values())
        counts["refined"] = to_int(self.refined)
        counts["cut"] = to_int(self.cut)
        counts["generations"] = to_int(self.generations)
        counts["batches"] = self.batches
        return counts


class RayBatch:
    """Rays of one generation: origin, direction, throughput, hash key, and
    the indirect paths each of its hits gathers (a real number per ray, see
    :mod:`.indirect`; ``None``: the integrator's ``indirect_samples``)."""

    def __init__(self, o, d, throughput, key, paths=None):
        self.o, self.d, self.throughput, self.key = o, d, throughput, key
        self.paths = paths

    def __len__(self) -> int:
        return dr.width(self.key)

    def take(self, index: mi.UInt32) -> "RayBatch":
        return RayBatch(dr.gather(mi.Point3f, self.o, index),
                        dr.gather(mi.Vector3f, self.d, index),
                        dr.gather(mi.Color3f, self.throughput, index),
                        dr.gather(mi.UInt32, self.key, index),
                        None if self.paths is None else dr.gather(mi.Float, self.paths, index))

    def fields(self):
        return self.o, self.d, self.throughput, self.key


@dataclass
class CapturedBatch:
    """What a capturing render keeps of one batch it traced: its rays, and
    the rays its shadow test cast, as cast (:mod:`.shadow_log`): the shadow
    rays tested, and the closest-hit queries that followed blocked ones
    through surfaces that let light pass (both empty where the batch tested
    no shadows)."""
    generation: int
    rays: RayBatch
    shadow: mi.Ray3f
    queries: mi.Ray3f


class Tracer:
    """What both tracers hold: ``trace(rays)`` gives radiance and alpha
    (primary hit) of camera rays, and where the shader gathers indirect
    light the part of the radiance it gathered (a third value), and adds
    to ``stats``. ``wavefront_size``:
    the most rays of one generation the wavefront tracer keeps at once, the
    unit of both tracers' launch sizes."""

    def __init__(self, shader: HitShader, intersect, refiner=None,
                 wavefront_size: int = 1 << 18):
        self.shader = shader
        self.scene_ref = shader.scene_ref
        self.wavefront_size = wavefront_size
        self.intersect = intersect
        self.refiner = refiner
        #: When a list, the wavefront tracer appends a :class:`CapturedBatch`
        #: of every batch it traces (the bench replays the very same rays
        #: through Mitsuba's own ray casting).
        self.captured = None
        self._start()

    def reload(self) -> None:
        """Ready for another render: shape placements may have changed
        since the last one (frozen kernels take the tables as arguments)."""
        if self.refiner is not None:
            self.refiner.load_tables()
        self._start()

    def _start(self) -> None:
        """Fresh statistics, and the tables the kernels read besides the
        scene and the rays."""
        self.stats = RayStats()
        self.kernel_inputs = self.refiner.tables() if self.refiner is not None else ()

    @property
    def camera_batch(self) -> int:
        """Most camera samples given to ``trace_camera`` at once."""
        return self.wavefront_size

    @property
    def launch_rays(self) -> int:
        """About the most rays in flight at once, for the memory estimate."""
        return self.camera_batch

    def trace_camera(self, sensor: mi.Sensor, positions: mi.Point2f, keys: mi.UInt32,
                     lens: mi.Point2f = None, paths: mi.Float = None):
        """``trace`` of the camera rays through ``positions`` (pixel units
        in the crop window) from ``lens`` (see ``camera_rays``), gathering
        ``paths`` indirect paths per hit."""
        ray, weight = camera_rays(sensor, positions, lens)
        return self.trace(RayBatch(ray.o, ray.d, mi.Color3f(weight), keys, paths))

    def statistics(self) -> dict:
        """Rays traced since the last ``reload``, by kind."""
        return self.stats.as_dict()
