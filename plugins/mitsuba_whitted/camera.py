"""Camera rays through given points of a sensor's crop window."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi


def pixel_centres(film: mi.Film) -> mi.Point2f:
    """Centre of every pixel of the crop window, row-major, in pixel units."""
    width, height = film.crop_size()
    index = dr.arange(mi.UInt32, width * height)
    return mi.Point2f(mi.Float(index % width) + 0.5, mi.Float(index // width) + 0.5)


def camera_rays(sensor: mi.Sensor, positions: mi.Point2f, lens: mi.Point2f = None):
    """Rays (and sensor weights) through ``positions``, given in pixel units
    relative to the crop window, from ``lens`` (points of the unit square,
    which a camera with an aperture maps onto it; its centre if ``None``).
    The time is the middle of the shutter interval."""
    # Mitsuba's sensors take film positions relative to the crop window.
    inv_size = 1.0 / mi.ScalarVector2f(sensor.film().crop_size())
    time = sensor.shutter_open() + 0.5 * sensor.shutter_open_time()
    aperture = mi.Point2f(0.5) if lens is None else lens
    return sensor.sample_ray(time, 0.5, positions * inv_size, aperture)
