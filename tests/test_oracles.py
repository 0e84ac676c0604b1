"""The float64 and long-double oracles (``validation/oracles/``) against
closed forms and against 50-digit decimal arithmetic written with another
method.

The oracles judge float32 results against bounds of 4 float32 ulp (4.8e-7
relative) and up; ``ORACLE_T`` asks for 1e-9, 480 times less, so that an
oracle's own error never moves a verdict.
"""

from __future__ import annotations

import math
from decimal import Decimal, localcontext

import numpy as np
import pytest

from validation.oracles import cylinder, fresnel, sphere

ORACLE_T = 1e-9
#: Decimal digits of the independent solutions: far beyond long double's 19.
DIGITS = 50
SIDE, BOTTOM, TOP = cylinder.PART_SIDE, cylinder.PART_BOTTOM, cylinder.PART_TOP


def decimals(*values):
    """Exact decimal copies of float64 values."""
    return [Decimal(float(v)) for v in values]


# ------------------------------------------------------------------ cylinder

def decimal_cylinder(o, d, t_min=0.0):
    """First hit (t, part) of the ray on the canonical capped cylinder in
    50-digit arithmetic, or None. The side is solved around the line's
    closest approach to the axis (foot parameter and half chord), not with
    the quadratic formula; a tie between side and cap goes to the side."""
    with localcontext() as context:
        context.prec = DIGITS
        ox, oy, oz, dx, dy, dz = decimals(*o, *d)
        found = []
        a = dx * dx + dz * dz
        if a > 0:
            foot = -(ox * dx + oz * dz) / a
            squared_distance = (ox + foot * dx) ** 2 + (oz + foot * dz) ** 2
            if squared_distance <= 1:
                half = ((1 - squared_distance) / a).sqrt()
                found += [(t, SIDE) for t in (foot - half, foot + half) if 0 <= oy + t * dy <= 1]
        if dy != 0:
            for height, part in ((0, BOTTOM), (1, TOP)):
                t = (height - oy) / dy
                if (ox + t * dx) ** 2 + (oz + t * dz) ** 2 <= 1:
                    found.append((t, part))
        found = [hit for hit in found if hit[0] > Decimal(float(t_min))]
        return min(found) if found else None


def random_rays(rng, count, distance):
    """Origins ``distance`` from the solid's centre (or inside it, for
    distance 0), aimed at random points of a box around the solid; direction
    lengths from 1e-2 to 1e2."""
    if distance == 0:
        angle = rng.uniform(0, 2 * np.pi, count)
        radius = np.sqrt(rng.uniform(0, 1, count))
        o = np.c_[radius * np.cos(angle), rng.uniform(0, 1, count), radius * np.sin(angle)]
    else:
        direction = rng.normal(size=(count, 3))
        o = [0, 0.5, 0] + distance * direction / np.linalg.norm(direction, axis=1, keepdims=True)
    d = rng.uniform([-1.3, -0.3, -1.3], [1.3, 1.3, 1.3], (count, 3)) - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o, d * 10.0 ** rng.uniform(-2, 2, (count, 1))


@pytest.mark.parametrize("distance", [0.0, 3.0, 1e3, 1e6])
def test_cylinder_oracle_matches_50_digit_solutions(distance):
    o, d = random_rays(np.random.default_rng(7), 400, distance)
    ref = cylinder.intersect(o, d, 0.0)
    band = 1e-12 * (1 + np.abs(o).max(axis=1))
    exact = [decimal_cylinder(o[i], d[i]) for i in range(len(o))]
    hit = np.array([e is not None for e in exact])
    assert hit.sum() > 100
    assert np.all((hit == ref["hit"]) | (ref["margin"] < band))
    both = np.flatnonzero(hit & ref["hit"])
    t = np.array([float(exact[i][0]) for i in both])
    np.testing.assert_allclose(ref["t"][both], t, rtol=ORACLE_T, atol=0)
    assert [exact[i][1] for i in both] == list(ref["part"][both])
    point = o[both] + t[:, None] * d[both]
    np.testing.assert_allclose(ref["p"][both], point, rtol=0, atol=ORACLE_T * (1 + distance))
    radial = point * [1, 0, 1]
    normal = np.where((ref["part"][both] == SIDE)[:, None], radial, [0, 1, 0])
    normal[ref["part"][both] == BOTTOM] = [0, -1, 0]
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    np.testing.assert_allclose(ref["n"][both], normal, rtol=0, atol=ORACLE_T * (1 + distance))


def test_cylinder_oracle_near_tangency_from_far_away():
    """Lines 1e4 away passing the axis at 1 - delta: the textbook
    discriminant cancels most digits there, yet t = 1e4 - sqrt(1 - x^2)
    holds to ORACLE_T; closer than the band, a miss is excused."""
    x = 1 - 10.0 ** -np.arange(3, 15)
    o = np.c_[x, np.full_like(x, 0.5), np.full_like(x, -1e4)]
    ref = cylinder.intersect(o, np.tile([0.0, 0, 1], (len(x), 1)), 0.0)
    band = 1e-12 * (1 + 1e4)
    assert np.all(ref["hit"] | (ref["margin"] < band))
    assert ref["hit"][:6].all()
    expected = 1e4 - np.sqrt((1 - x) * (1 + x))
    np.testing.assert_allclose(ref["t"][ref["hit"]], expected[ref["hit"]], rtol=ORACLE_T, atol=0)


@pytest.mark.parametrize("o, d, t_min, t, part, normal", [
    ((0, 0.5, -5), (0, 0, 1), 0, 4, SIDE, (0, 0, -1)),
    ((0, 0.5, -5), (0, 0, 2), 0, 2, SIDE, (0, 0, -1)),          # t in units of |d|
    ((0, 0.5, -5), (0, 0, 1), 4.5, 6, SIDE, (0, 0, 1)),         # past t_min: the exit
    ((0.3, -2, 0.4), (0, 1, 0), 0, 2, BOTTOM, (0, -1, 0)),
    ((0.3, 3, 0.4), (0, -1, 0), 0, 2, TOP, (0, 1, 0)),
    ((0, 0.5, 0), (1, 0, 0), 0, 1, SIDE, (1, 0, 0)),            # from inside
    ((0, 1, -5), (0, 0, 1), 0, 4, SIDE, (0, 0, -1)),            # in the top cap's plane
    ((0, 2, -2), (0, -1, 1), 0, 1, SIDE, (0, 0, -1)),           # at the rim: side wins
])
def test_cylinder_oracle_on_closed_form_rays(o, d, t_min, t, part, normal):
    ref = cylinder.intersect(np.array([o], float), np.array([d], float), t_min)
    assert ref["hit"][0] and ref["part"][0] == part
    assert ref["t"][0] == pytest.approx(t, rel=1e-15)
    np.testing.assert_allclose(ref["n"][0], normal, atol=1e-15)


def test_cylinder_oracle_misses_and_respects_t_max():
    o = np.array([[2, 0.5, -5], [0, 0.5, -5], [0, 1.5, -5]], float)
    d = np.array([[0, 0, 1], [0, 0, 1], [0, 0, 1]], float)
    ref = cylinder.intersect(o, d, 0.0, np.array([np.inf, 3.0, np.inf]))
    assert not ref["hit"].any() and np.all(ref["t"] == np.inf)


def test_cylinder_margin_is_the_distance_from_tangency():
    """Horizontal lines at mid-height, 1 + delta from the axis: hit exactly
    when delta < 0, and the margin is |delta|."""
    x = 1 + np.array([-1e-3, -1e-6, -1e-9, 1e-9, 1e-6, 1e-3, 0.0])
    delta = x - 1                       # exact: Sterbenz
    o = np.c_[x, np.full_like(x, 0.5), np.full_like(x, -5)]
    ref = cylinder.intersect(o, np.tile([0.0, 0, 1], (len(x), 1)), 0.0)
    np.testing.assert_array_equal(ref["hit"], delta <= 0)
    np.testing.assert_allclose(ref["margin"], np.abs(delta), rtol=1e-9, atol=1e-18)


def test_placed_cylinder_maps_rays_in_and_normals_out():
    """The solid stretched to an elliptic cylinder by (2, 3, 1) and moved
    by (1, -1, 4): at the canonical point (c, 1/2, c), c = 1/sqrt(2), the
    normal is the inverse transpose's image of (c, 0, c): (1, 0, 2) / sqrt 5.
    A ray 5 away along it, coming back, meets the surface there at t = 5."""
    to_world = np.diag([2.0, 3.0, 1.0, 1.0])
    to_world[:3, 3] = [1, -1, 4]
    c = math.sqrt(0.5)
    point = (to_world @ [c, 0.5, c, 1])[:3]
    normal = np.array([1.0, 0, 2]) / math.sqrt(5)
    ref = cylinder.intersect_placed(np.linalg.inv(to_world), [point + 5 * normal], [-normal])
    assert ref["hit"][0] and ref["part"][0] == SIDE
    assert ref["t"][0] == pytest.approx(5, rel=1e-14)
    np.testing.assert_allclose(ref["n_world"][0], normal, atol=1e-14)


# -------------------------------------------------------------------- sphere

def decimal_sphere(o, d, center, radius):
    """The textbook quadratic |o + t d - c|^2 = r^2 in 50 digits: its
    smaller root where it is real and ahead, and |rho / r - 1| with rho the
    line's distance from the centre."""
    with localcontext() as context:
        context.prec = DIGITS
        o, d, c = decimals(*o), decimals(*d), decimals(*center)
        r = Decimal(float(radius))
        oc = [oi - ci for oi, ci in zip(o, c)]
        a = sum(x * x for x in d)
        b = 2 * sum(x * y for x, y in zip(d, oc))
        squared = sum(x * x for x in oc)
        rho = (squared - b * b / (4 * a)).sqrt()
        margin = abs(rho / r - 1)
        discriminant = b * b - 4 * a * (squared - r * r)
        t = (-b - discriminant.sqrt()) / (2 * a) if discriminant >= 0 else None
        return (t if t is not None and t > 0 else None), margin


@pytest.mark.parametrize("radius", [1e-3, 1.0, 1e3])
def test_sphere_oracle_matches_50_digit_solutions(radius):
    """Origins 2 to 10 radii from the centre, aimed near it (about half the
    lines hit), and lines grazing it at r (1 + delta), delta down to 1e-12."""
    rng = np.random.default_rng(11)
    center = radius * np.array([0.3, -0.2, 0.1])
    direction = rng.normal(size=(300, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    o = center + radius * rng.uniform(2, 10, (300, 1)) * direction
    aim = center + radius * rng.uniform(-1.5, 1.5, (300, 3)) - o
    d = aim * 10.0 ** rng.uniform(-2, 2, (300, 1))
    ref = sphere.intersect(o, d, center, radius)
    exact = [decimal_sphere(o[i], d[i], center, radius) for i in range(len(o))]
    hit = np.array([t is not None for t, _ in exact])
    assert 50 < hit.sum() < 250
    np.testing.assert_array_equal(hit, ref["hit"])
    t = np.array([float(t) for t, _ in exact if t is not None])
    np.testing.assert_allclose(ref["t"][hit], t, rtol=ORACLE_T, atol=0)
    np.testing.assert_allclose(ref["margin"], [float(m) for _, m in exact], rtol=0, atol=1e-15)


def test_sphere_oracle_on_closed_form_rays():
    center, radius = np.array([1.0, 2.0, 3.0]), 0.5
    o = center + np.array([[0, 0, -2.5], [0, 0, -2.5], [0.5 * (1 - 1e-9), 0, -2.5],
                           [0.5 * (1 + 1e-9), 0, -2.5], [0, 0, 2.5]])
    d = np.array([[0, 0, 1], [0, 0, 0.5], [0, 0, 1], [0, 0, 1], [0, 0, 1]], float)
    ref = sphere.intersect(o, d, center, radius)
    np.testing.assert_array_equal(ref["hit"], [True, True, True, False, False])
    half_chord = 0.5 * math.sqrt(1 - (1 - 1e-9) ** 2)
    np.testing.assert_allclose(ref["t"][:3], [2, 4, 2.5 - half_chord], rtol=1e-12)
    np.testing.assert_allclose(ref["margin"][2:4], [1e-9, 1e-9], rtol=1e-6)


# ------------------------------------------------------------------- Fresnel

@pytest.mark.parametrize("n_i, n_t", [(1.0, 1.5), (1.5, 1.0), (1.0, 1.33), (2.4, 1.0)])
def test_fresnel_oracle_at_normal_incidence_and_brewster(n_i, n_t):
    normal = ((n_i - n_t) / (n_i + n_t)) ** 2
    assert fresnel.reflectance(1.0, n_i, n_t) == pytest.approx(normal, rel=1e-14)
    # At Brewster's angle p-polarised light is not reflected at all, and
    # the s amplitude is (n_i^2 - n_t^2) / (n_i^2 + n_t^2).
    brewster = math.cos(math.atan(n_t / n_i))
    expected = ((n_i ** 2 - n_t ** 2) / (n_i ** 2 + n_t ** 2)) ** 2 / 2
    assert fresnel.reflectance(brewster, n_i, n_t) == pytest.approx(expected, rel=1e-12)


def test_fresnel_oracle_reflects_everything_beyond_the_critical_angle_and_at_grazing():
    critical = math.sqrt(1 - (1 / 1.5) ** 2)
    beyond = np.linspace(0, critical * (1 - 1e-12), 50)
    assert np.all(fresnel.reflectance(beyond, 1.5, 1.0) == 1)
    assert fresnel.reflectance(0.0, 1.0, 1.5) == pytest.approx(1, abs=1e-15)
    assert fresnel.reflectance(-0.6, 1.0, 1.5) == fresnel.reflectance(0.6, 1.0, 1.5)


@pytest.mark.parametrize("n_i, n_t", [(1.0, 1.5), (1.5, 1.0)])
def test_fresnel_oracle_matches_fresnels_sine_and_tangent_laws(n_i, n_t):
    """r_s = -sin(i - t) / sin(i + t), r_p = tan(i - t) / tan(i + t), with
    Snell's law for t; light going the other way at angle t reflects the
    same share."""
    limit = math.asin(min(1.0, n_t / n_i))
    incidence = np.linspace(0.01, limit - 0.01, 200)
    refracted = np.arcsin(n_i / n_t * np.sin(incidence))
    r_s = -np.sin(incidence - refracted) / np.sin(incidence + refracted)
    r_p = np.tan(incidence - refracted) / np.tan(incidence + refracted)
    expected = (r_s ** 2 + r_p ** 2) / 2
    np.testing.assert_allclose(fresnel.reflectance(np.cos(incidence), n_i, n_t), expected,
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(fresnel.reflectance(np.cos(refracted), n_t, n_i), expected,
                               rtol=0, atol=1e-12)
