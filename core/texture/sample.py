"""A texture looked up at the UVs of a view's pixels (the texture-domain result seen by each view)."""

from __future__ import annotations

import numpy as np

from ..geometry.bilinear import clamped_corners, interpolate
from ..geometry.texels import texel_of_uv
from ..masks import masked

__all__ = ["sample_texture"]


def sample_texture(texture: np.ndarray, uv: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Bilinear lookup of an (N, N, C) texture (row 0 at v = 1) at (H, W, 2) uv; NaN outside ``mask``."""
    n = texture.shape[0]
    tex = np.asarray(texture, dtype=np.float32).reshape(n * n, -1)
    out = np.full(uv.shape[:2] + (tex.shape[1],), np.nan, dtype=np.float32)
    y, x = texel_of_uv(masked(uv, mask), n)
    idx, wts = clamped_corners(np.clip(x, 0, n - 1), np.clip(y, 0, n - 1), n, n)
    out[mask] = interpolate(tex, idx, wts, nan_as_zero=True)
    return out
