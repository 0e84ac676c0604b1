"""PNG files of the pixels the page shows, made in memory with ``zlib``:
quick to encode (the page waits for each), and no file on the disk."""

from __future__ import annotations

import struct
import zlib

import numpy as np

#: PNG's colour type by the number of 8-bit channels.
_COLOUR_TYPES = {1: 0, 2: 4, 3: 2, 4: 6}
#: Fast compression: the image crosses the loopback, not a network.
_LEVEL = 1


def encode(pixels: np.ndarray) -> bytes:
    """A PNG of ``pixels``: uint8 (height, width, channels), 1 to 4 channels."""
    height, width, channels = pixels.shape
    # Each row starts with its filter type, 0 (none).
    rows = np.zeros((height, 1 + width * channels), np.uint8)
    rows[:, 1:] = pixels.reshape(height, width * channels)
    header = struct.pack(">IIBBBBB", width, height, 8, _COLOUR_TYPES[channels], 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header)
            + _chunk(b"IDAT", zlib.compress(rows.tobytes(), _LEVEL)) + _chunk(b"IEND", b""))


def _chunk(kind: bytes, data: bytes) -> bytes:
    return (struct.pack(">I", len(data)) + kind + data
            + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))
