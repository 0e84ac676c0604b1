"""Which tracer renders a scene, assembled from its parts: the scene's
needs, the lighting, the shadow test, the analytic refinement."""

from __future__ import annotations

import mitsuba as mi

from ..analytic import AnalyticRefiner
from ..indirect import IndirectLight
from ..lighting import DirectLighting, LightingSettings, ShadowTester
from ..scene_needs import SceneNeeds
from ..scene_ref import SceneRef
from ..shading import HitShader, TreeSettings
from .base import Tracer
from .depth_first import DepthFirstTracer
from .wavefront import WavefrontTracer


def build_tracer(scene: mi.Scene, needs: SceneNeeds, shadows: str,
                 lighting: LightingSettings, tree: TreeSettings, wavefront_size: int,
                 wavefront: bool = False, differentiable: str = None,
                 photons=None) -> Tracer:
    """A tracer of ``scene`` built from its ``needs``: the depth-first one
    where its stack is deep enough, else (or when ``wavefront`` asks, e.g.
    to capture each generation's rays) the wavefront one. ``differentiable``
    asks for one whose traces Dr.Jit can differentiate: ``"graph"``, the
    wavefront one unfrozen (differentiated as a whole); ``"tree"``, one
    whose kernels differentiate a hit at a time (:mod:`.tree_replay`), the
    depth-first one where it serves. ``shadows``: the shadow mode of
    :class:`ShadowTester`. ``photons``: the lookup of a photon pass's
    tracer (:class:`.photons.progressive.PhotonLookup`), whose hits add the
    photons' light alone, and, where the lookup asks for them, one path
    from each hit that gathers photons at its vertices."""
    scene_ref = SceneRef(scene)
    refiner = (AnalyticRefiner(scene_ref, needs.analytic_shapes, needs.scale)
               if needs.analytic_shapes else None)
    intersect = refiner.intersect if refiner else plain_intersect(scene_ref)
    shadow_test = ShadowTester(scene_ref, needs, shadows, intersect)
    indirect = None
    if photons is not None:
        if photons.with_paths:
            indirect = IndirectLight(scene_ref, needs, 1, lighting.seed, intersect,
                                     shadow_test, photons=photons)
    elif lighting.indirect_samples:
        indirect = IndirectLight(scene_ref, needs, lighting.indirect_samples, lighting.seed,
                                 intersect, ShadowTester(scene_ref, needs, "blocking", intersect))
    shader = HitShader(scene_ref, needs, tree, DirectLighting(needs, lighting, shadow_test),
                       indirect, photons)
    if not wavefront and differentiable != "graph" and DepthFirstTracer.supports(shader):
        shadow_test.by_parts = differentiable == "tree"
        return DepthFirstTracer(shader, intersect, refiner, wavefront_size)
    return WavefrontTracer(shader, intersect, refiner, wavefront_size,
                           frozen=differentiable is None)


def plain_intersect(scene_ref: SceneRef):
    """``intersect(ray, active, coherent)``: Mitsuba's own intersection.

    The tracers pass ``coherent=True`` for the rays of a ray tree (Embree's
    packet traversal): camera rays, and the mirror and refracted rays of
    Whitted's smooth surfaces, stay coherent; shadow rays are faster in the
    incoherent mode."""
    def intersect(ray: mi.Ray3f, active: mi.Bool,
                  coherent: bool = False) -> mi.SurfaceInteraction3f:
        return scene_ref.get().ray_intersect(ray, mi.RayFlags.All, coherent, active)
    return intersect
