"""Per-view reflectance maps fused into one texture.

:func:`fuse_views` turns the image-domain solver's output (one reflectance map
per view, with each pixel's UV) into an RGBA texture: a robust, view-weighted
median across the views that see each texel; the texels no view saw are then
filled by :func:`core.texture.fill.fill_unseen`.

The texel convention is :mod:`core.geometry.texels`'s (and :mod:`core.solve.problem`'s).
"""

from __future__ import annotations

import numpy as np
import scipy.ndimage as ndi

from ..geometry.texels import texel_index
from .fill import fill_unseen

__all__ = ["fuse_views"]

# Texels seen by at most this many views use the sort-free median.
_PAIRWISE_MAX_K = 6


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
    n, inside = _check_args(maps, masks, uv, size, view_weight, inside)
    maps, c = _as_maps(maps)
    recs = [
        _view_records(i, maps[i], masks[i], uv[i], None if view_weight is None else view_weight[i], n, inside)
        for i in range(len(maps))
    ]
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


def _check_args(maps, masks, uv, size, view_weight, inside):
    """:func:`fuse_views`'s counts, size and ``inside`` checked; returns the size as an int and ``inside`` as bool."""
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
    return n, inside
