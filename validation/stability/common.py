"""What every stability case shares: its result row, the float32 units its
bounds are stated in, and the NumPy helpers that build float32 inputs."""

from __future__ import annotations

from dataclasses import dataclass

import mitsuba as mi
import numpy as np

#: Unit roundoff of float32: half an ulp of 1.
U32 = 2.0 ** -24
#: One float32 ulp at 1.
ULP32 = 2.0 ** -23
SEED = 363


@dataclass
class CaseResult:
    """One row of the stability table."""

    name: str
    measures: str            #: what is measured
    reference: str           #: the float64 reference used
    samples: int             #: rays, interactions or pixels
    nonfinite: int           #: NaN/Inf values in the results
    disagreements: int       #: hit/miss (or pixel) disagreements outside the band
    excused: int             #: disagreements inside the band
    band: str                #: where a disagreement is excused
    worst_error: float
    unit: str                #: unit of worst_error and bound
    bound: float
    passed: bool
    details: str = ""        #: secondary measures and their bounds


def f32(values) -> np.ndarray:
    """Round to float32 and back: the exact values the renderer receives."""
    return np.asarray(values, dtype=np.float32).astype(np.float64)


def unit_rows(v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` normalised; zero rows (a miss's normal) stay zero."""
    length = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(length > 0, length, 1)


def random_units(rng, count) -> np.ndarray:
    return unit_rows(rng.normal(size=(count, 3)))


def perpendicular_basis(d: np.ndarray):
    """Two unit vectors perpendicular to each row of the unit ``d``."""
    helper = np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    e1 = unit_rows(np.cross(d, helper))
    return e1, np.cross(d, e1)


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between rows of two unit-vector arrays, accurate near 0."""
    return 2 * np.arcsin(np.clip(np.linalg.norm(a - b, axis=-1) / 2, 0, 1))


def float32_rays(o: np.ndarray, d: np.ndarray) -> mi.Ray3f:
    return mi.Ray3f(mi.Point3f(*o.astype(np.float32).T), mi.Vector3f(*d.astype(np.float32).T))
