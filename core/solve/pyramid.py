"""Coarser copies of a problem, for coarse-to-fine solving.

Halving the texture and taking every other photo pixel keeps about as many
pixels per texel, so a coarse level costs a quarter of the fine one per
iteration, and TV spreads information twice as far per iteration. Pixels are
subsampled, not averaged: averaging UVs or normals across a seam or a
silhouette would invent surface that does not exist. The image-domain
correspondences whose source pixel survives are kept, in coarse coordinates.
"""

from __future__ import annotations

import numpy as np

from ..geometry.bilinear import interpolate, masked_corners
from ..geometry.texels import bilinear_texels, parent_texels
from ..masks import masked
from ..parallel import thread_map
from .problem import Correspondences, Problem, TextureLayout

__all__ = [
    "coarsen",
    "upsample_pixels",
    "upsample_bilinear",
    "upsample_onto",
    "seen_onto",
    "supported_size",
    "with_texture_size",
]

# Below these a level has too little data to say anything about the finer one.
MIN_SIZE = 32
MIN_PIXELS = 20_000


def _coarsen_layout(layout: TextureLayout) -> TextureLayout:
    n = layout.size // 2
    # The mean position of each 2x2 block's texels that have one (NaN for none), summed as np.nanmean does.
    total = np.zeros((n, n, 3), layout.texel_pos.dtype)
    count = np.zeros((n, n, 1), layout.texel_pos.dtype)
    for i in (0, 1):
        for j in (0, 1):
            q = layout.texel_pos[i : 2 * n : 2, j : 2 * n : 2]
            known = np.isfinite(q[..., :1])
            total += np.where(known, q, 0)
            count += known
    with np.errstate(invalid="ignore"):
        pos = total / count
    fine = layout.size
    pairs = layout.seam_pairs
    r, c = np.divmod(pairs, fine)
    coarse = (np.minimum(r // 2, n - 1)) * n + np.minimum(c // 2, n - 1)
    coarse = coarse[coarse[:, 0] != coarse[:, 1]]
    coarse = np.unique(np.sort(coarse, axis=1), axis=0) if coarse.size else coarse.reshape(0, 2)
    return TextureLayout(pos, coarse)


def _coarsen_correspondences(corr: Correspondences | None, fine: list, coarse: list) -> Correspondences | None:
    """The pairs whose source pixel is on the coarse grid, in coarse pixel coordinates.

    Coarse pixel ``(r, c)`` is fine pixel ``(2r, 2c)``; with pixel centres at
    integer coordinates, a fine position ``(x, y)`` is ``(x / 2, y / 2)`` on the
    coarse grid. Pairs that land outside the coarse image are dropped.
    """
    if corr is None:
        return None
    wf = np.array([m.shape[1] for m in fine])
    hc = np.array([m.shape[0] for m in coarse])
    wc = np.array([m.shape[1] for m in coarse])
    r, c = np.divmod(corr.pixel_a, wf[corr.view_a])
    xy = corr.xy_b * 0.5
    vb = corr.view_b
    keep = (r % 2 == 0) & (c % 2 == 0)
    keep &= (xy[:, 0] >= -0.5) & (xy[:, 1] >= -0.5) & (xy[:, 0] <= wc[vb] - 0.5) & (xy[:, 1] <= hc[vb] - 0.5)
    va = corr.view_a[keep]
    return Correspondences(
        view_a=va,
        pixel_a=(r[keep] // 2) * wc[va] + c[keep] // 2,
        view_b=vb[keep],
        xy_b=xy[keep],
        weight=corr.weight[keep],
    )


def coarsen(problem: Problem, texture: bool = True) -> Problem | None:
    """The problem at every other pixel (and half the texture size); None when too small to coarsen.

    Parameters
    ----------
    problem : Problem
    texture : bool
        Coarsen the texture layout too. False drops it (the image domain does
        not need it), and then its size does not limit the coarsening.

    Returns
    -------
    Problem or None
        None when a mask would be empty, the pixels would be fewer than
        ``MIN_PIXELS``, or the texture smaller than ``MIN_SIZE``.
    """
    layout = problem.texture if texture else None
    if layout is not None and layout.size < 2 * MIN_SIZE:
        return None
    sub = [np.ascontiguousarray(m[::2, ::2]) for m in problem.masks]
    if not all(m.any() for m in sub) or sum(int(m.sum()) for m in sub) < MIN_PIXELS:
        return None

    def half(seq):
        return None if seq is None else [np.ascontiguousarray(a[::2, ::2]) for a in seq]

    def half_rows(rows):  # per masked pixel: the rows of the pixels kept
        if rows is None:
            return None
        kept = [(np.cumsum(m.ravel()).reshape(m.shape) - 1)[::2, ::2][s] for m, s in zip(problem.masks, sub)]
        return [r[k] for r, k in zip(rows, kept)]

    return Problem(
        half(problem.images),
        sub,
        half(problem.normals),
        correspondences=_coarsen_correspondences(problem.correspondences, problem.masks, sub),
        uv=half(problem.uv),
        texture=None if layout is None else _coarsen_layout(layout),
        view_weight=half(problem.view_weight),
        names=list(problem.names),
        transfer=half_rows(problem.transfer),
        clipped=half(problem.clipped),
    )


def upsample_pixels(coarse: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """A coarse ``(h, w, C)`` view map sampled bilinearly at the fine mask's pixels.

    Coarse pixel ``(R, C)`` is fine pixel ``(2R, 2C)``, so fine ``(r, c)`` sits
    at ``(r / 2, c / 2)`` in the coarse map; only its finite (masked) pixels
    contribute. Returns ``(mask.sum(), C)``, NaN where none is near.
    """
    r, c = np.nonzero(mask)
    flat, w = masked_corners(c / 2.0, r / 2.0, np.isfinite(coarse[..., 0]))
    out = interpolate(coarse.reshape(-1, coarse.shape[-1]), flat, w, nan_as_zero=True)
    out[w.sum(axis=1) == 0] = np.nan
    return out


def supported_size(problem: Problem, texels_per_pixel: float) -> int:
    """The largest size, halving from the problem's texture, with at most ``texels_per_pixel`` seen texels per pixel.

    Texels beyond what the photos resolve carry no data of their own: TV fills
    them, at the cost of the whole solve. Never below ``MIN_SIZE``. (Coarser
    sizes count every texel in reach, not only those inside the islands.)
    """
    size = problem.texture.size
    pixels = sum(int(m.sum()) for m in problem.masks)
    while size // 2 >= MIN_SIZE:
        # Seen as the solver sees them: every texel a pixel's bilinear footprint reaches.
        inside = problem.texture.inside if size == problem.texture.size else np.ones((size, size), bool)
        hit = np.zeros(size * size, dtype=bool)
        for uv, m in zip(problem.uv, problem.masks):
            idx, w = bilinear_texels(masked(uv, m), inside)
            hit[idx[w > 0]] = True
        if np.count_nonzero(hit) <= texels_per_pixel * pixels:
            break
        size //= 2
    return size


def with_texture_size(problem: Problem, size: int) -> Problem:
    """The same photos on the texture layout halved down to ``size``."""
    layout = problem.texture
    while layout.size > size:
        layout = _coarsen_layout(layout)
    return problem.on_layout(layout)


def upsample_bilinear(coarse: np.ndarray, seen: np.ndarray, layout: TextureLayout):
    """A coarse ``(n, n, C)`` texture sampled bilinearly at the texel centres of a finer ``layout``.

    Only ``seen`` coarse texels contribute. A fine texel is seen when it is
    inside an island and the coarse texel it lies in was seen. Returns the
    ``(N, N, C)`` texture, NaN where not seen, and the seen mask.
    """
    return upsample_onto(coarse, seen, layout.inside)


def upsample_onto(coarse: np.ndarray, seen: np.ndarray, target: np.ndarray):
    """:func:`upsample_bilinear` at the texels of ``target``, an ``(N, N)`` bool mask, in place of a layout's
    islands; any ratio of the sizes, on the grid (no lookup per texel)."""
    size, n, channels = target.shape[0], seen.shape[0], coarse.shape[-1]
    # Channels first, the seen weight as one more, padded by a texel of weight 0 each side.
    padded = np.zeros((channels + 1, n + 2, n + 2), np.float32)
    padded[:channels, 1:-1, 1:-1] = np.moveaxis(np.where(seen[..., None], np.nan_to_num(coarse), 0), -1, 0)
    padded[channels, 1:-1, 1:-1] = seen
    # Sums of weight x value, and of weight, over the seen corners: rows, then columns, a channel at a time.
    rows = [_along(plane, 0, size) for plane in padded]  # (size, n + 2) each
    # Where the texel's own coarse texel was seen, it has at least a quarter of the weight: den > 0.
    fine_seen = seen_onto(seen, target)
    out = np.empty((size, size, channels), np.float32)

    def block(r0):  # the columns a block of rows at a time, on every core: each block stays in the cache
        r = slice(r0, r0 + _UPSAMPLE_ROWS)
        den = _along(rows[channels][r], 1, size)
        scale = np.divide(1.0, den, out=np.full_like(den, np.nan), where=fine_seen[r])
        for k in range(channels):
            value = _along(rows[k][r], 1, size)
            value *= scale
            out[r, :, k] = value

    thread_map(block, range(0, size, _UPSAMPLE_ROWS))
    return out, fine_seen


# Rows of :func:`upsample_onto`'s output made at a time.
_UPSAMPLE_ROWS = 64


def seen_onto(seen: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The texels of ``target`` (an ``(N, N)`` bool mask) that :func:`upsample_onto` gives a value from the
    coarser ``seen``: those whose own coarse texel was seen."""
    parent = parent_texels(target.shape[0], seen.shape[0])
    return target & seen[parent][:, parent]


def _along(a, axis, size):
    """``a`` (2-D, padded along ``axis`` by a zero each side) sampled linearly at ``size`` texel centres there.

    Texel ``i`` of ``size`` has its centre at ``(i + 0.5) * n / size - 0.5`` in the ``n`` texels' coordinates:
    at twice the size, a quarter of a texel from the centres (weights 1/4 and 3/4).
    """
    n = a.shape[axis] - 2
    at = (np.arange(size) + 0.5) * n / size - 0.5
    below = np.floor(at).astype(np.intp)
    frac = (at - below).astype(np.float32)
    shape = (size, 1) if axis == 0 else (1, size)
    out = np.take(a, below + 1, axis=axis)
    out *= (1 - frac).reshape(shape)
    out += np.take(a, below + 2, axis=axis) * frac.reshape(shape)
    return out
