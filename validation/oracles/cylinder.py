"""Long-double oracle for rays against the canonical capped cylinder
(``x^2 + z^2 <= 1``, ``0 <= y <= 1``).

Written apart from the Dr.Jit code and with another method: the candidate
formulation of the COSC363 ray tracer's report, which the package ports.
Every crossing of a surface is a candidate (the two roots of the textbook
quadratic, kept when their height lies in the slab; the two cap planes,
kept when the point lies in the unit disk), and the hit is the smallest
candidate in ``(t_min, t_max]``. It runs in ``np.longdouble``
(64-bit mantissa on x86, where even the naive discriminant at an origin 1e6
away keeps about 7 digits), with the side listed first so that a tie at the
rim goes to the side, as in the implementation's documented convention.

Besides the hit it returns, per ray, ``margin``: the smallest canonical
distance from any classification decision to its threshold (tangency of
the line to the side, a side candidate's height against 0 and 1, a cap
candidate's radius against 1, a candidate against ``t_min``). A ray with a
tiny margin may legitimately be classified either way by a computation with
rounding error; any other disagreement is a bug.
"""

from __future__ import annotations

import numpy as np

PART_SIDE, PART_BOTTOM, PART_TOP = 0, 1, 2


def _side_candidates(o, d):
    """Both roots of a t^2 + b t + c = 0 (textbook form), NaN where none."""
    a = d[:, 0] ** 2 + d[:, 2] ** 2
    b = 2 * (o[:, 0] * d[:, 0] + o[:, 2] * d[:, 2])
    c = o[:, 0] ** 2 + o[:, 2] ** 2 - 1
    disc = b * b - 4 * a * c
    real = (a > 0) & (disc >= 0)
    root = np.sqrt(np.where(real, disc, 0))
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = np.where(real, (-b - root) / (2 * a), np.nan)
        t2 = np.where(real, (-b + root) / (2 * a), np.nan)
        # Distance of the line from the axis, in the xz plane.
        cross = o[:, 0] * d[:, 2] - o[:, 2] * d[:, 0]
        axis_distance = np.where(a > 0, np.abs(cross) / np.sqrt(a), np.inf)
    return [t1, t2], np.abs(axis_distance - 1)


def _cap_candidates(o, d):
    """Crossings of y = 0 and y = 1, NaN where the ray is parallel to them."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return [np.where(d[:, 1] != 0, (h - o[:, 1]) / d[:, 1], np.nan)
                for h in (0, 1)]


def intersect(o, d, t_min, t_max=np.inf):
    """Reference hit of rays ``o + t d`` (arrays of shape (N, 3)).

    Returns a dict of float64 arrays: ``hit`` (bool), ``t`` (inf on a miss),
    ``part``, ``p`` (hit point on the exact surface), ``n`` (outward normal)
    and ``margin`` (see the module docstring).
    """
    o = np.asarray(o, dtype=np.longdouble)
    d = np.asarray(d, dtype=np.longdouble)
    t_min = np.broadcast_to(np.asarray(t_min, dtype=np.longdouble), len(o))
    t_max = np.broadcast_to(np.asarray(t_max, dtype=np.longdouble), len(o))
    speed = np.linalg.norm(d.astype(np.float64), axis=1)

    side_ts, tangency = _side_candidates(o, d)
    cap_ts = _cap_candidates(o, d)
    margin = tangency.astype(np.float64)

    best_t = np.full(len(o), np.inf, dtype=np.longdouble)
    best_part = np.full(len(o), -1)
    candidates = [(t, PART_SIDE) for t in side_ts] + list(zip(cap_ts, (PART_BOTTOM, PART_TOP)))
    for t, part in candidates:
        at = o + np.nan_to_num(t)[:, None] * d
        if part == PART_SIDE:
            on_part = (at[:, 1] >= 0) & (at[:, 1] <= 1)
            boundary = np.minimum(np.abs(at[:, 1]), np.abs(at[:, 1] - 1))
        else:
            radius = np.sqrt(at[:, 0] ** 2 + at[:, 2] ** 2)
            on_part = radius <= 1
            boundary = np.abs(radius - 1)
        exists = ~np.isnan(t)
        boundary = np.minimum(boundary, np.abs(t - t_min) * speed)
        margin = np.where(exists, np.minimum(margin, boundary.astype(np.float64)), margin)
        better = exists & on_part & (t > t_min) & (t <= t_max) & (t < best_t)
        best_t = np.where(better, t, best_t)
        best_part = np.where(better, part, best_part)

    hit = best_part >= 0
    p = o + np.where(hit, best_t, 0)[:, None] * d
    return {
        "hit": hit,
        "t": best_t.astype(np.float64),
        "part": best_part,
        "p": _onto_surface(p, best_part).astype(np.float64),
        "n": _normal(p, best_part),
        "margin": margin,
    }


def intersect_placed(world_to_canonical, o, d, t_min=0.0, t_max=np.inf):
    """:func:`intersect` of world rays with the solid that the 4x4 matrix
    ``world_to_canonical`` maps onto the canonical one: the rays are mapped
    in float64 (an affine map keeps ``t``), and ``n_world`` holds the
    normal mapped back (by the inverse transpose) and normalised."""
    m = np.asarray(world_to_canonical, dtype=np.float64)
    o, d = np.asarray(o, dtype=np.float64), np.asarray(d, dtype=np.float64)
    hit = intersect(o @ m[:3, :3].T + m[:3, 3], d @ m[:3, :3].T, t_min, t_max)
    n_world = hit["n"] @ m[:3, :3]
    length = np.linalg.norm(n_world, axis=1, keepdims=True)
    hit["n_world"] = n_world / np.where(length > 0, length, 1)
    return hit


def _onto_surface(p, part):
    p = p.copy()
    side = part == PART_SIDE
    radius = np.sqrt(p[:, 0] ** 2 + p[:, 2] ** 2)
    p[side, 0] /= radius[side]
    p[side, 2] /= radius[side]
    p[part == PART_BOTTOM, 1] = 0
    p[part == PART_TOP, 1] = 1
    return p


def _normal(p, part):
    n = np.zeros((len(p), 3))
    side = part == PART_SIDE
    radial = p[side][:, [0, 2]].astype(np.float64)
    radial /= np.linalg.norm(radial, axis=1)[:, None]
    n[side, 0], n[side, 2] = radial[:, 0], radial[:, 1]
    n[part == PART_BOTTOM, 1] = -1
    n[part == PART_TOP, 1] = 1
    return n
