"""The ``whitted`` integrator's settings: how each is read from the scene's
properties and checked, and the one-entry arrays through which
``mi.traverse`` shows and updates them."""

from __future__ import annotations

import mitsuba as mi

from ..errors import VariantError, check
from ..parameters import check_seed, checked_numbers, value_text

PLUGIN_NAME = "whitted"

AA_MODES = ("none", "grid", "adaptive", "contrast")
SHADOW_MODES = ("physical", "tinted")
#: ``max_depth = -1`` means "until pruned"; this cap keeps two facing
#: perfect mirrors from looping forever.
UNBOUNDED_DEPTH = 256
#: Deeper adaptive levels would place samples closer than float32 resolves.
AA_DEPTH_LIMIT = 16
#: Most indirect paths per hit: the Sobol points' 32-bit indices, and far
#: beyond what converges any image.
MAX_INDIRECT_SAMPLES = 1 << 20
#: Most photons of one pass (their Sobol indices are 32-bit; memory is
#: checked before a pass is traced).
MAX_PHOTONS = 1 << 30
#: Most photon passes of one render.
MAX_PHOTON_PASSES = 1 << 20


def _given(props: mi.Properties, name: str, default):
    """The property as given, of whatever type (``Properties.get`` with a
    default refuses another type than the default's with a message of its
    own), or ``default``."""
    return props.get(name) if name in props else default


#: The range of the 32-bit integers the settings are kept in (``mi.Int32``).
INT32_RANGE = (-(1 << 31), (1 << 31) - 1)


def _whole(default: int):
    def read(props: mi.Properties, name: str) -> int:
        given = _given(props, name, default)
        check(not isinstance(given, str), PLUGIN_NAME, name,
              f"must be a whole number (got {value_text(given)})")
        value = checked_numbers(given, PLUGIN_NAME, name)[0]
        check(value == int(value), PLUGIN_NAME, name, f"must be a whole number (got {value:g})")
        low, high = INT32_RANGE
        check(low <= value <= high, PLUGIN_NAME, name,
              f"must be a whole number from {low} to {high} (got {int(value)})")
        return int(value)
    return read


def _real(default: float):
    def read(props: mi.Properties, name: str) -> float:
        return checked_numbers(_given(props, name, default), PLUGIN_NAME, name)[0]
    return read


def _flag(default: bool):
    def read(props: mi.Properties, name: str) -> bool:
        value = _given(props, name, default)
        check(isinstance(value, bool), PLUGIN_NAME, name,
              f"must be true or false (got {value_text(value)})")
        return value
    return read


def _colour(props: mi.Properties, name: str) -> list:
    return checked_numbers(_given(props, name, 0.0), PLUGIN_NAME, name, size=3, broadcast=True)


#: The numeric settings: how each is read from the scene's properties (with
#: its default). ``mi.traverse`` exposes them as one-entry arrays.
SETTINGS = {
    "max_depth": _whole(10),
    "ambient": _colour,
    "emitter_samples": _whole(16),
    "indirect_samples": _whole(0),
    "min_throughput": _real(1e-4),
    "hide_emitters": _flag(False),
    "aa_samples": _whole(2),
    "aa_threshold": _real(0.1),
    "aa_max_depth": _whole(3),
    "aa_budget": _real(64.0),
    "wavefront_size": _whole(1 << 18),
    "photons": _whole(0),
    "photon_passes": _whole(16),
    "photon_radius": _real(0.0),
}


def is_whitted(integrator) -> bool:
    """Whether ``integrator`` is a ``whitted`` (its class is made anew for
    each variant, so it is told by the name it registers under)."""
    return getattr(type(integrator), "plugin_name", None) == PLUGIN_NAME


def read_settings(props: mi.Properties) -> dict:
    """The numeric settings of ``props``, each checked on its own."""
    return {name: read(props, name) for name, read in SETTINGS.items()}


def validate(v: dict) -> None:
    """Refuse settings ``v`` (by name) that make no sense together."""
    check(v["max_depth"] >= -1, PLUGIN_NAME, "max_depth",
          f"must be -1 (unbounded) or >= 0 (got {v['max_depth']})")
    check(v["emitter_samples"] >= 1, PLUGIN_NAME, "emitter_samples",
          f"must be >= 1 (got {v['emitter_samples']})")
    check(0 <= v["indirect_samples"] <= MAX_INDIRECT_SAMPLES, PLUGIN_NAME,
          "indirect_samples", f"must be between 0 and {MAX_INDIRECT_SAMPLES} "
          f"(got {v['indirect_samples']})")
    check(v["min_throughput"] >= 0, PLUGIN_NAME, "min_throughput",
          f"must be >= 0 (got {v['min_throughput']:g})")
    check(v["aa_samples"] >= 1, PLUGIN_NAME, "aa_samples",
          f"must be >= 1 (got {v['aa_samples']})")
    check(v["aa_threshold"] >= 0, PLUGIN_NAME, "aa_threshold",
          f"must be >= 0 (got {v['aa_threshold']:g})")
    check(0 <= v["aa_max_depth"] <= AA_DEPTH_LIMIT, PLUGIN_NAME, "aa_max_depth",
          f"must be between 0 and {AA_DEPTH_LIMIT} (got {v['aa_max_depth']})")
    check(v["aa_budget"] >= 4, PLUGIN_NAME, "aa_budget",
          f"must be >= 4 samples per pixel (got {v['aa_budget']:g})")
    check(v["wavefront_size"] >= 1024, PLUGIN_NAME, "wavefront_size",
          f"must be >= 1024 (got {v['wavefront_size']})")
    check(0 <= v["photons"] <= MAX_PHOTONS, PLUGIN_NAME, "photons",
          f"must be between 0 and {MAX_PHOTONS} (got {v['photons']})")
    check(1 <= v["photon_passes"] <= MAX_PHOTON_PASSES, PLUGIN_NAME, "photon_passes",
          f"must be between 1 and {MAX_PHOTON_PASSES} (got {v['photon_passes']})")
    check(v["photon_radius"] >= 0, PLUGIN_NAME, "photon_radius",
          f"must be >= 0, 0 for the pixel footprint (got {v['photon_radius']:g})")
    check(all(c >= 0 for c in v["ambient"]), PLUGIN_NAME, "ambient",
          f"must not be negative (got {list(v['ambient'])})")


class Exposed:
    """The settings as the one-entry arrays ``mi.traverse`` hands out, which
    an update writes into. Kept out of the integrator's ``__dict__``, which
    Dr.Jit traverses for the inputs of every frozen launch."""

    __slots__ = ("arrays",)

    def __init__(self, values: dict):
        self.arrays = {name: _as_array(value) for name, value in values.items()}

    def values(self) -> dict:
        """The settings as Python values (``ambient`` an RGB colour)."""
        return {name: _as_value(array) for name, array in self.arrays.items()}


def _as_array(value):
    if isinstance(value, bool):
        return mi.Bool(value)
    if isinstance(value, int):
        return mi.Int32(value)
    if isinstance(value, float):
        return mi.Float(value)
    return mi.Color3f(*value)


def _as_value(array):
    if isinstance(array, mi.Color3f):
        return mi.ScalarColor3f(array.numpy().ravel().tolist())
    convert = {mi.Bool: bool, mi.Int32: int, mi.Float: float}[type(array)]
    return convert(array.numpy().ravel()[0])


def seed_value(seed) -> int:
    """A render seed as a Python number (:func:`.parameters.check_seed`)."""
    return check_seed(seed, PLUGIN_NAME)


def require_supported_variant():
    variant = mi.variant()
    if variant.startswith("scalar"):
        raise VariantError(
            "the wavefront integrator needs a JIT variant such as 'llvm_ad_rgb' or "
            f"'cuda_ad_rgb' (the active variant is '{variant}').", PLUGIN_NAME)
    if not variant.endswith("_rgb"):
        raise VariantError(
            f"only RGB variants are supported (the active variant is '{variant}'); use "
            "'llvm_ad_rgb' or 'cuda_ad_rgb'.", PLUGIN_NAME)
