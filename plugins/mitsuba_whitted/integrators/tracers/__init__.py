"""The ray-tree tracers: two implementations over one base.

- :mod:`.base`: what a tracer is (camera samples in, radiance out) and
  the ray counts it keeps;
- :mod:`.depth_first`: each camera sample's tree in one frozen kernel with
  a per-lane stack, the default;
- :mod:`.wavefront`: one generation of rays at a time, for trees deeper
  than the stack and for capturing every ray;
- :mod:`.tree_replay`: the depth-first walk again, differentiating each
  hit in its frozen kernel (gradients);
- :mod:`.frozen`: the frozen-kernel wrapper both record their launches in;
- :mod:`.build`: which tracer a scene gets, assembled from its parts.
"""

from .base import RayBatch, Tracer
from .build import build_tracer
from .depth_first import DepthFirstTracer

__all__ = ["DepthFirstTracer", "RayBatch", "Tracer", "build_tracer"]
