"""Long-double oracle for rays against a sphere, from origins outside it.

It avoids the cancellation of the textbook quadratic: the line's distance
``rho`` from the centre comes from a cross product, the half chord from
``sqrt((r - rho)(r + rho))``, and ``t`` is the projection of the centre on
the line minus the half chord. ``margin`` is ``|rho / r - 1|``, the
relative distance of the line from tangency.
"""

from __future__ import annotations

import numpy as np


def intersect(o, d, center, radius) -> dict:
    """First hit of rays ``o + t d`` (arrays of shape (N, 3)) on the sphere:
    float64 arrays ``hit`` (bool), ``t`` (inf on a miss) and ``margin``."""
    o, d = np.asarray(o, dtype=np.longdouble), np.asarray(d, dtype=np.longdouble)
    length = np.sqrt((d * d).sum(axis=1))
    unit = d / length[:, None]
    to_centre = np.asarray(center, dtype=np.longdouble) - o
    along = (to_centre * unit).sum(axis=1)
    rho = np.sqrt((np.cross(to_centre, unit) ** 2).sum(axis=1))
    r = np.longdouble(radius)
    hit = (rho <= r) & (along > 0)
    half = np.sqrt(np.maximum((r - rho) * (r + rho), 0))
    t = (along - half) / length
    return {"hit": hit, "t": np.where(hit, t, np.inf).astype(np.float64),
            "margin": np.abs(rho / r - 1).astype(np.float64)}
