"""The light classic Whitted leaves out, gathered by path tracing from the
ray tree's smooth hits (``indirect_samples``).

Oracles: Mitsuba's ``path`` in expectation (``test_equivalence.py`` runs the
suite's indirect cases; here, the mean of a whole image against a converged
``path`` render), the classic integrator where nothing indirect can reach
the camera, the (0, m, 2)-net property of the Sobol points, and the
wavefront tracer, which walks the same trees one generation at a time.
"""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from conftest import assert_finite, cli, one_line
from mitsuba_whitted.compare.metrics import rel_mse
from mitsuba_whitted import load_file
from mitsuba_whitted.errors import ParameterError
from mitsuba_whitted.integrators import indirect, sequence
from mitsuba_whitted.integrators.camera_shader import pixel_keys
from validation.scenes import GLASS_BOX, camera, diffuse, floor, point_light, scene, sphere


def render(description_or_scene, **settings):
    loaded = (mi.load_dict(description_or_scene) if isinstance(description_or_scene, dict)
              else description_or_scene)
    whitted = mi.load_dict({"type": "whitted", **settings})
    return np.array(mi.render(loaded, integrator=whitted)), whitted


def lit_ball(size=24, sampler=None):
    """A diffuse ball on a diffuse floor under a point light, on an RGBA
    film: the floor lights the ball's underside, which classic Whitted
    leaves black. ``sampler``: the sensor's, for ``path``."""
    sensor = camera(origin=(0, 1, 5), size=size, crop={"pixel_format": "rgba"})
    if sampler is not None:
        sensor["sampler"] = {"type": sampler}
    return scene(floor(), sphere((0, 0, 0), 0.8, diffuse(0.8, 0.5, 0.3)),
                 point_light((1, 3, 2)), sensor=sensor)


# ----------------------------------------------------------------- samples

@pytest.mark.parametrize("pair", [0, 1, 7, 1000])
def test_each_pair_of_sobol_dimensions_is_a_net_in_every_prefix(pair):
    """The first 2^m samples of a pair fill every dyadic box of area 2^-m
    once (every split of the m bits between x and y), for every m: the
    index shuffle keeps power-of-two prefixes, and the Owen scramble keeps
    the net."""
    seeds = mi.UInt32([3, 12345, 0xDEADBEEF])
    for m in (2, 4, 6):
        count = 1 << m
        index = dr.tile(dr.arange(mi.UInt32, count), 3)
        lane_seeds = dr.repeat(seeds, count)
        point = sequence.PaddedSobol(lane_seeds).point(index, pair)
        x = np.array(point.x, dtype=np.float64).reshape(3, count)
        y = np.array(point.y, dtype=np.float64).reshape(3, count)
        for bits_x in range(m + 1):
            cell = ((x * (1 << bits_x)).astype(int) << (m - bits_x)) \
                + (y * (1 << (m - bits_x))).astype(int)
            for row in cell:
                assert sorted(row) == list(range(count)), (m, bits_x)


def test_pairs_and_seeds_give_uncorrelated_uniform_points():
    """Across many seeds, each coordinate is uniform (mean 1/2, variance
    1/12) and two pairs of the same sample are uncorrelated."""
    seeds = dr.arange(mi.UInt32, 1 << 16) * 7919
    generator = sequence.PaddedSobol(seeds)
    first = generator.point(mi.UInt32(3), 0)
    second = generator.point(mi.UInt32(3), 1)
    values = np.array([first.x, first.y, second.x, second.y], dtype=np.float64)
    standard_error = np.sqrt(1 / 12 / values.shape[1])
    assert np.all(np.abs(values.mean(axis=1) - 0.5) < 5 * standard_error)
    assert np.all(np.abs(values.var(axis=1) - 1 / 12) < 0.01)
    correlation = np.corrcoef(values)
    assert np.all(np.abs(correlation - np.eye(4)) < 5 / np.sqrt(values.shape[1]))


# ------------------------------------------------------------- the render

@pytest.mark.parametrize("side, paths", [(4, 16), (4, 64), (8, 32), (3, 12)])
def test_the_camera_samples_of_a_pixel_tile_one_sequence_with_their_paths(side, paths):
    """The keys of a pixel's side x side grid take distinct slots, and
    their windows (for ``paths`` paths per pixel) tile the first ``paths``
    samples of one sequence, whatever the shift: the pixel traces what it
    was given (32 paths among 64 samples are 32, not one each), weighed so
    that each sample's count over the shift has the mean it asked for."""
    share = side * side
    sub = dr.arange(mi.UInt32, share)
    offsets = mi.Point2f((mi.Float(sub % side) + 0.5) / side, (mi.Float(sub // side) + 0.5) / side)
    pixels = [(0, 0), (5, 3), (1023, 7)]
    positions = mi.Point2f(dr.repeat(mi.Float([x for x, _ in pixels]), share) + dr.tile(offsets.x, 3),
                           dr.repeat(mi.Float([y for _, y in pixels]), share) + dr.tile(offsets.y, 3))
    keys = pixel_keys(positions, share, width=2048)
    assert len(set(np.array(keys).tolist())) == 3 * share
    wanted = dr.full(mi.Float, paths / share, 3 * share)
    for salt in (1, 77, 0xC0FFEE):
        seeds, first, count, weight = (np.array(v) for v in
                                       indirect.path_window(wanted, keys, salt))
        for pixel in range(3):
            block = slice(pixel * share, (pixel + 1) * share)
            assert len(set(seeds[block].tolist())) == 1
            windows = sorted(i for f, c in zip(first[block], count[block]) for i in range(f, f + c))
            assert windows == list(range(paths))
        expected = 1 / (count if paths >= share else np.full(count.shape, paths / share))
        np.testing.assert_allclose(weight[count > 0], expected[count > 0])
    # Over the shift, each sample's count has its mean.
    means = np.mean([np.array(indirect.path_window(wanted, keys, salt)[2])
                     for salt in range(4000)], axis=0)
    np.testing.assert_allclose(means, paths / share, atol=0.05)


def test_other_keys_gather_on_their_own_with_at_least_one_path():
    """A key that is not a camera sample's (a ray of ``trace_rays``, a
    delta child's) has a sequence of its own from sample 0 and one path at
    least, however dim the tree's throughput to it."""
    keys = dr.arange(mi.UInt32, 1000)
    seeds, first, count, weight = (np.array(v) for v in indirect.path_window(
        dr.full(mi.Float, 0.3, 1000), keys, 5))
    assert len(set(seeds.tolist())) == 1000
    assert (first == 0).all() and (count == 1).all() and (weight == 1).all()
    _, _, count, weight = (np.array(v) for v in indirect.path_window(
        dr.full(mi.Float, 2.5, 1000), keys, 5))
    assert set(count.tolist()) == {2, 3} and abs(count.mean() - 2.5) < 0.1
    np.testing.assert_allclose(weight, 1 / count)


def test_a_pixel_with_one_path_per_camera_sample_is_as_good_as_a_stratified_path_pixel():
    """16 camera samples of a grid with one path each: the pixel's paths
    are one stratified set, so its relMSE against a converged ``path``
    (4096 spp) is no worse than that of ``path`` with 16 samples of the
    multi-jittered sampler (a quarter more at most: the grid and the
    jitter do not place camera samples alike); paths drawn from a sequence
    per camera sample had more than twice that error. Half a path per
    camera sample traces half the paths and keeps the mean."""
    loaded = mi.load_dict(lit_ball())
    depth = {"max_depth": 6}
    reference = np.mean([np.array(mi.render(loaded, integrator=mi.load_dict({"type": "path", **depth}),
                                            spp=1024, seed=100 + s))[..., :3]
                         for s in range(4)], axis=0)
    jittered = mi.load_dict(lit_ball(sampler="multijitter"))
    path_error = np.mean([rel_mse(np.array(mi.render(
        jittered, integrator=mi.load_dict({"type": "path", **depth}), spp=16, seed=s)), reference)
        for s in range(4)])
    whitted = mi.load_dict({"type": "whitted", "aa": "grid", "aa_samples": 4,
                            "indirect_samples": 16, **depth})
    images = [np.array(mi.render(loaded, integrator=whitted, seed=s)) for s in range(4)]
    whitted_error = np.mean([rel_mse(image, reference) for image in images])
    assert whitted_error < 1.25 * path_error, (whitted_error, path_error)
    full_rays = whitted.last_stats["indirect"]
    half = mi.load_dict({"type": "whitted", "aa": "grid", "aa_samples": 4,
                         "indirect_samples": 8, **depth})
    halves = np.stack([np.array(mi.render(loaded, integrator=half, seed=s))[..., :3]
                       for s in range(8)])
    assert half.last_stats["indirect"] == pytest.approx(full_rays / 2, rel=0.1)
    error = halves.mean(axis=(1, 2, 3)).std(ddof=1) / np.sqrt(len(halves))
    assert abs(halves.mean() - reference.mean()) < 4 * error + 1e-3 * reference.mean()



def test_gathering_converges_to_path_on_a_lit_ball():
    """The image mean within a few standard errors of path's (4096 spp),
    where classic Whitted lacks the light from the floor."""
    loaded = mi.load_dict(lit_ball())
    image, _ = render(loaded, indirect_samples=256, max_depth=6, aa="grid", aa_samples=4)
    classic, _ = render(loaded, max_depth=6, aa="grid", aa_samples=4)
    path = mi.load_dict({"type": "path", "max_depth": 6})
    passes = np.stack([np.array(mi.render(loaded, integrator=path, spp=256, seed=s))[..., :3]
                       for s in range(16)])
    reference = passes.mean(axis=0).mean()
    error = passes.mean(axis=(1, 2, 3)).std(ddof=1) / np.sqrt(len(passes))
    assert_finite(image)
    assert abs(image[..., :3].mean() - reference) < 4 * error + 1e-3 * reference
    assert reference - classic[..., :3].mean() > 100 * error


def test_zero_is_classic_whitted_and_so_is_a_depth_without_room():
    """No indirect part at 0, nor where max_depth leaves no second segment
    past a hit (2: direct light only): the image of classic Whitted, bit
    for bit, and no indirect rays."""
    loaded = mi.load_dict(lit_ball())
    classic, _ = render(loaded, max_depth=2)
    gathered, whitted = render(loaded, max_depth=2, indirect_samples=8)
    np.testing.assert_array_equal(classic, gathered)
    assert whitted.last_stats["indirect"] == 0


def test_hits_that_see_only_delta_chains_gather_nothing():
    """A mirror ball against an empty sky: no smooth hit, no indirect path."""
    mirror = scene(sphere((0, 0, 0), 1, {"type": "conductor"}), point_light((2, 2, 2)),
                   sky={"type": "constant"}, sensor=camera(size=16))
    _, whitted = render(mirror, indirect_samples=16)
    assert whitted.last_stats["indirect"] == 0
    image, lit = render(lit_ball(size=16), indirect_samples=16)
    # Every surface there is diffuse: each camera ray that hits starts 16
    # paths of at least one ray each.
    hits = int((image[..., 3] > 0).sum())
    assert hits > 100
    assert lit.last_stats["indirect"] >= 16 * hits


def test_a_hit_seen_through_a_dim_filter_gathers_with_that_share_of_the_paths():
    """Behind a sheet that passes a quarter of the light unbent (a
    dielectric of index 1), every hit gathers with a quarter of the paths
    (rounded at random): its noise reaches the pixel at a quarter of the
    weight. Same geometry, so the rays per path are alike."""
    sheet = {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, 4]),
             "bsdf": {"type": "dielectric", "int_ior": 1.0, "ext_ior": 1.0,
                      "specular_transmittance": {"type": "rgb", "value": [0.25] * 3}}}
    open_view, filtered = lit_ball(size=32), lit_ball(size=32)
    filtered["sheet"] = sheet
    image, direct = render(open_view, indirect_samples=16)
    dimmed, behind = render(filtered, indirect_samples=16)
    assert behind.last_stats["refraction"] > 0
    ratio = behind.last_stats["indirect"] / direct.last_stats["indirect"]
    assert ratio == pytest.approx(0.25, rel=0.1)
    assert_finite(dimmed)


def test_the_same_input_gives_the_same_bits_and_seeds_differ():
    loaded = small_glass_box()
    whitted = mi.load_dict({"type": "whitted", "indirect_samples": 4})
    first = np.array(mi.render(loaded, integrator=whitted, seed=3))
    again = np.array(mi.render(loaded, integrator=whitted, seed=3))
    other = np.array(mi.render(loaded, integrator=whitted, seed=4))
    np.testing.assert_array_equal(first, again)
    assert np.abs(first - other).max() > 0
    assert_finite(first)


def small_glass_box():
    """The closed box with glass, a mirror and a point light, small enough
    to render in a test."""
    return load_file(GLASS_BOX, res="24")


def test_both_tracers_trace_the_same_paths():
    """The wavefront tracer (which a capturing render uses) and the
    depth-first one walk the same trees with the same samples: equal to
    float rounding, but where rounding sends a path another way."""
    loaded = small_glass_box()
    settings = {"type": "whitted", "indirect_samples": 4, "max_depth": 6}
    depth_first = mi.load_dict(settings)
    wavefront = mi.load_dict(settings)
    wavefront.capture_rays = True
    a = np.array(mi.render(loaded, integrator=depth_first))
    b = np.array(mi.render(loaded, integrator=wavefront))
    close = np.isclose(a, b, rtol=1e-3, atol=1e-5).all(axis=-1)
    assert close.mean() > 0.99, close.mean()
    assert abs(a.mean() - b.mean()) < 1e-3 * a.mean()
    assert depth_first.last_stats["indirect"] == pytest.approx(
        wavefront.last_stats["indirect"], rel=1e-3)


def test_a_gradient_is_refused_in_one_sentence():
    loaded = mi.load_dict(lit_ball(size=8))
    whitted = mi.load_dict({"type": "whitted", "indirect_samples": 2})
    params = mi.traverse(loaded)
    key = next(k for k in params.keys() if k.endswith("reflectance.value"))
    dr.enable_grad(params[key])
    params.update()
    image = mi.render(loaded, params, integrator=whitted)
    with pytest.raises(ParameterError, match="indirect_samples"):
        dr.backward(image)


def test_an_ambient_term_with_indirect_light_warns_once(tmp_path):
    path = tmp_path / "scene.xml"
    path.write_text(GLASS_BOX.read_text().replace(
        '<integer name="indirect_samples" value="$indirect_samples"/>',
        '<integer name="indirect_samples" value="1"/><rgb name="ambient" value="0.1"/>'))
    (tmp_path / "out").mkdir()
    result = cli("render", str(path), "-o", str(tmp_path / "out" / "x.exr"), "-D", "res=16")
    assert result.returncode == 0, result.stderr
    warnings = [line for line in result.stderr.splitlines() if "indirect_samples > 0" in line]
    assert len(warnings) == 1 and "ambient" in warnings[0], result.stderr


def test_a_bad_count_from_the_command_line_is_one_sentence(tmp_path):
    """(Loading, XML and updates: ``test_plugin_parameters``.)"""
    result = cli("render", str(GLASS_BOX), "-o", str(tmp_path / "x.png"), "-D",
                 "indirect_samples=-2")
    assert result.returncode == 2
    assert "indirect_samples" in one_line(result.stderr)
