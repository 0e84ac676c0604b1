"""Low-discrepancy samples for the indirect light: Owen-scrambled Sobol
points, padded one pair of dimensions at a time.

An estimate draws the coordinates of its ``s``-th sample two at a time
from the first two dimensions of the Sobol sequence, a (0, 2)-sequence in
base 2: its first 2^k points fill every dyadic box of area 2^-k once. Each
pair of dimensions takes the points in an order of its own and is
scrambled on its own, so that pairs are uncorrelated with one another
(padding, as a sampler pads a 2D sequence to any number of dimensions):

- the index is shuffled by a nested uniform scramble of its bits, which
  maps every power-of-two block of indices onto a power-of-two block, so
  the first 2^k samples of a pair stay stratified whatever k is;
- each coordinate is Owen-scrambled: every dyadic interval's halves are
  swapped or not at random, which keeps the stratification and makes each
  point uniformly distributed, so estimates are unbiased.

Both scrambles are hash based (Burley 2020, "Practical Hash-based Owen
Scrambling": the Laine-Karras permutation with his constants), seeded by
the estimate's seed and the pair's index. Nothing is drawn from a random
stream: the samples are a function of the seed, as everything else in a
Whitted render is.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

#: The odd multipliers of Burley's Laine-Karras-style permutation.
_PERMUTATION_STEPS = (0x6C50B47C, 0xB82F1E52, 0xC7AFE638, 0x8D22F6E6)
#: Golden-ratio increment: spreads consecutive pair indices over 32 bits.
_GOLDEN = 0x9E3779B9
#: 2^-24: the float32 in [0, 1) of the top 24 bits of a 32-bit fraction.
_UNIT = 1.0 / (1 << 24)


def mix(value: mi.UInt32) -> mi.UInt32:
    """A 32-bit integer hash with full avalanche (two multiply-xorshift
    rounds, the "lowbias32" constants)."""
    value = value ^ (value >> 16)
    value = value * 0x7FEB352D
    value = value ^ (value >> 15)
    value = value * 0x846CA68B
    return value ^ (value >> 16)


def _permute_reversed(value: mi.UInt32, seed: mi.UInt32) -> mi.UInt32:
    """A random permutation of 32-bit integers in which each bit depends
    only on itself and the bits below it: on bit-reversed numbers, a nested
    uniform (Owen) scramble."""
    value = value + seed
    for step in _PERMUTATION_STEPS:
        value = value ^ (value * step)
    return value


def owen_scramble(fraction: mi.UInt32, seed: mi.UInt32) -> mi.UInt32:
    """Owen scramble of a 32-bit binary fraction (bit 31 is the 1/2 digit)."""
    return dr.brev(_permute_reversed(dr.brev(fraction), seed))


def sobol_pair(index: mi.UInt32) -> tuple:
    """The first two dimensions of the Sobol sequence at ``index``, as
    32-bit binary fractions: the van der Corput radical inverse, and the
    second dimension, whose generator matrix is Pascal's triangle mod 2
    (direction numbers ``v_0 = 2^31``, ``v_k = v_(k-1) ^ (v_(k-1) >> 1)``)."""
    second = mi.UInt32(0)
    direction = 1 << 31
    for bit in range(32):
        second = second ^ dr.select((index & (1 << bit)) != 0, mi.UInt32(direction), 0)
        direction ^= direction >> 1
    return dr.brev(index), second


def to_unit(fraction: mi.UInt32) -> mi.Float:
    """A 32-bit binary fraction as a float32 in [0, 1), rounded down."""
    return mi.Float(fraction >> 8) * _UNIT


class PaddedSobol:
    """``point(s, pair)``: the ``s``-th sample's coordinates in dimension
    pair ``pair``, for an estimate seeded by ``seed`` (per lane)."""

    def __init__(self, seed: mi.UInt32):
        self.seed = seed

    def point(self, sample: mi.UInt32, pair) -> mi.Point2f:
        base = mix(self.seed ^ mix(mi.UInt32(pair) * _GOLDEN + 1))
        shuffled = owen_scramble(sample, mix(base + 1))
        x, y = sobol_pair(shuffled)
        return mi.Point2f(to_unit(owen_scramble(x, mix(base + 2))),
                          to_unit(owen_scramble(y, mix(base + 3))))
