"""PNG files of the run's figures (:func:`hilsim.telemetry.plot_common.save`).

Pillow's encoder, as matplotlib calls it, tries the five row filters on every row and keeps
an alpha channel that an opaque figure does not use. Rows without a filter, three bytes a
pixel when every pixel is opaque, and zlib's fastest level make a file of about the same size
for the figures' flat colours in about a third of the time (docs/performance.md, "The plots
after the show"). Written from the PNG specification (W3C, second edition): the signature,
then IHDR, pHYs (the resolution), tEXt (e.g. Software), IDAT and IEND, each chunk with its
length and CRC-32. Any PNG reader reads the pixels back exactly.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

SIGNATURE = b"\x89PNG\r\n\x1a\n"

#: zlib's level: 1, the fastest (flat colours and thin lines compress well at any level)
LEVEL = 1

_RGB, _RGBA = 2, 6  # IHDR colour types, 8 bits a sample


def _chunk(kind: bytes, data: bytes) -> bytes:
    crc = zlib.crc32(data, zlib.crc32(kind))
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)


def encode(rgba: np.ndarray, *, dpi: float, text: dict[str, str] | None = None) -> bytes:
    """The PNG file of ``rgba``, an image of ``(height, width, 4)`` bytes (red, green, blue,
    alpha; the top row first): RGB when every pixel is opaque, else RGBA. ``dpi`` is stored
    as pixels per metre (pHYs); ``text`` as tEXt chunks (Latin-1)."""
    height, width, depth = rgba.shape
    if depth != 4 or rgba.dtype != np.uint8:
        raise ValueError(f"expected (height, width, 4) uint8 RGBA, got {rgba.shape} {rgba.dtype}")
    opaque = bool((rgba[:, :, 3] == 255).all())
    pixels = rgba[:, :, :3] if opaque else rgba
    rows = np.zeros((height, 1 + width * pixels.shape[2]), dtype=np.uint8)  # column 0: filter 0
    rows[:, 1:] = pixels.reshape(height, -1)
    header = struct.pack(">IIBBBBB", width, height, 8, _RGB if opaque else _RGBA, 0, 0, 0)
    per_metre = int(dpi / 0.0254 + 0.5)
    parts = [
        SIGNATURE,
        _chunk(b"IHDR", header),
        _chunk(b"pHYs", struct.pack(">IIB", per_metre, per_metre, 1)),
    ]
    for key, value in (text or {}).items():
        parts.append(_chunk(b"tEXt", key.encode("latin-1") + b"\0" + value.encode("latin-1")))
    parts.append(_chunk(b"IDAT", zlib.compress(rows.tobytes(), LEVEL)))
    parts.append(_chunk(b"IEND", b""))
    return b"".join(parts)
