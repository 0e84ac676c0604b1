"""Writing rendered images with OpenImageIO.

Low dynamic range formats (PNG, JPEG) get the sRGB transfer curve and 8 bits;
high dynamic range formats (EXR, HDR, PFM) keep linear float32 values.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .files import WriteError, cannot_write, check_writable, write_atomically

HDR_SUFFIXES = {".exr", ".hdr", ".pfm"}
LDR_SUFFIXES = {".png", ".jpg", ".jpeg"}


class ImageWriteError(WriteError):
    """The image could not be written."""


def linear_to_srgb(values: np.ndarray) -> np.ndarray:
    """The sRGB transfer curve (IEC 61966-2-1) on values clamped to [0, 1]."""
    v = np.clip(values, 0.0, 1.0)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.power(v, 1 / 2.4) - 0.055)


def to_8bit(linear: np.ndarray) -> np.ndarray:
    return np.round(linear_to_srgb(linear) * 255).astype(np.uint8)


def check_image_path(path: str | Path) -> Path:
    """``path`` if an image can be written there (a known suffix, a
    writable folder), else an :class:`ImageWriteError`; checked before a
    render, so that none is thrown away."""
    return check_writable(_known_format(path))


def _known_format(path: str | Path) -> Path:
    path = Path(path)
    if path.suffix.lower() not in HDR_SUFFIXES | LDR_SUFFIXES:
        raise ImageWriteError(
            f"mitsuba-whitted: cannot write '{path}': use one of "
            f"{', '.join(sorted(HDR_SUFFIXES | LDR_SUFFIXES))}.")
    return path


def write_image(path: str | Path, image: np.ndarray) -> None:
    """Write an (height, width, channels) linear image to ``path``, whole
    or not at all."""
    path = Path(path)
    image = np.ascontiguousarray(image, dtype=np.float32)
    if path.suffix.lower() in LDR_SUFFIXES:
        colour = to_8bit(image[..., :3])
        if image.shape[2] == 4:  # alpha stays linear
            alpha = np.round(np.clip(image[..., 3:], 0, 1) * 255).astype(np.uint8)
            colour = np.concatenate([colour, alpha], axis=2)
        image = colour
    write_pixels(path, image)


def write_pixels(path: str | Path, pixels: np.ndarray) -> None:
    """Write (height, width, channels) pixels as they are (uint8 or
    float32) to ``path``, whole or not at all."""
    path = _known_format(path)
    data = encode(path, pixels)
    write_atomically(path, lambda file: file.write(data))


def encode(path: Path, pixels: np.ndarray) -> bytes:
    """The bytes of ``pixels`` in the format of ``path``'s suffix.

    OpenImageIO writes them into an anonymous file in memory, so that no
    failure of the disk meets it: it reports some (a PNG written on a full
    disk still returns success, with the error kept aside), and its JPEG
    writer ends the whole process on one. The disk then sees only plain
    writes, whose errors Python raises."""
    import OpenImageIO as oiio

    height, width, channels = pixels.shape
    kind = oiio.UINT8 if pixels.dtype == np.uint8 else oiio.FLOAT
    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise cannot_write(path, f"OpenImageIO has no writer for it ({_oiio_reason(None, oiio)})")
    memory = os.memfd_create("mitsuba-whitted-image")
    try:
        failed = _failed_step(out, f"/proc/self/fd/{memory}",
                              oiio.ImageSpec(width, height, channels, kind), pixels)
        if failed is not None:
            raise cannot_write(path, f"OpenImageIO's {failed} failed while encoding it "
                                     f"({_oiio_reason(out, oiio)})")
        with open(memory, "rb", closefd=False) as encoded:
            return encoded.read()
    finally:
        os.close(memory)


def _failed_step(out, name: str, spec, pixels: np.ndarray) -> str | None:
    """Open, write and close ``out``; the first step that fails (returns
    false or leaves an error behind), or ``None``."""
    for step, call in (("open", lambda: out.open(name, spec)),
                       ("write_image", lambda: out.write_image(pixels)),
                       ("close", out.close)):
        if not call() or out.has_error:
            if step != "close":
                out.close()
            return step
    return None


def _oiio_reason(out, oiio) -> str:
    """OpenImageIO's error message, which is often empty."""
    text = (out.geterror() if out is not None else "") or oiio.geterror()
    return " ".join(text.split()) or "it gave no reason"


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
