"""PNG files of 8-bit RGB pixels, written with zlib and struct alone (the PNG specification, ISO/IEC 15948).

``sarbot image`` writes a picture beside every image; a plotting library costs half a second to import
for what is a header, the pixel rows deflated, and a checksum per chunk.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_RGB = 2  # IHDR colour type: truecolour, three samples per pixel
_METRES_PER_INCH = 0.0254


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def encode_png(rgb: np.ndarray, *, text: dict[str, str] | None = None, dpi: float | None = None,
               compress_level: int = 1) -> bytes:
    """The PNG file of ``rgb`` [height, width, 3] uint8, top row first.

    Parameters
    ----------
    text : dict, optional
        Keyword -> text, each a ``tEXt`` chunk (Latin-1; keywords such as "Title", "Description", "Software").
    dpi : float, optional
        Pixel density for viewers that print (a ``pHYs`` chunk).
    compress_level : int
        zlib's level; 1, the fastest, by default (a picture is written once per image and seldom kept).
    """
    rgb = np.ascontiguousarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8 or 0 in rgb.shape[:2]:
        raise ValueError(f"expected uint8 pixels [height, width, 3], got {rgb.dtype} {rgb.shape}")
    height, width = rgb.shape[:2]
    rows = np.zeros((height, 1 + 3 * width), np.uint8)  # each row: filter type 0 (none), then its pixels
    rows[:, 1:] = rgb.reshape(height, 3 * width)
    out = [_SIGNATURE, _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, _RGB, 0, 0, 0))]
    if dpi:
        per_metre = round(dpi / _METRES_PER_INCH)
        out.append(_chunk(b"pHYs", struct.pack(">IIB", per_metre, per_metre, 1)))
    for keyword, value in (text or {}).items():
        out.append(_chunk(b"tEXt", keyword.encode("latin-1") + b"\0" + value.encode("latin-1", "replace")))
    out += [_chunk(b"IDAT", zlib.compress(rows.tobytes(), compress_level)), _chunk(b"IEND", b"")]
    return b"".join(out)


def write_png(path: str | Path, rgb: np.ndarray, **kwargs) -> Path:
    """Write ``encode_png(rgb, **kwargs)`` to ``path`` (its folder created) and return the path."""
    path = Path(path)
    data = encode_png(rgb, **kwargs)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path
