"""Plugins register for whichever variant is active, before or after import."""

import subprocess
import sys

import drjit as dr
import mitsuba as mi
import pytest

import mitsuba_whitted

PLUGINS = {"whitted", "phong", "capped_cylinder", "tartan", "sphere_map", "planar_map"}


def test_every_plugin_is_registered():
    assert set(mitsuba_whitted.registered_plugins()) == PLUGINS


def run_python(code: str) -> str:
    return subprocess.run([sys.executable, "-c", code], check=True, capture_output=True,
                          text=True, timeout=300).stdout


@pytest.mark.parametrize("order", ["variant first", "import first"])
def test_registration_order(order):
    steps = ["import mitsuba_whitted", "import mitsuba as mi",
             "mi.set_variant('llvm_ad_rgb')"]
    if order == "variant first":
        steps = ["import mitsuba as mi", "mi.set_variant('llvm_ad_rgb')",
                 "import mitsuba_whitted"]
    code = "; ".join(steps + [
        "print(type(mi.load_dict({'type': 'whitted'})).__name__)",
        "print(type(mi.load_dict({'type': 'tartan'})).__name__)"])
    assert run_python(code).split() == ["WhittedIntegrator", "Tartan"]


def test_plugins_follow_variant_changes():
    try:
        mi.set_variant("scalar_rgb")
        assert mi.load_dict({"type": "phong"}) is not None
    finally:
        mitsuba_whitted.set_variant("llvm_ad_rgb")
    integrator = mi.load_dict({"type": "whitted"})
    assert isinstance(integrator, mi.SamplingIntegrator)


def test_unknown_variant_is_one_sentence():
    with pytest.raises(mitsuba_whitted.VariantError,
                       match="^mitsuba-whitted: variant 'llvm_ad_rgbx' is not available"):
        mitsuba_whitted.set_variant("llvm_ad_rgbx")


def test_a_variant_whose_backend_cannot_start_is_one_sentence():
    """A CUDA variant without a GPU: a clear error, and the variant that
    was active stays usable."""
    if "cuda_ad_rgb" not in mi.variants() or dr.has_backend(dr.JitBackend.CUDA):
        pytest.skip("this machine has no CUDA variant, or can run it")
    with pytest.raises(mitsuba_whitted.VariantError,
                       match="'cuda_ad_rgb' cannot be used on this machine.*NVIDIA"):
        mitsuba_whitted.set_variant("cuda_ad_rgb")
    assert mi.variant() == "llvm_ad_rgb"
    assert isinstance(mi.load_dict({"type": "whitted"}), mi.SamplingIntegrator)


def test_whitted_is_told_apart_from_other_integrators_in_every_variant():
    """The plugin's class is made anew on each variant change: the check
    does not hold on to one of them."""
    from mitsuba_whitted.integrators.settings import is_whitted

    before = mi.load_dict({"type": "whitted"})
    try:
        mitsuba_whitted.set_variant("llvm_ad_mono")
        assert not is_whitted(mi.load_dict({"type": "path"}))
    finally:
        mitsuba_whitted.set_variant("llvm_ad_rgb")
    after = mi.load_dict({"type": "whitted"})
    assert type(after) is not type(before)
    assert is_whitted(before) and is_whitted(after)
    assert not is_whitted(mi.load_dict({"type": "path"})) and not is_whitted(None)


def test_the_mitsuba_entry_point_names_this_package():
    """Mitsuba 3.10 imports the module that each ``mitsuba`` entry point
    names when a variant becomes active (mitsuba3 PR #1943, in the form
    ``name = "module"``); 3.9.1 ignores the group, hence the explicit import."""
    from importlib.metadata import entry_points

    found = [ep for ep in entry_points(group="mitsuba") if ep.dist.name == "mitsuba-whitted"]
    assert [(ep.name, ep.value) for ep in found] == [("whitted", "mitsuba_whitted")]
    assert found[0].load() is mitsuba_whitted
