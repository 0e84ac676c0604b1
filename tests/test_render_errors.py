"""Errors of ``mi.render`` from Python, as a user who catches them reads
them: the package's own sentence in ``str(error)`` (not Dr.Jit's "see
above" wrapper), Ctrl-C as ``KeyboardInterrupt``, and one sentence for a
seed that 32 bits do not hold and for a scene of another variant.

Oracles: the exception's class and its message, and the image of a valid
render, which the checks leave as it was."""

import os
import signal

import mitsuba as mi
import numpy as np
import pytest

import mitsuba_whitted
from conftest import VARIANT
from mitsuba_whitted.errors import ParameterError, VariantError
from validation.scenes import camera, diffuse, floor, integrator, point_light, scene, sphere


def small_scene(**whitted):
    return mi.load_dict(scene(floor(), sphere((0, 0, 0), 0.7, diffuse(0.5, 0.5, 0.5)), point_light((2, 3, 4), 30.0),
                              sensor=camera(size=8), whitted=integrator(**whitted)))


def assert_own_sentence(error: BaseException, start: str) -> None:
    text = str(error)
    assert text.startswith(start), text
    assert "drjit.custom" not in text and "see above" not in text, text
    assert error.__cause__ is None and error.__suppress_context__, repr(error.__cause__)


def negative_light(loaded):
    params = mi.traverse(loaded)
    key = next(key for key in params.keys() if key.endswith("intensity.value"))
    params[key] = type(params[key])(-1.0)
    params.update()
    return loaded


def too_many_samples(loaded):
    params = mi.traverse(loaded.integrator())
    params["aa_budget"] = 1e9
    params["aa_samples"] = 30000
    params.update()
    return loaded


@pytest.mark.parametrize("spoil, start", [
    (negative_light, "whitted: parameter 'intensity.value' of emitter"),
    (too_many_samples, "whitted: parameter 'aa_samples' makes this 8 x 8 render need about"),
], ids=["negative-light", "memory"])
def test_a_refusal_during_a_render_is_the_packages_error(spoil, start):
    loaded = spoil(small_scene(aa="grid"))
    with pytest.raises(ParameterError) as refused:
        mi.render(loaded)
    assert_own_sentence(refused.value, start)


@pytest.mark.parametrize("seed, name", [
    (-1, "seed"), (2**40, "seed"), (2**32, "seed"), (2.5, "seed"), ("3", "seed"),
    (2**40, "seed_grad"),
])
def test_a_seed_beyond_32_bits_is_one_sentence(seed, name):
    loaded = small_scene()
    with pytest.raises(ParameterError) as refused:
        mi.render(loaded, **{name: seed})
    assert str(refused.value) == (f"mi.render: parameter '{name}' must be a whole number from 0 "
                               f"to 2^32 - 1 (got {seed!r})")


def test_valid_seeds_render_as_before():
    loaded = small_scene()
    plain = np.array(mi.render(loaded, seed=7))
    np.testing.assert_array_equal(np.array(mi.render(loaded, seed=mi.UInt32(7))), plain)
    mi.render(loaded, seed=2**32 - 1)


def test_ctrl_c_during_a_render_is_a_keyboard_interrupt():
    """A real SIGINT, sent while the integrator renders (from its progress
    display), with Python's own handler."""
    loaded = small_scene(aa="grid")
    loaded.integrator().progress = lambda *args: os.kill(os.getpid(), signal.SIGINT)
    with pytest.raises(KeyboardInterrupt):
        mi.render(loaded)
    loaded.integrator().progress = None
    assert np.isfinite(np.array(mi.render(loaded))).all()


@pytest.mark.parametrize("other", [name for name in ("scalar_rgb", "llvm_ad_mono")
                                   if name in mi.variants()])
def test_a_scene_of_another_variant_is_one_sentence(other):
    """Another backend, and the same backend with another colour model."""
    loaded = small_scene()
    try:
        mitsuba_whitted.set_variant(other)
        with pytest.raises(VariantError) as refused:
            mi.render(loaded)
    finally:
        mitsuba_whitted.set_variant(VARIANT)
    assert str(refused.value) == (
        f"mi.render: the scene was loaded in variant '{VARIANT}', and the active variant is "
        f"'{other}'; load it again, or call mi.set_variant('{VARIANT}') first.")
    assert np.isfinite(np.array(mi.render(loaded))).all()


def test_mitsubas_own_errors_pass_unchanged():
    loaded = small_scene()
    with pytest.raises(IndexError):
        mi.render(loaded, sensor=5)
