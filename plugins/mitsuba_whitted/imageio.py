"""Writing rendered images with OpenImageIO.

Low dynamic range formats (PNG, JPEG) get the sRGB transfer curve and 8 bits;
high dynamic range formats (EXR, HDR, PFM) keep linear float32 values.

An image is luminance or RGB, then perhaps alpha, with its colour associated
with alpha, as a film develops it (a pixel half covered holds half its
colour). PNG and EXR keep alpha, PNG with the colour unassociated from it as
its specification asks; JPEG, HDR and PFM have no alpha and store the colour
alone, which is the image over black; HDR stores RGB only, so luminance is
repeated in its three channels.
"""

from __future__ import annotations

import os
import shutil
from contextlib import contextmanager
from functools import cache
from pathlib import Path

import numpy as np

from .files import ReadError, WriteError, cannot_write, check_writable, write_atomically
from .system import available_memory, available_text, size_text

HDR_SUFFIXES = {".exr", ".hdr", ".pfm"}
LDR_SUFFIXES = {".png", ".jpg", ".jpeg"}
ALPHA_SUFFIXES = {".png", ".exr"}
RGB_ONLY_SUFFIXES = {".hdr"}


class ImageFormatError(WriteError):
    """An image cannot be written in the format asked for: its suffix
    names no format this package writes, or its pixels are not of the
    format's type."""


def linear_to_srgb(values: np.ndarray) -> np.ndarray:
    """The sRGB transfer curve (IEC 61966-2-1) on values clamped to [0, 1]."""
    v = np.clip(values, 0.0, 1.0)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.power(v, 1 / 2.4) - 0.055)


def to_8bit(linear: np.ndarray) -> np.ndarray:
    return np.round(linear_to_srgb(linear) * 255).astype(np.uint8)


def check_image_path(path: str | Path) -> Path:
    """``path`` if an image can be written there (a known suffix, a
    writable folder), else an :class:`ImageFormatError`; checked before a
    render, so that none is thrown away."""
    return _known_format(check_writable(path))


def _known_format(path: str | Path) -> Path:
    path = Path(path)
    if path.suffix.lower() not in HDR_SUFFIXES | LDR_SUFFIXES:
        raise ImageFormatError(
            f"cannot write '{path}': use one of "
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
        raise ImageFormatError(f"cannot write '{path}': its pixels "
                              f"are {pixels.dtype}, and the format stores {np.dtype(wanted)}.")
    height, width, channels = pixels.shape
    with _Encoder(path, width, height, channels) as encoder:
        encoder.check(encoder.out.write_image(pixels), "write_image")
        encoder.save()


def png_bytes(pixels: np.ndarray) -> bytes:
    """A PNG of 8-bit ``pixels`` (height, width, channels), made in memory
    by Mitsuba's bitmap writer at its fastest compression, for a page that
    waits for each image."""
    import mitsuba as mi

    stream = mi.MemoryStream()
    mi.Bitmap(np.ascontiguousarray(pixels)).write(stream, mi.Bitmap.FileFormat.PNG, 1)
    return bytes(stream.raw_buffer())


def stored_pixels(path: Path, image: np.ndarray) -> np.ndarray:
    """Linear pixels (height, width, channels) as the format of ``path``
    stores them (see the module's docstring): 8-bit sRGB with linear alpha
    for PNG and JPEG, float32 otherwise."""
    image = np.ascontiguousarray(image, dtype=np.float32)
    suffix = path.suffix.lower()
    colours, alphas = _layout(image.shape[2])
    colour, alpha = image[..., :colours], image[..., colours:]
    if suffix in RGB_ONLY_SUFFIXES:
        colour = np.repeat(colour, 3 // colours, axis=2)
    keeps_alpha = alphas and suffix in ALPHA_SUFFIXES
    if suffix not in LDR_SUFFIXES:
        return np.concatenate([colour, alpha], axis=2) if keeps_alpha \
            else np.ascontiguousarray(colour)
    if not keeps_alpha:
        return to_8bit(colour)
    alpha = np.clip(alpha, 0, 1)
    straight = np.divide(colour, alpha, out=colour.copy(), where=alpha > 0)
    return np.concatenate([to_8bit(straight), np.round(alpha * 255).astype(np.uint8)], axis=2)


def stored_channels(path: str | Path, channels: int) -> int:
    """How many channels an image of ``channels`` has in the format of
    ``path``."""
    suffix = Path(path).suffix.lower()
    colours, alphas = _layout(channels)
    return (3 if suffix in RGB_ONLY_SUFFIXES else colours) \
        + (alphas if suffix in ALPHA_SUFFIXES else 0)


def _layout(channels: int) -> tuple[int, int]:
    """Colour channels (luminance or RGB) and alpha channels (0 or 1) of
    an image of ``channels``."""
    return (1 if channels <= 2 else 3), (1 if channels in (2, 4) else 0)


def stored_bytes(path: str | Path, width: int, height: int, channels: int) -> int:
    """How many bytes the pixels of such an image take as the format of
    ``path`` stores them (before compression)."""
    per_value = 1 if Path(path).suffix.lower() in LDR_SUFFIXES else 4
    return width * height * stored_channels(path, channels) * per_value


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
            encoders.append(_Encoder(path, width, height, stored_channels(path, channels)))
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
        # By the format's extension, which is ASCII (_known_format), not the
        # path: OpenImageIO takes names as UTF-8 only, and it writes to
        # memory here.
        self.out = oiio.ImageOutput.create(path.suffix[1:])
        if self.out is None:
            raise cannot_write(path, f"OpenImageIO has no writer for it "
                                     f"({_oiio_reason(None, oiio)})")
        self.memory = os.memfd_create("mitsuba-whitted-image")
        self.check(self.out.open(f"/proc/self/fd/{self.memory}",
                                 _spec(oiio, path, width, height, channels)), "open")

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


def _spec(oiio, path: Path, width: int, height: int, channels: int):
    """What OpenImageIO is told of the pixels :func:`stored_pixels` makes
    for ``path``: their type, their channels (luminance or RGB, then
    perhaps alpha), and for PNG that their colour is already unassociated
    from alpha, which OpenImageIO would otherwise divide by alpha once
    more, after the sRGB curve."""
    ldr = path.suffix.lower() in LDR_SUFFIXES
    spec = oiio.ImageSpec(width, height, channels, oiio.UINT8 if ldr else oiio.FLOAT)
    colours, alphas = _layout(channels)
    if colours == 1:
        spec.channelnames = ("Y", "A")[:channels]
    spec.alpha_channel = channels - 1 if alphas else -1
    if ldr:
        spec.attribute("oiio:UnassociatedAlpha", 1)
    return spec


def _oiio_reason(out, oiio) -> str:
    """OpenImageIO's error message, which is often empty."""
    text = (out.geterror() if out is not None else "") or oiio.geterror()
    return " ".join(text.split()) or "it gave no reason"


def read_image(path: str | Path) -> np.ndarray:
    """Read an image as float32 (height, width, channels), as stored; a
    :class:`~.files.ReadError` for one that OpenImageIO cannot read, or
    whose pixels would not fit in the memory available (:func:`too_large`)."""
    import OpenImageIO as oiio

    with _opened(path) as image:
        refusal = _refusal(image)
        if refusal:
            raise ReadError(f"cannot read '{path}': {refusal}.")
        return image.read_image(oiio.FLOAT)


def image_refusal(path: str | Path) -> str | None:
    """Why the image at ``path`` cannot be read into memory, as
    :func:`read_image` says it; ``None`` if it can, or if ``path`` is not
    named as an image that OpenImageIO reads (a mesh, a spectrum)."""
    if Path(path).suffix.lower()[1:] not in _image_extensions():
        return None
    with _opened(path) as image:
        return _refusal(image)


def _refusal(image) -> str | None:
    """Why the image OpenImageIO has opened (``None``: could not open)
    cannot be read into memory; ``None`` if it can. OpenImageIO refuses a
    header that declares more pixels than its file can hold (more than
    10000 times its size)."""
    if image is None:
        import OpenImageIO as oiio

        return f"OpenImageIO cannot read it ({_oiio_reason(None, oiio)})"
    return too_large(image.spec(), available_memory())


def too_large(spec, available: int | None) -> str | None:
    """Why an image whose header is ``spec`` would not fit in ``available``
    bytes as float32, as :func:`read_image` and Mitsuba's ``bitmap`` hold
    its pixels; ``None`` if it fits (or the memory is not known). A header
    can declare any size, and the allocation that fails is then
    ``std::bad_alloc`` in the middle of a scene's loading."""
    needed = spec.width * spec.height * max(spec.depth, 1) * spec.nchannels * 4
    if available is None or needed <= available:
        return None
    return (f"its header declares {spec.width} x {spec.height} pixels of {spec.nchannels} "
            f"channels, {size_text(needed)} as float32, and {available_text(available)}")


@contextmanager
def _opened(path: str | Path):
    """An OpenImageIO reader open on ``path`` (its header read, no pixel),
    or ``None`` if it reads no image there; closed after the block.
    OpenImageIO's own limit on the size a header declares is lifted for the
    opening: it caps at 32 GiB, refusing images that fit in this machine's
    memory, and counts bytes as stored, letting others through that do not
    fit as float32; :func:`too_large` decides instead."""
    import OpenImageIO as oiio

    limit = oiio.get_int_attribute("limits:imagesize_MB")
    oiio.attribute("limits:imagesize_MB", 0)
    try:
        image = oiio.ImageInput.open(str(path))
    finally:
        oiio.attribute("limits:imagesize_MB", limit)
    try:
        yield image
    finally:
        if image is not None:
            image.close()


@cache
def _image_extensions() -> set[str]:
    """The file extensions OpenImageIO reads (it lists them as
    "tiff:tif,tiff;png:png;...")."""
    import OpenImageIO as oiio

    formats = oiio.get_string_attribute("extension_list").split(";")
    return {extension for entry in formats for extension in entry.partition(":")[2].split(",")}
