"""Bilinear lookups on a pixel or texel grid: the four corners and their weights.

Continuous coordinates put the centre of cell ``(row r, col c)`` at ``(x, y) = (c, r)``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["clamped_corners", "masked_corners", "interpolate"]


def clamped_corners(x, y, w, h):
    """Corners (flat indices ``(K, 4)``) and weights of lookups at ``(x, y)`` inside a ``(h, w)`` grid.

    The last row and column reuse their neighbour as the lower corner, so a
    point on the far border gets its whole weight from the border cells.
    """
    x0 = np.clip(np.floor(x).astype(np.intp), 0, max(w - 2, 0))
    y0 = np.clip(np.floor(y).astype(np.intp), 0, max(h - 2, 0))
    fx, fy = x - x0, y - y0
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    idx = np.stack([y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1], axis=1)
    wts = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], axis=1)
    return idx, wts


def masked_corners(x, y, valid):
    """Four corners (flat indices into a (H, W) grid) and weights of continuous (x, y).

    Corners outside the grid or where ``valid`` is False get weight 0; the rest
    are renormalised. Returns ``corners (K, 4)``, ``weights (K, 4)``.
    """
    h, w = valid.shape
    x0 = np.floor(x).astype(np.intp)
    y0 = np.floor(y).astype(np.intp)
    fx = (x - x0).astype(np.float32)
    fy = (y - y0).astype(np.float32)
    xs = np.stack([x0, x0 + 1, x0, x0 + 1], axis=1)
    ys = np.stack([y0, y0, y0 + 1, y0 + 1], axis=1)
    wts = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], axis=1)
    inside = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)
    xs = np.clip(xs, 0, w - 1)
    ys = np.clip(ys, 0, h - 1)
    flat = ys * w + xs
    ok = inside & valid.ravel()[flat]
    wts = np.where(ok, wts, 0)
    total = wts.sum(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        wts = np.where(total > 0, wts / total, 0).astype(np.float32)
    return flat, wts


def interpolate(values, corners, weights, nan_as_zero: bool = False):
    """The weighted sum of ``values`` (flat cells first, (N, ...) ) at ``corners`` (K, 4): (K, ...).

    With ``nan_as_zero``, NaN cells count as 0 (replaced in the values looked up, not in a copy of all).
    """
    v = values[corners]
    if nan_as_zero:
        np.nan_to_num(v, copy=False)
    return np.einsum("kj,kj...->k...", weights, v)
