"""Coarser copies of a texture-domain problem, for coarse-to-fine solving.

Halving the texture and taking every other photo pixel keeps about as many
pixels per texel, so a coarse level costs a quarter of the fine one per
iteration, and TV spreads information twice as far per iteration. Pixels are
subsampled, not averaged: averaging UVs or normals across a seam or a
silhouette would invent surface that does not exist.
"""
from __future__ import annotations

import warnings

import numpy as np

from .problem import Problem, TextureLayout

__all__ = ["coarsen", "upsample_texels"]

# Below these a level has too little data to say anything about the finer one.
MIN_SIZE = 32
MIN_PIXELS = 20_000


def _coarsen_layout(layout: TextureLayout) -> TextureLayout:
    n = layout.size // 2
    p = layout.texel_pos[: 2 * n, : 2 * n].reshape(n, 2, n, 2, 3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # blocks with no texel stay NaN
        pos = np.nanmean(p, axis=(1, 3))
    fine = layout.size
    pairs = layout.seam_pairs
    r, c = np.divmod(pairs, fine)
    coarse = (np.minimum(r // 2, n - 1)) * n + np.minimum(c // 2, n - 1)
    coarse = coarse[coarse[:, 0] != coarse[:, 1]]
    coarse = np.unique(np.sort(coarse, axis=1), axis=0) if coarse.size else coarse.reshape(0, 2)
    return TextureLayout(pos, coarse)


def coarsen(problem: Problem) -> Problem | None:
    """The problem at half the texture size and every other pixel; None when too small to coarsen.

    The image-domain correspondences are not carried over.
    """
    if problem.texture is None or problem.texture.size < 2 * MIN_SIZE:
        return None
    sub = [np.ascontiguousarray(m[::2, ::2]) for m in problem.masks]
    if not all(m.any() for m in sub) or sum(int(m.sum()) for m in sub) < MIN_PIXELS:
        return None

    def half(seq):
        return None if seq is None else [np.ascontiguousarray(a[::2, ::2]) for a in seq]

    return Problem(half(problem.images), sub, half(problem.normals), uv=half(problem.uv),
                   texture=_coarsen_layout(problem.texture), view_weight=half(problem.view_weight),
                   names=list(problem.names))


def upsample_texels(coarse: np.ndarray, size: int) -> np.ndarray:
    """Nearest-parent upsampling of a ``(n, n, C)`` texture to ``(size, size, C)`` (NaN stays NaN)."""
    idx = np.minimum(np.arange(size) // 2, coarse.shape[0] - 1)
    return coarse[idx][:, idx]
