"""The depth-first tracer: its per-lane stack against a plain-Python stack, and
its images and ray counts against the wavefront tracer's."""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from conftest import assert_finite
from validation.scenes import (REPORT_SCENE, ROOT, camera, floor, glass_scene, integrator,
                               point_light, rgb, scene, sphere, wall)
from mitsuba_whitted.integrators.tracers.depth_first import (MAX_STACK, DepthFirstTracer,
                                                             LaneStack, stack_capacity)
from mitsuba_whitted.integrators.tracers.wavefront import WavefrontTracer

CAPACITY = 6
ROOTS = [0.5, 3.0, 10.0, 7.0, 2.2, 30.0, 1.5, 4.0, 12.0, 0.1, 17.0, 2.0]


def _children(value: float):
    return [value * 0.5, value * 0.5 + 0.1]


def python_walk(root: float):
    """Depth-first walk of a value tree: weighted sum and nodes visited."""
    stack, total, visited = [(root, 0)], 0.0, 0
    while stack:
        value, depth = stack.pop()
        total += value * (depth + 1)
        visited += 1
        for child in _children(value):
            if child > 1.0 and len(stack) < CAPACITY:
                stack.append((child, depth + 1))
    return total, visited


def _visit(stack, size, total, visited):
    value, depth = stack.read(size)
    total = total + value * mi.Float(depth + 1)
    visited = visited + 1
    for child in _children(value):
        size = stack.push(size, (child, depth + 1), (child > 1.0) & (size < CAPACITY))
    return size, total, visited


@dr.syntax
def lane_walk(roots: mi.Float):
    stack = LaneStack.allocate((mi.Float, mi.UInt32), CAPACITY)
    size = stack.push(mi.UInt32(0), (roots, mi.UInt32(0)), mi.Bool(True))
    total, visited = mi.Float(0), mi.UInt32(0)
    while size > 0:
        size, total, visited = _visit(stack, size - 1, total, visited)
    return total, visited


def python_order(root: float) -> int:
    """A hash of the order in which a plain depth-first walk visits nodes."""
    stack, order = [(root, 0)], 0
    while stack:
        value, depth = stack.pop()
        order = (order * 31 + int(np.float32(value) * 8) + depth) % 2**32
        for child in _children(value):
            if child > 1.0:
                stack.append((child, depth + 1))
    return order


def _visit_holding(stack, size, node, total, order):
    """The depth-first tracer's scheme: go on with the last child, leave earlier
    ones on the stack, pop where there is no child."""
    value, depth = node
    total = total + value * mi.Float(depth + 1)
    order = order * 31 + mi.UInt32(value * 8) + depth
    live = mi.Bool(False)
    for child in _children(value):
        valid = child > 1.0
        size = stack.push(size, node, live & valid)
        node = (dr.select(valid, child, node[0]), dr.select(valid, depth + 1, node[1]))
        live |= valid
    node, size, popped = stack.pop(size, node, ~live & (size > 0))
    return size, node, live | popped, total, order


@dr.syntax
def lane_walk_holding(roots: mi.Float):
    stack = LaneStack.allocate((mi.Float, mi.UInt32), CAPACITY)
    size, node, live = mi.UInt32(0), (roots, mi.UInt32(0)), mi.Bool(True)
    total, order = mi.Float(0), mi.UInt32(0)
    while live:
        size, node, live, total, order = _visit_holding(stack, size, node, total, order)
    return total, order


def test_lane_stack_matches_a_python_stack_when_lanes_diverge():
    """Lanes of one packet at different heights (the case Dr.Jit's per-lane
    local-memory indexing gets wrong) still walk their own trees."""
    total, visited = lane_walk(mi.Float(ROOTS))
    expected = [python_walk(root) for root in ROOTS]
    np.testing.assert_allclose(np.array(total), [e[0] for e in expected], rtol=1e-6)
    assert list(np.array(visited)) == [e[1] for e in expected]


def test_stack_capacity_bounds_a_depth_first_walk():
    assert stack_capacity(0, 3) == 1
    assert stack_capacity(4, 3) == 9
    assert stack_capacity(9, 1) == 1


def _render_both(loaded, whitted):
    """The image and counts of the depth-first tracer, then of the wavefront
    tracer (which ``capture_rays`` selects)."""
    results = []
    for capture in (False, True):
        whitted.capture_rays = capture
        image = np.array(mi.render(loaded, integrator=whitted))
        assert_finite(image)
        results.append((image, dict(whitted.last_stats)))
    return results


COUNTS = ("camera", "reflection", "refraction", "passthrough", "shadow", "shadow_march", "refined",
          "generations", "aa_samples")


@pytest.mark.parametrize("settings", [
    dict(max_depth=3), dict(max_depth=4, hide_emitters=True), dict(max_depth=10),
    dict(max_depth=8, aa="adaptive", aa_threshold=0.05, emitter_samples=4),
    dict(max_depth=6, shadows="tinted", ambient=rgb(0.1, 0.1, 0.1)),
], ids=["depth 3", "depth 4 hidden emitters", "depth 10", "adaptive", "tinted shadows"])
def test_stack_and_wavefront_tracers_agree(settings):
    """Same trees, summed in another order: float rounding apart, the same
    image, and exactly the same rays."""
    (stack, stack_counts), (wave, wave_counts) = _render_both(
        mi.load_dict(glass_scene(32)), mi.load_dict(integrator(**settings)))
    np.testing.assert_allclose(stack, wave, rtol=1e-5, atol=1e-6)
    assert {k: stack_counts[k] for k in COUNTS} == {k: wave_counts[k] for k in COUNTS}


def test_tracers_agree_on_the_report_scene():
    """Cylinder refinement, tinted shadows, textures, three delta components."""
    loaded = mi.load_file(str(REPORT_SCENE), res="64", aa_max_depth="3")
    (stack, stack_counts), (wave, wave_counts) = _render_both(loaded, loaded.integrator())
    np.testing.assert_allclose(stack, wave, rtol=1e-5, atol=1e-6)
    assert {k: stack_counts[k] for k in COUNTS} == {k: wave_counts[k] for k in COUNTS}
    assert stack_counts["refined"] > 0


def test_each_tracer_where_it_belongs():
    whitted = mi.load_dict(integrator(max_depth=10))
    loaded = mi.load_dict(glass_scene(8))
    assert isinstance(whitted.make_tracer(loaded), DepthFirstTracer)
    assert isinstance(whitted.make_tracer(loaded, wavefront=True), WavefrontTracer)
    # Unbounded depth with two children per glass hit: no stack is enough.
    unbounded = mi.load_dict(integrator(max_depth=-1))
    assert stack_capacity(255, 2) > MAX_STACK
    assert isinstance(unbounded.make_tracer(loaded), WavefrontTracer)


def test_every_anti_aliasing_level_replays_one_recording():
    """The first render records the stack kernel once and replays it for
    each adaptive level after the first (an input that is a literal in one
    launch and memory in the next makes Dr.Jit record again), and so do
    later renders (``mi.render`` seeds the sensor's sampler after each
    render, which the kernels take as an input with the sensor)."""
    loaded = mi.load_file(str(REPORT_SCENE), res="96", aa_max_depth="4")
    for _ in range(3):
        mi.render(loaded)
        assert loaded.integrator().last_stats["aa_levels"] == 4
        assert loaded.integrator()._state.tracer._camera_kernel.frozen.n_recordings == 1


def _change_lights_and_colours(loaded):
    params = mi.traverse(loaded)
    for key in params.keys():
        if key.endswith("intensity.value"):
            params[key] = params[key] * 0.5
        elif key.endswith("bsdf.reflectance.value"):
            params[key] = mi.Color3f(0.1, 0.7, 0.2)
    params.update()


def test_a_reused_tracer_sees_parameter_updates():
    """The second render with one integrator replays the first render's
    kernels; lights and colours changed through ``mi.traverse`` in between
    must show exactly as in a fresh render of a fresh copy."""
    path = str(ROOT / "scenes" / "cases" / "cylinder.xml")
    loaded = mi.load_file(path, res="32")
    before = np.array(mi.render(loaded))
    tracer = loaded.integrator()._state.tracer
    _change_lights_and_colours(loaded)
    reused = np.array(mi.render(loaded))
    assert loaded.integrator()._state.tracer is tracer
    copy = mi.load_file(path, res="32")
    _change_lights_and_colours(copy)
    fresh = np.array(mi.render(copy))
    assert not np.allclose(reused, before)
    np.testing.assert_array_equal(reused, fresh)


def test_tracers_agree_through_pass_through_surfaces():
    """A checkered mask, a null sphere and glass: straight-through children
    as well as reflected and refracted ones."""
    opacity = {"type": "checkerboard", "to_uv": mi.ScalarTransform4f().scale([8, 8, 1])}
    masked = sphere((0, 0, 0), 0.8, {"type": "mask", "opacity": opacity,
                                     "bsdf": {"type": "diffuse"}})
    glass = sphere((0.5, 0.3, 1.2), 0.3, {"type": "dielectric"})
    null = sphere((-0.7, 0.2, 1.0), 0.3, {"type": "null"})
    loaded = mi.load_dict(scene(floor(), wall(), masked, glass, null, point_light((1, 3, 3)),
                                sensor=camera(size=32)))
    (stack, stack_counts), (wave, wave_counts) = _render_both(
        loaded, mi.load_dict(integrator(max_depth=8, aa="grid", aa_samples=2)))
    np.testing.assert_allclose(stack, wave, rtol=1e-5, atol=1e-6)
    assert {k: stack_counts[k] for k in COUNTS} == {k: wave_counts[k] for k in COUNTS}
    assert stack_counts["passthrough"] > 0


def test_a_reused_tracer_follows_the_sensor():
    """Camera rays are made inside the frozen kernel: alternating between
    two sensors (other pose, field of view and film size) must give each
    sensor's own image, bit for bit as a fresh integrator renders it."""
    near = camera(size=24, fov=40)
    far = camera(origin=(1.5, 1.0, 4.0), size=16, fov=25)
    loaded = mi.load_dict(scene(floor(), wall(), sphere((0, 0, 0), 0.6, {"type": "dielectric"}),
                                point_light((1, 3, 3)), sensor=near, second_sensor=far))
    settings = integrator(max_depth=6, aa="grid", aa_samples=2)
    reused = mi.load_dict(settings)
    images = [np.array(mi.render(loaded, sensor=index, integrator=reused))
              for index in (0, 1, 0, 1)]
    for index, image in zip((0, 1, 0, 1), images):
        assert_finite(image)
        fresh = np.array(mi.render(loaded, sensor=index, integrator=mi.load_dict(settings)))
        np.testing.assert_array_equal(image, fresh)
    assert images[0].shape != images[1].shape


def _sensor(kind, size=24):
    """A perspective, thin-lens or orthographic view of the glass scene."""
    view = mi.ScalarTransform4f().look_at(origin=[0, 1, 5], target=[0, 0, 0], up=[0, 1, 0])
    film = {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"}}
    if kind == "orthographic":
        return {"type": "orthographic", "to_world": view.scale([1.5, 1.5, 1]), "film": film}
    lens = {"aperture_radius": 0.2, "focus_distance": 5.0} if kind == "thinlens" else {}
    return {"type": kind, "fov": 40, "to_world": view, "film": film, **lens}


def _render_with(kind, renders=3):
    description = glass_scene()
    description["sensor"] = _sensor(kind)
    loaded, whitted = mi.load_dict(description), mi.load_dict(integrator(max_depth=6))
    for _ in range(renders):
        image = np.array(mi.render(loaded, integrator=whitted))
        assert_finite(image)
    return image, whitted._state.tracer


@pytest.mark.parametrize("kind", ["thinlens", "orthographic"])
def test_a_sensor_that_cannot_be_frozen_still_replays_frozen_kernels(kind):
    """Mitsuba 3.9.1 keeps the thin-lens and orthographic cameras' JIT
    members from ``dr.freeze``: their camera rays are made outside the
    stack kernel, whose frozen recording of rays from memory then replays
    render after render instead of being recorded anew each time."""
    _, tracer = _render_with(kind)
    kernels = (tracer._camera_kernel, tracer._kernel)
    replayed = [kernel for kernel in kernels if kernel.enabled and kernel.frozen.n_recordings]
    assert replayed and all(kernel.frozen.n_recordings <= 2 for kernel in replayed)


def test_a_thin_lens_renders_as_the_pinhole_at_its_aperture_centre():
    """Camera rays leave from the aperture's centre (deterministic), so a
    thin lens gives the perspective camera's image, made by the other path."""
    pinhole, _ = _render_with("perspective", renders=1)
    lens, _ = _render_with("thinlens", renders=1)
    np.testing.assert_allclose(lens, pinhole, rtol=1e-5, atol=1e-6)


def test_holding_the_next_node_walks_in_the_same_order():
    """Keeping the next node in registers and popping only where a node has
    no child visits the nodes of a plain depth-first walk, in its order
    (so the tracer's sums keep their order, and their bits)."""
    total, order = lane_walk_holding(mi.Float(ROOTS))
    np.testing.assert_allclose(np.array(total), [python_walk(root)[0] for root in ROOTS],
                               rtol=1e-6)
    assert list(np.array(order)) == [python_order(root) for root in ROOTS]
