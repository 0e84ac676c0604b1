"""Float64 oracle for the Fresnel reflectance of a smooth dielectric
interface, from the textbook amplitude coefficients of s- and
p-polarised light."""

from __future__ import annotations

import numpy as np


def reflectance(cos_i, n_i, n_t):
    """Unpolarised reflectance for light inside index ``n_i`` meeting index
    ``n_t`` at incidence cosine ``cos_i`` (its sign is ignored); 1 beyond
    the critical angle."""
    cos_i = np.abs(cos_i)
    sin_t2 = (n_i / n_t) ** 2 * (1 - cos_i ** 2)
    cos_t = np.sqrt(np.maximum(1 - sin_t2, 0))
    # 0 / 0 at grazing incidence beyond the critical angle, where F is 1.
    with np.errstate(invalid="ignore"):
        r_s = (n_i * cos_i - n_t * cos_t) / (n_i * cos_i + n_t * cos_t)
        r_p = (n_t * cos_i - n_i * cos_t) / (n_t * cos_i + n_i * cos_t)
    return np.where(sin_t2 >= 1, 1.0, (r_s ** 2 + r_p ** 2) / 2)
