"""Writing rendered images with OpenImageIO.

Low dynamic range formats (PNG, JPEG) get the sRGB transfer curve and 8 bits;
high dynamic range formats (EXR, HDR, PFM) keep linear float32 values.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

HDR_SUFFIXES = {".exr", ".hdr", ".pfm"}
LDR_SUFFIXES = {".png", ".jpg", ".jpeg"}


class ImageWriteError(RuntimeError):
    """The image could not be written."""


def linear_to_srgb(values: np.ndarray) -> np.ndarray:
    """The sRGB transfer curve (IEC 61966-2-1) on values clamped to [0, 1]."""
    v = np.clip(values, 0.0, 1.0)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.power(v, 1 / 2.4) - 0.055)


def to_8bit(linear: np.ndarray) -> np.ndarray:
    return np.round(linear_to_srgb(linear) * 255).astype(np.uint8)


def write_image(path: str | Path, image: np.ndarray) -> None:
    """Write an (height, width, channels) linear image to ``path``."""
    import OpenImageIO as oiio

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in HDR_SUFFIXES | LDR_SUFFIXES:
        raise ImageWriteError(
            f"mitsuba-whitted: cannot write '{path}': use one of "
            f"{', '.join(sorted(HDR_SUFFIXES | LDR_SUFFIXES))}.")
    image = np.ascontiguousarray(image, dtype=np.float32)
    if suffix in LDR_SUFFIXES:
        colour = to_8bit(image[..., :3])
        if image.shape[2] == 4:  # alpha stays linear
            alpha = np.round(np.clip(image[..., 3:], 0, 1) * 255).astype(np.uint8)
            colour = np.concatenate([colour, alpha], axis=2)
        pixels, kind = colour, oiio.UINT8
    else:
        pixels, kind = image, oiio.FLOAT
    height, width, channels = pixels.shape
    if path.parent and not path.parent.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), oiio.ImageSpec(width, height, channels, kind)):
        raise ImageWriteError(f"mitsuba-whitted: cannot write '{path}': {oiio.geterror()}")
    try:
        out.write_image(pixels)
    finally:
        out.close()


def read_image(path: str | Path) -> np.ndarray:
    """Read an image as float32 (height, width, channels), as stored."""
    import OpenImageIO as oiio

    image = oiio.ImageInput.open(str(path))
    if image is None:
        raise ImageWriteError(f"mitsuba-whitted: cannot read '{path}': {oiio.geterror()}")
    try:
        return image.read_image(oiio.FLOAT)
    finally:
        image.close()
