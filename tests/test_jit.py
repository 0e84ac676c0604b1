"""Dr.Jit helpers against numpy."""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from conftest import address
from mitsuba_whitted.jit import ALIGNMENT, device_array, sum_blocks


@pytest.mark.parametrize("block", [1, 4, 16, 17, 64, 1024])
def test_sum_blocks_matches_numpy_and_repeats_exactly(block):
    values = np.random.default_rng(block).uniform(size=3 * block * 50).astype(np.float32)
    colours = mi.Color3f(mi.Float(values[0::3]), mi.Float(values[1::3]), 0.5)
    first, second = sum_blocks(colours, block), sum_blocks(colours, block)
    expected = np.stack([values[0::3], values[1::3], np.full(block * 50, 0.5, np.float32)])
    expected = expected.astype(np.float64).reshape(3, -1, block).sum(axis=2)
    np.testing.assert_allclose(np.array(first), expected, rtol=1e-5)
    assert np.array_equal(np.array(first), np.array(second))


def test_sum_blocks_of_integers_is_exact():
    counts = dr.arange(mi.UInt32, 12)
    assert list(sum_blocks(counts, 4)) == [6, 22, 38]


@pytest.mark.parametrize("array_type, dtype", [(mi.Float, np.float32), (mi.UInt32, np.uint32),
                                               (mi.Float64, np.float64), (mi.Bool, np.bool_)])
@pytest.mark.parametrize("layout", ["offset", "strided", "float64", "matrix"])
def test_device_array_is_aligned_owned_and_holds_the_values(array_type, dtype, layout):
    base = np.arange(1, 2 * 3 * 97 + 2) % 7
    values = {"offset": base.astype(dtype)[1:],       # one element past an allocation
              "strided": base.astype(dtype)[::2],
              "float64": base.astype(np.float64),
              "matrix": base[:582].astype(dtype).reshape(97, 6)[:, ::-1]}[layout]
    expected = np.ravel(values).astype(dtype)
    result = device_array(array_type, values)
    values[...] = 0                                   # the result is a copy
    assert address(result) % ALIGNMENT == 0
    np.testing.assert_array_equal(np.array(result), expected)


def test_a_plain_conversion_of_an_offset_view_is_unaligned():
    """What device_array exists for: Dr.Jit maps an offset NumPy view as it
    is, so its kernels would see an unaligned buffer."""
    view = np.arange(65, dtype=np.float32)[1:]
    assert address(mi.Float(view)) == view.ctypes.data
    assert address(mi.Float(view)) % ALIGNMENT != 0
