"""Checks of the inputs before the solve, by stated rules: photos that cannot be images of light on the mesh."""

from __future__ import annotations

import numpy as np

from .errors import DelightError
from .geometry.texels import STRETCH_FACTOR, triangle_areas, uv_stretched
from .masks import masked

__all__ = ["NEGATIVE_MAX_SHARE", "check_photos", "check_uv_layout"]

#: Share of a photo's pixels on the mesh that may be negative before the photo is refused; below it the
#: negative pixels are left out (a few come from denoisers and resampling).
NEGATIVE_MAX_SHARE = 0.01


def check_photos(names, photos, masks) -> list:
    """Refuse photos that are negative or black on the mesh; leave out the few negative pixels.

    Parameters
    ----------
    names : list of str
        The views' names, for messages.
    photos : list of (H, W, 3) float arrays
        Linear photos.
    masks : list of (H, W) bool arrays
        Pixels that see the mesh; negative pixels are removed from them in place.

    Returns
    -------
    warnings : list of str
        One line per photo that had negative pixels left out.

    Raises
    ------
    DelightError
        A photo with more than :data:`NEGATIVE_MAX_SHARE` of its mesh pixels negative, or with no positive
        value on the mesh.
    """
    warnings = []
    for name, photo, mask in zip(names, photos, masks):
        px = masked(photo, mask)
        if px.size == 0:
            continue
        negative = (px < 0).any(axis=1)
        share = float(negative.mean())
        if share > NEGATIVE_MAX_SHARE:
            raise DelightError(
                f"camera {name!r}: {100 * share:.0f} % of its photo's pixels on the mesh are "
                "negative, so it is not a linear image of light: check how the photo was exported "
                "and its colour space"
            )
        if not (px > 0).any():
            raise DelightError(
                f"camera {name!r}: its photo is black wherever it sees the mesh: check that it is "
                "the right photo and that it is exposed"
            )
        if negative.any():
            mask[mask] = ~negative
            warnings.append(f"camera {name!r}: {int(negative.sum())} negative pixels on the mesh were left out")
    return warnings


_BLOCK = 1 << 21


def _centre_coverage(q, n):
    """Per texel, how many triangles (texel coordinates ``q``, (T, 3, 2)) cover its centre."""
    lo = np.clip(np.ceil(q.min(axis=1)).astype(np.int64), 0, n)
    hi = np.clip(np.floor(q.max(axis=1)).astype(np.int64), -1, n - 1)
    w = np.maximum(hi[:, 0] - lo[:, 0] + 1, 0)
    h = np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)
    offs = np.concatenate([[0], np.cumsum(w * h)])
    (x0, y0), (x1, y1), (x2, y2) = q[:, 0].T, q[:, 1].T, q[:, 2].T
    det = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    count = np.zeros(n * n, dtype=np.int32)
    for k0 in range(0, int(offs[-1]), _BLOCK):
        k = np.arange(k0, min(k0 + _BLOCK, int(offs[-1])), dtype=np.int64)
        t = np.searchsorted(offs, k, side="right") - 1
        x = lo[t, 0] + (k - offs[t]) % w[t]
        y = lo[t, 1] + (k - offs[t]) // w[t]
        d = det[t]
        b1 = ((x - x0[t]) * (y2[t] - y0[t]) - (x2[t] - x0[t]) * (y - y0[t])) / d
        b2 = ((x1[t] - x0[t]) * (y - y0[t]) - (x - x0[t]) * (y1[t] - y0[t])) / d
        # Strictly inside, so that a centre on an edge shared by two faces is not an overlap.
        inside = (d != 0) & (b1 > 1e-9) & (b2 > 1e-9) & (b1 + b2 < 1 - 1e-9)
        count += np.bincount(y[inside] * n + x[inside], minlength=n * n).astype(np.int32)
    return count


def check_uv_layout(tri_uv, tri_pos, size) -> list:
    """Warnings about a UV layout that degrades the albedo: overlapping islands, faces with no UV area,
    and stretched faces, each with the share of the texture or of the surface affected.

    Parameters
    ----------
    tri_uv : (T, 3, 2) float array
        UV of the triangles' corners.
    tri_pos : (T, 3, 3) float array
        World positions of the corners.
    size : int
        Texture size N (zero-area faces are judged in its texels).
    """
    n = int(size)
    q = np.empty(tri_uv.shape, dtype=np.float64)
    q[..., 0] = tri_uv[..., 0] * n - 0.5
    q[..., 1] = (1.0 - tri_uv[..., 1]) * n - 0.5
    uv_area, area = triangle_areas(tri_uv, tri_pos)
    uv_area *= n * n  # texels
    total = float(area.sum())
    warnings = []
    if total <= 0:
        return warnings
    flat = uv_area < 1e-6 * max(float(np.median(uv_area)), 1e-12)
    if flat.any():
        warnings.append(
            f"UV layout: {int(flat.sum())} faces ({100 * area[flat].sum() / total:.1f} % of the "
            "surface) have no area in the UV map, so their albedo cannot be stored: unwrap them"
        )
    stretched = ~flat & uv_stretched(tri_uv, tri_pos)
    if stretched.any():
        warnings.append(
            f"UV layout: {int(stretched.sum())} faces ({100 * area[stretched].sum() / total:.1f} % "
            f"of the surface) are stretched more than {STRETCH_FACTOR:g}x in the UV map (n-gons across a "
            "seam?): re-unwrap them"
        )
    # Overlaps are measured on at most a 512^2 grid: enough for a share, and cheap at any texture size.
    m = min(n, 512)
    cover = _centre_coverage(q[~flat] * (m / n) + 0.5 * (m / n - 1.0), m)
    used = np.count_nonzero(cover)
    over = np.count_nonzero(cover > 1)
    if used and over / used > 0.001:
        warnings.append(
            f"UV layout: {100 * over / used:.1f} % of the used texels are covered by overlapping UV "
            "islands, which then share one albedo: unwrap without overlaps"
        )
    return warnings
