"""Shared fixtures: every test runs in the JIT variant the package targets."""

import pytest

import mitsuba_whitted

VARIANT = mitsuba_whitted.DEFAULT_VARIANT
# Set at import so test modules can build Mitsuba values at module level.
mitsuba_whitted.set_variant(VARIANT)


@pytest.fixture(autouse=True, scope="session")
def variant():
    mitsuba_whitted.set_variant(VARIANT)
    return VARIANT


def assert_finite(image) -> None:
    """Every rendered image of the suite must be free of NaN and Inf."""
    values = image.numpy() if hasattr(image, "numpy") else image
    import numpy as np
    assert np.isfinite(values).all(), f"{np.size(values) - np.isfinite(values).sum()} non-finite values"


def address(array) -> int:
    """Where a flat LLVM array's memory is (NumPy views it without a copy)."""
    import numpy as np
    return np.from_dlpack(array).ctypes.data
