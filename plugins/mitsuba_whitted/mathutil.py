"""Small numerical helpers shared by the plugins.

The Dr.Jit helpers are precision generic: they work on whatever array type
they are given (``mi.Float``, ``mi.Float64``, scalar floats), so a caller can
choose its precision once and reuse them. The numpy helpers work on scalar
float64 matrices (scene set-up, not per-ray work).
"""

from __future__ import annotations

import drjit as dr
import numpy as np

#: A matrix whose :func:`inverse_condition` is below this is treated as
#: singular: inverting it in float64 (unit roundoff 1.1e-16) can then err by
#: up to ~1e-6 relative, the size of float32 rounding, so the inverse would no
#: longer be trustworthy for a float32 renderer.
SINGULAR_CONDITION = 1e-10


def difference_of_products(a, b, c, d):
    """``a*b - c*d`` with one rounding error's worth of accuracy.

    Kahan's algorithm: the product ``c*d`` is rounded once, and the rounding
    error is recovered exactly with an FMA and added back, so the result has
    no catastrophic cancellation even when ``a*b`` and ``c*d`` nearly cancel.
    """
    cd = c * d
    cd_error = dr.fma(-c, d, cd)
    return dr.fma(a, b, -cd) + cd_error


def solve_quadratic(a, half_b, c, discriminant=None):
    """Real roots of ``a t^2 + 2 half_b t + c = 0`` without cancellation.

    Returns ``(valid, t_near, t_far)`` with ``t_near <= t_far``; ``valid`` is
    false where there is no real root (the ``t`` values are then meaningless).

    - The reduced discriminant ``half_b^2 - a c`` is formed with
      :func:`difference_of_products`, unless the caller passes a better one
      (a formulation that cancels analytically, e.g. Lagrange's identity).
    - ``q = -(half_b + sign(half_b) sqrt(disc))`` adds two numbers of the same
      sign, so it never cancels; the roots are ``q/a`` and ``c/q`` (Vieta),
      both accurate, instead of ``(-half_b +- sqrt(disc))/a`` where one of
      the two loses all its digits when ``a c`` is small next to ``half_b^2``.
    - ``a == 0`` degrades to the linear equation: its single root is
      returned as both roots (invalid when ``half_b == 0`` too).
    - ``q == 0`` happens only for ``half_b == 0 == disc``, i.e. ``c == 0``:
      the double root is 0 (``c/q`` would be 0/0).
    """
    if discriminant is None:
        discriminant = difference_of_products(half_b, half_b, a, c)
    root = dr.sqrt(dr.maximum(discriminant, 0))
    q = -(half_b + dr.copysign(root, half_b))
    q_is_zero = q == 0
    t_from_q = dr.select(q_is_zero, 0, q / a)
    t_from_c = dr.select(q_is_zero, 0, c / q)

    linear = a == 0
    t_linear = -c / (2 * half_b)

    t_near = dr.select(linear, t_linear, dr.minimum(t_from_q, t_from_c))
    t_far = dr.select(linear, t_linear, dr.maximum(t_from_q, t_from_c))
    valid = dr.select(linear, half_b != 0, discriminant >= 0)
    return valid, t_near, t_far


def inverse_condition(matrix) -> float:
    """``sigma_min / sigma_max`` of a square matrix, in [0, 1]: 1 for a
    similarity, 0 for a singular (or non-finite) matrix. Rounding errors of a
    solve with the matrix grow like its reciprocal."""
    m = np.asarray(matrix, dtype=np.float64)
    if not np.all(np.isfinite(m)):
        return 0.0
    singular_values = np.linalg.svd(m, compute_uv=False)
    if singular_values[0] == 0:
        return 0.0
    return float(singular_values[-1] / singular_values[0])


def invert_affine_f64(matrix) -> np.ndarray:
    """Inverse of a 4x4 affine matrix (last row 0 0 0 1) in float64.

    Singularity is judged on the 3x3 linear block alone (a translation says
    nothing about invertibility, and its size must not make a well-scaled
    matrix look singular), by :func:`inverse_condition` against
    :data:`SINGULAR_CONDITION`. Raises ``np.linalg.LinAlgError`` for a singular
    block and ``ValueError`` for a projective (non-affine) matrix.
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4) or not np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError("expected a 4x4 affine matrix with last row (0, 0, 0, 1)")
    linear = m[:3, :3]
    if inverse_condition(linear) < SINGULAR_CONDITION:
        raise np.linalg.LinAlgError("linear part is singular or nearly so")
    inverse = np.eye(4)
    inverse[:3, :3] = np.linalg.inv(linear)
    inverse[:3, 3] = -inverse[:3, :3] @ m[:3, 3]
    return inverse


def hammersley(count: int) -> np.ndarray:
    """``count`` points of the Hammersley set in the unit square, shape
    ``(count, 2)``, float64: ``x`` at the centres of ``count`` equal columns,
    ``y`` the base-2 radical inverse of the index, moved to the centre of
    its dyadic interval.

    Every one of the ``count`` columns holds one point, and for a power of
    two so does every dyadic row (a (0, m, 2)-net), so an axis-aligned edge
    is resolved to 1/``count`` of the square, where an ``n x n`` grid of the
    same count resolves it to 1/``n``. On sloped edges it does about as well
    as such a grid (measured; ``tests/test_antialias.py``).
    """
    index = np.arange(count, dtype=np.uint64)
    bits = int(count - 1).bit_length()
    reversed_index = np.zeros(count, dtype=np.uint64)
    for bit in range(bits):
        reversed_index |= ((index >> np.uint64(bit)) & np.uint64(1)) << np.uint64(bits - 1 - bit)
    x = (index + 0.5) / count
    y = (reversed_index + 0.5) / float(1 << bits)
    return np.stack([x, y], axis=1)


def radical_inverse(count: int, base: int) -> np.ndarray:
    """The base-``base`` radical inverse of ``0 ... count - 1`` (the index's
    digits mirrored about the point), float64: the van der Corput points
    that the Halton and Hammersley sets take one base per dimension."""
    index = np.arange(count, dtype=np.int64)
    result, scale = np.zeros(count), 1.0 / base
    while index.any():
        result += (index % base) * scale
        index //= base
        scale /= base
    return result
