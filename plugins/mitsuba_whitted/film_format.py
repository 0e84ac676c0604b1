"""What a film develops its image to."""

from __future__ import annotations

import re

import mitsuba as mi


def developed_format(film: mi.Film):
    """The ``mi.Bitmap.PixelFormat`` the film develops to (an hdrfilm's
    ``pixel_format``); RGB(A) for a film that does not say. Mitsuba's
    films name it only in their description."""
    stated = re.search(r"pixel_format = (\w+)", str(film))
    formats = mi.Bitmap.PixelFormat.__members__
    if stated is not None and stated.group(1).upper() in formats:
        return formats[stated.group(1).upper()]
    return formats["RGBA" if film.flags() & mi.FilmFlags.Alpha else "RGB"]


def develops_to_rgb(film: mi.Film) -> bool:
    """Whether the film's image is RGB, with or without alpha."""
    return developed_format(film).name in ("RGB", "RGBA")
