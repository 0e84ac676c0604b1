"""Ray trees of any depth: traced without Python's recursion, pruned and
capped as documented, and never left running forever.

Oracle: a closed box of six emitting mirrors seen from inside. Every ray
hits a wall, which adds its radiance Le and reflects the ray with weight r,
so every pixel is exactly Le (1 + r + ... + r^(K-1)) = Le (1 - r^K) / (1 - r),
where K is the number of rays of the chain: ``max_depth``, or fewer where
the pruning (``min_throughput``) stops it."""

import math

import mitsuba as mi
import numpy as np
import pytest

from conftest import assert_finite
from mitsuba_whitted.integrators import whitted as whitted_module
from mitsuba_whitted.integrators.scene_needs import SceneNeeds
from mitsuba_whitted.integrators.shading import MAX_TREE_RAYS, HitShader, TreeSettings
from validation.scenes import camera, diffuse, floor, integrator, point_light, rgb, scene, sphere

LE, R = 0.25, 0.99
TRACERS = {"depth-first tracer": False, "wavefront tracer": True}

#: A wall's placement: the axis it faces along and its side; its front
#: (the rectangle's +z) faces the inside of the box.
WALLS = [((0, 1, 0), 90), ((0, 1, 0), -90), ((1, 0, 0), -90), ((1, 0, 0), 90),
         ((0, 1, 0), 0), ((0, 1, 0), 180)]


def mirror_box(*inside, size=6):
    T = mi.ScalarTransform4f
    walls = {}
    for index, (axis, angle) in enumerate(WALLS):
        walls[f"wall_{index}"] = {
            "type": "rectangle",
            "to_world": T().rotate(axis, angle) @ T().translate([0, 0, -2]) @ T().scale(2.0),
            "bsdf": {"type": "conductor", "specular_reflectance": rgb(R, R, R)},
            "emitter": {"type": "area", "radiance": rgb(LE, LE, LE)},
        }
    return mi.load_dict(scene(*inside, sensor=camera(origin=(0.3, 0.2, 1.0), fov=70, size=size),
                              **walls))


def chain_radiance(rays: int) -> float:
    return LE * (1 - R ** rays) / (1 - R)


def render(loaded, capture: bool, **settings):
    whitted = mi.load_dict(integrator(**settings))
    whitted.capture_rays = capture
    image = np.array(mi.render(loaded, integrator=whitted))
    assert_finite(image)
    return image, whitted.last_stats


@pytest.mark.parametrize("capture", TRACERS.values(), ids=TRACERS.keys())
def test_a_thousand_generations_are_traced_to_the_pruning(capture):
    """max_depth 1000; the chain is pruned once r^k < 1e-4: K = 917 rays,
    far more generations than Python's recursion limit allows a tracer
    that recurses once per generation."""
    image, stats = render(mirror_box(), capture, max_depth=1000, min_throughput=1e-4)
    rays = 1 + math.floor(math.log(1e-4) / math.log(R))
    assert rays == 917 and stats["generations"] == rays
    np.testing.assert_allclose(image, chain_radiance(rays), rtol=2e-4)
    assert stats["cut"] == 0


@pytest.mark.parametrize("capture", TRACERS.values(), ids=TRACERS.keys())
def test_unbounded_depth_without_pruning_stops_at_256_generations(capture):
    image, stats = render(mirror_box(), capture, max_depth=-1, min_throughput=0)
    assert stats["generations"] == 256
    np.testing.assert_allclose(image, chain_radiance(256), rtol=1e-4)


@pytest.mark.parametrize("capture", TRACERS.values(), ids=TRACERS.keys())
def test_trees_that_double_every_generation_stop_at_the_ray_cap(capture, monkeypatch):
    """A glass ball in the mirror box, nothing pruned: every hit on the ball
    spawns two rays. The trees stop at MAX_TREE_RAYS rays per camera sample
    (on average over a launch for the wavefront tracer), with a warning."""
    warnings = []
    monkeypatch.setattr(whitted_module, "_warn", warnings.append)
    glass = sphere((0, 0, 0), 1.2, {"type": "dielectric", "int_ior": 1.5})
    _, stats = render(mirror_box(glass, size=4), capture, max_depth=30, min_throughput=0)
    # Rays are counted by kind when spawned; those cut were never traced.
    traced = stats["camera"] + stats["reflection"] + stats["refraction"] - stats["cut"]
    assert stats["cut"] > 0
    assert traced <= MAX_TREE_RAYS * stats["camera"]
    assert len(warnings) == 1 and "'max_depth'" in warnings[0]
    assert f"{stats['cut']:,} rays were left untraced" in warnings[0]


def test_a_sample_count_passed_to_mi_render_is_named_once(monkeypatch):
    warnings = []
    monkeypatch.setattr(whitted_module, "_warn", warnings.append)
    loaded = mirror_box(size=4)
    whitted = mi.load_dict(integrator(max_depth=3))
    plain = np.array(mi.render(loaded, integrator=whitted))
    for _ in range(2):
        np.testing.assert_array_equal(np.array(mi.render(loaded, integrator=whitted, spp=16)),
                                      plain)
    assert len(warnings) == 1
    assert "spp=16 is not used" in warnings[0] and "'aa'" in warnings[0]


#: What some users write for "no limit": the largest ``max_depth``.
LARGEST_DEPTH = 2 ** 31 - 1
#: ``HitShader.work`` calls a render may make: a few per kernel recorded
#: and per generation traced, never one per possible generation.
WORK_CALLS = 1000


def open_scene(*objects):
    """``objects`` over a lit floor under an open sky: every ray tree ends
    where its rays reach a diffuse surface or leave the scene."""
    return mi.load_dict(scene(floor(), *objects, point_light((1, 3, 3)),
                              sensor=camera(origin=(0, 1, 5), size=12)))


def count_work(monkeypatch) -> list:
    """Count the calls of ``HitShader.work``, failing past ``WORK_CALLS``."""
    calls, work = [], HitShader.work

    def counted(shader, generation):
        calls.append(generation)
        assert len(calls) <= WORK_CALLS, "the cost follows max_depth, not the rays traced"
        return work(shader, generation)

    monkeypatch.setattr(HitShader, "work", counted)
    return calls


OPEN_SCENES = {
    "no mirrors, depth-first": ((sphere((0, 0, 0), 0.8, diffuse(0.7, 0.3, 0.2)),), False),
    "mirror balls, depth-first": ((sphere((-0.6, 0, 0), 0.6, {"type": "conductor"}),
                                   sphere((0.6, 0.1, 0), 0.5, {"type": "conductor"})), False),
    "glass and mirror, wavefront": ((sphere((-0.6, 0, 0), 0.6, {"type": "dielectric"}),
                                     sphere((0.7, 0, -0.5), 0.5, {"type": "conductor"})), True),
}


@pytest.mark.parametrize("objects, capture", OPEN_SCENES.values(), ids=OPEN_SCENES.keys())
def test_the_largest_max_depth_costs_only_the_generations_its_trees_reach(objects, capture,
                                                                        monkeypatch):
    """max_depth 2^31 - 1 against the least max_depth that lets every
    generation reached do all its work (a hit of generation g spawns
    children while g + 3 <= max_depth: the deepest generation reached, in
    Mitsuba's count of path segments, plus its hit's shadow ray and the
    children it did not have): the same bits, the same rays, and as few
    calls deciding what a generation computes."""
    calls = count_work(monkeypatch)
    loaded = open_scene(*objects)
    image, stats = render(loaded, capture, max_depth=LARGEST_DEPTH)
    unbounded_calls = len(calls)
    calls.clear()
    reached = stats["generations"]
    bounded, bounded_stats = render(loaded, capture, max_depth=reached + 2)
    np.testing.assert_array_equal(image, bounded)
    assert stats == bounded_stats
    assert unbounded_calls == len(calls)
    assert reached <= 8


@pytest.mark.parametrize("emitters", [False, True], ids=["lamps only", "emitters to hit"])
@pytest.mark.parametrize("components", [(), (0,), (0, 1)], ids=["0", "1", "2"])
def test_spawning_generations_are_those_whose_work_spawns(emitters, components):
    """The count the depth-first stack is sized by, against its definition:
    the generations below max_depth whose ``work`` spawns, asked one by
    one."""
    needs = SceneNeeds(delta_components=components, smooth_surfaces=True,
                       sampled_lights=[None] if emitters else [])
    for depth in range(12):
        shader = HitShader(None, needs, TreeSettings(depth, 1e-4, False), None)
        expected = sum(1 for generation in range(depth) if shader.work(generation).spawn)
        assert shader.spawning_generations() == expected, depth
