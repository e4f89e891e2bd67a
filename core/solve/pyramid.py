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
from ..geometry.texels import bilinear_texels, uv_of_texel
from .problem import Correspondences, Problem, TextureLayout

__all__ = ["coarsen", "upsample_pixels", "upsample_bilinear", "supported_size", "with_texture_size"]

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
            idx, w = bilinear_texels(uv[m], inside)
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
    if layout.size == 2 * seen.shape[0]:
        return _upsample_twice(coarse, seen, layout.inside)
    return _upsample_lookup(coarse, seen, layout.inside)


def _upsample_lookup(coarse, seen, inside):
    """:func:`upsample_bilinear` by a bilinear lookup per fine texel (any ratio of sizes)."""
    size, n = inside.shape[0], seen.shape[0]
    parent = np.minimum(np.arange(size) * n // size, n - 1)
    r, c = np.nonzero(inside & seen[parent][:, parent])
    idx, w = bilinear_texels(uv_of_texel(r, c, size), seen)
    fine = np.full((size, size, coarse.shape[-1]), np.nan, dtype=np.float32)
    ok = w.sum(axis=1) > 0
    fine[r[ok], c[ok]] = interpolate(coarse.reshape(-1, coarse.shape[-1]), idx[ok], w[ok], nan_as_zero=True)
    return fine, np.isfinite(fine[..., 0])


# Texel centres of a texture twice as large fall a quarter of a coarse texel from the coarse centres: fine row
# 2k is at coarse row k - 1/4 (weights 1/4, 3/4 on rows k - 1, k), 2k + 1 at k + 1/4 (3/4, 1/4 on k, k + 1).
def _twice(a, axis):
    """The bilinear weights above along ``axis`` of ``a``, which is padded there with a zero each side."""
    n = a.shape[axis] - 2
    shape = list(a.shape)
    shape[axis] = 2 * n
    out = np.empty(shape, a.dtype)

    def part(s):
        return (slice(None),) * axis + (s,)

    centre = a[part(slice(1, n + 1))]
    for parity, side in ((0, slice(0, n)), (1, slice(2, n + 2))):
        o = out[part(slice(parity, None, 2))]
        np.multiply(centre, np.float32(0.75), out=o)
        o += np.float32(0.25) * a[part(side)]
    return out


def _upsample_twice(coarse, seen, inside):
    """:func:`upsample_bilinear` onto a texture of twice the size, on the grid (no lookup per texel)."""
    n, C = seen.shape[0], coarse.shape[-1]
    # Channels first, the seen weight as one more, padded by a texel of weight 0 each side.
    padded = np.zeros((C + 1, n + 2, n + 2), np.float32)
    padded[:C, 1:-1, 1:-1] = np.moveaxis(np.where(seen[..., None], np.nan_to_num(coarse), 0), -1, 0)
    padded[C, 1:-1, 1:-1] = seen
    both = _twice(_twice(padded, 1), 2)  # sums of weight x value, and of weight, over the seen corners
    den = both[C]
    fine_seen = inside & np.repeat(np.repeat(seen, 2, axis=0), 2, axis=1) & (den > 0)
    scale = np.divide(1.0, den, out=np.full_like(den, np.nan), where=fine_seen)
    both[:C] *= scale
    return np.ascontiguousarray(np.moveaxis(both[:C], 0, -1)), fine_seen
