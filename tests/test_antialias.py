"""Anti-aliasing patterns against independent models.

Oracles: a plain-Python recursion over cells that applies the report's
documented rule (split a quadrant whose clamped colour differs from the mean
of its three siblings by more than the threshold) to an exact half-plane
image; numpy float64 for the neighbourhood contrast; the exact area of a
pixel on one side of a sloped edge (polygon clipping) for convergence.
"""

from fractions import Fraction

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from conftest import assert_finite
from mitsuba_whitted.integrators.antialias import (AdaptiveSampler, ContrastSampler,
                                                   SampleBudget, neighbourhood_contrast,
                                                   render_grid)
from mitsuba_whitted.integrators.render_plan import Band
from validation.scenes import camera, integrator, rgb, scene

WIDTH, HEIGHT = 6, 4
#: A vertical edge inside pixel column 2, a third of the way across:
#: 1/3 = 0.010101... in binary keeps crossing the middle half of the cells.
EDGE = 2 + 1 / 3


def edge_shader(positions, keys, lens=None, share=1):
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
    sampler = AdaptiveSampler(0.25, max_depth, SampleBudget(1e9), warn=pytest.fail)
    radiance, alpha, count = sampler.render(Band.whole(WIDTH, HEIGHT), edge_shader)
    expected, per_level = reference(max_depth, 0.25)
    assert list(count.per_level) == per_level
    image = np.array(radiance.x).reshape(HEIGHT, WIDTH)
    np.testing.assert_allclose(image, expected, rtol=1e-6)
    np.testing.assert_array_equal(np.array(alpha), 1.0)


def test_extra_samples_only_in_edge_pixels():
    sampler = AdaptiveSampler(0.25, 5, SampleBudget(1e9), warn=pytest.fail)
    _, _, count = sampler.render(Band.whole(WIDTH, HEIGHT), edge_shader)
    samples = np.array(count.per_pixel).reshape(HEIGHT, WIDTH)
    assert (samples[:, 2] > 4).all()
    assert (np.delete(samples, 2, axis=1) == 4).all()
    assert samples.sum() == count.samples


def noise_shader(positions, keys, lens=None, share=1):
    """A colour that differs at every sample: the worst case."""
    a, b = mi.sample_tea_32(mi.UInt32(positions.x * 4096), mi.UInt32(positions.y * 4096))
    return mi.Color3f(mi.Float(a & 1), mi.Float(b & 1), 0.5), dr.ones(mi.Float, dr.width(positions))


def test_threshold_zero_on_noise_stops_at_the_budget():
    warnings = []
    sampler = AdaptiveSampler(0.0, 16, SampleBudget(16.0), warn=warnings.append)
    radiance, _, count = sampler.render(Band.whole(32, 32), noise_shader)
    assert count.samples <= 16 * 32 * 32
    assert count.budget_hit_at is not None and count.budget_hit_at < 16
    assert len(warnings) == 1 and "aa_budget" in warnings[0]
    assert np.isfinite(np.array(radiance)).all()


def test_grid_is_the_mean_of_its_samples():
    radiance, _, count = render_grid(Band.whole(WIDTH, HEIGHT), 3, edge_shader)
    image = np.array(radiance.x).reshape(HEIGHT, WIDTH)
    assert count.samples == WIDTH * HEIGHT * 9
    # Column 2: sub-sample centres at 2 + 1/6, 2.5, 2 + 5/6 -> one third white.
    np.testing.assert_allclose(image[:, 2], 1 / 3, rtol=1e-6)
    np.testing.assert_array_equal(image[:, :2], 1.0)
    np.testing.assert_array_equal(image[:, 3:], 0.0)


def render_emitting_square(**settings):
    """An emitting square on black, 20 x 20 pixels, its edges 0.4 of a pixel
    into the border pixels: (scene, integrator, image, camera samples per
    pixel)."""
    square = {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(0.75),
              "emitter": {"type": "area", "radiance": rgb(1, 1, 1)}}
    loaded = mi.load_dict(scene(square, sensor=camera(size=20, fov=30)))
    whitted = mi.load_dict(integrator(**settings))
    image = np.array(mi.render(loaded, integrator=whitted))
    assert_finite(image)
    assert whitted.last_stats["aa_samples"] == np.array(whitted.last_sample_map).sum()
    return loaded, whitted, image, np.array(whitted.last_sample_map).reshape(20, 20)


def test_adaptive_render_of_a_scene_refines_only_silhouettes():
    """An emitting square on black: refinement only along its border."""
    _, _, image, samples = render_emitting_square(aa="adaptive", aa_max_depth=3,
                                                  aa_threshold=0.25)
    flat = (image.max(axis=2) == 0) | (image.min(axis=2) == 1)
    assert 0 < (~flat).sum() < 100
    assert (samples[flat] == 4).all()
    assert (samples[~flat] > 4).all()


def test_budget_warning_reaches_the_render():
    disk = {"type": "sphere", "radius": 0.8, "emitter": {"type": "area", "radiance": rgb(1, 1, 1)}}
    loaded = mi.load_dict(scene(disk, sensor=camera(size=16, fov=30)))
    whitted = mi.load_dict(integrator(aa="adaptive", aa_max_depth=16, aa_threshold=0.0,
                                      aa_budget=5))
    image = mi.render(loaded, integrator=whitted)
    assert_finite(image)
    assert whitted.last_stats["aa_budget_hit_at"] is not None
    assert whitted.last_stats["aa_samples"] <= 5 * 16 * 16


# ------------------------------------------------------------------ contrast


def numpy_contrast(image: np.ndarray) -> np.ndarray:
    """(max - min) / (max + min) over each pixel's 3 x 3 neighbourhood
    (clamped at the border), largest over channels; float64."""
    height, width, _ = image.shape
    padded = np.pad(image.astype(np.float64), ((1, 1), (1, 1), (0, 0)), mode="edge")
    windows = np.stack([padded[dy:dy + height, dx:dx + width]
                        for dy in range(3) for dx in range(3)])
    high, low = windows.max(axis=0), windows.min(axis=0)
    spread = high + low
    ratio = np.divide(high - low, spread, out=np.zeros_like(spread), where=spread > 0)
    return ratio.max(axis=2)


def test_neighbourhood_contrast_matches_numpy():
    rng = np.random.default_rng(7)
    height, width = 9, 13
    image = rng.uniform(0, 2, (height, width, 4)) * (rng.uniform(size=(height, width, 1)) > 0.3)
    flat = image.reshape(-1, 4)
    radiance = mi.Color3f(*(mi.Float(flat[:, c]) for c in range(3)))
    contrast = neighbourhood_contrast(radiance, mi.Float(flat[:, 3]), width, height)
    np.testing.assert_allclose(np.array(contrast).reshape(height, width),
                               numpy_contrast(image), rtol=1e-5, atol=1e-7)


def test_contrast_refines_the_pixels_beside_an_edge_exactly():
    """The edge lies between the centres of columns 1 and 2, so only those
    are refined; of 64 Hammersley points in column 2, those with x below
    1/3 are white: (i + 0.5) / 64 < 1/3 for i = 0 ... 20."""
    sampler = ContrastSampler(0.1, 8, SampleBudget(1e9), warn=pytest.fail)
    radiance, alpha, count = sampler.render(Band.whole(WIDTH, HEIGHT), edge_shader)
    image = np.array(radiance.x).reshape(HEIGHT, WIDTH)
    samples = np.array(count.per_pixel).reshape(HEIGHT, WIDTH)
    assert (samples[:, 1:3] == 65).all() and (np.delete(samples, [1, 2], axis=1) == 1).all()
    assert samples.sum() == count.samples == WIDTH * HEIGHT + 2 * HEIGHT * 64
    np.testing.assert_array_equal(image[:, :2], 1.0)
    np.testing.assert_allclose(image[:, 2], 21 / 64, rtol=1e-6)
    np.testing.assert_array_equal(image[:, 3:], 0.0)
    np.testing.assert_array_equal(np.array(alpha), 1.0)


def half_plane_shader(normal, offset):
    """White where ``normal . (x, y) < offset`` (pixel units)."""
    nx, ny, c = (dr.opaque(mi.Float, v) for v in (*normal, offset))

    def shade(positions, keys, lens=None, share=1):
        white = mi.Float(nx * positions.x + ny * positions.y < c)
        return mi.Color3f(white), dr.ones(mi.Float, dr.width(positions))
    return shade


def covered_area(normal, offset, x0: float, y0: float) -> float:
    """Exact area of pixel (x0, y0) on the white side: the unit square
    clipped by the half-plane (Sutherland-Hodgman), then the shoelace sum."""
    def level(p):
        return normal[0] * p[0] + normal[1] * p[1] - offset

    square = [(x0, y0), (x0 + 1, y0), (x0 + 1, y0 + 1), (x0, y0 + 1)]
    clipped = []
    for p, q in zip(square, square[1:] + square[:1]):
        if level(p) < 0:
            clipped.append(p)
        if (level(p) < 0) != (level(q) < 0):
            t = level(p) / (level(p) - level(q))
            clipped.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])))
    return 0.5 * abs(sum(p[0] * q[1] - q[0] * p[1]
                         for p, q in zip(clipped, clipped[1:] + clipped[:1])))


def edge_errors(render, normal, offset, size=12):
    """Per-pixel error of ``render(width, height, shader)`` on a half-plane."""
    exact = np.array([[covered_area(normal, offset, x, y) for x in range(size)]
                      for y in range(size)])
    radiance, _, _ = render(size, size, half_plane_shader(normal, offset))
    return np.array(radiance.x).reshape(size, size) - exact


def render_contrast_8(width, height, shader):
    sampler = ContrastSampler(0.1, 8, SampleBudget(1e9), warn=pytest.fail)
    return sampler.render(Band.whole(width, height), shader)


def render_grid_8(width, height, shader):
    return render_grid(Band.whole(width, height), 8, shader)


@pytest.mark.parametrize("normal", [(1.0, 0.0), (0.0, -1.0)])
def test_contrast_resolves_axis_aligned_edges_to_one_over_the_count(normal):
    """64 Hammersley points hold one point per 1/64 column and row: the
    coverage of an axis-aligned edge is right to 1/64, where an 8 x 8 grid
    is off by up to 1/16 (exact areas as the oracle)."""
    offset = (5 + 1 / np.pi) * sum(normal)
    assert np.abs(edge_errors(render_contrast_8, normal, offset)).max() <= 1 / 64 + 1e-6
    assert np.abs(edge_errors(render_grid_8, normal, offset)).max() > 1 / 20


def test_contrast_on_sloped_edges_is_as_accurate_as_a_grid():
    """Over edges of many orientations, the RMS error of 64 Hammersley
    points stays within 1.25 times that of an 8 x 8 grid (a grid's own
    strength: irrational slopes make its row errors cancel)."""
    angles = np.linspace(0.05, np.pi / 2 - 0.05, 7)
    contrast, grid = [], []
    for angle in angles:
        normal = (float(np.cos(angle)), float(np.sin(angle)))
        offset = 6.0 * (normal[0] + normal[1]) + 0.37
        contrast.append(edge_errors(render_contrast_8, normal, offset))
        grid.append(edge_errors(render_grid_8, normal, offset))
    rms = [np.sqrt(np.mean(np.square(errors))) for errors in (contrast, grid)]
    assert rms[0] < 1.25 * rms[1]


def test_contrast_budget_takes_fewer_points_with_a_warning():
    warnings = []
    sampler = ContrastSampler(0.0, 16, SampleBudget(8.0), warn=warnings.append)
    radiance, _, count = sampler.render(Band.whole(32, 32), noise_shader)
    assert count.samples <= 8 * 32 * 32
    assert len(warnings) == 1 and "aa_budget" in warnings[0]
    assert np.isfinite(np.array(radiance)).all()


@pytest.mark.parametrize("sampler", [
    AdaptiveSampler(0.0, 3, SampleBudget(400.0), warn=pytest.fail),
    ContrastSampler(0.0, 4, SampleBudget(64.0), warn=pytest.fail)],
                         ids=["adaptive", "contrast"])
def test_a_channel_the_shader_broadcasts_is_refined_like_the_others(sampler):
    """noise_shader's blue channel is one value for all samples (width 1):
    refined pixels are scattered into it, so it must come back full width
    and hold that value (a scatter into the width-1 array wrote past it)."""
    radiance, _, count = sampler.render(Band.whole(16, 16), noise_shader)
    assert count.samples > 4 * 16 * 16
    assert dr.width(radiance.z) == 16 * 16
    assert np.array_equal(np.array(radiance.z), np.full(16 * 16, 0.5, np.float32))


def test_contrast_render_of_a_scene_refines_only_silhouettes():
    """An emitting square on black: flat pixels away from its border keep
    their single centre sample; the same render twice is bit-identical."""
    loaded, whitted, image, samples = render_emitting_square(aa="contrast", aa_samples=4,
                                                             aa_threshold=0.1)
    partial = (image.max(axis=2) > 0) & (image.min(axis=2) < 1)
    assert 0 < partial.sum() < 100
    assert (samples[partial] == 17).all()
    assert (samples[0] == 1).all() and samples[10, 10] == 1
    np.testing.assert_array_equal(image, np.array(mi.render(loaded, integrator=whitted)))
