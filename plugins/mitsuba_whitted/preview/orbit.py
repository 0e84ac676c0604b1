"""The preview's camera: an origin that orbits, dollies and pans about a
target, with the up direction the scene's camera had.

A sensor's ``to_world`` says where the camera is and where it looks, not
how far away what it looks at is, nor the up direction its ``<lookat>``
gave: the target is put at the distance the session finds (what the
central ray hits), and the up direction is the world axis closest to the
camera's own up, so that orbiting turns about the scene's vertical even
when the camera looks down on it. Mitsuba's ``look_at`` makes the
matrix's columns the camera's left, up and forward directions.
"""

from __future__ import annotations

import numpy as np

#: The closest the view direction comes to the up direction (radians), so
#: that orbiting over the top does not flip the camera.
_POLE_MARGIN = 0.01
#: The shortest distance to the target, as a fraction of the starting one.
_NEAREST = 1e-3


class Orbit:
    """A look-at camera: ``origin``, ``target`` and ``up`` (NumPy vectors)."""

    def __init__(self, origin, target, up):
        self.origin = np.asarray(origin, np.float64)
        self.target = np.asarray(target, np.float64)
        self.up = _unit(np.asarray(up, np.float64))
        self._nearest = _NEAREST * np.linalg.norm(self.origin - self.target)

    @classmethod
    def of_matrix(cls, matrix, distance: float) -> "Orbit":
        """The camera of a ``to_world`` matrix (4 x 4), looking at a target
        ``distance`` ahead."""
        matrix = np.asarray(matrix, np.float64)
        origin, forward = matrix[:3, 3], _unit(matrix[:3, 2])
        return cls(origin, origin + forward * distance, _nearest_axis(matrix[:3, 1]))

    def copy(self) -> "Orbit":
        return Orbit(self.origin, self.target, self.up)

    def orbit(self, yaw: float, pitch: float) -> None:
        """Turn the origin about the target: ``yaw`` radians about the up
        direction, ``pitch`` about the camera's left, short of the poles."""
        offset = _rotated(self.origin - self.target, self.up, yaw)
        elevation = np.arccos(np.clip(np.dot(_unit(offset), self.up), -1, 1))
        pitch = np.clip(pitch, elevation - np.pi + _POLE_MARGIN, elevation - _POLE_MARGIN)
        left = _unit(np.cross(self.up, -offset))
        self.origin = self.target + _rotated(offset, left, pitch)

    def dolly(self, steps: float) -> None:
        """Move towards the target (``steps`` < 0) or away, by a factor of
        e^steps of the distance."""
        offset = (self.origin - self.target) * np.exp(steps)
        distance = np.linalg.norm(offset)
        if distance < self._nearest:
            offset *= self._nearest / distance
        self.origin = self.target + offset

    def pan(self, right: float, up: float) -> None:
        """Slide origin and target across the view, by fractions of the
        distance between them."""
        forward = _unit(self.target - self.origin)
        left = _unit(np.cross(self.up, forward))
        shift = (np.cross(forward, left) * up - left * right) * np.linalg.norm(
            self.target - self.origin)
        self.origin = self.origin + shift
        self.target = self.target + shift

    def lookat_xml(self) -> str:
        """The ``<lookat>`` of a scene file that places the camera so."""
        return (f'<lookat origin="{_text(self.origin)}" target="{_text(self.target)}" '
                f'up="{_text(self.up)}"/>')


def _unit(vector: np.ndarray) -> np.ndarray:
    return vector / np.linalg.norm(vector)


def _nearest_axis(vector: np.ndarray) -> np.ndarray:
    """The world axis (signed) closest in direction to ``vector``."""
    axis = np.zeros(3)
    largest = np.argmax(np.abs(vector))
    axis[largest] = np.sign(vector[largest])
    return axis


def _rotated(vector: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """``vector`` turned by ``angle`` about the unit ``axis`` (Rodrigues)."""
    cos, sin = np.cos(angle), np.sin(angle)
    return vector * cos + np.cross(axis, vector) * sin + axis * np.dot(axis, vector) * (1 - cos)


def _text(vector: np.ndarray) -> str:
    return ", ".join(f"{value:.6g}" for value in vector)
