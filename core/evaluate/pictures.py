"""Pixel arrays of a run's results: linear images and lighting spheres as 8-bit sRGB, tiled in a grid.

Everything returns uint8 sRGB ``(H, W, 3)`` arrays, row 0 at the top, for the
add-on's preview images and the demo's figures. Linear inputs are tone-mapped
by :func:`to_srgb8` (divide by white, clip, then the sRGB curve). Text and
axes are not drawn here: the panel labels the previews and the demo draws
with matplotlib.
"""

from __future__ import annotations

import numpy as np

from ..geometry.sh import sh_basis
from ..io.photos import linear_to_srgb

__all__ = ["to_srgb8", "sphere_normals", "shade_sphere", "lighting_spheres", "grid", "BACKGROUND"]

#: Grey behind pictures and where an image has no value (NaN).
BACKGROUND = (40, 40, 40)


def to_srgb8(linear, white=1.0, background=BACKGROUND) -> np.ndarray:
    """Tone-map linear RGB to 8-bit sRGB: divide by ``white``, clip to [0, 1], encode; NaN -> background.

    ``linear`` is ``(H, W)``, ``(H, W, 1)`` (grey) or ``(H, W, >= 3)`` (RGB, any further channel dropped).
    """
    a = np.asarray(linear, dtype=np.float64)
    if a.ndim == 2:
        a = a[:, :, None]
    a = np.repeat(a, 3, axis=2) if a.shape[2] == 1 else a[:, :, :3]
    bad = ~np.all(np.isfinite(a), axis=2)
    out = np.round(linear_to_srgb(np.nan_to_num(a / float(white))) * 255).astype(np.uint8)
    out[bad] = background
    return out


def sphere_normals(size: int):
    """World normals of a unit sphere seen from the front (from -Y, +Z up, +X to the right).

    Returns
    -------
    normals : (size, size, 3) float64, NaN outside the disc
    inside : (size, size) bool
    """
    c = (np.arange(size) + 0.5) / size * 2 - 1
    x, z = np.meshgrid(c, -c)  # row 0 at the top = +Z
    r2 = x * x + z * z
    inside = r2 < 1
    n = np.stack([x, -np.sqrt(np.clip(1 - r2, 0, None)), z], axis=-1)
    n[~inside] = np.nan
    return n, inside


def shade_sphere(sh, size: int = 96, sun=None) -> np.ndarray:
    """Linear shading ``sigma . nu(n)`` of the front-facing sphere, ``(size, size, C)``, NaN outside.

    ``sh`` is ``(C, 9)`` (or ``(9,)``), in the basis of :mod:`core.geometry.sh`; with ``sun`` (the direction
    towards it) ``(C, 10)``, the last coefficient the sun's, shading ``max(0, n . sun)`` (a sphere casts
    no shadow on itself).
    """
    s = np.atleast_2d(np.asarray(sh, dtype=np.float64))
    n, inside = sphere_normals(size)
    t = sh_basis(n[inside], dtype=np.float64)
    if sun is not None:
        w = np.asarray(sun, np.float64) / np.linalg.norm(sun)
        t = np.concatenate([t, np.maximum(n[inside] @ w, 0.0)[:, None]], axis=1)
    out = np.full((size, size, s.shape[0]), np.nan)
    out[inside] = t @ s.T
    return out


def lighting_spheres(sigmas, size=96, white=None, sun=None) -> np.ndarray:
    """One shaded sphere per view (``sigmas`` is ``(m, C, 9)``, or 10 with ``sun``: :func:`shade_sphere`), all on
    one exposure.

    ``white`` (default: 1.2 x the 99th percentile of all the shading shown) maps to
    full brightness, so the views' lights keep their relative strengths.

    Returns
    -------
    (m, size, size, 3) uint8 sRGB, :data:`BACKGROUND` outside the discs
    """
    shades = [shade_sphere(s, size, sun) for s in np.asarray(sigmas, dtype=np.float64)]
    if white is None:
        vals = np.concatenate([s[np.isfinite(s)] for s in shades]) if shades else np.zeros(0)
        p99 = float(np.percentile(vals, 99)) if vals.size else 0.0
        white = 1.2 * p99 if p99 > 0 else 1.0  # a little headroom so bright sides keep their gradient
    return np.array([to_srgb8(s, white) for s in shades], dtype=np.uint8).reshape(-1, size, size, 3)


def grid(pictures, columns=4, gap=6, background=BACKGROUND) -> np.ndarray:
    """Tile uint8 pictures in rows of ``columns``, ``gap`` pixels apart and around, each top-left aligned.

    A cell is as wide as the widest picture in its column and as tall as the tallest in its row.
    """
    pics = [np.asarray(p, dtype=np.uint8)[..., :3] for p in pictures]
    if not pics:
        raise ValueError("grid: no pictures")
    rows = [pics[i : i + columns] for i in range(0, len(pics), columns)]
    widths = [max(r[k].shape[1] for r in rows if k < len(r)) for k in range(min(columns, len(pics)))]
    heights = [max(p.shape[0] for p in r) for r in rows]
    out = np.empty((gap + sum(h + gap for h in heights), gap + sum(w + gap for w in widths), 3), dtype=np.uint8)
    out[:] = background
    y = gap
    for r, h in zip(rows, heights):
        x = gap
        for p, w in zip(r, widths):
            out[y : y + p.shape[0], x : x + p.shape[1]] = p
            x += w + gap
        y += h + gap
    return out
