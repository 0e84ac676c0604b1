"""Dr.Jit helpers against numpy."""

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from mitsuba_whitted.jit import sum_blocks


@pytest.mark.parametrize("block", [1, 4, 64, 1024])
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
