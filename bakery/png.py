"""PNG encoding of 8-bit images (RGB or RGBA, zlib level 9, filter 0 on every row, no colour chunks). Pure numpy +
zlib; used by the report's previews (:mod:`bakery.report.png`) and the glTF export's RGBD images."""

from __future__ import annotations

import struct
import zlib

import numpy as np

#: PNG colour type of each supported channel count (2: truecolour, 6: truecolour with alpha).
_COLOUR_TYPE = {3: 2, 4: 6}


def encode_png(pixels: np.ndarray) -> bytes:
    """PNG bytes of an (H, W, 3) or (H, W, 4) uint8 image."""
    pixels = np.ascontiguousarray(pixels, dtype=np.uint8)
    if pixels.ndim != 3 or pixels.shape[2] not in _COLOUR_TYPE:
        raise ValueError(f"encode_png needs (H, W, 3) or (H, W, 4), got {pixels.shape}")
    h, w, c = pixels.shape
    raw = b"".join(b"\x00" + pixels[i].tobytes() for i in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", w, h, 8, _COLOUR_TYPE[c], 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
