"""The gradients' tree replay walks the depth-first tracer's trees.

It sums each camera sample's radiance as a tree, from the leaves up: a
node's own radiance plus its children's, each times its weight, with a
frame per node whose children are pending. Oracle: the depth-first
tracer's radiance for the same rays, summed node by node as each is
visited. The two agree to float32 rounding on mirrors, glass and tinted
shadows, and on trees cut at ``MAX_TREE_RAYS``; and the walk traces as
many rays as the tracer (the cut keeps the same rays).
"""

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsuba_whitted.camera import camera_rays
from mitsuba_whitted.integrators.tracers import DepthFirstTracer, RayBatch
from mitsuba_whitted.integrators.tracers.tree_replay import TreeWalk
from test_deep_trees import mirror_box
from test_gradients import gallery
from validation.scenes import integrator, sphere


def walked_and_traced(loaded, whitted) -> tuple:
    """Per pixel centre of ``loaded``'s sensor: what the tree replay walked
    (a backward pass with a zero adjoint), the depth-first tracer's
    radiance and its ray counts."""
    sensor = loaded.sensors()[0]
    width, height = sensor.film().crop_size()
    index = dr.arange(mi.UInt32, width * height)
    positions = mi.Point2f(mi.Float(index % width) + 0.5, mi.Float(index // width) + 0.5)
    ray, weight = camera_rays(sensor, positions)
    rays = RayBatch(ray.o, ray.d, mi.Color3f(weight), mi.sample_tea_32(index, mi.UInt32(7))[0])
    walking = whitted.make_tracer(loaded, differentiable="tree")
    tracing = whitted.make_tracer(loaded)
    assert isinstance(walking, DepthFirstTracer) and isinstance(tracing, DepthFirstTracer)
    with walking.scene_ref.holding(loaded), tracing.scene_ref.holding(loaded):
        walked = TreeWalk(walking).backward(rays, dr.zeros(mi.Color3f, len(rays)), [])
        traced, _ = tracing.trace(rays)
        stats = tracing.statistics()
    return walked, np.array(traced), stats


def assert_same_trees(walked, traced, stats):
    """The same radiance to rounding, and every ray the tracer traced (all
    those spawned but the cut ones) walked once."""
    assert np.abs(traced).max() > 0
    np.testing.assert_allclose(np.array(walked.radiance), traced, rtol=1e-5,
                               atol=1e-6 * np.abs(traced).max())
    spawned = sum(stats[kind] for kind in ("camera", "reflection", "refraction", "passthrough"))
    assert np.array(walked.visited, dtype=np.int64).sum() == spawned - stats["cut"]
    assert np.array(walked.revisited).sum() > 0


def test_the_walk_sums_the_depth_first_tracer_s_trees():
    """A textured ball seen directly, in a mirror and through a glass ball,
    tinted shadows, two lights: trees of reflected and refracted rays."""
    loaded = mi.load_dict(gallery(size=24))
    walked, traced, stats = walked_and_traced(loaded, loaded.integrator())
    assert stats["reflection"] > 0 and stats["refraction"] > 0 and stats["shadow_march"] > 0
    assert_same_trees(walked, traced, stats)


def test_trees_cut_at_the_ray_cap_are_walked_as_traced():
    """A glass ball in a box of emitting mirrors, nothing pruned: trees
    that double every generation stop at MAX_TREE_RAYS rays, and the walk
    finishes the frames left open by the cut."""
    glass = sphere((0, 0, 0), 1.2, {"type": "dielectric", "int_ior": 1.5})
    loaded = mirror_box(glass, size=4)
    whitted = mi.load_dict(integrator(max_depth=30, min_throughput=0))
    walked, traced, stats = walked_and_traced(loaded, whitted)
    assert stats["cut"] > 0
    assert_same_trees(walked, traced, stats)
