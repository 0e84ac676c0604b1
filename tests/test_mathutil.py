"""Shared maths helpers against exact arithmetic (``fractions``, ``decimal``)
and numpy float64."""

from decimal import Decimal, getcontext
from fractions import Fraction

import mitsuba as mi
import numpy as np
import pytest

from mitsuba_whitted.mathutil import (difference_of_products, hammersley, inverse_condition,
                                      invert_affine_f64, solve_quadratic)

FLOAT32_ULP = 2.0 ** -23  # spacing of float32 numbers in [1, 2)


def exact_roots(a, half_b, c):
    """Roots of a t^2 + 2 half_b t + c with 60 significant digits."""
    getcontext().prec = 60
    a, half_b, c = (Decimal(float(v)) for v in (a, half_b, c))
    root = (half_b * half_b - a * c).sqrt()
    return sorted([float((-half_b - root) / a), float((-half_b + root) / a)])


def f32(values):
    return np.asarray(values, dtype=np.float32)


def test_difference_of_products_is_exact_to_two_ulp():
    # Products that agree in most of their digits: the naive a*b - c*d keeps
    # only the rounding noise of the products.
    rng = np.random.default_rng(3)
    a, b = f32(rng.uniform(1, 2, 1000)), f32(rng.uniform(1, 2, 1000))
    c = f32(a * (1 + rng.uniform(-1e-6, 1e-6, 1000)))
    d = b
    got = difference_of_products(*(mi.Float(v) for v in (a, b, c, d))).numpy()
    exact = np.array([float(Fraction(float(p)) * Fraction(float(q)) - Fraction(float(r)) * Fraction(float(s)))
                      for p, q, r, s in zip(a, b, c, d)])
    ulp = np.spacing(np.abs(exact).astype(np.float32)).astype(np.float64)
    # Jeannerod, Louvet & Muller (2013): Kahan's algorithm is within 2 ulp.
    assert np.all(np.abs(got - exact) <= 2 * ulp), np.max(np.abs(got - exact) / ulp)
    naive = (a * b - c * d).astype(np.float64)
    assert np.max(np.abs(naive - exact) / ulp) > 100, "test data should defeat the naive formula"


@pytest.mark.parametrize("small, large", [(3e-5, 7e4), (-2e-6, 5e3), (1e-3, -9e5)])
def test_quadratic_keeps_both_roots_when_one_is_tiny(small, large):
    # t^2 - (small + large) t + small*large: half_b^2 >> a c, so the textbook
    # formula subtracts two nearly equal numbers for the small root.
    a, half_b, c = f32([1.0, -(small + large) / 2, small * large])
    valid, t_near, t_far = solve_quadratic(mi.Float(a), mi.Float(half_b), mi.Float(c))
    expected = exact_roots(a, half_b, c)
    got = [t_near.numpy()[0], t_far.numpy()[0]]
    assert valid.numpy()[0]
    # A handful of float32 roundings (coefficients are exact inputs here).
    assert np.allclose(got, expected, rtol=4 * FLOAT32_ULP, atol=0), (got, expected)

    root = np.sqrt(np.float32(half_b * half_b - a * c))
    naive = [(-half_b - root) / a, (-half_b + root) / a]
    naive_small = naive[int(np.argmin(np.abs(naive)))]
    small_expected = expected[int(np.argmin(np.abs(expected)))]
    assert abs(naive_small - small_expected) > 0.01 * abs(small_expected), \
        "the coefficients should defeat the textbook formula"


def test_quadratic_random_coefficients_against_exact_roots():
    rng = np.random.default_rng(7)
    n = 2000
    r1 = rng.choice([-1, 1], n) * 10.0 ** rng.uniform(-4, 4, n)
    r2 = rng.choice([-1, 1], n) * 10.0 ** rng.uniform(-4, 4, n)
    a = f32(10.0 ** rng.uniform(-3, 3, n))
    half_b, c = f32(-a * (r1 + r2) / 2), f32(a * r1 * r2)
    valid, t_near, t_far = solve_quadratic(mi.Float(a), mi.Float(half_b), mi.Float(c))
    expected = np.array([exact_roots(*coeffs) for coeffs in zip(a, half_b, c)])
    got = np.stack([t_near.numpy(), t_far.numpy()], 1)
    assert valid.numpy().all()
    # Rounding c and half_b to float32 moves the exact roots by a few ulp;
    # the solver itself adds a few more (sqrt, q, two divisions).
    relative = np.abs(got - expected) / np.abs(expected)
    assert relative.max() < 8 * FLOAT32_ULP, relative.max()


def test_quadratic_degenerate_cases_are_finite():
    a, half_b, c = (mi.Float(v) for v in ([1, 1, 0, 0, 1], [0, 0, 2, 0, 0], [1, 0, -4, 1, -4]))
    valid, t_near, t_far = solve_quadratic(a, half_b, c)
    # t^2 + 1: no root; t^2: double root 0; 4t - 4: linear root 1;
    # 1 = 0: nothing; t^2 - 4: +-2.
    assert valid.numpy().tolist() == [False, True, True, False, True]
    assert t_near.numpy()[[1, 2, 4]].tolist() == [0, 1, -2]
    assert t_far.numpy()[[1, 2, 4]].tolist() == [0, 1, 2]


def test_quadratic_uses_a_given_discriminant():
    # A discriminant supplied by the caller replaces the internal one.
    valid, t_near, t_far = solve_quadratic(mi.Float(1), mi.Float(0), mi.Float(-1), mi.Float(4))
    assert valid.numpy()[0] and t_near.numpy()[0] == -2 and t_far.numpy()[0] == 0.5


def test_quadratic_works_in_float64():
    a, half_b, c = 1.0, -(1e-9 + 1e9) / 2, 1.0
    valid, t_near, t_far = solve_quadratic(mi.Float64(a), mi.Float64(half_b), mi.Float64(c))
    expected = exact_roots(a, half_b, c)
    assert np.allclose([t_near.numpy()[0], t_far.numpy()[0]], expected, rtol=1e-15, atol=0)


def test_inverse_condition_against_known_singular_values():
    rotation = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))[0]
    assert inverse_condition(rotation * 7) == pytest.approx(1)
    # R . diag(s): singular values are s, whatever the rotation.
    assert inverse_condition(rotation @ np.diag([1e-3, 1, 1e3])) == pytest.approx(1e-6)
    assert inverse_condition([[1, 2, 3], [2, 4, 6], [0, 0, 1]]) < 1e-15
    assert inverse_condition(np.zeros((3, 3))) == 0
    assert inverse_condition(np.full((3, 3), np.nan)) == 0


def test_invert_affine_f64():
    rng = np.random.default_rng(2)
    m = np.eye(4)
    m[:3, :3] = rng.normal(size=(3, 3)) * [1e-3, 1, 1e3]
    m[:3, 3] = [1e6, -2e6, 3e6]  # large translations are not singularity
    inverse = invert_affine_f64(m)
    assert np.allclose(inverse, np.linalg.inv(m), rtol=1e-10, atol=1e-12)
    assert np.allclose(inverse @ m, np.eye(4), atol=1e-9)
    assert np.array_equal(inverse[3], [0, 0, 0, 1])


def test_invert_affine_f64_rejects_bad_matrices():
    singular = np.diag([1.0, 1.0, 0.0, 1.0])
    with pytest.raises(np.linalg.LinAlgError):
        invert_affine_f64(singular)
    projective = np.eye(4)
    projective[3, 2] = 1
    with pytest.raises(ValueError):
        invert_affine_f64(projective)


@pytest.mark.parametrize("m", [0, 1, 4, 6, 8])
def test_hammersley_is_a_net_in_base_two(m):
    """2^m points: every dyadic box of area 2^-m (any split 2^a x 2^(m-a))
    holds exactly one point, the (0, m, 2)-net property."""
    points = hammersley(1 << m)
    assert points.shape == (1 << m, 2)
    assert ((points > 0) & (points < 1)).all()
    for a in range(m + 1):
        columns = np.floor(points[:, 0] * (1 << a)).astype(int)
        rows = np.floor(points[:, 1] * (1 << (m - a))).astype(int)
        boxes = columns * (1 << (m - a)) + rows
        assert np.array_equal(np.sort(boxes), np.arange(1 << m))


def test_hammersley_of_any_count_has_one_point_per_column():
    points = hammersley(100)
    assert np.array_equal(np.sort(np.floor(points[:, 0] * 100).astype(int)), np.arange(100))
    assert len(np.unique(points[:, 1])) == 100
