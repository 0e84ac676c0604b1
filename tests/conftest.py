"""Shared fixtures: every test runs in the JIT variant the package targets.
Also the helpers of the tests that run the command line as a user would."""

import re
import subprocess
import sys

import numpy as np
import pytest

import mitsuba_whitted
from validation.scenes import ROOT

VARIANT = mitsuba_whitted.DEFAULT_VARIANT
# Set at import so test modules can build Mitsuba values at module level.
mitsuba_whitted.set_variant(VARIANT)


@pytest.fixture(autouse=True, scope="session")
def variant():
    mitsuba_whitted.set_variant(VARIANT)
    return VARIANT


#: RGB to CIE XYZ for the sRGB primaries and D65 white (IEC 61966-2-1, to
#: six digits, as Mitsuba's colour conversion takes it); its middle row is
#: luminance.
SRGB_TO_XYZ = np.array([[0.412453, 0.357580, 0.180423],
                        [0.212671, 0.715160, 0.072169],
                        [0.019334, 0.119193, 0.950227]])


def assert_finite(image) -> None:
    """Every rendered image of the suite must be free of NaN and Inf."""
    values = image.numpy() if hasattr(image, "numpy") else image
    assert np.isfinite(values).all(), f"{np.size(values) - np.isfinite(values).sum()} non-finite values"


def read_only(image: np.ndarray) -> np.ndarray:
    """``image``, made read-only: an image rendered once and shared by
    several tests, none of which may change it for the others."""
    image.flags.writeable = False
    return image


def address(array) -> int:
    """Where a flat LLVM array's memory is (NumPy views it without a copy)."""
    return np.from_dlpack(array).ctypes.data


def cli(*args, env=None, check=False, timeout=600, module="mitsuba_whitted.cli",
        preexec_fn=None):
    """``mitsuba-whitted *args`` (or ``python -m module *args``) in a
    process of its own, started in the repository's root (``preexec_fn``
    runs in it first, as for ``subprocess.run``); its output as text, bytes
    that are not UTF-8 as Python decodes file names."""
    return subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT,
                          env=env, capture_output=True, text=True, check=check,
                          timeout=timeout, preexec_fn=preexec_fn, errors="surrogateescape")


def one_line(stderr: str) -> str:
    """The single line of ``stderr``, which must name its cause: no
    traceback, no colour codes, no pointer elsewhere, no C++ source
    location, no empty reason after a colon."""
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    line = lines[0]
    for noise in ("Traceback", "\x1b[", "(see above)", "drjit.custom"):
        assert noise not in line, line
    assert not re.search(r"\[\w+\.cpp:\d+\]", line), line
    assert not line.rstrip(".").endswith(":"), line
    return line



def limit_whitted(monkeypatch, **limits) -> None:
    """Every ``whitted`` made until the test ends plans its renders with
    these :class:`~mitsuba_whitted.integrators.render_plan.Limits` (a
    ``band_samples`` that cuts a small film into bands, a ``memory``)."""
    import mitsuba as mi

    from mitsuba_whitted.integrators.render_plan import Limits

    whitted = type(mi.load_dict({"type": "whitted"}))
    monkeypatch.setattr(whitted, "limits", Limits(**limits))
