"""Where on the lens each camera sample looks from, for cameras with an
aperture (``thinlens``): distributed ray tracing (Cook, Porter and
Carpenter 1984) of depth of field, without a random number anywhere.

The points are placed in the unit square, which the sensor maps onto its
aperture disk, and stratified together with the film positions: a blur
couples a film coordinate with a lens coordinate, so what matters is how
the pairs (film x, lens x), (film y, lens y), ... fill their squares, not
only how film and lens points fill theirs.

- An n x n grid of film strata (i, j) takes lens strata such that every
  pair of the four coordinates takes all n^2 combinations (an orthogonal
  array of strength 2, Bose 1938): (i + j, i + 2 j) mod n for odd n, and
  (i + j, i + x j) in the field of 2^m elements (+ is XOR, x the
  polynomial x) for n = 2^m >= 4. For other even n no such pairing exists
  in general, and (i + j, i) mod n gives all combinations for five of the
  six pairs. The lens strata are then relabelled by permutations that
  differ from pixel to pixel (Kensler 2013), which keeps every pair's
  combinations.
- The contrast refinement's Hammersley points (k / N, phi_2(k)) take the
  next two Halton dimensions, (phi_3(k), phi_5(k)), shifted per pixel
  modulo 1 (Cranley and Patterson 1976).
- The adaptive refinement pairs each cell's 2 x 2 quadrants with the 2 x 2
  quarters of the cell's square of the lens as the grid does for n = 2.

Seeds are hashes of where the samples are, never of their order or keys,
so an image does not depend on how the film is cut into bands.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..jit import unit_pair
from ..mathutil import radical_inverse

#: Salts of the hashes that seed the permutations.
PIXEL_SALT, CELL_SALT, ROW_SALT = 0x5EED1E45, 0xCE11CE11, 0x0F0F0F0F


@dr.syntax
def permute(index: mi.UInt32, count, seed: mi.UInt32) -> mi.UInt32:
    """A permutation of ``0 ... count - 1`` chosen by ``seed``, applied to
    ``index`` (Kensler's hash, with cycle walking: the hash permutes the
    next power of two, and values past ``count`` are hashed again)."""
    count = mi.UInt32(count)
    mask = count - 1
    for shift in (1, 2, 4, 8, 16):
        mask |= mask >> shift
    value = mi.UInt32(index)
    first = mi.Bool(True)
    while first | (value >= count):
        value = _hash_within(value, mask, seed)
        first = mi.Bool(False)
    return (value + seed) % count


def _hash_within(i: mi.UInt32, w: mi.UInt32, p: mi.UInt32) -> mi.UInt32:
    """One round of Kensler's invertible hash on the bits of ``w``."""
    i ^= p
    i *= 0xE170893D
    i ^= p >> 16
    i ^= (i & w) >> 4
    i ^= p >> 8
    i *= 0x0929EB3F
    i ^= p >> 23
    i ^= (i & w) >> 1
    i *= 1 | (p >> 27)
    i *= 0x6935FA69
    i ^= (i & w) >> 11
    i *= 0x74DCB303
    i ^= (i & w) >> 2
    i *= 0x9E501CC3
    i ^= (i & w) >> 2
    i *= 0xC860A3DF
    i &= w
    i ^= i >> 5
    return i


def pixel_seed(pixel: mi.UInt32) -> mi.UInt32:
    """The seed of a pixel's permutations (its index in the crop window)."""
    return mi.sample_tea_32(pixel, mi.UInt32(PIXEL_SALT), 16)[0]


def position_seed(position: mi.Point2f) -> mi.UInt32:
    """A seed from a film position (exact: cells sit on dyadic fractions)."""
    x = dr.reinterpret_array(mi.UInt32, position.x)
    y = dr.reinterpret_array(mi.UInt32, position.y)
    return mi.sample_tea_32(x ^ mi.UInt32(CELL_SALT), y, 16)[0]


#: Irreducible polynomials of the fields of 2^m elements, m = 2 ... 10
#: (their bits are the coefficients, x^m included).
FIELD_POLYNOMIALS = {4: 0b111, 8: 0b1011, 16: 0b10011, 32: 0b100101, 64: 0b1000011,
                     128: 0b10000011, 256: 0b100011011, 512: 0b1000010001,
                     1024: 0b10000001001}


def paired_strata(i: mi.UInt32, j: mi.UInt32, n: int, seed: mi.UInt32) -> tuple:
    """The lens stratum (column, row) of an n x n grid paired with film
    stratum (i, j) of an n x n grid (see the module's docstring)."""
    if n % 2:
        column, row = (i + j) % n, (i + 2 * j) % n
    elif n in FIELD_POLYNOMIALS:
        column, row = i ^ j, i ^ _times_x(j, n)
    else:
        column, row = (i + j) % n, i
    # The row's seed is hashed anew: Kensler's hash of two seeds that differ
    # in a few bits gives correlated permutations.
    row_seed = mi.sample_tea_32(seed, mi.UInt32(ROW_SALT), 16)[0]
    return permute(column, n, seed), permute(row, n, row_seed)


def _times_x(value: mi.UInt32, n: int) -> mi.UInt32:
    """``value`` times the polynomial x in the field of ``n`` = 2^m elements."""
    doubled = value << 1
    return dr.select(doubled >= n, doubled ^ FIELD_POLYNOMIALS[n], doubled)


def grid_lens(sub: mi.UInt32, n: int, seed: mi.UInt32) -> mi.Point2f:
    """The lens point of sample ``sub`` (row-major) of an n x n grid: a
    point of its paired lens stratum, placed in it by a hash."""
    column, row = paired_strata(sub % n, sub // n, n, seed)
    return mi.Point2f(mi.Float(column), mi.Float(row)) / n + jitter(seed, sub) / n


def jitter(seed: mi.UInt32, index: mi.UInt32) -> mi.Vector2f:
    """A point of [0, 1)^2 hashed from ``seed`` and ``index``: where in its
    stratum a lens point lies. Spread so, rather than at the centres, the
    points of every pixel are an unbiased sample of its aperture."""
    return mi.Vector2f(*unit_pair(seed, index, rounds=16))


def halton_lens(sub: mi.UInt32, count: int, seed: mi.UInt32) -> mi.Point2f:
    """The lens point of point ``sub`` of ``count`` Hammersley points:
    its third and fourth Halton coordinates, shifted by the seed."""
    table = mi.Point2f(mi.Float(radical_inverse(count, 3)), mi.Float(radical_inverse(count, 5)))
    shifted = dr.gather(mi.Point2f, table, sub) + hashed_lens(seed)
    return shifted - dr.floor(shifted)


def hashed_lens(seed: mi.UInt32) -> mi.Point2f:
    """One lens point from a seed (a pixel's single first-pass sample)."""
    return mi.Point2f(jitter(seed, mi.UInt32(PIXEL_SALT)))
