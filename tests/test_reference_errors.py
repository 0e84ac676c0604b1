"""Where Mitsuba's own answer is wrong (validation report, section 5).

Each test checks that Mitsuba is still wrong in the way the report
describes, against a closed form or a float64 reference, and that this
package gets that value. A Mitsuba that fixes a case makes its test fail
with a message saying so: the case then leaves that section and can join
the equivalence tests.
"""

import mitsuba as mi
import numpy as np
import pytest

from validation import reference_errors
from validation.equivalence import BLEND_DIFFUSE, BLEND_WEIGHT
from validation.reference_errors import BLACK, MIRROR_WEIGHT
from validation.stability.cylinder import CYLINDER_T_BOUND


def fixed(what: str) -> str:
    return (f"Mitsuba {mi.__version__} now gets {what} right: remove the case from 'Where the "
            "reference is wrong' (validation/run.py, tests/test_reference_errors.py) and "
            "compare Whitted with it in the equivalence tests instead.")


@pytest.mark.parametrize("diffuse, weight", [(BLACK, MIRROR_WEIGHT), (BLEND_DIFFUSE, BLEND_WEIGHT)],
                         ids=["black diffuse and mirror", "the equivalence case's blend"])
def test_blendbsdf_darkens_its_delta_lobe(diffuse, weight):
    """Path's mean on parallel rays at incidence 0.75 is the closed form of
    what ``BlendBSDF::sample`` does (within 5 standard errors), not the
    true value."""
    (row,) = reference_errors.blend_delta_lobe(diffuse, weight, cosines=(0.75,))
    tolerance = 5 * row.path_error
    if np.all(np.abs(row.path - row.true) <= tolerance):
        pytest.fail(fixed("blendbsdf's delta lobe"))
    assert np.all(np.abs(row.path - row.mitsuba) <= tolerance), (row.path, row.mitsuba)
    assert np.all(row.true - row.mitsuba > 20 * row.path_error)


def test_whitted_renders_the_blend_of_a_black_diffuse_and_a_mirror_exactly():
    rows = reference_errors.blend_delta_lobe(cosines=(1.0, 0.2))
    assert all(row.whitted_error <= 1e-7 for row in rows)


def test_mitsuba_cylinder_is_never_hit_from_1e4_radii():
    row = reference_errors.cylinder_far_away(1e4, rays=1024)
    if row.mitsuba_hits > 0:
        pytest.fail(fixed("its cylinder seen from 1e4 radii away"))
    assert row.reference_hits > 300 and row.mitsuba_disagreements == row.reference_hits
    # The capped cylinder: every hit, t within 4 float32 ulp of 1e4.
    assert row.capped_disagreements == 0
    assert row.capped_t <= CYLINDER_T_BOUND * 1.01e4


def test_mitsuba_cylinder_drifts_from_1e3_radii():
    row = reference_errors.cylinder_far_away(1e3, rays=1024)
    if row.mitsuba_t < 1e-3:
        pytest.fail(fixed("its cylinder seen from 1e3 radii away"))
    assert row.mitsuba_t > 0.01
    assert row.capped_disagreements == 0
    assert row.capped_t <= CYLINDER_T_BOUND * 1.01e3


def test_mitsuba_cylinder_under_a_rotation_about_a_non_unit_axis_is_another_solid():
    row = reference_errors.cylinder_rotated(rays=1024)
    if row.mitsuba_disagreements == 0:
        pytest.fail(fixed("its cylinder under a rotation about a non-unit axis"))
    assert row.mitsuba_disagreements > 0.2 * row.reference_hits
    assert row.capped_disagreements == 0 and row.capped_t < 1e-5


def test_path_loses_a_point_light_behind_surfaces_that_let_it_through():
    """At the centre of each ball's shadow Whitted's physical shadows give
    the closed form; path gives nothing behind any of them."""
    shares = reference_errors.pass_through_shares(
        {"path": mi.load_dict({"type": "path", "max_depth": 2}),
         "whitted": mi.load_dict({"type": "whitted", "max_depth": 2})})
    expected = [share for _, share in reference_errors.PASS_THROUGH.values()]
    path, _ = shares["path"]
    if np.any(path > 0.5 * np.array(expected)):
        pytest.fail(fixed("point lights behind null, mask, thin or index-matched surfaces "
                          "in its path integrator"))
    assert np.all(path == 0)
    np.testing.assert_allclose(shares["whitted"][0], expected, rtol=1e-5)
