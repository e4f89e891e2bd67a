"""Photo pixels: the sRGB curve both ways, area-averaged downscaling, and 8-bit photos kept as their codes."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy import sparse

__all__ = [
    "srgb_to_linear",
    "linear_to_srgb",
    "photo_working_mp",
    "working_size",
    "downscale",
    "clipped_pixels",
    "CLIP_CODE",
    "CodedPhoto",
    "photo_pixels",
    "photo_scaled",
]

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


def photo_working_mp(per_photo, total, n_photos):
    """The megapixels each of ``n_photos`` photos is downscaled to at most: ``per_photo``, less where the photos
    together would exceed ``total`` (``None`` or ``0``: no limit, as for ``per_photo``)."""
    if not total or total <= 0 or n_photos < 1:
        return per_photo
    share = total / n_photos
    return share if per_photo is None or per_photo <= 0 or share < per_photo else per_photo


def working_size(h, w, max_mp):
    """``(H', W')``: the size :func:`downscale` brings an ``H`` x ``W`` photo to."""
    if max_mp is None or max_mp <= 0 or w * h <= max_mp * 1e6:
        return h, w
    s = np.sqrt(max_mp * 1e6 / (w * h))
    return max(1, int(np.floor(h * s))), max(1, int(np.floor(w * s)))


def downscale(photo, max_mp):
    """Area-average a photo down to at most ``max_mp`` megapixels.

    ``photo``: ``(H, W, C)`` float32, or an 8-bit one's :class:`CodedPhoto`, whose colours are worked out a few
    rows at a time and never held whole. The output is made in blocks of rows, each from the input rows it
    averages: the same sums in the same order as over the whole photo at once, with each block in the cache.

    Returns
    -------
    photo : (H', W', C) float32
    scale : (sx, sy)
        ``W'/W`` and ``H'/H`` (1, 1 when the photo already fits).
    """
    coded = isinstance(photo, CodedPhoto)
    h, w = photo.shape[:2]
    h2, w2 = working_size(h, w, max_mp)
    if (h2, w2) == (h, w):
        return photo.colours() if coded else photo, (1.0, 1.0)
    ay, ax = _area_matrix(h, h2), _area_matrix(w, w2)
    c = photo.shape[2]
    out = np.empty((h2, w2, c), np.float32)
    for i0 in range(0, h2, _DOWNSCALE_ROWS):
        i1 = min(i0 + _DOWNSCALE_ROWS, h2)
        part = ay[i0:i1]
        j0, j1 = int(part.indices.min()), int(part.indices.max()) + 1
        block = photo.rows(j0, j1) if coded else photo[j0:j1]
        rows = (part[:, j0:j1] @ block.reshape(j1 - j0, w * c)).reshape(i1 - i0, w, c)
        cols = ax @ rows.transpose(1, 0, 2).reshape(w, (i1 - i0) * c)
        out[i0:i1] = cols.reshape(w2, i1 - i0, c).transpose(1, 0, 2)
    return out, (w2 / w, h2 / h)


# Output rows of :func:`downscale` made at a time.
_DOWNSCALE_ROWS = 8


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


# Rows of codes turned into colours at a time: the codes and their colours stay in cache.
_CODE_ROWS = 64


@dataclass
class CodedPhoto:
    """An 8-bit photo as its codes and the tables that give their linear colours: a quarter of its float32 size.

    Codes ``(r, g, b)`` have the colour ``tables[0][r] + tables[1][g] + tables[2][b]`` (a colour space that is a
    curve per channel and then a matrix), times ``gains`` per channel if set; a grey photo's one code stands for
    all three channels. The colours are worked out where they are read, so a photo read for a few pixels at a
    time is never held as floats.
    """

    codes: np.ndarray  # (H, W, 3) or, grey, (H, W, 1) uint8, row 0 at the top
    tables: np.ndarray  # (3, 256, 3) float32
    gains: np.ndarray | None = None  # (3,) float32
    # Where each channel's colour depends on its own code alone (sRGB, Non-Color, linear Rec.709): the three
    # channels' curves, (3, 256).
    _curves: np.ndarray | None = field(init=False, repr=False, default=None)

    def __post_init__(self):
        t = self.tables
        if all(np.all(t[k][:, j] == 0) for k in range(3) for j in range(3) if j != k):
            self._curves = np.stack([t[k][:, k] for k in range(3)])

    @property
    def shape(self) -> tuple:
        """``(H, W, 3)``, as the photo's colours."""
        return (*self.codes.shape[:2], 3)

    def scaled(self, gains) -> CodedPhoto:
        """The photo with its colours times ``gains`` ``(3,)`` float32 (the same numbers as ``colours() * gains``)."""
        return replace(self, gains=np.asarray(gains, np.float32))

    def colours(self) -> np.ndarray:
        """The whole photo's colours, ``(H, W, 3)`` float32."""
        h, w = self.codes.shape[:2]
        out = np.empty((h, w, 3), np.float32)
        for r0 in range(0, h, _CODE_ROWS):
            rows = slice(r0, r0 + _CODE_ROWS)
            out[rows] = self._colours_of(self.codes[rows])
        return out

    def rows(self, r0: int, r1: int) -> np.ndarray:
        """The colours ``(r1 - r0, W, 3)`` float32 of rows ``r0`` to ``r1``."""
        return self._colours_of(self.codes[r0:r1])

    def pixels(self, rows: slice, index) -> np.ndarray:
        """The colours ``(P, 3)`` float32 of the pixels ``index`` (flat, row by row) of the rows ``rows``."""
        codes = self.codes[rows]
        return self._colours_of(np.take(codes.reshape(-1, codes.shape[-1]), index, axis=0))

    def _colours_of(self, codes):
        grey = codes.shape[-1] == 1
        if self._curves is not None:  # channel by channel, each code looked up in its own curve
            out = np.empty((*codes.shape[:-1], 3), np.float32)
            for k in range(3):
                # Every index is in range; "raise" would buffer.
                np.take(self._curves[k], codes[..., 0 if grey else k], out=out[..., k], mode="clip")
        else:
            if grey:
                codes = np.repeat(codes, 3, axis=-1)
            t = self.tables
            out = t[0][codes[..., 0]] + t[1][codes[..., 1]] + t[2][codes[..., 2]]
        if self.gains is not None:
            out *= self.gains
        return out


def photo_pixels(photo, rows: slice, index) -> np.ndarray:
    """The colours ``(P, C)`` float32 of the pixels ``index`` (flat, row by row) of a photo's rows ``rows``.

    ``photo``: ``(H, W, C)`` float32, or a :class:`CodedPhoto`.
    """
    if isinstance(photo, CodedPhoto):
        return photo.pixels(rows, index)
    part = photo[rows]
    return np.take(part.reshape(-1, part.shape[-1]), index, axis=0)  # rows by index: np.take is several times faster


def photo_scaled(photo, gains):
    """``photo`` (an array or a :class:`CodedPhoto`) with its colours times ``gains`` per channel."""
    return photo.scaled(gains) if isinstance(photo, CodedPhoto) else photo * gains
