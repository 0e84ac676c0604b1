"""Camera rays through given points of a sensor's crop window."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi


def pixel_centres(film: mi.Film) -> mi.Point2f:
    """Centre of every pixel of the crop window, row-major, in pixel units."""
    width, height = film.crop_size()
    index = dr.arange(mi.UInt32, width * height)
    return mi.Point2f(mi.Float(index % width) + 0.5, mi.Float(index // width) + 0.5)


def camera_rays(sensor: mi.Sensor, positions: mi.Point2f):
    """Rays (and sensor weights) through ``positions``, given in pixel units
    relative to the crop window. The aperture and time are fixed at their
    centres, so thin-lens cameras render as pinholes (deterministic)."""
    return rays_through(sensor, positions, *camera_placement(sensor))


def camera_placement(sensor: mi.Sensor) -> tuple:
    """What :func:`rays_through` needs besides the sensor: the scale from
    pixels to film positions and the mid-shutter time, as opaque JIT values,
    so that a frozen kernel receives them as inputs (a literal would stay
    baked into its recording when the film or shutter changes)."""
    # Mitsuba's sensors take film positions relative to the crop window.
    width, height = sensor.film().crop_size()
    time = sensor.shutter_open() + 0.5 * sensor.shutter_open_time()
    return (mi.Vector2f(dr.opaque(mi.Float, 1.0 / width), dr.opaque(mi.Float, 1.0 / height)),
            dr.opaque(mi.Float, time))


def rays_through(sensor: mi.Sensor, positions: mi.Point2f, film_scale: mi.Vector2f,
                 time: mi.Float):
    """:func:`camera_rays` with its placement given."""
    return sensor.sample_ray(time, 0.5, positions * film_scale, mi.Point2f(0.5))
