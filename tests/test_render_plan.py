"""Renders cut into bands, and the memory check before a render.

Oracles: the same render in one piece (bands must not change a pixel),
Mitsuba's own film (``render_rows`` must give what ``develop`` gives), and
the sizes of the arrays a film needs (Dr.Jit's 2^32 entries)."""

import mitsuba as mi
import numpy as np
import pytest

from conftest import assert_finite, limit_whitted
from mitsuba_whitted.errors import ParameterError
from mitsuba_whitted.integrators import antialias
from mitsuba_whitted.integrators import whitted as whitted_module
from mitsuba_whitted.integrators.render_plan import Demand, Limits, plan_render
from validation.scenes import (camera, diffuse, floor, glass_scene, integrator, point_light, rgb,
                              scene, sphere)

GIB = 1 << 30


def lit_scene(size=24, **film):
    """Point-lit spheres over a floor, with silhouettes to refine."""
    sensor = camera(origin=(0, 1, 5), size=size)
    sensor["film"].update(film)
    return mi.load_dict(scene(floor(), sphere((-0.6, 0, 0), 0.5, diffuse(0.8, 0.3, 0.2)),
                              sphere((0.7, 0, 0.3), 0.6, {"type": "dielectric"}),
                              point_light((1, 3, 3)), sensor=sensor))


def render(loaded, limits=None, **settings):
    whitted = mi.load_dict(integrator(**settings))
    if limits is not None:
        whitted.limits = limits
    image = np.array(mi.render(loaded, integrator=whitted))
    return image, whitted


@pytest.fixture
def small_bands(monkeypatch):
    """Bands of a few rows of a 20 x 20 film."""
    limit_whitted(monkeypatch, band_samples=1500)


#: Settings, and a number of samples per band that cuts a 24 x 24 film
#: into bands of a few rows (bands are sized for ``typical_samples`` per pixel
#: where refinement may add samples) without stopping the refinement.
SETTINGS = [(dict(aa="none"), 100), (dict(aa="grid", aa_samples=3), 100),
            (dict(aa="contrast", aa_samples=4, aa_threshold=0.05), 2000),
            (dict(aa="adaptive", aa_max_depth=4, aa_threshold=0.05, aa_budget=16), 2000)]


@pytest.mark.parametrize("settings, band_samples", SETTINGS, ids=[s["aa"] for s, _ in SETTINGS])
def test_bands_give_the_image_of_one_piece(settings, band_samples, monkeypatch):
    whole, whitted = render(lit_scene(), **settings)
    assert whitted.last_stats["bands"] == 1
    banded, whitted = render(lit_scene(), Limits(band_samples=band_samples), **settings)
    assert whitted.last_stats["bands"] > 3
    assert_finite(banded)
    np.testing.assert_array_equal(banded, whole)


def test_bands_with_sampled_lights_are_deterministic(small_bands):
    """Area lights take their shadow-ray points from the sample keys, which
    stay unique and fixed when the film is cut into bands."""
    loaded = mi.load_dict(glass_scene(size=20))
    first, whitted = render(loaded, aa="adaptive", aa_max_depth=3, aa_threshold=0.05)
    second, _ = render(loaded, aa="adaptive", aa_max_depth=3, aa_threshold=0.05)
    assert whitted.last_stats["bands"] > 1
    assert_finite(first)
    np.testing.assert_array_equal(first, second)


def test_a_crop_window_is_banded_in_place():
    crop = dict(crop_offset_x=3, crop_offset_y=5, crop_width=14, crop_height=11)
    whole, _ = render(lit_scene(**crop), aa="grid", aa_samples=2)
    banded, whitted = render(lit_scene(**crop), Limits(band_samples=40), aa="grid",
                             aa_samples=2)
    assert whitted.last_stats["bands"] > 3
    np.testing.assert_array_equal(banded, whole)


@pytest.mark.parametrize("pixel_format", ["rgb", "rgba"])
def test_rows_to_a_file_hold_what_the_film_develops(pixel_format, small_bands):
    loaded = lit_scene(size=20, pixel_format=pixel_format)
    whitted = mi.load_dict(integrator(aa="contrast", aa_samples=4, aa_threshold=0.05))
    developed = np.array(mi.render(loaded, integrator=whitted))
    image = np.full_like(developed, np.nan)

    def take(first_row, rows):
        assert rows.dtype == np.float32
        image[first_row:first_row + len(rows)] = rows

    whitted.render_rows(loaded, take)
    assert whitted.last_stats["bands"] > 1
    np.testing.assert_array_equal(image, developed)


def test_a_band_stops_refining_where_it_would_keep_too_many_samples(monkeypatch):
    warnings = []
    monkeypatch.setattr(whitted_module, "_warn", warnings.append)
    image, whitted = render(lit_scene(), Limits(band_samples=3000), aa="adaptive",
                            aa_max_depth=8, aa_threshold=0.0, aa_budget=400)
    assert_finite(image)
    bands = whitted.last_stats["bands"]
    assert bands > 1 and whitted.last_stats["aa_samples"] <= 3000 * bands
    assert warnings and all("keeps in memory at once" in warning for warning in warnings)


def test_a_film_too_large_for_memory_is_refused_before_it_is_allocated():
    loaded = mi.load_dict(scene(sensor=camera(size=20000)))
    whitted = mi.load_dict(integrator())
    whitted.limits = Limits(memory=lambda: 2 * GIB)
    with pytest.raises(ParameterError) as error:
        mi.render(loaded, integrator=whitted)
    message = str(error.value)
    assert message.startswith("whitted: parameter 'film'")
    assert "20000 x 20000" in message and "'width' and 'height'" in message
    assert "\n" not in message


def test_a_film_past_dr_jit_s_array_limit_is_refused_whatever_the_memory():
    with pytest.raises(ParameterError, match="2\\^32"):
        plan_render(Demand(40000, 40000, 1, 1 << 21, 40000 * 40000 * 9),
                    Limits(memory=lambda: 1 << 50))


def test_samples_that_do_not_fit_name_the_budget():
    with pytest.raises(ParameterError) as error:
        plan_render(Demand(4000, 3000, 100000, 1 << 16, 0), Limits(memory=lambda: GIB))
    assert str(error.value).startswith("whitted: parameter 'aa_budget'")


def test_bands_are_sized_for_typical_refinement_and_cover_the_film():
    plan = plan_render(Demand(20000, 20000, 64, 1 << 21, 0))
    assert plan.rows_per_band == Limits().band_samples // (Limits().typical_samples * 20000)
    assert sum(band.rows for band in plan.bands()) == 20000
    assert plan.band_bytes < 2 * GIB
    assert plan_render(Demand(600, 600, 64, 1 << 21, 0)).band_count == 1


def box_downsampled(image: np.ndarray, n: int) -> np.ndarray:
    """Means of the n x n blocks of ``image``."""
    height, width, channels = image.shape
    return image.reshape(height // n, n, width // n, n, channels).mean(axis=(1, 3))


@pytest.mark.parametrize("n, budget", [(12, 64.0), (9, 16.0), (5, 4.0)])
def test_an_explicit_grid_past_the_budget_traces_every_sample_with_a_warning(
        n, budget, monkeypatch):
    """``aa_samples`` n past ``aa_budget``: the grid the user asked for,
    n² samples in every pixel, and one warning. Oracle: the pixel centres of
    a film n times finer in each direction lie where the grid's samples
    do; their block means are the grid's pixels (to float rounding of the
    sample positions)."""
    warnings = []
    monkeypatch.setattr(whitted_module, "_warn", warnings.append)
    loaded = lit_scene(size=8)
    image, whitted = render(loaded, aa="grid", aa_samples=n, aa_budget=budget)
    assert_finite(image)
    assert whitted.last_stats["aa_samples"] == 8 * 8 * n * n
    assert len(warnings) == 1 and f"{n * n} camera samples per pixel" in warnings[0]
    mi.render(loaded, integrator=whitted)
    assert len(warnings) == 1, "the same grid warns once"
    fine, _ = render(lit_scene(size=8 * n), aa="none")
    np.testing.assert_allclose(image, box_downsampled(fine, n), atol=2e-3)


def test_grid_keys_number_the_samples_modulo_2_to_the_32():
    """A grid asked for explicitly may number more than 2^32 samples over
    a film (10^4 x 10^4 pixels of 12 x 12): its keys wrap as UInt32 sums
    do. Oracle: the same numbers in Python's integers."""
    first_pixel, n = 5 * 10 ** 7, 12
    _, keys, _ = antialias._grid_positions(10 ** 4, first_pixel, 3, n)
    expected = (first_pixel * n * n + np.arange(3 * n * n)) % (1 << 32)
    np.testing.assert_array_equal(keys.numpy(), expected)


def test_a_grid_within_the_budget_renders_without_a_warning(monkeypatch):
    warnings = []
    monkeypatch.setattr(whitted_module, "_warn", warnings.append)
    _, whitted = render(lit_scene(size=4), aa="grid", aa_samples=8)
    assert whitted.last_stats["aa_samples"] == 4 * 4 * 64 and warnings == []


def test_a_grid_within_a_raised_budget_renders_with_samples_traced_in_launches():
    """700 x 700 samples in each of 2 x 2 pixels, against the same pixels'
    means worked out from a grid of 4 x 4 pixels that each take a quarter
    of the samples (a 350 x 350 grid): a surface of one flat colour."""
    loaded = mi.load_dict(scene(sphere((0, 0, 0), 2.0, {"type": "diffuse",
                                                        "reflectance": rgb(0.5, 0.5, 0.5)}),
                                point_light((0, 0, 5)), sensor=camera(size=2, fov=5)))
    image, whitted = render(loaded, aa="grid", aa_samples=700, aa_budget=490000)
    assert whitted.last_stats["aa_samples"] == 4 * 700 * 700
    assert_finite(image)
    centre, _ = render(loaded, aa="none")
    np.testing.assert_allclose(image, centre, rtol=2e-3)


@pytest.mark.parametrize("suffix", [".exr", ".png"])
def test_the_command_writes_a_film_band_by_band_as_the_film_would_hold_it(
        tmp_path, monkeypatch, suffix):
    """``mitsuba-whitted render`` hands whitted's bands to the file's
    encoder and never holds a film of the whole image: the file holds what
    ``mi.render`` develops, stored as the format stores it."""
    from pathlib import Path

    from mitsuba_whitted import cli
    from mitsuba_whitted.imageio import read_image, stored_pixels

    limit_whitted(monkeypatch, band_samples=40 * 16)
    path = tmp_path / "scene.xml"
    path.write_text(BANDED_SCENE)
    out = tmp_path / f"out{suffix}"
    assert cli.main(["render", str(path), "-o", str(out)]) == 0
    developed = np.array(mi.render(mi.load_file(str(path))))
    stored = read_image(out)
    if suffix == ".png":
        stored = np.round(stored * 255).astype(np.uint8)
    np.testing.assert_array_equal(stored, stored_pixels(Path(out), developed))


def test_the_command_refuses_a_film_it_cannot_hold_and_writes_nothing(tmp_path, monkeypatch,
                                                                      capsys):
    from mitsuba_whitted import cli

    limit_whitted(monkeypatch, memory=lambda: GIB)
    path = tmp_path / "scene.xml"
    path.write_text(BANDED_SCENE.replace('value="40"', 'value="60000"')
                    .replace('value="30"', 'value="60000"'))
    out = tmp_path / "out.exr"
    assert cli.main(["render", str(path), "-o", str(out)]) == 2
    error = capsys.readouterr().err
    # The image's 43 GB in the file's encoder are the largest part.
    assert error.count("\n") == 1 and "whitted: parameter 'film'" in error
    assert "60000 x 60000" in error
    assert not out.exists() and list(tmp_path.iterdir()) == [path]


#: A 40 x 30 point-lit scene, adaptive anti-aliasing.
BANDED_SCENE = """<scene version="3.0.0">
    <integrator type="whitted"><string name="aa" value="adaptive"/>
        <float name="aa_threshold" value="0.05"/></integrator>
    <sensor type="perspective">
        <transform name="to_world"><lookat origin="0, 1, 5" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm"><integer name="width" value="40"/>
            <integer name="height" value="30"/><rfilter type="box"/></film>
    </sensor>
    <shape type="sphere"><float name="radius" value="0.8"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.3, 0.2"/></bsdf></shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/>
            <translate y="-1"/></transform>
        <bsdf type="dielectric"/></shape>
    <emitter type="point"><point name="position" x="1" y="3" z="3"/>
        <rgb name="intensity" value="20"/></emitter>
</scene>"""
