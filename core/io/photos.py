"""Photo pixels: the sRGB curve both ways, and area-averaged downscaling."""

from __future__ import annotations

import numpy as np
from scipy import sparse

__all__ = ["srgb_to_linear", "linear_to_srgb", "working_size", "downscale", "clipped_pixels", "CLIP_CODE"]

#: 8-bit code from which a channel counts as clipped: JPEG ringing spreads a saturated area's 255 over
#: nearby codes, and a pixel whose true value lay beyond the ceiling says nothing about its albedo.
CLIP_CODE = 250


def srgb_to_linear(values):
    """The exact sRGB EOTF (IEC 61966-2-1) of values in [0, 1]."""
    v = np.asarray(values, dtype=np.float32)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(values):
    """The inverse of :func:`srgb_to_linear`: linear values in [0, 1] (clipped first) to sRGB-encoded ones."""
    v = np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)


def _area_matrix(n_in, n_out):
    """Sparse ``(n_out, n_in)`` box-filter matrix: output pixel j averages input [j, j+1) * n_in/n_out."""
    ratio = n_in / n_out
    k = int(np.ceil(ratio)) + 1
    j = np.repeat(np.arange(n_out), k)
    lo = np.arange(n_out) * ratio
    i = (np.floor(lo).astype(np.int64)[:, None] + np.arange(k)).ravel()
    a = np.repeat(lo, k)
    b = a + ratio
    overlap = np.clip(np.minimum(i + 1, b) - np.maximum(i, a), 0.0, None) / ratio
    ok = (overlap > 0) & (i < n_in)
    # float32 as the photos are: a float64 matrix would make scipy copy each photo to float64 first (5x slower).
    return sparse.csr_matrix((overlap[ok].astype(np.float32), (j[ok], i[ok])), shape=(n_out, n_in))


def working_size(h, w, max_mp):
    """``(H', W')``: the size :func:`downscale` brings an ``H`` x ``W`` photo to."""
    if max_mp is None or max_mp <= 0 or w * h <= max_mp * 1e6:
        return h, w
    s = np.sqrt(max_mp * 1e6 / (w * h))
    return max(1, int(np.floor(h * s))), max(1, int(np.floor(w * s)))


def downscale(photo, max_mp):
    """Area-average a photo down to at most ``max_mp`` megapixels.

    Returns
    -------
    photo : (H', W', 3) float32
    scale : (sx, sy)
        ``W'/W`` and ``H'/H`` (1, 1 when the photo already fits).
    """
    h, w = photo.shape[:2]
    h2, w2 = working_size(h, w, max_mp)
    if (h2, w2) == (h, w):
        return photo, (1.0, 1.0)
    ay, ax = _area_matrix(h, h2), _area_matrix(w, w2)
    c = photo.shape[2]
    rows = (ay @ photo.reshape(h, w * c)).reshape(h2, w, c)
    cols = ax @ rows.transpose(1, 0, 2).reshape(w, h2 * c)
    out = cols.reshape(w2, h2, c).transpose(1, 0, 2)
    return np.ascontiguousarray(out, dtype=np.float32), (w2 / w, h2 / h)


def clipped_pixels(codes, code: int = CLIP_CODE) -> np.ndarray:
    """Pixels of an 8-bit photo at or above ``code`` in some channel, ``(H, W)`` bool.

    ``codes`` are the photo's 8-bit codes, as integers or as ``Image.pixels`` holds them for an 8-bit image
    (code / 255), so that clipping is judged before any colour-space decoding.
    """
    codes = np.asarray(codes)
    level = code if np.issubdtype(codes.dtype, np.integer) else (code - 0.5) / 255.0
    # Channel by channel: np.any over a last axis of 3 reduces each pixel on its own, several times slower.
    out = codes[..., 0] >= level
    for k in range(1, codes.shape[-1]):
        out |= codes[..., k] >= level
    return out
