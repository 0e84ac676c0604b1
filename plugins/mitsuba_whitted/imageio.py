"""Writing rendered images with OpenImageIO.

Low dynamic range formats (PNG, JPEG) get the sRGB transfer curve and 8 bits;
high dynamic range formats (EXR, HDR, PFM) keep linear float32 values.
"""

from __future__ import annotations

import os
import shutil
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
    path = _known_format(path)
    write_pixels(path, stored_pixels(path, image))


def write_pixels(path: str | Path, pixels: np.ndarray) -> None:
    """Write (height, width, channels) pixels, already as the format of
    ``path`` stores them (uint8 sRGB for PNG and JPEG, float32 otherwise),
    whole or not at all."""
    path = _known_format(path)
    wanted = np.uint8 if path.suffix.lower() in LDR_SUFFIXES else np.float32
    if pixels.dtype != wanted:
        raise ImageWriteError(f"mitsuba-whitted: cannot write '{path}': its pixels "
                              f"are {pixels.dtype}, and the format stores {np.dtype(wanted)}.")
    height, width, channels = pixels.shape
    with _Encoder(path, width, height, channels) as encoder:
        encoder.check(encoder.out.write_image(pixels), "write_image")
        encoder.save()


def stored_pixels(path: Path, image: np.ndarray) -> np.ndarray:
    """Linear pixels as the format of ``path`` stores them: 8-bit sRGB
    (alpha linear) for PNG and JPEG, float32 otherwise."""
    image = np.ascontiguousarray(image, dtype=np.float32)
    if path.suffix.lower() not in LDR_SUFFIXES:
        return image
    colour = to_8bit(image[..., :3])
    if image.shape[2] == 4:  # alpha stays linear
        alpha = np.round(np.clip(image[..., 3:], 0, 1) * 255).astype(np.uint8)
        colour = np.concatenate([colour, alpha], axis=2)
    return colour


def stored_bytes(path: str | Path, width: int, height: int, channels: int) -> int:
    """How many bytes the pixels of such an image take as the format of
    ``path`` stores them (before compression)."""
    per_value = 1 if Path(path).suffix.lower() in LDR_SUFFIXES else 4
    return width * height * channels * per_value


def write_rows(path: str | Path, width: int, height: int, channels: int, render) -> None:
    """Write a linear image that arrives in bands of rows: ``render(put)``
    calls ``put(first_row, rows)`` with float32 arrays (rows, width,
    channels), top to bottom. Each band is encoded as it arrives, so the
    whole image is never in memory as floats; the file is written whole or
    not at all, as by :func:`write_image`."""
    path = _known_format(path)
    encoders = []  # made with the first band: a render refused before it meets no encoder

    def put(first_row: int, rows: np.ndarray) -> None:
        if not encoders:
            encoders.append(_Encoder(path, width, height, channels))
        encoders[0].check(encoders[0].out.write_scanlines(
            first_row, first_row + len(rows), 0, stored_pixels(path, rows)), "write_scanlines")

    try:
        render(put)
        if not encoders:
            raise cannot_write(path, "the render gave no rows")
        encoders[0].save()
    finally:
        for encoder in encoders:
            encoder.__exit__()


class _Encoder:
    """An OpenImageIO writer (``out``) open on an anonymous file in memory.

    OpenImageIO writes into memory so that no failure of the disk meets it:
    it reports some (a PNG written on a full disk still returns success,
    with the error kept aside), and its JPEG writer ends the whole process
    on one. The disk then sees only plain writes, whose errors Python
    raises."""

    def __init__(self, path: Path, width: int, height: int, channels: int):
        import OpenImageIO as oiio

        self.oiio, self.path = oiio, path
        self.out = oiio.ImageOutput.create(str(path))
        if self.out is None:
            raise cannot_write(path, f"OpenImageIO has no writer for it "
                                     f"({_oiio_reason(None, oiio)})")
        # The pixels' type as stored_pixels makes them for this format.
        kind = oiio.UINT8 if path.suffix.lower() in LDR_SUFFIXES else oiio.FLOAT
        self.memory = os.memfd_create("mitsuba-whitted-image")
        self.check(self.out.open(f"/proc/self/fd/{self.memory}",
                                 oiio.ImageSpec(width, height, channels, kind)), "open")

    def __enter__(self) -> "_Encoder":
        return self

    def __exit__(self, *exc) -> None:
        os.close(self.memory)

    def check(self, succeeded: bool, step: str) -> None:
        """Raise the sentence for ``step`` of the writer if it failed
        (returned false or left an error behind)."""
        if succeeded and not self.out.has_error:
            return
        reason_text = _oiio_reason(self.out, self.oiio)
        if step != "close":
            self.out.close()
        raise cannot_write(self.path, f"OpenImageIO's {step} failed while encoding it "
                                      f"({reason_text})")

    def save(self) -> None:
        """Close the writer, check it, and copy the encoded file to the
        path, whole or not at all."""
        self.check(self.out.close(), "close")
        with open(self.memory, "rb", closefd=False) as encoded:
            write_atomically(self.path, lambda file: shutil.copyfileobj(encoded, file, 1 << 24))


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
