"""Whitted against Mitsuba's path tracer where both models coincide: the
equivalence suite of ``validation/equivalence.py``, the very cases of the
validation report's section 1, with fewer path samples per ray.

Oracle: Mitsuba's own ``path`` integrator, run on exactly the pixel-centre
rays Whitted traces. The statistical test (``compare.equivalence_test``)
has a family-wise false-alarm rate of 1e-3 per scene; the broken cases show
that it does reject scenes where Whitted is known to be wrong.
"""

import numpy as np
import pytest

from mitsuba_whitted.compare import ReferenceCache
from validation.equivalence import equivalence_cases, run_equivalence

BATCHES, SPP = 32, 32
CASES = {case.name: case for case in equivalence_cases()}


@pytest.mark.parametrize("name", CASES)
def test_whitted_and_path_agree_exactly_where_expected(name):
    case = CASES[name]
    result = run_equivalence(case, BATCHES, SPP)
    assert np.isfinite(result.whitted).all()
    # The scene must actually show something, or agreement means nothing.
    assert result.path.max() > 0.05
    assert result.passed == case.expect_agree, result.summary()
    # Under equivalence t^2 averages about 1 (below 1 where path is
    # noiseless); a broken case differs by far more than the noise.
    if case.expect_agree:
        assert result.noise_multiple < 1.5, result.noise_multiple
    else:
        assert result.noise_multiple > 20, result.noise_multiple


def test_cases_that_share_a_path_scene_share_its_cached_batches(tmp_path):
    """The broken glass compares against the right glass's path batches:
    one reference, rendered once, from the cache the second time."""
    cache = ReferenceCache(tmp_path)
    right = run_equivalence(CASES["Fresnel glass"], BATCHES, SPP, cache)
    wrong = run_equivalence(CASES["broken: glass reflecting 50%"], BATCHES, SPP, cache)
    assert (cache.hits, cache.misses) == (1, 1)
    np.testing.assert_array_equal(right.path, wrong.path)
    assert len(list(tmp_path.glob("*.npz"))) == 1
