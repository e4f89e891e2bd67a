"""Per-view reflectance maps fused into one texture, and unseen texels filled.

:func:`fuse_views` turns the image-domain solver's output (one reflectance map
per view, with each pixel's UV) into an RGBA texture: a robust, view-weighted
median across the views that see each texel. :func:`fill_unseen` fills the
texels that no view saw, by harmonic (Laplace) interpolation inside each UV
island plus a few texels of dilation past the island borders; the
texture-domain solver uses it too.

The texel convention is :mod:`core.uvlayout`'s (and :mod:`core.problem`'s).
"""
from __future__ import annotations

import numpy as np
import scipy.ndimage as ndi
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .cg import pcg
from .uvlayout import texel_index

__all__ = ["fuse_views", "fill_unseen"]

# Unknowns up to which the Laplace system is factorised directly; above it
# the solve recurses on a 2x coarser grid and refines with CG (SuperLU on a
# 2D grid costs ~1 s at 160k unknowns and ~5 s at 490k on this machine).
_DIRECT_MAX = 60_000
_CG_MAX_ITER = 300
_CG_TOL = 1e-5
# Texels seen by at most this many views use the sort-free median.
_PAIRWISE_MAX_K = 6


# ---------------------------------------------------------------- fusion

def _as_maps(maps):
    out = []
    for i, m in enumerate(maps):
        m = np.asarray(m, dtype=np.float32)
        if m.ndim == 2:
            m = m[:, :, None]
        if m.ndim != 3:
            raise ValueError(f"fuse_views: map of view {i} must be (H, W, C), got {m.shape}")
        out.append(m)
    c = out[0].shape[2]
    for i, m in enumerate(out):
        if m.shape[2] != c:
            raise ValueError(f"fuse_views: view {i} has {m.shape[2]} channels, view 0 has {c}")
    return out, c


def _view_records(i, vmap, mask, uv, weight, n, inside):
    """Per-view weighted mean of the pixels that land in each texel.

    Returns
    -------
    hit : (k,) sorted flat texel indices; vals : (C, k) means; wv : (k,) the
    view's weight in each texel, the mean weight of its pixels there.
    """
    hw = vmap.shape[:2]
    mask = np.asarray(mask, dtype=bool)
    uv = np.asarray(uv)
    if mask.shape != hw:
        raise ValueError(f"fuse_views: mask of view {i} is {mask.shape}, its map is {hw}")
    if uv.shape != hw + (2,):
        raise ValueError(f"fuse_views: uv of view {i} is {uv.shape}, expected {hw + (2,)}")
    pix = np.flatnonzero(mask)
    uvm = uv.reshape(-1, 2)[pix]
    if not np.isfinite(uvm).all():
        raise ValueError(f"fuse_views: uv of view {i} is NaN or infinite inside its mask")
    if weight is None:
        w = None
    else:
        weight = np.asarray(weight)
        if weight.shape != hw:
            raise ValueError(f"fuse_views: view_weight of view {i} is {weight.shape}, expected {hw}")
        w = weight.ravel()[pix].astype(np.float64)
        if not np.isfinite(w).all() or (w.size and w.min() < 0):
            raise ValueError(f"fuse_views: view_weight of view {i} must be finite and >= 0 inside its mask")
    x = vmap.reshape(-1, vmap.shape[2])[pix]
    tex = texel_index(uvm, n)
    # Pixels whose reflectance is undefined (NaN, e.g. zero shading) carry no data.
    keep = tex >= 0
    for ch in range(x.shape[1]):
        keep &= np.isfinite(x[:, ch])
    if inside is not None:
        keep[keep] = inside.ravel()[tex[keep]]
    tex = tex[keep]
    x = x[keep]
    w = np.ones(tex.size) if w is None else w[keep]
    n2 = n * n
    cnt = np.bincount(tex, minlength=n2)
    hit = np.flatnonzero(cnt)
    cnt = cnt[hit]
    sw = np.bincount(tex, weights=w, minlength=n2)[hit]
    pos = sw > 0
    sw_safe = np.where(pos, sw, 1.0)
    vals = np.empty((x.shape[1], hit.size))
    for ch in range(x.shape[1]):
        xc = x[:, ch].astype(np.float64)
        swx = np.bincount(tex, weights=w * xc, minlength=n2)[hit]
        vals[ch] = swx / sw_safe
        if not pos.all():
            # All-zero weights (grazing pixels only): plain mean.
            sx = np.bincount(tex, weights=xc, minlength=n2)[hit]
            vals[ch] = np.where(pos, vals[ch], sx / cnt)
    return hit, vals, sw / cnt


def _group_by_texel(recs, n2):
    """Lay the views' records out grouped by texel, without a global sort.

    Returns the seen texels (U,), each texel's record count and start (U,),
    and the grouped values (C, K) and weights (K,). Each view's texels are
    sorted and unique, so its records scatter to increasing positions.
    """
    cnt = np.zeros(n2, dtype=np.int32)
    for hit, _, _ in recs:
        cnt[hit] += 1
    texels = np.flatnonzero(cnt)
    count = cnt[texels].astype(np.intp)
    start = np.cumsum(count) - count
    lut = np.zeros(n2, dtype=np.intp)
    lut[texels] = np.arange(texels.size)
    fill = np.zeros(texels.size, dtype=np.intp)
    c = recs[0][1].shape[0]
    vals = np.empty((c, int(count.sum())))
    wts = np.empty(vals.shape[1])
    for hit, v, w in recs:
        cid = lut[hit]
        at = start[cid] + fill[cid]
        fill[cid] += 1
        vals[:, at] = v
        wts[at] = w
    return texels, count, start, vals, wts


def _median_pairwise(vals, w, s0, k):
    """Weighted median of groups of k records starting at ``s0``, without sorting.

    The lower weighted median is the smallest value v_j whose weight at or
    below it, S_j = sum_i w_i [v_i <= v_j], reaches half the total; the upper
    one the smallest with S_j above half. O(k^2) column operations, faster
    than a row-wise sort for the few views that see a texel.
    """
    wc = [w[s0 + j] for j in range(k)]
    total = sum(wc)
    lo_t, hi_t = 0.5 * total * (1 - 1e-9), 0.5 * total * (1 + 1e-9)
    out = np.empty((s0.size, vals.shape[0]))
    for ch in range(vals.shape[0]):
        vc = [vals[ch][s0 + j] for j in range(k)]
        lower = np.full(s0.size, np.inf)
        upper = np.full(s0.size, np.inf)
        for j in range(k):
            below = wc[j].copy()
            for i in range(k):
                if i != j:
                    below += np.where(vc[i] <= vc[j], wc[i], 0.0)
            np.copyto(lower, vc[j], where=(below >= lo_t) & (vc[j] < lower))
            np.copyto(upper, vc[j], where=(below > hi_t) & (vc[j] < upper))
        out[:, ch] = 0.5 * (lower + upper)
    return out


def _weighted_median(count, start, vals, w):
    """Weighted median of each texel's records, channel by channel.

    Parameters
    ----------
    count, start : (U,) records per texel and the first one's position.
    vals : (C, K) values grouped by texel; w : (K,) weights >= 0.

    Returns
    -------
    (U, C) medians.

    Notes
    -----
    Texels with the same number k of records (at most the number of views)
    are sorted together as a (G, k) array. When the weight splits exactly in
    half, the two middle values are averaged (so two equal views give their
    mean). A texel whose records all have weight 0 uses equal weights.
    """
    total = np.add.reduceat(w, start) if start.size else np.zeros(0)
    if np.any(total <= 0):
        w = np.where(np.repeat(total > 0, count), w, 1.0)
    med = np.empty((start.size, vals.shape[0]))
    for k in np.unique(count):
        g = np.flatnonzero(count == k)
        if k == 1:
            med[g] = vals[:, start[g]].T
            continue
        if k <= _PAIRWISE_MAX_K:
            med[g] = _median_pairwise(vals, w, start[g], k)
            continue
        idx = start[g][:, None] + np.arange(k)
        wk = w[idx]
        rows = np.arange(g.size)
        for ch in range(vals.shape[0]):
            v = vals[ch][idx]
            o = np.argsort(v, axis=1)
            v = np.take_along_axis(v, o, axis=1)
            cw = np.cumsum(np.take_along_axis(wk, o, axis=1), axis=1)
            half = 0.5 * cw[:, -1:]
            lower = np.argmax(cw >= half * (1 - 1e-9), axis=1)
            upper = np.argmax(cw > half * (1 + 1e-9), axis=1)
            med[g, ch] = 0.5 * (v[rows, lower] + v[rows, upper])
    return med


def fuse_views(maps, masks, uv, size, view_weight=None, inside=None, margin=4):
    """Fuse per-view reflectance maps into one RGBA texture.

    Every masked pixel lands in the texel that contains its UV. Per texel and
    view, the pixels are averaged (weighted by ``view_weight``); across the
    views, the texel takes the weighted median, the weight of a view being
    the mean ``view_weight`` of its pixels there. The median rejects outliers
    such as a specular highlight in one view; grazing views count less.

    Parameters
    ----------
    maps : list of (H, W, C) or (H, W) arrays
        Reflectance per view (C the same for all views). Pixels that are NaN
        or infinite are ignored.
    masks : list of (H, W) bool arrays
        Pixels that see the surface.
    uv : list of (H, W, 2) arrays
        UV of each pixel, finite inside the mask.
    size : int
        Texture size N.
    view_weight : list of (H, W) arrays, optional
        Confidence of each pixel, >= 0 (typically the cosine between normal
        and viewing ray). Default 1.
    inside : (N, N) bool array, optional
        Texels inside UV islands (``TextureLayout.inside``). Pixels landing
        outside it are ignored, and unseen texels are filled within it. When
        None, the islands are taken as the seen texels with gaps of up to 4
        texels closed.
    margin : int, optional
        Texels of dilation past the islands, see :func:`fill_unseen`.

    Returns
    -------
    (N, N, C + 1) float32 array
        Colour, then alpha: A = 1 on texels that at least one view saw and 0
        elsewhere. Unseen texels are filled by :func:`fill_unseen`.

    Raises
    ------
    ValueError
        On inconsistent shapes or non-finite UV or weights inside a mask, or
        when no masked pixel lands in the texture.
    """
    m = len(maps)
    if m == 0:
        raise ValueError("fuse_views: no views")
    for what, seq in (("masks", masks), ("uv", uv), ("view_weight", view_weight)):
        if seq is not None and len(seq) != m:
            raise ValueError(f"fuse_views: {len(seq)} {what} for {m} maps")
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 1:
        raise ValueError(f"fuse_views: size must be a positive integer, got {size!r}")
    n = int(size)
    if inside is not None:
        inside = np.asarray(inside, dtype=bool)
        if inside.shape != (n, n):
            raise ValueError(f"fuse_views: inside must be ({n}, {n}), got {inside.shape}")
    maps, c = _as_maps(maps)
    recs = [_view_records(i, maps[i], masks[i], uv[i], None if view_weight is None else view_weight[i],
                          n, inside) for i in range(m)]
    if sum(r[0].size for r in recs) == 0:
        raise ValueError("fuse_views: no masked pixel lands in the texture (check the UVs and inside)")
    texels, count, start, vals, wts = _group_by_texel(recs, n * n)
    med = _weighted_median(count, start, vals, wts)
    colour = np.zeros((n * n, c))
    colour[texels] = med
    seen = np.zeros(n * n, dtype=bool)
    seen[texels] = True
    seen = seen.reshape(n, n)
    if inside is None:
        inside = ndi.binary_closing(seen, structure=np.ones((3, 3), bool), iterations=2) | seen
    out = np.empty((n, n, c + 1), dtype=np.float32)
    out[..., :c] = fill_unseen(colour.reshape(n, n, c), seen, inside, margin)
    out[..., c] = seen
    return out


# ---------------------------------------------------------------- filling

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
    for dr, dc, w in ((0, 0, (1 - fr) * (1 - fc)), (0, 1, (1 - fr) * fc),
                      (1, 0, fr * (1 - fc)), (1, 1, fr * fc)):
        rq, cq = r0 + dr, c0 + dc
        ok = (rq >= 0) & (rq < nc0) & (cq >= 0) & (cq < nc1)
        rq, cq = np.where(ok, rq, 0), np.where(ok, cq, 0)
        w = w * (ok & dom_c[rq, cq])[:, None]
        acc += w * coarse[rq, cq]
        wsum += w
    return acc / wsum


def _harmonic(vals, fixed, dom):
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
    vals_c = block_sum(vals) / np.maximum(cnt, 1)[..., None]      # vals is 0 off fixed
    dom_c = block_sum(dom.astype(np.float32)) > 0
    free_c, x_c = _harmonic(vals_c, fixed_c, dom_c)
    vals_c.reshape(-1, vals_c.shape[-1])[free_c] = x_c
    x0 = _upsample(vals_c, dom_c, dom.shape, free)
    inv_deg = 1.0 / deg
    for ch in range(rhs.shape[1]):
        x0[:, ch] = pcg(a.__matmul__, np.ascontiguousarray(rhs[:, ch]), np.ascontiguousarray(x0[:, ch]), inv_deg,
                        _CG_MAX_ITER, _CG_TOL)
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


def fill_unseen(texture, seen, inside, margin=4):
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
    if tex.ndim != 3 or tex.shape[0] != tex.shape[1]:
        raise ValueError(f"fill_unseen: texture must be (N, N, C) or (N, N), got {np.shape(texture)}")
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
    c = tex.shape[2]
    idx = np.flatnonzero(seen)
    data = tex.reshape(n * n, c)[idx].astype(np.float64)
    bad = ~np.isfinite(data).all(axis=1)
    if bad.any():
        r, col = divmod(int(idx[np.argmax(bad)]), n)
        raise ValueError(f"fill_unseen: seen texel (row {r}, col {col}) is NaN or infinite")
    vals = np.zeros((n, n, c))
    flat = vals.reshape(n * n, c)
    flat[idx] = data
    dom = inside | seen
    labels, nlab = ndi.label(dom)
    has_seen = np.bincount(labels.ravel()[idx], minlength=nlab + 1) > 0
    has_seen[0] = False
    orphan = dom & ~has_seen[labels]
    free, x = _harmonic(vals, seen, dom & ~orphan)
    flat[free] = x
    flat[np.flatnonzero(orphan)] = data.mean(axis=0)
    vals = _dilate(vals, dom, margin)
    out = vals.astype(np.float32)
    return out[..., 0] if flat_in else out
