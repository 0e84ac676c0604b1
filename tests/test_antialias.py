"""Adaptive anti-aliasing against an independent model of the report's rule.

Oracle: a plain-Python recursion over cells that applies the documented
rule (split a quadrant whose clamped colour differs from the mean of its
three siblings by more than the threshold) to an exact half-plane image.
"""

from fractions import Fraction

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from conftest import assert_finite
from mitsuba_whitted.integrators.antialias import AdaptiveSampler, render_grid
from scenes import camera, integrator, rgb, scene

WIDTH, HEIGHT = 6, 4
#: A vertical edge inside pixel column 2, a third of the way across:
#: 1/3 = 0.010101... in binary keeps crossing the middle half of the cells.
EDGE = 2 + 1 / 3


def edge_shader(positions, keys):
    """White left of the edge, black right of it."""
    white = mi.Float(positions.x < EDGE)
    return mi.Color3f(white), dr.ones(mi.Float, dr.width(positions))


def reference_cell(x0, y0, size, level, max_depth, threshold, per_level):
    """(value, samples) of a cell whose four quadrants are sampled."""
    quads = [(x0 + (0.25 + 0.5 * i) * size, y0 + (0.25 + 0.5 * j) * size)
             for j in range(2) for i in range(2)]
    per_level[level] = per_level.get(level, 0) + 4
    colors = [1.0 if x < Fraction(7, 3) else 0.0 for x, _ in quads]
    values = []
    for q, (x, y) in enumerate(quads):
        others = (sum(colors) - colors[q]) / 3
        if level < max_depth and abs(colors[q] - others) > threshold:
            corner = (x - size / 4, y - size / 4)
            values.append(reference_cell(*corner, size / 2, level + 1, max_depth,
                                         threshold, per_level))
        else:
            values.append(colors[q])
    return sum(values) / 4


def reference(max_depth, threshold):
    per_level = {}
    image = np.array([[reference_cell(Fraction(x), Fraction(y), Fraction(1), 0, max_depth,
                                      threshold, per_level)
                       for x in range(WIDTH)] for y in range(HEIGHT)], dtype=float)
    return image, [per_level[k] for k in sorted(per_level)]


@pytest.mark.parametrize("max_depth", [0, 1, 4, 7])
def test_adaptive_matches_reference_recursion(max_depth):
    sampler = AdaptiveSampler(0.25, max_depth, 1e9, warn=pytest.fail)
    radiance, alpha, count = sampler.render(WIDTH, HEIGHT, edge_shader)
    expected, per_level = reference(max_depth, 0.25)
    assert list(count.per_level) == per_level
    image = np.array(radiance.x).reshape(HEIGHT, WIDTH)
    np.testing.assert_allclose(image, expected, rtol=1e-6)
    np.testing.assert_array_equal(np.array(alpha), 1.0)


def test_extra_samples_only_in_edge_pixels():
    sampler = AdaptiveSampler(0.25, 5, 1e9, warn=pytest.fail)
    _, _, count = sampler.render(WIDTH, HEIGHT, edge_shader)
    samples = np.array(count.per_pixel).reshape(HEIGHT, WIDTH)
    assert (samples[:, 2] > 4).all()
    assert (np.delete(samples, 2, axis=1) == 4).all()
    assert samples.sum() == count.samples


def noise_shader(positions, keys):
    """A colour that differs at every sample: the worst case."""
    a, b = mi.sample_tea_32(mi.UInt32(positions.x * 4096), mi.UInt32(positions.y * 4096))
    return mi.Color3f(mi.Float(a & 1), mi.Float(b & 1), 0.5), dr.ones(mi.Float, dr.width(positions))


def test_threshold_zero_on_noise_stops_at_the_budget():
    warnings = []
    sampler = AdaptiveSampler(0.0, 16, 16.0, warn=warnings.append)
    radiance, _, count = sampler.render(32, 32, noise_shader)
    assert count.samples <= 16 * 32 * 32
    assert count.budget_hit_at is not None and count.budget_hit_at < 16
    assert len(warnings) == 1 and "aa_budget" in warnings[0]
    assert np.isfinite(np.array(radiance)).all()


def test_grid_is_the_mean_of_its_samples():
    radiance, _, count = render_grid(WIDTH, HEIGHT, 3, edge_shader)
    image = np.array(radiance.x).reshape(HEIGHT, WIDTH)
    assert count.samples == WIDTH * HEIGHT * 9
    # Column 2: sub-sample centres at 2 + 1/6, 2.5, 2 + 5/6 -> one third white.
    np.testing.assert_allclose(image[:, 2], 1 / 3, rtol=1e-6)
    np.testing.assert_array_equal(image[:, :2], 1.0)
    np.testing.assert_array_equal(image[:, 3:], 0.0)


def test_adaptive_render_of_a_scene_refines_only_silhouettes():
    """An emitting square on black: refinement only along its border."""
    square = {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(0.8),
              "emitter": {"type": "area", "radiance": rgb(1, 1, 1)}}
    loaded = mi.load_dict(scene(square, sensor=camera(size=20, fov=30)))
    whitted = mi.load_dict(integrator(aa="adaptive", aa_max_depth=3, aa_threshold=0.25))
    image = np.array(mi.render(loaded, integrator=whitted))
    assert_finite(image)
    samples = np.array(whitted.last_sample_map).reshape(20, 20)
    flat = (image.max(axis=2) == 0) | (image.min(axis=2) == 1)
    assert (samples[flat] == 4).all()
    assert (samples[~flat] > 4).all()
    assert whitted.last_stats["aa_samples"] == samples.sum()


def test_budget_warning_reaches_the_render():
    disk = {"type": "sphere", "radius": 0.8, "emitter": {"type": "area", "radiance": rgb(1, 1, 1)}}
    loaded = mi.load_dict(scene(disk, sensor=camera(size=16, fov=30)))
    whitted = mi.load_dict(integrator(aa="adaptive", aa_max_depth=16, aa_threshold=0.0,
                                      aa_budget=5))
    image = mi.render(loaded, integrator=whitted)
    assert_finite(image)
    assert whitted.last_stats["aa_budget_hit_at"] is not None
    assert whitted.last_stats["aa_samples"] <= 5 * 16 * 16
