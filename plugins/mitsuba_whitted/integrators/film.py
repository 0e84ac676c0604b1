"""The film's side of a render: its storage, the image blocks the bands
are put into it as, the pixel format it develops to, and the adjoints of a
developed image taken back to RGB."""

from __future__ import annotations

import re

import drjit as dr
import mitsuba as mi
import numpy as np

from ..errors import ParameterError, check
from .settings import PLUGIN_NAME


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


def film_channels(film: mi.Film) -> int:
    """Values per pixel of the film's storage: RGB or RGBA, and a weight
    (whatever the pixel format it develops to: luminance and XYZ are
    developed from RGB)."""
    width, height = film.crop_size()
    check(width * height > 0, PLUGIN_NAME, "film",
          f"has no pixels to render ({width} x {height}): give it a 'width' and 'height' of "
          "at least 1")
    if film.flags() & mi.FilmFlags.Spectral:
        raise ParameterError(PLUGIN_NAME, "film",
                             f"must be an RGB film such as 'hdrfilm' (got {film.class_name()}, "
                             "which stores spectral bands)")
    return 5 if film.flags() & mi.FilmFlags.Alpha else 4


def film_entries(film: mi.Film, channels: int, develop: bool = True) -> int:
    """The floats a film of ``channels`` values per pixel holds during a
    render: its storage, and where it is developed the developed image
    (one value fewer per pixel: no weight)."""
    width, height = film.crop_size()
    return width * height * (2 * channels - 1 if develop else channels)


def developed(rows: np.ndarray, pixel_format) -> np.ndarray:
    """RGB(A) ``rows`` (rows, width, 3 or 4) in ``pixel_format``, converted
    as a film's ``develop`` converts them."""
    stored = mi.Bitmap.PixelFormat.RGBA if rows.shape[2] == 4 else mi.Bitmap.PixelFormat.RGB
    if pixel_format == stored:
        return rows
    converted = np.array(mi.Bitmap(rows, stored).convert(pixel_format, mi.Struct.Type.Float32,
                                                         False))
    return converted.reshape(rows.shape[0], rows.shape[1], -1)


def image_block(film: mi.Film, band, radiance: mi.Color3f, alpha: mi.Float,
                 channels: int):
    """An image block holding the finished pixels of ``band`` (weight 1
    each), placed on the film where the band lies."""
    values = [radiance.x, radiance.y, radiance.z]
    if channels == 5:
        values.append(alpha)
    values.append(dr.ones(mi.Float, band.pixels))
    data = dr.empty(mi.Float, band.pixels * channels)
    base = dr.arange(mi.UInt32, band.pixels) * channels
    for index, value in enumerate(values):
        dr.scatter(data, value, base + index)
    tensor = mi.TensorXf(data, shape=(band.rows, band.width, channels))
    offset = film.crop_offset() + mi.ScalarPoint2i(0, band.first_row)
    return mi.ImageBlock(tensor, offset)


def adjoint_pixels(grad_in, film: mi.Film):
    """``adjoint(band)``: the radiance adjoints of ``band``'s pixels, from
    ``grad_in``, an adjoint of the film's developed image in its pixel
    format (its alpha, a coverage, has no derivative): luminance and XYZ
    are linear in RGB, so their adjoints reach RGB through the transpose."""
    width, height = film.crop_size()
    channels = film.base_channels_count()
    shape = tuple(grad_in.shape)
    if shape != (height, width, channels):
        raise ParameterError(PLUGIN_NAME, "grad_in",
                             f"must have the shape of the image, {(height, width, channels)} "
                             f"(got {shape})")
    values = dr.detach(grad_in.array)
    matrix = _colour_matrix(developed_format(film))

    def adjoint(band) -> mi.Color3f:
        base = (dr.arange(mi.UInt32, band.pixels) + dr.opaque(mi.UInt32, band.first_pixel)) \
            * channels
        developed = [dr.gather(mi.Float, values, base + k) for k in range(len(matrix))]
        if matrix is IDENTITY:
            return mi.Color3f(*developed)
        return mi.Color3f(*[sum(row[c] * value for row, value in zip(matrix, developed))
                            for c in range(3)])

    return adjoint


#: The colour matrix of an RGB film.
IDENTITY = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def _colour_matrix(pixel_format) -> tuple:
    """Rows of the linear map from RGB to the colour channels of
    ``pixel_format`` (one row for luminance, three for RGB and XYZ), as
    the film's develop applies it."""
    colour = pixel_format.name.removesuffix("A")  # the colour channels, without alpha
    if colour == "RGB":
        return IDENTITY
    unit = np.eye(3, dtype=np.float32).reshape(1, 3, 3)  # pure red, green and blue pixels
    converted = developed(unit, mi.Bitmap.PixelFormat.__members__[colour])[0]
    return tuple(tuple(float(v) for v in converted[:, k]) for k in range(converted.shape[1]))
