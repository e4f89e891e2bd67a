"""Write 8-bit PNG files from NumPy arrays (zlib + struct, no imaging library).

Enough for the pictures the demo and the benchmarks draw; Blender is not
needed. Arrays are ``(H, W)``, ``(H, W, 3)`` or ``(H, W, 4)`` uint8, row 0 at
the top.
"""
from __future__ import annotations

import os
import struct
import zlib

import numpy as np

from ..io.atomic import atomic_path

__all__ = ["encode_png", "write_png"]

_COLOUR_TYPE = {1: 0, 3: 2, 4: 6}    # grey, RGB, RGBA


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def encode_png(array) -> bytes:
    """The PNG file's bytes for a uint8 image.

    Raises
    ------
    ValueError
        Not uint8, or not 1, 3 or 4 channels.
    """
    a = np.asarray(array)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.dtype != np.uint8:
        raise ValueError(f"encode_png: need uint8 pixels, got {a.dtype}")
    if a.ndim != 3 or a.shape[2] not in _COLOUR_TYPE or a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(f"encode_png: need (H, W), (H, W, 3) or (H, W, 4), got {a.shape}")
    h, w, c = a.shape
    # Filter type 0 (none) on every row: a zero byte in front of each scanline.
    raw = np.zeros((h, 1 + w * c), dtype=np.uint8)
    raw[:, 1:] = a.reshape(h, w * c)
    header = struct.pack(">IIBBBBB", w, h, 8, _COLOUR_TYPE[c], 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header)
            + _chunk(b"IDAT", zlib.compress(raw.tobytes(), 9)) + _chunk(b"IEND", b""))


def write_png(path, array):
    """Write a uint8 image as PNG (atomically: a failure leaves no partial file)."""
    data = encode_png(array)
    with atomic_path(os.fspath(path), suffix=".png") as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data)
