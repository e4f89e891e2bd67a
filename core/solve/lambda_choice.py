"""The TV weight of the lighting: :data:`LIGHT_LAMBDA` for the two-stage solve's lighting stage, and for the
paper's one stage, the weight that how much the lighting differs between the photos calls for.

(The albedo stage's weight is chosen from the photos' colour texture: :mod:`core.solve.albedo_weight`.)

Under one fixed light a Lambertian surface point looks equally bright from
every view (same normal, same shading). When the light moves between shots,
view v sees it scaled by ``s_v(n)`` instead: a smooth function of the normal
that differs per view. How much it differs decides how ill-posed the problem
is (the paper, section 3): with fixed lighting only TV separates albedo from
shading, so lambda must be large; with varying lighting the views pin the
shading down and a small lambda is much truer.

:func:`lighting_variation` measures it on the photos alone, before solving:
per view, the part of its log brightness (relative to the other views) that
the normal's SH basis explains, without the constant (an exposure change).
:func:`choose_lambda` maps it to the lambda measured best on either side of a
threshold that separates the fixed-light scenes from those with a light per
shot (the values are in docs/measurements.md).
"""

from __future__ import annotations

import numpy as np

from ..geometry.sh import sh_basis
from ..geometry.texels import texel_index
from ..masks import masked

__all__ = [
    "LIGHT_LAMBDA",
    "lighting_variation",
    "choose_lambda",
    "auto_lambda",
    "describe_lambda",
    "VARYING_THRESHOLD",
    "LAMBDA_FIXED",
    "LAMBDA_VARYING",
]

#: TV weight of the lighting stage where the pipeline picks it (two stages): strong, so that the lighting keeps
#: the shading and not the albedo; chosen by leave-one-scene-out over 48 scenes (docs/measurements.md).
LIGHT_LAMBDA = 8.0
VARYING_THRESHOLD = 0.2  # above every fixed-light scene measured, below every moving-light one
LAMBDA_FIXED = 5.0
LAMBDA_VARYING = 0.5
_MIN_SHARED = 100  # cells seen by two views or more, below which we cannot tell


def lighting_variation(images, masks, normals, uvs, size: int = 128) -> float | None:
    """How much each view's brightness departs from the others' as a smooth function of the normal.

    Each surface cell's log brightness in view v, minus its mean over the
    views, is ``log s_v(n) - mean_w log s_w(n)``: a function of the normal
    alone, which a moving light makes large and smooth. It is fitted per view
    by the 2nd-order SH basis of the cell's normal; the RMS of the fit,
    without its constant (an exposure change), is returned. Disagreement that
    the normal does not explain (misregistration on an approximate mesh,
    highlights, noise) stays out.

    Parameters
    ----------
    images : list of (H, W, C) arrays
        Linear photos.
    masks : list of (H, W) bool arrays
    normals : list of (H, W, 3) arrays
        World-space unit normals of the masked pixels.
    uvs : list of (H, W, 2) arrays
        UV coordinate of each masked pixel's surface point.
    size : int
        The surface is cut into ``size x size`` UV cells.

    Returns
    -------
    float or None
        About 0.01 to 0.05 under one fixed light, 0.2 or more when the light
        moves between shots; None when fewer than 100 cells are seen by two
        views.
    """
    m = len(images)
    cell, view, log, normal = _pixel_logs(images, masks, normals, uvs, size)
    # Mean log brightness of each (cell, view), and each cell's mean normal.
    # Counted per possible (cell, view) rather than through np.unique: the same sums, without a sort.
    cell_view = cell * m + view
    counts = np.bincount(cell_view, minlength=size * size * m)
    key = np.flatnonzero(counts)
    n_obs = counts[key]
    mean = np.bincount(cell_view, weights=log, minlength=size * size * m)[key] / n_obs
    c, v = key // m, key % m
    shared = np.bincount(c)[c] >= 2
    c, v, mean, n_obs = c[shared], v[shared], mean[shared], n_obs[shared]
    if c.size == 0:
        return None
    cell_ids, c = np.unique(c, return_inverse=True)
    if cell_ids.size < _MIN_SHARED:
        return None
    w_obs = n_obs.astype(np.float64)
    dev = _two_way_residual(mean, c, v, w_obs, m)
    cell_normal = np.stack(
        [np.bincount(cell, weights=normal[:, k], minlength=size * size)[cell_ids] for k in range(3)], axis=1
    )
    cell_normal /= np.maximum(np.linalg.norm(cell_normal, axis=1, keepdims=True), 1e-12)
    return _explained_rms(sh_basis(cell_normal[c], np.float64), dev, v, w_obs, m)


def _pixel_logs(images, masks, normals, uvs, size):
    """Cell, view, log luminance and normal of every masked pixel with a cell and a positive luminance."""
    cells, views, logs, norms = [], [], [], []
    for v, (img, mask, nrm, uv) in enumerate(zip(images, masks, normals, uvs)):
        lum = masked(img, mask).astype(np.float64).mean(axis=-1)
        t = texel_index(masked(uv, mask), size)
        ok = (t >= 0) & (lum > 0) & np.isfinite(lum)
        cells.append(t[ok])
        views.append(np.full(int(ok.sum()), v))
        logs.append(np.log(lum[ok]))
        norms.append(masked(nrm, mask)[ok].astype(np.float64))
    return tuple(np.concatenate(a) for a in (cells, views, logs, norms))


def _two_way_residual(mean, c, v, w_obs, m):
    """``mean`` minus a weighted two-way fit ``cell + view``.

    The view term takes each view's exposure, so that it does not leak into
    the normal-dependent part through which views see which cells.
    """
    wc = np.bincount(c, weights=w_obs)
    wv = np.bincount(v, weights=w_obs, minlength=m)
    offset = np.zeros(m)
    for _ in range(20):
        cell_mean = np.bincount(c, weights=w_obs * (mean - offset[v])) / wc
        offset = np.bincount(v, weights=w_obs * (mean - cell_mean[c]), minlength=m) / np.maximum(wv, 1e-12)
    return mean - cell_mean[c] - offset[v]


def _explained_rms(nu, dev, v, w_obs, m):
    """Weighted RMS of each view's SH fit to ``dev``, its constant removed; None when no view has 10 cells."""
    explained, total = 0.0, 0.0
    for k in range(m):
        sel = v == k
        if sel.sum() < 10:
            continue
        X, y, w = nu[sel], dev[sel], w_obs[sel]
        coef = np.linalg.lstsq(X * np.sqrt(w)[:, None], y * np.sqrt(w), rcond=None)[0]
        fit = X @ coef
        fit -= np.average(fit, weights=w)  # an exposure change is not a lighting change
        explained += float(np.sum(w * fit * fit))
        total += float(w.sum())
    return float(np.sqrt(explained / total)) if total else None


def choose_lambda(variation: float | None) -> float:
    """The TV weight for a measured :func:`lighting_variation` (fixed lighting when unknown)."""
    if variation is not None and variation > VARYING_THRESHOLD:
        return LAMBDA_VARYING
    return LAMBDA_FIXED


def auto_lambda(problem) -> tuple:
    """``(lambda, variation)`` for a :class:`core.solve.problem.Problem`; variation is None without UVs or overlap."""
    variation = (
        None if problem.uv is None else lighting_variation(problem.images, problem.masks, problem.normals, problem.uv)
    )
    return choose_lambda(variation), variation


def describe_lambda(lam: float, variation: float | None, auto: bool) -> str:
    """How lambda was set, for messages: ``"lambda 0.5 (auto: lighting varies ... by 0.45)"``."""
    if not auto:
        return f"lambda {lam:g}"
    if variation is None:
        return f"lambda {lam:g} (auto: too little overlap between the photos to tell)"
    return f"lambda {lam:g} (auto: lighting varies between the photos by {variation:.2f})"
