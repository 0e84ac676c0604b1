"""Derivatives of whitted images (``render_forward``, ``render_backward``).

Oracles: central finite differences of the image sum accumulated in float64
(a step per parameter), the other AD mode, and Mitsuba's ``prb`` in
expectation on scenes where Whitted and path tracing agree. The scenes
put each parameter behind mirrors and glass, with several lights, and keep
its change from moving any silhouette or shadow edge, which is not
differentiated.
"""

import functools

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from conftest import SRGB_TO_XYZ, limit_whitted, read_only
from mitsuba_whitted.compare import equivalence_test
from mitsuba_whitted.compare.gradient_equivalence import (gradient_values,
                                                          prb_gradient_batches, whitted_gradient)
from mitsuba_whitted.errors import ParameterError, VariantError
from mitsuba_whitted.integrators import gradients
from mitsuba_whitted.jit import device_array

from validation.scenes import (camera, diffuse, floor, integrator, point_light, rgb, scene, sphere,
                               wall)

#: Relative tolerance against finite differences: float32 renders differ
#: in the last bits between the two steps, about 1e-4 of the gradients
#: measured here.
RTOL = 2e-3


def texture(size=8, seed=1):
    """A small float bitmap (its data differentiable) of random colours."""
    values = np.random.default_rng(seed).uniform(0.1, 0.9, (size, size, 3))
    return {"type": "bitmap", "bitmap": mi.Bitmap(values.astype(np.float32)),
            "format": "variant", "raw": True}


def phong(diffuse_reflectance=None, exponent=30.0):
    return {"type": "phong", "exponent": exponent,
            "diffuse_reflectance": diffuse_reflectance or rgb(0.6, 0.4, 0.2),
            "specular_reflectance": rgb(0.3, 0.3, 0.3)}


def glass(transmittance=(0.9, 0.8, 0.7)):
    return {"type": "dielectric", "int_ior": 1.5, "specular_transmittance": rgb(*transmittance)}


def mirror():
    return {"type": "conductor", "material": "none", "specular_reflectance": rgb(0.8, 0.85, 0.9)}


def gallery(size=20, aa="none", shadows="tinted", max_depth=6, **objects):
    """A textured Phong ball seen directly, in a mirror and through a glass
    ball, a textured floor under tinted shadows, two point lights."""
    content = {
        "ball": sphere((0.7, 0.1, 0.2), 0.55, phong({"type": "sphere_map", "texture": texture()})),
        "lens": sphere((-0.55, -0.1, 0.9), 0.45, glass()),
        "mirror": wall(z=-1.6, size=3, bsdf=mirror()),
        "ground": floor(y=-0.7, size=3, bsdf=diffuse(0.5, 0.5, 0.5)),
        "key": point_light((2, 3, 4), 25.0),
        "fill": point_light((-3, 2, 3), 12.0),
    }
    content.update(objects)
    return scene(sensor=camera(origin=(0, 0.6, 5), size=size),
                 whitted=integrator(aa=aa, shadows=shadows, max_depth=max_depth,
                                    ambient=rgb(0.05, 0.05, 0.05)), **content)


def open_scene(size=20, **objects):
    """Phong balls, a mirror behind them and lights in front: no object
    shadows another where it can be seen, so moving a light moves no edge."""
    content = {
        "left": sphere((-0.75, 0, 0), 0.6, phong()),
        "right": sphere((0.75, 0, 0), 0.6, phong(rgb(0.2, 0.5, 0.7), 12.0)),
        "mirror": wall(z=-1.5, size=3, bsdf=mirror()),
        "key": point_light((0.5, 2.5, 4), 25.0),
        "fill": point_light((-2, -1, 4), 10.0),
    }
    content.update(objects)
    return scene(sensor=camera(origin=(0, 0, 5), size=size),
                 whitted=integrator(max_depth=5), **content)


def image_sum(description) -> float:
    image = mi.render(mi.load_dict(description))
    return float(np.asarray(image, dtype=np.float64)[..., :3].sum())


def _replaced(value, component: int, delta: float):
    """``value`` (an array, tensor or transform) with one entry moved."""
    if isinstance(value, mi.AffineTransform4f):
        matrix = np.array(value.matrix, dtype=np.float64)[..., 0]
        matrix.flat[component] += delta
        return mi.AffineTransform4f(mi.ScalarTransform4f(matrix))
    values = np.array(value, dtype=np.float64)
    values.flat[component] += delta
    flat = device_array(mi.Float, values.ravel())
    if isinstance(value, mi.TensorXf):
        return mi.TensorXf(flat, values.shape)
    if dr.depth_v(value) > 1:
        return type(value)(*[dr.gather(mi.Float, flat, mi.UInt32(i)) for i in range(3)])
    return type(value)(flat)


def finite_difference(description, key, component, step) -> float:
    sums = []
    for sign in (1, -1):
        loaded = mi.load_dict(description)
        params = mi.traverse(loaded)
        params[key] = _replaced(params[key], component, sign * step)
        params.update()
        image = mi.render(loaded)
        sums.append(float(np.asarray(image, dtype=np.float64)[..., :3].sum()))
    return (sums[0] - sums[1]) / (2 * step)


def load(description, replay="tree"):
    """The scene, its integrator differentiating with the ``replay`` kind:
    ``"graph"`` is the oracle of the default ``"tree"``."""
    loaded = mi.load_dict(description)
    loaded.integrator().gradient_replay = replay
    return loaded


def backward_gradient(description, keys, replay="tree"):
    """The gradient of the image sum for each of ``keys``, flat."""
    loaded = load(description, replay)
    params = mi.traverse(loaded)
    for key in keys:
        dr.enable_grad(params[key])
    params.update()
    image = mi.render(loaded, params)
    dr.backward(dr.sum(image[..., :3], axis=None))
    return [_flat(dr.grad(params[key])) for key in keys]


def _flat(value) -> np.ndarray:
    """The entries of an array, a tensor or a transform's matrix, in float64."""
    if isinstance(value, mi.AffineTransform4f):
        value = np.array(value.matrix)[..., 0]
    return np.array(value, dtype=np.float64).ravel()


def forward_derivative(description, key, component, replay="tree") -> float:
    """The derivative of the image sum along one entry of ``key``."""
    loaded = load(description, replay)
    params = mi.traverse(loaded)
    dr.enable_grad(params[key])
    params.update()
    dr.set_grad(params[key], _replaced(dr.zeros(type(params[key]), dr.shape(params[key]))
                                       if not isinstance(params[key], mi.AffineTransform4f)
                                       else params[key], component, 1.0))
    image = mi.render(loaded, params)
    dr.forward_to(image)
    return float(np.asarray(dr.grad(image), dtype=np.float64)[..., :3].sum())


def check_against_differences(description, key, component, step, rtol=RTOL):
    """The backward gradient of ``component`` of ``key`` (None: the entry
    whose gradient is largest) against its finite difference, and the whole
    gradient against the graph replay's."""
    (gradient,) = backward_gradient(description, [key])
    if component is None:
        component = int(np.argmax(np.abs(gradient)))
    expected = finite_difference(description, key, component, step)
    assert abs(expected) > 1e-3, "the parameter must change the image"
    assert gradient[component] == pytest.approx(expected, rel=rtol)
    check_against_graph(gradient, backward_gradient(description, [key], "graph")[0])


#: The tree and graph replays sum the same terms in different orders: they
#: agree to float32 rounding, relative to the gradient's largest entry.
REPLAY_RTOL = 1e-5


def check_against_graph(gradient, oracle):
    scale = np.abs(oracle).max()
    assert scale > 0, "the oracle's gradient must not vanish"
    np.testing.assert_allclose(gradient, oracle, rtol=0, atol=REPLAY_RTOL * scale)


# ------------------------------------------------ each kind of parameter

CASES = {
    # key, component (None: the entry whose gradient is largest), step, scene
    "phong diffuse texel": ("ball.bsdf.diffuse_reflectance.texture.data", None, 1e-2, gallery),
    "phong specular reflectance": ("ball.bsdf.specular_reflectance.value", 1, 1e-3, gallery),
    "phong exponent": ("right.bsdf.exponent", 0, 1e-2, open_scene),
    "conductor reflectance": ("mirror.bsdf.specular_reflectance.value", 0, 1e-3, gallery),
    "dielectric transmittance": ("lens.bsdf.specular_transmittance.value", 2, 1e-3, gallery),
    "diffuse reflectance": ("ground.bsdf.reflectance.value", 0, 1e-3, gallery),
    "point light intensity": ("fill.intensity.value", 0, 1e-2, gallery),
    "point light position": ("key.position", 1, 1e-2, open_scene),
    "ambient": ("integrator.ambient", 1, 1e-3, gallery),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_gradient_matches_finite_differences(case):
    key, component, step, make = CASES[case]
    check_against_differences(make(), key, component, step)


def test_texel_gradient_comes_through_mirror_and_glass():
    """A texel of the ball seen only in the mirror and through the glass
    still gets its gradient from both paths."""
    hidden = gallery(ball=sphere((0.4, 0.1, -0.9), 0.5,
                                 phong({"type": "sphere_map", "texture": texture()})),
                     lens=sphere((0.25, 0.1, 1.6), 0.5, glass()))
    hidden["sensor"] = camera(origin=(0.3, 0.6, 5), target=(-0.5, 0, 0), size=20)
    check_against_differences(hidden, "ball.bsdf.diffuse_reflectance.texture.data", None, 1e-2)


def test_textures_and_blend_match_finite_differences():
    described = gallery(
        ball=sphere((0.7, 0.1, 0.2), 0.55, {
            "type": "blendbsdf", "weight": 0.4, "bsdf_0": phong({"type": "tartan",
                                                                  "frequency": 5.0}),
            "bsdf_1": mirror()}),
        ground=floor(y=-0.7, size=3, bsdf={"type": "diffuse", "reflectance": {
            "type": "planar_map", "x_min": -2.0, "x_max": 2.5, "z_min": -3.0, "z_max": 2.0,
            "texture": texture(seed=2)}}),
        globe=sphere((-0.1, 0.9, -0.6), 0.35, phong({
            "type": "sphere_map", "center": [-0.1, 0.9, -0.6], "texture": texture(seed=3),
            "to_world": mi.ScalarTransform4f().rotate([0, 1, 0], 20)})))
    for key, component, step in (("ball.bsdf.weight.value", 0, 1e-3),
                                 ("ball.bsdf.bsdf_0.diffuse_reflectance.color", 0, 1e-3),
                                 ("ground.bsdf.reflectance.x_min", 0, 1e-3),
                                 ("globe.bsdf.diffuse_reflectance.center", 0, 1e-3),
                                 ("globe.bsdf.diffuse_reflectance.to_world", 1, 1e-3)):
        check_against_differences(described, key, component, step)


def test_lights_match_finite_differences():
    """Spot light (intensity, placement), environment and area radiance,
    and a thin dielectric's index (its Fresnel weights, on camera and
    shadow rays)."""
    spot = {"type": "spot", "intensity": rgb(40, 40, 40), "cutoff_angle": 60.0,
            "beam_width": 50.0, "to_world": mi.ScalarTransform4f().look_at(
                origin=[0.2, 0.5, 4], target=[0, 0, 0], up=[0, 1, 0])}
    lamp = {"type": "sphere", "center": [1.5, 1.5, 2.5], "radius": 0.2,
            "emitter": {"type": "area", "radiance": rgb(8, 8, 8)}}
    pane = wall(z=1.2, size=0.6, bsdf={"type": "thindielectric", "int_ior": 1.6})
    described = open_scene(spot=spot, lamp=lamp, pane=pane,
                           sky={"type": "constant", "radiance": rgb(0.2, 0.3, 0.4)})
    described["integrator"]["emitter_samples"] = 4
    described["integrator"]["shadows"] = "physical"
    # Radiances enter linearly: a large step has no truncation error.
    for key, component, step in (("spot.intensity.value", 0, 1.0),
                                 ("spot.to_world", 3, 1e-2),
                                 ("sky.radiance.value", 2, 0.1),
                                 ("lamp.emitter.radiance.value", 0, 1.0),
                                 ("pane.bsdf.eta", 0, 1e-3)):
        check_against_differences(described, key, component, step)


@pytest.mark.parametrize("aa", ["none", "grid", "adaptive", "contrast"])
@pytest.mark.parametrize("shadows", ["physical", "tinted"])
def test_every_antialiasing_and_shadow_mode(aa, shadows):
    """The camera samples the anti-aliasing placed (refined where the image
    asked) are differentiated; a glass ball's transmittance reaches the
    image through refraction and, tinted, through its shadow."""
    described = gallery(size=12, aa=aa, shadows=shadows)
    described["integrator"].update(aa_samples=3, aa_threshold=0.05, aa_max_depth=2)
    check_against_differences(described, "lens.bsdf.specular_transmittance.value", 1, 1e-3)


@pytest.mark.parametrize("aa", ["grid", "adaptive"])
def test_a_camera_with_an_aperture(aa):
    """A thin lens whose samples spread over its aperture (depth of field):
    the camera samples keep their lens points through the derivative, in
    both modes."""
    described = gallery(size=12, aa=aa)
    described["integrator"].update(aa_samples=2, aa_threshold=0.05, aa_max_depth=2)
    described["sensor"].update(type="thinlens", aperture_radius=0.15, focus_distance=4.0)
    key = "lens.bsdf.specular_transmittance.value"
    check_against_differences(described, key, 1, 1e-3)
    (gradient,) = backward_gradient(described, [key])
    assert forward_derivative(described, key, 1) == pytest.approx(gradient[1], rel=1e-5)


def test_both_tracers():
    """An unbounded depth traces with the wavefront tracer, a small one
    with the depth-first one; the gradient is the image's in both."""
    for depth in (4, -1):
        described = gallery(size=12, max_depth=depth,
                            cylinder={"type": "capped_cylinder", "center": [1.3, -0.7, -0.5],
                                      "radius": 0.25, "height": 0.8,
                                      "bsdf": phong(rgb(0.7, 0.6, 0.1))})
        described["integrator"]["min_throughput"] = 1e-3
        check_against_differences(described, "cylinder.bsdf.diffuse_reflectance.value", 0,
                                  1e-3)


# ----------------------------------------------------- the two AD modes


def test_forward_mode_agrees_with_backward_mode():
    described = gallery(size=16)
    keys = ["ball.bsdf.diffuse_reflectance.texture.data", "lens.bsdf.specular_transmittance.value",
            "key.intensity.value"]
    backward = backward_gradient(described, keys)
    for key, gradient in zip(keys, backward):
        component = int(np.argmax(np.abs(gradient)))
        forward = forward_derivative(described, key, component)
        assert forward == pytest.approx(gradient[component], rel=1e-5)
        assert forward == pytest.approx(forward_derivative(described, key, component, "graph"),
                                        rel=REPLAY_RTOL)


def test_a_zero_channel_of_a_pass_through_weight_keeps_its_derivative():
    """A glass pane that passes no green, seen through and casting tinted
    shadows: green's derivative of its transmittance is the light a little
    green would let through, over the pane's refracted rays and its
    shadows, which a derivative taken relative to the weight (zero) would
    lose. The shadow ray crosses the pane once: the product of what its
    crossings pass has one zero."""
    pane = wall(z=1.5, size=0.7, bsdf=glass((0.9, 0.0, 0.6)))
    described = open_scene(pane=pane)
    described["integrator"]["shadows"] = "tinted"
    check_against_differences(described, "pane.bsdf.specular_transmittance.value", 1, 1e-3)


def test_a_replay_dr_jit_cannot_record_falls_back_to_the_graph_replay():
    """A spot light that moves, whose shadow rays cross a thin dielectric,
    is differentiated by the graph replay (Dr.Jit 1.5 refuses to record
    that derivative inside the tree replay's loop): the gradient is the
    graph replay's, bit for bit, in two derivatives running."""
    spot = {"type": "spot", "intensity": rgb(40, 40, 40), "cutoff_angle": 60.0,
            "to_world": mi.ScalarTransform4f().look_at(origin=[0.2, 0.5, 4], target=[0, 0, 0],
                                                       up=[0, 1, 0])}
    pane = wall(z=1.2, size=0.6, bsdf={"type": "thindielectric", "int_ior": 1.6})
    described = open_scene(spot=spot, pane=pane)
    graph = backward_gradient(described, ["spot.to_world"], "graph")[0]
    loaded = load(described)
    params = mi.traverse(loaded)
    for _ in range(2):
        dr.enable_grad(params["spot.to_world"])
        params.update()
        dr.backward(dr.sum(mi.render(loaded, params)[..., :3], axis=None))
        assert np.array_equal(_flat(dr.grad(params["spot.to_world"])), graph)
        dr.disable_grad(params["spot.to_world"])
    assert loaded.integrator()._state.replay_refused is not None


def forward_image(description, key, component=None) -> np.ndarray:
    """The tangent image along one entry of ``key``, or along all of them
    at once (``component`` None)."""
    loaded = mi.load_dict(description)
    params = mi.traverse(loaded)
    dr.enable_grad(params[key])
    params.update()
    zero = dr.zeros(type(params[key]), dr.shape(params[key]))
    dr.set_grad(params[key], zero + 1 if component is None else _replaced(zero, component, 1.0))
    image = mi.render(loaded, params)
    dr.forward_to(image)
    return np.array(dr.grad(image))


def test_forward_mode_holds_no_more_than_one_band_of_launches(monkeypatch):
    """render_forward, like render, lets a band's camera samples go before
    the next band: the shader that records them holds no more launches
    than the band being rendered has made, and the tangent image is that
    of a render in one band, bit for bit."""
    described = gallery(size=16, aa="grid")
    key, component = "lens.bsdf.specular_transmittance.value", 1
    whole = forward_image(described, key, component)
    held = []

    class CountingShader(gradients.RecordingShader):
        def __call__(self, positions, *args):
            result = super().__call__(positions, *args)
            band = int(dr.min(positions.y)[0]) // 4
            held.append((band, len(self.launches)))
            return result

    monkeypatch.setattr(gradients, "RecordingShader", CountingShader)
    # Four rows of 16 pixels per band, one sample each (aa 'grid' reduces
    # its samples launch by launch): four bands.
    limit_whitted(monkeypatch, band_samples=4 * 16)
    banded = forward_image(described, key, component)
    bands = [band for band, _ in held]
    assert len(set(bands)) == 4
    for index, (band, launches) in enumerate(held):
        assert launches <= bands[:index + 1].count(band)
    assert np.abs(whole).max() > 0
    np.testing.assert_array_equal(banded, whole)


#: Pixels per side of the gallery rendered in bands.
BANDED_SIZE = 16


@functools.lru_cache(maxsize=None)
def tangent_image_in_one_band(key) -> np.ndarray:
    """``forward_image`` of the banded tests' gallery along all of ``key``,
    at the default band size (one band): the reference of every band count,
    so rendered once per key."""
    return read_only(forward_image(gallery(size=BANDED_SIZE), key))


@pytest.mark.parametrize("rows", [2, 4], ids=["8-bands", "4-bands"])
@pytest.mark.parametrize("key", ["ball.bsdf.diffuse_reflectance.texture.data",
                                 "lens.bsdf.specular_transmittance.value", "key.intensity.value"])
def test_forward_mode_in_bands_is_forward_mode_in_one(monkeypatch, key, rows):
    """Every tangent of the parameter reaches each band's pixels once: the
    tangent image is that of a render in one band, bit for bit, for a
    texture seen directly, through glass and in a mirror."""
    whole = tangent_image_in_one_band(key)   # before the band size changes
    limit_whitted(monkeypatch, band_samples=rows * BANDED_SIZE)
    banded = forward_image(gallery(size=BANDED_SIZE), key)
    assert np.abs(whole).max() > 0
    np.testing.assert_array_equal(banded, whole)


@pytest.mark.parametrize("pixel_format", ["luminance", "xyza"])
def test_a_film_of_another_pixel_format_differentiates_its_own_image(pixel_format):
    """Luminance and XYZ are linear in RGB (the sRGB-to-XYZ matrix): the
    tangent image is the RGB one through the matrix, alpha has none, and
    the gradient of the developed channels' sum is that of the RGB image
    weighed by the matrix's column sums."""
    key = "lens.bsdf.specular_transmittance.value"
    matrix = SRGB_TO_XYZ[1:2] if pixel_format == "luminance" else SRGB_TO_XYZ
    described = gallery(size=12)
    other = gallery(size=12)
    other["sensor"]["film"]["pixel_format"] = pixel_format

    tangent = forward_image(other, key)
    expected = forward_image(described, key).astype(np.float64) @ matrix.T
    np.testing.assert_allclose(tangent[..., :len(matrix)], expected, rtol=1e-5, atol=1e-7)
    assert not tangent[..., len(matrix):].any()

    def gradient(description, weights):
        loaded = mi.load_dict(description)
        params = mi.traverse(loaded)
        dr.enable_grad(params[key])
        params.update()
        image = mi.render(loaded, params)
        dr.backward(sum(float(w) * dr.sum(image[..., c], axis=None)
                        for c, w in enumerate(weights)))
        return _flat(dr.grad(params[key]))

    np.testing.assert_allclose(gradient(other, np.ones(len(matrix))),
                               gradient(described, matrix.sum(axis=0)), rtol=1e-5)


DETERMINISM_KEYS = ["ball.bsdf.diffuse_reflectance.texture.data",
                    "ball.bsdf.specular_reflectance.value", "key.intensity.value"]


def gradient_digests(runs: int) -> list:
    """sha256 of the gradients of a 128 x 128 gallery (2 x 2 grid), ``runs``
    times over."""
    import hashlib

    loaded = mi.load_dict(gallery(size=128, aa="grid"))
    params = mi.traverse(loaded)
    digests = []
    for _ in range(runs):
        for key in DETERMINISM_KEYS:
            dr.enable_grad(params[key])
            params.set_dirty(key)
        params.update()
        image = mi.render(loaded, params)
        dr.backward(dr.sum(image, axis=None))
        digests.append(hashlib.sha256(b"".join(np.array(dr.grad(params[key])).tobytes()
                                                for key in DETERMINISM_KEYS)).hexdigest())
        for key in DETERMINISM_KEYS:
            dr.clear_grad(params[key])
    return digests


def test_gradients_are_bit_identical_from_run_to_run():
    """Texels and constants read by many lanes get their gradients by
    scatter-adds, whose order threads would change: the same bits in
    three runs, and in another process."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    digests = gradient_digests(3)
    assert digests[0] == digests[1] == digests[2]
    tests = Path(__file__).resolve().parent
    # The test module, and the validation package it imports, as pytest finds them.
    path = os.pathsep.join([str(tests), str(tests.parent), os.environ.get("PYTHONPATH", "")])
    child = subprocess.run(
        [sys.executable, "-c", "import mitsuba_whitted; mitsuba_whitted.set_variant('llvm_ad_rgb');"
         "from test_gradients import gradient_digests; print(gradient_digests(1)[0])"],
        capture_output=True, text=True, timeout=300, cwd=tests,
        env=dict(os.environ, PYTHONPATH=path))
    assert child.returncode == 0, child.stderr
    assert child.stdout.split()[-1] == digests[0]


def test_gradients_reach_parameters_computed_from_others():
    """A parameter set from other variables passes its gradient on."""
    loaded = mi.load_dict(gallery(size=12))
    params = mi.traverse(loaded)
    scale = mi.Float(2.0)
    dr.enable_grad(scale)
    key = "fill.intensity.value"
    base = mi.Color3f(params[key])
    params[key] = base * scale
    params.update()
    image = mi.render(loaded, params)
    dr.backward(dr.sum(image[..., :3], axis=None))
    (direct,) = backward_gradient(gallery(size=12), [key])
    assert float(dr.grad(scale)[0]) == pytest.approx(float(np.dot(direct, np.ravel(base))),
                                                       rel=1e-5)


# ----------------------------------------------------------- against prb


PRB_DEPTH = 8


@pytest.mark.parametrize("name", ["diffuse ball", "phong ball, two lights", "mirror"])
def test_gradient_equals_prb_in_expectation(name):
    """The same test as the images' equivalence: Welch's t per parameter
    entry between whitted's exact derivative and batches of prb's."""
    lights = [point_light((2, 3, 4)), point_light((-3, 1, 4), 8.0)]
    ball = {"diffuse ball": diffuse(0.8, 0.5, 0.2),
            "phong ball, two lights": phong(rgb(0.6, 0.3, 0.1), 20.0),
            "mirror": diffuse(0.2, 0.7, 0.3)}[name]
    objects = {"ball": sphere((0.3, 0, 0.3), 0.7, ball), "key": lights[0]}
    if name != "diffuse ball":
        objects["fill"] = lights[1]
    if name == "mirror":
        objects["mirror"] = wall(z=-1.5, size=3, bsdf={"type": "conductor", "material": "Au"})
    loaded = mi.load_dict(scene(sensor=camera(origin=(-1.0, 0.5, 4), size=16),
                                whitted=integrator(max_depth=PRB_DEPTH, min_throughput=0.0),
                                **objects))
    params = mi.traverse(loaded)
    keys = [next(k for k in params.keys() if k.startswith("ball.bsdf.") and "reflectance" in k),
            "key.intensity.value"]
    for key in keys:
        dr.enable_grad(params[key])
    params.update()
    exact = whitted_gradient(loaded, params, keys)
    estimates = prb_gradient_batches(loaded, params, keys, batches=24, spp=16,
                                     max_depth=PRB_DEPTH)
    result = equivalence_test(exact[None], estimates)
    assert result.passed, result.summary()
    assert np.abs(exact).min() > 0.05


def test_prb_comparison_notices_a_wrong_gradient():
    """The test rejects a gradient that is off by 2%."""
    loaded = mi.load_dict(scene(sphere((0, 0, 0), 1, diffuse(0.8, 0.5, 0.2)),
                                point_light((2, 3, 4)), sensor=camera(size=16),
                                whitted=integrator(max_depth=PRB_DEPTH)))
    params = mi.traverse(loaded)
    keys = ["object_0.bsdf.reflectance.value"]
    dr.enable_grad(params[keys[0]])
    params.update()
    exact = whitted_gradient(loaded, params, keys)
    estimates = prb_gradient_batches(loaded, params, keys, batches=24, spp=64,
                                     max_depth=PRB_DEPTH)
    assert equivalence_test(exact[None], estimates).passed
    assert not equivalence_test(1.02 * exact[None], estimates).passed


# --------------------------------------------------------------- wrong use


@pytest.mark.parametrize("key", ["box.vertex_positions", "ball.to_world", "sensor.to_world"])
def test_geometry_and_camera_are_refused_in_one_sentence(key):
    loaded = mi.load_dict(scene(point_light((2, 3, 4)), sensor=camera(size=8),
                                whitted=integrator(),
                                box={"type": "cube", "to_world": mi.ScalarTransform4f().scale(0.3),
                                     "bsdf": diffuse(0.5, 0.5, 0.5)},
                                ball=sphere((1, 0, 0), 0.3, diffuse(0.5, 0.5, 0.5))))
    params = mi.traverse(loaded)
    dr.enable_grad(params[key])
    params.update()
    for mode in ("backward", "forward"):
        image = mi.render(loaded, params)
        with pytest.raises(ParameterError) as error:
            if mode == "backward":
                dr.backward(image)
            else:
                dr.set_grad(params[key], dr.ones(type(params[key]), dr.shape(params[key]))
                            if not isinstance(params[key], mi.AffineTransform4f) else 1.0)
                dr.forward_to(image)
        message = str(error.value)
        assert message.startswith(f"whitted: parameter '{key}'") and "\n" not in message
        dr.clear_grad(params[key])


def test_a_variant_without_differentiation_is_refused():
    try:
        mi.set_variant("scalar_rgb")
        with pytest.raises(VariantError, match="^whitted: gradients need"):
            gradients.require_differentiable(0)
    finally:
        mi.set_variant("llvm_ad_rgb")


def test_adjoint_image_of_another_shape_is_refused():
    loaded = mi.load_dict(gallery(size=8))
    integrator_ = loaded.integrator()
    with pytest.raises(ParameterError, match="parameter 'grad_in' must have the shape"):
        integrator_.render_backward(loaded, mi.traverse(loaded), dr.ones(mi.TensorXf, (4, 4, 3)))


def test_image_is_unchanged_by_a_gradient():
    """A render after a derivative gives the same bits as before it."""
    loaded = mi.load_dict(gallery(size=16, aa="adaptive"))
    before = np.array(mi.render(loaded))
    params = mi.traverse(loaded)
    key = "ball.bsdf.diffuse_reflectance.texture.data"
    dr.enable_grad(params[key])
    params.update()
    dr.backward(mi.render(loaded, params))
    gradient_values(params, [key])
    after = np.array(mi.render(loaded))
    assert np.array_equal(before, after)


def test_a_tile_too_large_for_memory_is_refused_naming_the_parameter(monkeypatch):
    """The primal render fits; the graph replay's tile, traced again with
    AD, would not. (The tree replay's tile holds less than a render's
    launch.)"""
    from mitsuba_whitted.integrators import render_plan
    tile_bytes = gradients.TILE_FACTOR * (1 << 18) * gradients.TILE_SAMPLE_BYTES
    limit_whitted(monkeypatch, memory=lambda: render_plan.RESERVE + tile_bytes // 2)
    loaded = load(gallery(size=8), "graph")
    params = mi.traverse(loaded)
    dr.enable_grad(params["key.intensity.value"])
    params.update()
    image = mi.render(loaded, params)
    with pytest.raises(ParameterError, match="^whitted: parameter 'wavefront_size' makes this"):
        dr.backward(image)


def test_inverse_rendering_example_recovers_the_texture(tmp_path):
    """The README's example, small: a texture seen only in a mirror and
    through glass, recovered from grey with Adam on whitted's gradients."""
    from validation import inverse_texture

    problem = inverse_texture.Problem(inverse_texture.whitted_integrator(), resolution=48,
                                      texture_size=16)
    start = problem.texture_error()
    history = inverse_texture.optimise(problem, 40, 0.05, report=lambda line: None)
    assert history[-1]["texture_error"] < 0.3 * start
    assert history[-1]["loss"] < 0.01 * history[0]["loss"]
    inverse_texture.write_results(problem, history, "whitted", tmp_path)
    assert (tmp_path / "loss.png").stat().st_size > 0
    assert (tmp_path / "whitted_texture.png").stat().st_size > 0


def test_gradient_is_of_the_image_mi_render_returned():
    """Area lights are sampled by a pattern the render's seed turns:
    mi.render gives the gradient a hash of its seed, which whitted takes
    back, and a seed of that size renders too."""
    lamp = {"type": "sphere", "center": [1.5, 1.5, 2.5], "radius": 0.3,
            "emitter": {"type": "area", "radiance": rgb(8, 8, 8)}}
    described = open_scene(size=12, lamp=lamp)
    described["integrator"]["emitter_samples"] = 2
    loaded = mi.load_dict(described)
    params = mi.traverse(loaded)
    key = "right.bsdf.diffuse_reflectance.value"
    dr.enable_grad(params[key])
    params.update()
    gradients_by_seed = {}
    for seed in (3, 4):
        image = mi.render(loaded, params, seed=seed)
        dr.backward(dr.sum(image[..., :3], axis=None))
        gradients_by_seed[seed] = gradient_values(params, [key])
    # Linear in the reflectance: the image's own derivative is exact.
    for seed, gradient in gradients_by_seed.items():
        changed = mi.load_dict(described)
        changed_params = mi.traverse(changed)
        changed_params[key] = _replaced(changed_params[key], 0, 0.1)
        changed_params.update()
        difference = (np.asarray(mi.render(changed, seed=seed), dtype=np.float64)
                      - np.asarray(mi.render(loaded, seed=seed), dtype=np.float64))
        assert gradient[0, 0] == pytest.approx(difference[..., :3].sum() / 0.1, rel=1e-4)
    assert gradients_by_seed[3][0, 0] != gradients_by_seed[4][0, 0]
    large = mi.render(loaded, seed=int(mi.sample_tea_32(mi.UInt32(3), mi.UInt32(1))[0][0]))
    assert np.isfinite(np.asarray(large)).all()


# ------------------------------------------- the render's launches, kept


def kept_gradient(described, key, before_backward=None):
    """The gradient of ``key`` after ``mi.render``, with
    ``before_backward(loaded, params)`` run in between; and whether the
    render's kept launches were still there when the derivative began."""
    loaded = load(described)
    params = mi.traverse(loaded)
    dr.enable_grad(params[key])
    params.update()
    image = mi.render(loaded, params)
    kept = loaded.integrator()._state.kept is not None
    if before_backward is not None:
        before_backward(loaded, params)
    dr.backward(dr.sum(image[..., :3], axis=None))
    return _flat(dr.grad(params[key])), kept


ADAPTIVE = dict(size=16, aa="adaptive")
TRANSMITTANCE = "lens.bsdf.specular_transmittance.value"


def test_the_derivative_reads_the_render_s_launches_for_the_same_bits():
    """The derivative's anti-aliasing reads the radiance the render traced
    instead of tracing it again: the same gradient, bit for bit, as with
    the launches dropped."""
    def drop(loaded, params):
        loaded.integrator()._state.kept = None

    read, kept = kept_gradient(gallery(**ADAPTIVE), TRANSMITTANCE)
    traced, _ = kept_gradient(gallery(**ADAPTIVE), TRANSMITTANCE, drop)
    assert kept
    assert np.array_equal(read, traced)


def test_a_parameter_changed_after_the_render_is_not_read_from_its_launches():
    """A parameter updated between the render and its derivative (the
    glass's transmittance, which the anti-aliasing sees): the derivative
    traces, and equals that of a scene loaded with the new value."""
    from mitsuba_whitted.integrators.kept_launches import fingerprint
    new = (0.5, 0.6, 0.9)

    def update(loaded, params):
        kept, sensor = loaded.integrator()._state.kept, loaded.sensors()[0]
        assert kept.key == fingerprint(loaded, sensor, 0)
        params[TRANSMITTANCE] = mi.Color3f(*new)
        params.update()
        dr.enable_grad(params[TRANSMITTANCE])
        assert kept.key != fingerprint(loaded, sensor, 0)

    changed, _ = kept_gradient(gallery(**ADAPTIVE), TRANSMITTANCE, update)
    described = gallery(**ADAPTIVE)
    described["lens"]["bsdf"] = glass(new)
    expected, _ = kept_gradient(described, TRANSMITTANCE)
    assert np.array_equal(changed, expected)


def test_launches_that_do_not_match_make_the_derivative_trace_them():
    """Kept launches whose first samples differ from the derivative's (its
    keys altered): no kept launch is read, the derivative starts again,
    tracing, and gives the gradient of launches not kept, bit for bit."""
    read = []

    def alter(loaded, params):
        kept = loaded.integrator()._state.kept
        keys, outputs = kept.launches[0]
        kept.launches[0] = (keys + 1, outputs)
        reader = kept.reader

        def counting_reader():
            inner = reader()

            def counted(keys):
                outputs = inner(keys)
                read.append(dr.width(keys))
                return outputs
            return counted
        kept.reader = counting_reader

    def drop(loaded, params):
        loaded.integrator()._state.kept = None

    altered, _ = kept_gradient(gallery(**ADAPTIVE), TRANSMITTANCE, alter)
    traced, _ = kept_gradient(gallery(**ADAPTIVE), TRANSMITTANCE, drop)
    assert read == []
    assert np.array_equal(altered, traced)


def test_a_render_too_large_to_keep_keeps_nothing(monkeypatch):
    """Launches past KEPT_BYTES, or past an eighth of the memory available,
    are not kept: the derivative traces, with the same bits."""
    from mitsuba_whitted.integrators import kept_launches
    one_launch = 16 * 16 * kept_launches.SAMPLE_BYTES
    expected, kept = kept_gradient(gallery(**ADAPTIVE), TRANSMITTANCE)
    assert kept
    monkeypatch.setattr(kept_launches, "KEPT_BYTES", one_launch)
    gradient, kept = kept_gradient(gallery(**ADAPTIVE), TRANSMITTANCE)
    assert not kept and np.array_equal(gradient, expected)
    monkeypatch.undo()
    from mitsuba_whitted.system import available_memory
    monkeypatch.setattr(kept_launches, "MEMORY_SHARE", one_launch / available_memory())
    gradient, kept = kept_gradient(gallery(**ADAPTIVE), TRANSMITTANCE)
    assert not kept and np.array_equal(gradient, expected)


def test_a_derivative_leaves_the_render_s_statistics():
    """``last_stats`` is the render's after its derivative too, which reads
    the kept launches and traces no camera sample of its own."""
    loaded = load(gallery(**ADAPTIVE))
    params = mi.traverse(loaded)
    dr.enable_grad(params[TRANSMITTANCE])
    params.update()
    image = mi.render(loaded, params)
    rendered = dict(loaded.integrator().last_stats)
    dr.backward(dr.sum(image, axis=None))
    assert rendered["camera"] > 0 and rendered["aa_levels"] > 0
    assert loaded.integrator().last_stats == rendered
