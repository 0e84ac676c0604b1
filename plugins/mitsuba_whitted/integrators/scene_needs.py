"""What a scene needs from the Whitted integrator, found once at set-up.

The integrator builds its kernels from this summary so that it models only
what the scene has: no transmission logic without transmissive surfaces, a
plain ``ray_test`` when nothing lets shadow rays through, no analytic
refinement without analytic shapes, no emitter loop over lights that do not
exist.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mitsuba as mi

from ..shapes.analytic import is_analytic
from .offsets import scene_scale


@dataclass
class SceneNeeds:
    #: Emitters with a delta position or direction (point, spot, directional).
    delta_lights: list = field(default_factory=list)
    #: Emitters sampled with shadow rays (area lights, environment maps).
    sampled_lights: list = field(default_factory=list)
    #: Component indices that are delta (mirror/refraction) in some BSDF.
    delta_components: tuple = ()
    #: Component indices that transmit without scattering in some BSDF.
    transmission_components: tuple = ()
    #: Some BSDF has a null (pass-through) part, e.g. ``null`` or ``mask``.
    null_surfaces: bool = False
    #: Some BSDF transmits light at all (delta transmission or null).
    transmissive: bool = False
    #: Some BSDF has a smooth (diffuse or glossy) part that lights reach.
    smooth_surfaces: bool = False
    #: The scene's size, for offsets that scale with it (``offsets``).
    scale: float = 1.0
    #: Shapes whose hits are refined by an exact analytic intersection.
    analytic_shapes: list = field(default_factory=list)
    #: Each BSDF's flags, component by component: the kernels are
    #: specialised to them (``bsdf_query``), so a change must rebuild them.
    bsdf_flags: tuple = ()

    @property
    def hittable_emitters(self) -> bool:
        """Whether a ray can reach emission: an area or environment light."""
        return bool(self.sampled_lights)


def _bsdfs(scene: mi.Scene):
    seen = {}
    for shape in scene.shapes():
        bsdf = shape.bsdf()
        if bsdf is not None:
            seen[id(bsdf)] = bsdf
    return list(seen.values())


def _components_with(bsdfs, flag: mi.BSDFFlags, without=mi.BSDFFlags.Empty) -> tuple:
    found = set()
    for bsdf in bsdfs:
        for i in range(bsdf.component_count()):
            flags = bsdf.flags(i)
            if mi.has_flag(flags, flag) and not mi.has_flag(flags, without):
                found.add(i)
    return tuple(sorted(found))


def analyse(scene: mi.Scene) -> SceneNeeds:
    """Summarise what ``scene`` requires from the Whitted integrator."""
    needs = SceneNeeds()
    for emitter in scene.emitters():
        if mi.has_flag(emitter.flags(), mi.EmitterFlags.Delta):
            needs.delta_lights.append(emitter)
        else:
            needs.sampled_lights.append(emitter)

    bsdfs = _bsdfs(scene)
    needs.delta_components = _components_with(bsdfs, mi.BSDFFlags.Delta,
                                              without=mi.BSDFFlags.Null)
    needs.transmission_components = _components_with(
        bsdfs, mi.BSDFFlags.DeltaTransmission, without=mi.BSDFFlags.Null)
    needs.null_surfaces = any(mi.has_flag(b.flags(), mi.BSDFFlags.Null) for b in bsdfs)
    needs.transmissive = bool(needs.transmission_components) or needs.null_surfaces
    needs.smooth_surfaces = any(mi.has_flag(b.flags(), mi.BSDFFlags.Smooth) for b in bsdfs)
    needs.scale = scene_scale(scene)
    needs.analytic_shapes = [s for s in scene.shapes() if is_analytic(s)]
    needs.bsdf_flags = tuple(tuple(b.flags(i) for i in range(b.component_count())) for b in bsdfs)
    return needs
