"""The numerical-stability table (validation/stability/) on its quick
subset: every hard case must stay within its stated bound, and the
comparisons must be able to fail."""

import math
import re

import numpy as np
import pytest

from conftest import read_only
from validation.stability import acne, cylinder, glass, run_stability, stability_markdown
from validation.stability.common import SEED

#: Cases that fail today, for reasons outside this table's code (see the
#: case docstrings); strict, so a fix shows up as an unexpected pass.
CASE_NAMES = [
    "cylinder: parallel to the axis", "cylinder: grazing the side",
    "cylinder: in the cap plane y = 0", "cylinder: in the cap plane y = 1",
    "cylinder: through the rim", "cylinder: from inside", "cylinder: from 1e4 away",
    "cylinder: scene scale 1000", "cylinder: scene scale 0.001",
    "sphere: tangent rays", "glass: total internal reflection",
    "glass: Fresnel near the critical angle", "sphere_map asin: poles and seams",
    "sphere_map atan: poles and seams", "sphere_map equirect: poles and seams",
    "tartan: coordinates 1e6 to 1e15", "acne: glass and diffuse at scale 0.001",
    "acne: glass and diffuse at scale 1000", "shadow acne: lit plane, grazing light",
]


@pytest.fixture(scope="module")
def results():
    return {result.name: result for result in run_stability(quick=True)}


def test_every_case_ran(results):
    assert list(results) == CASE_NAMES
    assert len(results) >= 12


@pytest.mark.parametrize("name", CASE_NAMES)
def test_case_within_its_bound(results, name):
    result = results[name]
    assert result.nonfinite == 0, f"{result.nonfinite} NaN/Inf"
    assert result.disagreements == 0, f"{result.disagreements} disagreements outside the band"
    assert result.worst_error <= result.bound, f"{result.worst_error:g} > {result.bound:g} {result.unit}"
    assert result.passed, result.details


def test_markdown_has_one_row_per_case(results):
    table = stability_markdown(list(results.values()))
    rows = [line for line in table.splitlines() if line.startswith("| ") and "---" not in line]
    assert len(rows) == 1 + len(results)          # header + cases
    for name in results:
        assert sum(row.startswith(f"| {name} |") for row in rows) == 1
    for row in rows[1:]:
        assert not re.search(r"\b(nan|inf)\b", row, re.IGNORECASE), row


def naive_float32_cylinder(o, d):
    """The report's textbook side quadratic in float32 (b^2 - 4ac, no
    care), with the caps: a deliberately fragile implementation."""
    o, d = o.astype(np.float32), d.astype(np.float32)
    a = d[:, 0] ** 2 + d[:, 2] ** 2
    b = 2 * (o[:, 0] * d[:, 0] + o[:, 2] * d[:, 2])
    c = o[:, 0] ** 2 + o[:, 2] ** 2 - np.float32(1)
    disc = b * b - 4 * a * c
    with np.errstate(all="ignore"):
        t_side = (-b - np.sqrt(disc)) / (2 * a)
        y = o[:, 1] + t_side * d[:, 1]
        side = (disc >= 0) & (t_side > 0) & (y >= 0) & (y <= 1)
        t_cap = np.where(d[:, 1] > 0, -o[:, 1], 1 - o[:, 1]) / d[:, 1]
        p = o + t_cap[:, None] * d
        cap = (t_cap > 0) & (p[:, 0] ** 2 + p[:, 2] ** 2 <= 1)
    t = np.where(side & (~cap | (t_side < t_cap)), t_side, np.where(cap, t_cap, np.inf))
    hit = side | cap
    point = o + np.where(hit, t, 0)[:, None] * d
    n = np.where((side & (t == t_side))[:, None], point * np.array([1, 0, 1], np.float32),
                 np.c_[np.zeros(len(o)), np.where(d[:, 1] > 0, -1, 1), np.zeros(len(o))])
    return hit, t.astype(np.float64), n.astype(np.float64)


def test_cylinder_comparison_fails_a_naive_float32_solve():
    """The far-away case's comparison, fed the textbook float32 quadratic:
    its discriminant cancels from 1e4 away, so it must fail the bound."""
    o, d = cylinder.far_bundle(1024, np.random.default_rng(SEED), 1e4)
    scene = cylinder.cylinder_scene()
    ref = cylinder.cylinder_reference(scene, o, d)
    hit, t, n = naive_float32_cylinder(o, d)
    result = cylinder.judge_cylinder("naive", "float32 quadratic", ref, hit, t, n,
                                     proxy=np.ones(len(o), bool))
    assert not result.passed
    assert result.worst_error > 100 * result.bound or result.disagreements > 0
    # The same comparison passes the integrator's own exact path on these rays.
    good = cylinder.judge_cylinder("exact", "", ref, *cylinder.exact_cylinder_hits(scene, o, d))
    assert good.passed


def test_fresnel_comparison_fails_a_wrong_formula():
    """Schlick's approximation in place of the exact Fresnel equations must
    fail the per-ray allowance near the critical angle."""
    theta = math.asin(1 / glass.IOR) - np.logspace(-6, -1, 200)
    cos_i = np.cos(theta).astype(np.float32).astype(np.float64)
    # Schlick for light leaving the denser medium uses the transmitted cosine.
    cos_t = np.sqrt(1 - (glass.IOR * np.sin(theta)) ** 2)
    r0 = ((glass.IOR - 1) / (glass.IOR + 1)) ** 2
    schlick = r0 + (1 - r0) * (1 - cos_t) ** 5
    worst, _ = glass.judge_fresnel(cos_i, schlick, (1 - schlick) * glass.IOR ** 2)
    assert worst > 1


#: The report's image size (its pixels per side).
REPORT_SIZE = 96


@pytest.fixture(scope="module")
def unscaled_at_report_size():
    """The scale-1 glass scene at the report's size: every scale's case
    compares with this same image, so it is rendered once."""
    return read_only(acne.render(acne.scaled_glass_scene(1.0, REPORT_SIZE)))


@pytest.mark.parametrize("scale", [1e-3, 1e3])
def test_acne_case_at_the_report_size(unscaled_at_report_size, scale):
    """At the report's image size (96^2) rays bouncing inside the glass
    cylinder reach edges that the quick subset's pixels miss: the scaled
    image must still match the scale-1 one rendered with offsets of the
    same relative size."""
    result = acne.acne_at_scale(REPORT_SIZE, scale, unscaled_at_report_size)
    assert result.disagreements == 0 and result.passed, result.details
