"""What marks a shape as analytic: a mesh that only stands in for an exact
surface, which the ``whitted`` integrator puts in its place at every hit
(:mod:`mitsuba_whitted.integrators.analytic`).

Python shapes derive from ``mi.Mesh`` alone (nanobind takes one base), so
the mark is a class attribute set by the :func:`analytic` decorator.
"""

from __future__ import annotations

#: What an analytic shape gives the integrator: float64 4x4 matrices placing
#: its canonical shape in the world, and back.
PLACEMENT = ("canonical_to_world_matrix", "world_to_canonical_matrix")


def analytic(cls):
    """Class decorator marking a shape class as analytic; the class must
    have the methods of ``PLACEMENT``."""
    missing = [name for name in PLACEMENT if not callable(getattr(cls, name, None))]
    if missing:
        raise TypeError(f"{cls.__name__} is marked analytic but lacks {', '.join(missing)}")
    cls.analytic_surface = True
    return cls


def is_analytic(shape) -> bool:
    """Whether ``shape`` is an instance of a class marked :func:`analytic`."""
    return getattr(type(shape), "analytic_surface", False) is True
