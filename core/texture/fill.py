"""Texels that no view saw, filled: harmonic (Laplace) interpolation inside each UV island, then a
few texels of dilation past the island borders (so that mipmaps and filtering do not bleed the
background in). Used after both the texture-domain solve and the image-domain fusion; after the
former also for the texels the photos show only at the object's outline (:func:`outline_only`).
"""

from __future__ import annotations

import numpy as np
import scipy.ndimage as ndi
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..geometry.texels import bilinear_texels, coarser_any, parent_texels
from ..parallel import thread_map
from ..solve.cg import pcg
from ..solve.pyramid import upsample_onto

__all__ = ["fill_unseen", "fill_scaled_up", "outline_only", "outline_pixels", "OUTLINE_EVIDENCE"]

#: :func:`outline_only`: a texel whose pixels off the outlines weigh less than this fraction of the median
#: texel's pixels is filled from its neighbours.
OUTLINE_EVIDENCE = 0.05

# Unknowns up to which the Laplace system is factorised directly; above it the solve recurses on a
# 2x coarser grid and refines with CG (a direct 2D solve grows superlinearly).
_DIRECT_MAX = 60_000
_CG_MAX_ITER = 300
_CG_TOL = 1e-5


def _laplace_system(vals, fixed, dom):
    """5-point Laplace system on the free texels of ``dom``, fixed ones as data.

    Returns
    -------
    free : (K,) flat indices of the free texels (dom and not fixed).
    a : (K, K) CSR matrix, the graph Laplacian of dom restricted to the free
        texels (five stored entries per row, unused ones 0).
    rhs : (K, C) sums of the fixed neighbours' values.
    deg : (K,) the diagonal (number of dom neighbours).
    """
    n0, n1 = dom.shape
    dom_f = dom.ravel()
    free = np.flatnonzero(dom_f & ~fixed.ravel())
    k = free.size
    ids = np.full(dom_f.size, -1, dtype=np.intp)
    ids[free] = np.arange(k)
    r, c = np.divmod(free, n1)
    vflat = vals.reshape(dom_f.size, -1)
    deg = np.zeros(k)
    rhs = np.zeros((k, vflat.shape[1]))
    cols = np.empty((k, 5), dtype=np.intp)
    data = np.zeros((k, 5))
    cols[:, 4] = np.arange(k)
    for d, (ok, off) in enumerate(((r > 0, -n1), (r < n0 - 1, n1), (c > 0, -1), (c < n1 - 1, 1))):
        q = np.where(ok, free + off, 0)
        ok &= dom_f[q]
        j = ids[q]
        deg += ok
        u = ok & (j >= 0)
        cols[:, d] = np.where(u, j, cols[:, 4])
        data[:, d] = np.where(u, -1.0, 0.0)
        f = np.flatnonzero(ok & (j < 0))
        rhs[f] += vflat[q[f]]
    data[:, 4] = deg
    a = sp.csr_matrix((data.ravel(), cols.ravel(), np.arange(0, 5 * k + 1, 5)), shape=(k, k))
    return free, a, rhs, deg


def _upsample(coarse, dom_c, shape, where):
    """Bilinear upsampling by 2 of ``coarse`` at fine flat texels ``where``,
    using only coarse texels in ``dom_c`` (weights renormalised)."""
    nc0, nc1 = dom_c.shape
    r, c = np.divmod(where, shape[1])
    # Fine centre r sits at r / 2 - 0.25 in coarse texel coordinates.
    rr, cc = r / 2 - 0.25, c / 2 - 0.25
    r0, c0 = np.floor(rr).astype(np.intp), np.floor(cc).astype(np.intp)
    fr, fc = (rr - r0)[:, None], (cc - c0)[:, None]
    acc = np.zeros((where.size, coarse.shape[-1]))
    wsum = np.zeros((where.size, 1))
    for dr, dc, w in ((0, 0, (1 - fr) * (1 - fc)), (0, 1, (1 - fr) * fc), (1, 0, fr * (1 - fc)), (1, 1, fr * fc)):
        rq, cq = r0 + dr, c0 + dc
        ok = (rq >= 0) & (rq < nc0) & (cq >= 0) & (cq < nc1)
        rq, cq = np.where(ok, rq, 0), np.where(ok, cq, 0)
        w = w * (ok & dom_c[rq, cq])[:, None]
        acc += w * coarse[rq, cq]
        wsum += w
    return acc / wsum


def _harmonic(vals, fixed, dom, threads=None):
    """Harmonic interpolant of the fixed texels on the free texels of ``dom``.

    ``vals`` (n0, n1, C) must be 0 off ``fixed``, and every 4-connected
    component of ``dom`` must hold a fixed texel. Solves directly when small;
    otherwise solves the 2x coarser problem first (cascadic multigrid),
    upsamples it as the start and refines with CG.

    Returns
    -------
    free : (K,) flat indices of the free texels; x : (K, C) their values.
    """
    free, a, rhs, deg = _laplace_system(vals, fixed, dom)
    if free.size == 0:
        return free, np.zeros((0, vals.shape[-1]))
    if free.size <= _DIRECT_MAX or min(dom.shape) < 8:
        return free, spla.spsolve(a.tocsc(), rhs).reshape(free.size, -1)
    n0, n1 = dom.shape
    p0, p1 = n0 + n0 % 2, n1 + n1 % 2

    def blocks(x):
        if (p0, p1) != (n0, n1):
            x = np.pad(x, ((0, p0 - n0), (0, p1 - n1)) + ((0, 0),) * (x.ndim - 2))
        return x.reshape(p0 // 2, 2, p1 // 2, 2, *x.shape[2:])

    def block_sum(x):
        x = blocks(x)
        return x[:, 0, :, 0] + x[:, 0, :, 1] + x[:, 1, :, 0] + x[:, 1, :, 1]

    cnt = block_sum(fixed.astype(np.float32))
    fixed_c = cnt > 0
    vals_c = block_sum(vals) / np.maximum(cnt, 1)[..., None]  # vals is 0 off fixed
    dom_c = block_sum(dom.astype(np.float32)) > 0
    free_c, x_c = _harmonic(vals_c, fixed_c, dom_c, threads)
    vals_c.reshape(-1, vals_c.shape[-1])[free_c] = x_c
    x0 = _upsample(vals_c, dom_c, dom.shape, free)
    inv_deg = 1.0 / deg

    def refine(ch):
        rhs_ch, x_ch = np.ascontiguousarray(rhs[:, ch]), np.ascontiguousarray(x0[:, ch])
        return pcg(a.__matmul__, rhs_ch, x_ch, inv_deg, _CG_MAX_ITER, _CG_TOL)

    for ch, x in enumerate(thread_map(refine, range(rhs.shape[1]), threads)):
        x0[:, ch] = x
    return free, x0


def _dilate(vals, filled, rings):
    """Grow ``filled`` by ``rings`` texels; each new texel takes the mean of
    its filled 8-neighbours. Works on the ring texels only."""
    n0, n1 = filled.shape
    flat = vals.reshape(n0 * n1, -1)
    filled = filled.copy()
    ff = filled.ravel()
    box = np.ones((3, 3), bool)
    for _ in range(rings):
        new = np.flatnonzero((ndi.binary_dilation(filled, box) & ~filled).ravel())
        if new.size == 0:
            break
        r, c = np.divmod(new, n1)
        cnt = np.zeros(new.size)
        acc = np.zeros((new.size, flat.shape[1]))
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                if dr == 0 and dc == 0:
                    continue
                ok = (r + dr >= 0) & (r + dr < n0) & (c + dc >= 0) & (c + dc < n1)
                q = np.where(ok, new + dr * n1 + dc, 0)
                ok &= ff[q]
                cnt += ok
                acc += ok[:, None] * flat[q]
        flat[new] = acc / cnt[:, None]
        ff[new] = True
    return vals


def fill_unseen(texture, seen, inside, margin=4, threads=None):
    """Fill the texels that no view saw.

    Inside each UV island (4-connected component of ``inside | seen``), the
    unseen texels take the harmonic interpolant of the seen ones (Laplace
    equation, seen texels fixed, no flux across the island border), so a
    linear ramp is recovered exactly. Islands without any seen texel take the
    mean of all seen texels. Then ``margin`` rings of texels past the islands
    take the mean of their filled neighbours, so that mipmaps show no seams.
    Everything else is 0.

    Parameters
    ----------
    texture : (N, N, C) or (N, N) array
        Values; only the seen texels are read (others may be NaN).
    seen : (N, N) bool array
        Texels with data; their values must be finite and are kept.
    inside : (N, N) bool array
        Texels inside UV islands.
    margin : int, optional
        Rings of dilation past the islands (default 4).
    threads : int or None
        The channels are refined on up to this many threads (None: every core).

    Returns
    -------
    (N, N, C) or (N, N) float32 array, like ``texture``.

    Raises
    ------
    ValueError
        On shape mismatch, non-finite seen values, a negative margin, or
        when no texel is seen.
    """
    tex = np.asarray(texture)
    flat_in = tex.ndim == 2
    if flat_in:
        tex = tex[..., None]
    seen, inside = _check_args(tex, np.shape(texture), seen, inside, margin)
    n, c = tex.shape[0], tex.shape[2]
    # The seen values in float64 where they are and 0 elsewhere, in one pass over the texture (no index lists).
    vals = np.zeros((n, n, c))
    np.copyto(vals, tex, where=seen[..., None])
    if not np.isfinite(vals).all():
        r, col = divmod(int(np.argmax(~np.isfinite(vals).all(axis=2))), n)
        raise ValueError(f"fill_unseen: seen texel (row {r}, col {col}) is NaN or infinite")
    flat = vals.reshape(n * n, c)
    dom = inside | seen
    labels, nlab = ndi.label(dom)
    has_seen = np.bincount(labels[seen], minlength=nlab + 1) > 0
    has_seen[0] = False
    orphan = dom & ~has_seen[labels]
    # Islands without a seen texel take the mean of the seen ones.
    mean = flat[np.flatnonzero(seen)].mean(axis=0) if orphan.any() else None
    free, x = _harmonic(vals, seen, dom & ~orphan, threads)
    flat[free] = x
    if mean is not None:
        flat[orphan.ravel()] = mean
    vals = _dilate(vals, dom, margin)
    out = vals.astype(np.float32)
    return out[..., 0] if flat_in else out


def fill_scaled_up(texture, seen, inside, margin=4, threads=None):
    """:func:`fill_unseen` for a texture solved smaller than ``inside`` and scaled up to it after.

    The texture is filled at its own size, where its texels hold the data, then sampled bilinearly at the
    texels of ``inside``'s size (:func:`core.solve.pyramid.upsample_onto`); its margin is as many of its
    texels as cover ``margin`` of the larger, and one more. Filled at the larger size, the harmonic fill would
    solve for (size ratio)^2 times as many texels, for the same values. Its islands are where any texel of
    ``inside`` is, so every texel of ``inside`` lies in a filled one.

    Parameters
    ----------
    texture : (n, n, C) array
        Values; only the seen texels are read.
    seen : (n, n) bool array
        Its texels with data.
    inside : (N, N) bool array
        The texels inside UV islands at the larger size, ``N >= n`` (``N == n``: :func:`fill_unseen`).
    margin : int
        Rings of texels past the islands at the larger size.
    threads : int or None
        As :func:`fill_unseen`.

    Returns
    -------
    (N, N, C) float32 array: 0 beyond the margin.
    """
    seen, inside = np.asarray(seen, bool), np.asarray(inside, bool)
    n, size = seen.shape[0], inside.shape[0]
    if n == size:
        return fill_unseen(texture, seen, inside, margin, threads)
    rings = 1 + -(-margin * n // size)
    small_inside = coarser_any(inside, n)
    filled = fill_unseen(texture, seen, small_inside, rings, threads)
    covered = ndi.binary_dilation(small_inside | seen, np.ones((3, 3), bool), iterations=rings)
    parent = parent_texels(size, n)
    fine, known = upsample_onto(filled, covered, covered[parent][:, parent])
    fine[~known] = 0.0
    return fine


def _check_args(tex, shape, seen, inside, margin):
    """:func:`fill_unseen`'s arguments checked (``tex`` is (N, N, C), ``shape`` as given); returns the masks as bool."""
    if tex.ndim != 3 or tex.shape[0] != tex.shape[1]:
        raise ValueError(f"fill_unseen: texture must be (N, N, C) or (N, N), got {shape}")
    n = tex.shape[0]
    seen = np.asarray(seen, dtype=bool)
    inside = np.asarray(inside, dtype=bool)
    for what, a in (("seen", seen), ("inside", inside)):
        if a.shape != (n, n):
            raise ValueError(f"fill_unseen: {what} must be ({n}, {n}) like the texture, got {a.shape}")
    if isinstance(margin, bool) or not isinstance(margin, (int, np.integer)) or margin < 0:
        raise ValueError(f"fill_unseen: margin must be an integer >= 0, got {margin!r}")
    if not seen.any():
        raise ValueError("fill_unseen: no texel is seen, nothing to fill from")
    return seen, inside


def outline_pixels(mask):
    """The pixels of ``mask`` on its outline: a 4-neighbour off the mask (not past the photo's border)."""
    # ndi.binary_erosion(mask, border_value=1) by four shifted ANDs: the same pixels, forty times faster.
    inner = mask.copy()
    inner[1:] &= mask[:-1]
    inner[:-1] &= mask[1:]
    inner[:, 1:] &= mask[:, :-1]
    inner[:, :-1] &= mask[:, 1:]
    return mask & ~inner


def outline_only(uvs, masks, weights, seen, used=None, evidence=OUTLINE_EVIDENCE):
    """The texels the photos show only at the object's outline: ``(N, N)`` bool.

    A pixel on the outline (:func:`outline_pixels`) holds the background blended in by the lens and the
    pixel's filter, and a camera a pixel off puts it on the wrong texel. A texel seen, whose pixels off the
    outlines weigh less than ``evidence`` times the median texel's pixels, has no clean view: the pipeline
    fills it from its neighbours, as an unseen one.

    Parameters
    ----------
    uvs, masks : lists of (H, W, 2) and (H, W) arrays
        Each view's UV per pixel and where the mesh covers it.
    weights : list of (H, W) arrays or None
        Each pixel's weight (the view weight; None: 1), spread over its four texels by their bilinear
        weights, as the solve's observations are.
    seen : (N, N) bool array
        The texels seen (by the solve).
    used : list of (H, W) bool arrays, optional
        The pixels the solve used (within ``masks``; default ``masks``): only they count.
    evidence : float
        The fraction of the median; 0 finds nothing.
    """
    seen = np.asarray(seen, bool)
    used = masks if used is None else used
    if evidence <= 0 or not seen.any():
        return np.zeros(seen.shape, bool)
    n2 = seen.size
    total, clean = np.zeros(n2), np.zeros(n2)
    for i, (u, m) in enumerate(zip(used, masks)):
        flat, wts = bilinear_texels(uvs[i][u], seen)
        if weights is not None:
            wts = wts * weights[i][u][:, None]
        wts = wts.astype(np.float64)
        total += np.bincount(flat.ravel(), weights=wts.ravel(), minlength=n2)
        off = ~outline_pixels(m)[u]
        clean += np.bincount(flat[off].ravel(), weights=wts[off].ravel(), minlength=n2)
    counted = seen.ravel() & (total > 0)
    median = np.median(total[counted]) if counted.any() else 0.0
    return (seen.ravel() & (clean <= evidence * median)).reshape(seen.shape)
