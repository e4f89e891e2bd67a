"""Texture space of a UV-mapped triangle mesh, from plain arrays.

:func:`texture_layout` rasterises the mesh in UV space into a
:class:`core.solve.problem.TextureLayout` (world position of every texel, and texel
pairs across UV seams). The helpers :func:`texel_of_uv`, :func:`uv_of_texel`,
:func:`texel_index` and :func:`bilinear_texels` hold the texel convention of
:mod:`core.solve.problem` in one place, so the solver and the fusion share it:
texel ``(r, c)`` of an ``(N, N)`` texture has its centre at
``u = (c + 0.5) / N``, ``v = 1 - (r + 0.5) / N`` (row 0 at the top, v up).

Internally, rasterisation works in continuous texel coordinates ``(x, y) =
(col, row)``, where texel centres sit on integers and texel ``(r, c)`` covers
``[c - 0.5, c + 0.5] x [r - 0.5, r + 0.5]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..masks import masked
from .bilinear import masked_corners
from .runs import runs

__all__ = [
    "TextureLayout",
    "texel_of_uv",
    "uv_of_texel",
    "texel_index",
    "texels_reached",
    "parent_texels",
    "coarser_any",
    "bilinear_texels",
    "nearest_texel",
    "texel_totals",
    "texture_layout",
    "MATCHED_SIZE_MAX",
    "pixel_matched_size",
    "uv_stretched",
    "triangle_areas",
    "STRETCH_FACTOR",
]


def _fail(msg):
    raise ValueError(msg)


@dataclass
class TextureLayout:
    """The mesh's UV texture grid, for the texture-domain solver.

    Parameters
    ----------
    texel_pos : (N, N, 3) float array
        World position of each texel centre on the surface, found by
        rasterising the mesh in UV space; NaN for texels outside every UV
        island. It defines which texels exist and the surface length of each
        texel edge (the TV weights).
    seam_pairs : (K, 2) int array, optional
        Flat texel indices ``r * N + c`` of neighbours across UV seams, from
        the mesh edge adjacency.
    """

    texel_pos: np.ndarray
    seam_pairs: np.ndarray | None = None

    def __post_init__(self):
        self.texel_pos = np.asarray(self.texel_pos, dtype=np.float32)
        p = self.texel_pos
        if p.ndim != 3 or p.shape[0] != p.shape[1] or p.shape[2] != 3:
            _fail(f"texture layout: texel_pos must be (N, N, 3), got {p.shape}")
        self._inside = _finite(p)
        self._inside.flags.writeable = False  # made once and shared: an (N, N) array over a large texture
        if not self._inside.any():
            _fail("texture layout: no texel lies inside a UV island")
        n2 = p.shape[0] * p.shape[1]
        if self.seam_pairs is None:
            self.seam_pairs = np.zeros((0, 2), dtype=np.intp)
        self.seam_pairs = np.asarray(self.seam_pairs, dtype=np.intp).reshape(-1, 2)
        if self.seam_pairs.size and (self.seam_pairs.min() < 0 or self.seam_pairs.max() >= n2):
            _fail(f"texture layout: seam_pairs index out of range [0, {n2})")

    @property
    def size(self) -> int:
        return int(self.texel_pos.shape[0])

    @property
    def inside(self) -> np.ndarray:
        """(N, N) bool: texels inside a UV island (read-only)."""
        return self._inside


def _finite(a):
    """``np.all(np.isfinite(a), axis=2)`` of ``(N, N, 3)``, channel by channel: ten times faster over a last axis
    of 3."""
    out = np.isfinite(a[..., 0])
    for k in range(1, a.shape[2]):
        out &= np.isfinite(a[..., k])
    return out


# Candidate (texel, triangle) pairs processed per block, to bound memory.
_BLOCK = 1 << 20
#: Area ratio (UV per surface, against the median) beyond which a triangle counts as stretched.
STRETCH_FACTOR = 10.0


def _check_size(n):
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"texture size must be a positive integer, got {n!r}")
    return int(n)


def texel_of_uv(uv, n):
    """Continuous texel coordinates of UV points.

    Parameters
    ----------
    uv : (..., 2) array_like
        Blender UV coordinates (u right, v up).
    n : int
        Texture size N.

    Returns
    -------
    row, col : (...) float64 arrays
        Texel ``(r, c)``'s centre is at ``(row, col) = (r, c)``.
    """
    n = _check_size(n)
    uv = np.asarray(uv, dtype=np.float64)
    if uv.shape[-1:] != (2,):
        raise ValueError(f"texel_of_uv: uv must be (..., 2), got {uv.shape}")
    return (1.0 - uv[..., 1]) * n - 0.5, uv[..., 0] * n - 0.5


def uv_of_texel(row, col, n):
    """UV coordinates of continuous texel coordinates (inverse of :func:`texel_of_uv`).

    Parameters
    ----------
    row, col : array_like
        Continuous texel coordinates (integers are texel centres).
    n : int
        Texture size N.

    Returns
    -------
    uv : (..., 2) float64 array
    """
    n = _check_size(n)
    row = np.asarray(row, dtype=np.float64)
    col = np.asarray(col, dtype=np.float64)
    return np.stack(np.broadcast_arrays((col + 0.5) / n, 1.0 - (row + 0.5) / n), axis=-1)


def parent_texels(size: int, n: int) -> np.ndarray:
    """For each row (or column) of a ``size`` x ``size`` texture, the row (column) of a coarser ``n`` x ``n``
    texture that holds it: the texels a texture solved at ``n`` and scaled up to ``size`` took their values from.
    """
    return np.minimum(np.arange(size) * n // size, n - 1)


def coarser_any(mask, n: int) -> np.ndarray:
    """An ``(N, N)`` bool ``mask`` brought to ``n`` x ``n`` (``n <= N``): a texel is set where a texel of ``mask``
    that it holds (:func:`parent_texels`) is set."""
    mask = np.asarray(mask, bool)
    starts = np.searchsorted(parent_texels(mask.shape[0], n), np.arange(n))
    return np.logical_or.reduceat(np.logical_or.reduceat(mask, starts, axis=0), starts, axis=1)


def texel_index(uv, n):
    """Flat index ``r * N + c`` of the texel containing each UV point.

    Points on the outer border (u or v exactly 0 or 1) belong to the border
    texels.

    Parameters
    ----------
    uv : (..., 2) array_like
    n : int

    Returns
    -------
    (...) intp array
        -1 where the point lies outside the unit square or is not finite.
    """
    row, col = texel_of_uv(uv, n)
    with np.errstate(invalid="ignore"):
        ok = (row >= -0.5) & (row <= n - 0.5) & (col >= -0.5) & (col <= n - 0.5)
        r = np.clip(np.floor(np.where(ok, row, 0.0) + 0.5), 0, n - 1).astype(np.intp)
        c = np.clip(np.floor(np.where(ok, col, 0.0) + 0.5), 0, n - 1).astype(np.intp)
    return np.where(ok, r * n + c, -1)


def texels_reached(texel):
    """``np.unique(texel, return_inverse=True)`` of pixels' texel indices ``(P,)``: each texel once, in order, and
    which of them each pixel is in.

    The pixels of a photo, in row order, reach their texels in runs, which a stable sort takes whole: about 3x
    faster than np.unique's quicksort.
    """
    texel = np.asarray(texel).ravel()
    order = np.argsort(texel, kind="stable")
    ordered = texel[order]
    first = np.empty(ordered.size, bool)
    first[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    at = np.empty(ordered.size, np.intp)
    at[order] = np.cumsum(first) - 1
    return ordered[first], at


def bilinear_texels(uv, valid):
    """The four texels around each UV point and their bilinear weights, as a renderer samples a texture.

    Parameters
    ----------
    uv : (K, 2) array_like
    valid : (N, N) bool array
        Texels that may be used (for example the UV islands); the size N is its shape.

    Returns
    -------
    index : (K, 4) intp array
        Flat texel indices (clamped into the texture).
    weight : (K, 4) float32 array
        Bilinear weights; texels outside the texture or not ``valid`` get 0
        and the rest are renormalised to sum to 1 (all 0 if none is valid).
    """
    row, col = texel_of_uv(uv, valid.shape[0])
    return masked_corners(col, row, valid)


def nearest_texel(uv, valid):
    """Of :func:`bilinear_texels`, the texel of largest weight around each UV point, and the weights' sum.

    Returns
    -------
    index : (K,) intp array
    weight : (K,) float32 array
        1 where a ``valid`` texel is among the four, else 0.
    """
    flat, wts = bilinear_texels(uv, valid)
    best = np.argmax(wts, axis=1)[:, None]
    return np.take_along_axis(flat, best, axis=1)[:, 0], wts.sum(axis=1)


def _check_mesh(tri_uv, tri_pos, tri_vert):
    tri_uv = np.asarray(tri_uv, dtype=np.float64)
    tri_pos = np.asarray(tri_pos, dtype=np.float64)
    tri_vert = np.asarray(tri_vert)
    if tri_uv.ndim != 3 or tri_uv.shape[1:] != (3, 2):
        raise ValueError(f"texture_layout: tri_uv must be (T, 3, 2), got {tri_uv.shape}")
    t = tri_uv.shape[0]
    if t == 0:
        raise ValueError("texture_layout: the mesh has no triangles")
    if tri_pos.shape != (t, 3, 3):
        raise ValueError(f"texture_layout: tri_pos must be ({t}, 3, 3) like tri_uv, got {tri_pos.shape}")
    if tri_vert.shape != (t, 3):
        raise ValueError(f"texture_layout: tri_vert must be ({t}, 3) like tri_uv, got {tri_vert.shape}")
    if not np.issubdtype(tri_vert.dtype, np.integer):
        raise ValueError(f"texture_layout: tri_vert must hold integer vertex indices, got {tri_vert.dtype}")
    for name, a in (("tri_uv", tri_uv), ("tri_pos", tri_pos)):
        bad = ~np.isfinite(a).reshape(t, -1).all(axis=1)
        if bad.any():
            raise ValueError(
                f"texture_layout: {name} of triangle {int(np.flatnonzero(bad)[0])} "
                f"is NaN or infinite ({int(bad.sum())} triangles)"
            )
    if tri_vert.min() < 0:
        raise ValueError("texture_layout: tri_vert holds negative vertex indices")
    return tri_uv, tri_pos, tri_vert.astype(np.int64)


def _barycentric_planes(q):
    """Per triangle, barycentrics as affine functions of texel coordinates.

    Parameters
    ----------
    q : (T, 3, 2) vertices in (x, y) texel coordinates.

    Returns
    -------
    a, b, c : (T, 3) arrays with ``lambda_i(x, y) = a_i x + b_i y + c_i``.
    ok : (T,) bool, False for triangles of (nearly) zero UV area.
    """
    qj = np.roll(q, -1, axis=1)  # vertex i+1
    qk = np.roll(q, -2, axis=1)  # vertex i+2
    d = qk - qj  # edge opposite vertex i
    den = d[:, 0, 0] * (q[:, 0, 1] - qj[:, 0, 1]) - d[:, 0, 1] * (q[:, 0, 0] - qj[:, 0, 0])
    # 1e-9 texel^2: such triangles cover no texel in any meaningful way.
    ok = np.abs(den) > 1e-9
    den = np.where(ok, den, 1.0)[:, None]
    a = -d[..., 1] / den
    b = d[..., 0] / den
    c = (d[..., 1] * qj[..., 0] - d[..., 0] * qj[..., 1]) / den
    return a, b, c, ok


def _closest_on_boundary(qt, x, y):
    """Barycentrics of the point of each triangle's boundary closest to (x, y).

    Parameters
    ----------
    qt : (K, 3, 2) triangle vertices; x, y : (K,) points (outside the triangles).
    """
    p = np.stack([x, y], axis=1).astype(np.float64)
    k = np.arange(p.shape[0])
    best_d = np.full(p.shape[0], np.inf)
    lam = np.zeros((p.shape[0], 3))
    for i in range(3):
        j, m = (i + 1) % 3, (i + 2) % 3
        d = qt[:, m] - qt[:, j]
        s = np.clip(np.sum((p - qt[:, j]) * d, axis=1) / np.maximum(np.sum(d * d, axis=1), 1e-300), 0, 1)
        dist = np.sum((qt[:, j] + s[:, None] * d - p) ** 2, axis=1)
        better = dist < best_d
        best_d[better] = dist[better]
        lam[better] = 0.0
        lam[k[better], j] = 1.0 - s[better]
        lam[k[better], m] = s[better]
    return lam


def triangle_areas(tri_uv, tri_pos):
    """Each triangle's area in the UV square and on the surface: ``(T,), (T,)``."""
    tri_uv = np.asarray(tri_uv, dtype=np.float64)
    tri_pos = np.asarray(tri_pos, dtype=np.float64)
    e1, e2 = tri_uv[:, 1] - tri_uv[:, 0], tri_uv[:, 2] - tri_uv[:, 0]
    uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    area = 0.5 * np.linalg.norm(np.cross(tri_pos[:, 1] - tri_pos[:, 0], tri_pos[:, 2] - tri_pos[:, 0]), axis=1)
    return uv_area, area


def uv_stretched(tri_uv, tri_pos, factor=STRETCH_FACTOR):
    """(T,) bool: triangles stretched ``factor`` times in the UV map, against the median of the mesh.

    A triangle counts when its UV area per surface area is ``factor`` times off the median, or when
    one of its edges is ``factor`` times longer in UV, per surface length, than the median edge.
    An n-gon whose corners lie in two UV islands is split into such triangles: they span the gap
    between the islands and cover texels that belong to other faces. The edge test catches the
    slivers among them, whose area looks normal.
    """
    uv_area, area = triangle_areas(tri_uv, tri_pos)
    usable = (uv_area > 0) & (area > 0)
    if not usable.any():
        return np.zeros(len(tri_uv), dtype=bool)
    ratio = uv_area / np.where(area > 0, area, 1.0)
    median = float(np.median(ratio[usable]))
    stretched = usable & ((ratio > factor * median) | (ratio < median / factor))
    tri_uv = np.asarray(tri_uv, dtype=np.float64)
    tri_pos = np.asarray(tri_pos, dtype=np.float64)
    uv_len = np.linalg.norm(np.roll(tri_uv, -1, axis=1) - tri_uv, axis=2)
    length = np.linalg.norm(np.roll(tri_pos, -1, axis=1) - tri_pos, axis=2)
    edge_ratio = uv_len / np.where(length > 0, length, 1.0)
    edge_median = float(np.median(edge_ratio[usable]))
    return stretched | (usable & np.any(edge_ratio > factor * edge_median, axis=1))


def _row_spans(a, b, c, slack, lo, hi, ok):
    """The candidate texels of each triangle as runs on the rows of its box: triangle, row, first column, length.

    On each row, the columns where every ``lambda_i + slack_i >= 0`` (a linear bound in x per edge), widened
    by a texel each side against rounding: :func:`_rasterise` tests each candidate exactly, in the same order
    as over the whole box (triangle, then row, then column), and a triangle fills about half its box.
    """
    h = np.where(ok & (hi[:, 0] >= lo[:, 0]), np.maximum(hi[:, 1] - lo[:, 1] + 1, 0), 0)
    tris = np.flatnonzero(h > 0)
    run, place = runs(h[tris])
    tri = np.take(tris, run)
    row = np.take(lo[tris, 1], run) + place
    x0 = lo[tri, 0].astype(np.float64)
    x1 = hi[tri, 0].astype(np.float64)
    yf = row.astype(np.float64)
    for i in range(3):
        ai = a[tri, i]
        rest = b[tri, i] * yf + c[tri, i] + slack[tri, i]
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = -rest / np.where(ai != 0, ai, 1.0)
        x0 = np.where(ai > 0, np.maximum(x0, np.floor(bound) - 1), x0)
        x1 = np.where(ai < 0, np.minimum(x1, np.ceil(bound) + 1), x1)
        x1 = np.where((ai == 0) & (rest < 0), x0 - 1, x1)
    length = np.maximum(x1 - x0 + 1, 0).astype(np.int64)
    keep = length > 0
    return tri[keep], row[keep], x0[keep].astype(np.int64), length[keep]


def _rasterise(q, tri_pos, n, margin, low_priority=None):
    """World position per texel by conservative rasterisation (see :func:`texture_layout`)."""
    a, b, c, ok = _barycentric_planes(q)
    grad = np.hypot(a, b)
    # A texel counts when its bilinear footprint, the square of half-side 1
    # around its centre, meets the triangle (grown by margin): then every
    # bilinear lookup inside a triangle finds data. The square meets the
    # half-plane lambda_i >= 0 iff lambda_i at its centre is >= -(|a| + |b|)
    # (the square's support). A mere touch (< 1e-6 texel) does not count.
    slack = (np.abs(a) + np.abs(b)) + (margin - 1e-6) * grad
    inv_grad = 1.0 / np.where(grad > 0, grad, 1.0)
    grow = 1.0 + margin
    # Texels whose square overlaps the grown bounding box by more than 1e-6.
    lo = np.floor(q.min(axis=1) - grow + 1e-6).astype(np.int64) + 1
    hi = np.ceil(q.max(axis=1) + grow - 1e-6).astype(np.int64) - 1
    lo = np.clip(lo, 0, n - 1)
    hi = np.clip(hi, -1, n - 1)
    outside = (q.max(axis=1) + grow < 0) | (q.min(axis=1) - grow > n - 1)
    hi = np.where(outside, lo - 1, hi)
    span_tri, span_row, span_x0, span_len = _row_spans(a, b, c, slack, lo, hi, ok)
    offs = np.concatenate([[0], np.cumsum(span_len)])
    total = int(offs[-1])

    best = np.full(n * n, -np.inf)
    pos = np.full((n * n, 3), np.nan, dtype=np.float32)
    for k0 in range(0, total, _BLOCK):
        k1 = min(k0 + _BLOCK, total)
        # The block's spans, and how many of each span's candidates it holds.
        s0, s1 = (int(np.searchsorted(offs, e, side="right")) - 1 for e in (k0, k1 - 1))
        spans = np.arange(s0, s1 + 1)
        count = np.minimum(offs[s0 + 1 : s1 + 2], k1) - np.maximum(offs[s0 : s1 + 1], k0)
        # What is one number per span (its triangle's planes, its row's term) is worked out per span and
        # repeated over its candidates: the same values as per candidate, fewer gathers.
        ts = span_tri[spans]
        run, place = runs(count)
        t = np.take(ts, run)
        y = np.take(span_row[spans], run)
        x = np.take(span_x0[spans] + (np.maximum(offs[spans], k0) - offs[spans]), run)
        x += place
        xf = x.astype(np.float64)
        yf = span_row[spans].astype(np.float64)
        lam = [np.take(a[ts, i], run) * xf for i in range(3)]
        for i in range(3):  # a x + b y + c, in that order
            lam[i] += np.take(b[ts, i] * yf, run)
            lam[i] += np.take(c[ts, i], run)
        keep = (lam[0] + np.take(slack[ts, 0], run) >= 0) & (lam[1] + np.take(slack[ts, 1], run) >= 0)
        keep &= lam[2] + np.take(slack[ts, 2], run) >= 0
        t, x, y = t[keep], x[keep], y[keep]
        lam = np.stack([li[keep] for li in lam], axis=1)
        # Signed distance (texels) to the triangle's edge lines: >= 0 inside.
        # Texels whose centre is covered win over those only overlapped.
        d = lam * inv_grad[t]
        score = np.minimum(np.minimum(d[:, 0], d[:, 1]), d[:, 2])
        key = score
        if low_priority is not None:
            # Stretched triangles only take texels that no other triangle reaches.
            key = score - np.where(low_priority[t], 2.0 * n, 0.0)
        flat = y * n + x
        np.maximum.at(best, flat, key)
        win = key >= best[flat]
        t, lam, flat = t[win], lam[win], flat[win]
        # Outside the triangle, take the closest point of the triangle, so that
        # positions stay on the surface (extrapolating a sliver could land far).
        out = np.flatnonzero(score[win] < 0)
        if out.size:
            lam[out] = _closest_on_boundary(q[t[out]], x[win][out], y[win][out])
        pos[flat] = np.einsum("ki,kij->kj", lam, tri_pos[t])
    return pos.reshape(n, n, 3)


def _seam_pairs(q, tri_vert, inside, n):
    """Texel pairs across UV seams (see :func:`texture_layout`)."""
    ea = np.array([0, 1, 2])
    eb = np.array([1, 2, 0])
    ec = np.array([2, 0, 1])  # vertex opposite each edge
    va = tri_vert[:, ea].ravel()
    vb = tri_vert[:, eb].ravel()
    swap = va > vb
    lo_v = np.where(swap, vb, va)
    hi_v = np.where(swap, va, vb)
    qa = q[:, ea].reshape(-1, 2)
    qb = q[:, eb].reshape(-1, 2)
    q_lo = np.where(swap[:, None], qb, qa)  # UV at the lower vertex index
    q_hi = np.where(swap[:, None], qa, qb)
    q_opp = q[:, ec].reshape(-1, 2)
    key = lo_v * (int(tri_vert.max()) + 1) + hi_v
    order = np.argsort(key, kind="stable")
    ks = key[order]
    start = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    count = np.diff(np.r_[start, ks.size])
    # Manifold edges only: an edge shared by more than two triangles is ambiguous.
    two = start[count == 2]
    e1 = order[two]
    e2 = order[two + 1]
    gap = np.maximum(np.abs(q_lo[e1] - q_lo[e2]).max(axis=1), np.abs(q_hi[e1] - q_hi[e2]).max(axis=1))
    seam = gap > 1e-3  # in texels
    e1, e2 = e1[seam], e2[seam]
    if e1.size == 0:
        return np.zeros((0, 2), dtype=np.intp)
    len1 = np.linalg.norm(q_hi[e1] - q_lo[e1], axis=1)
    len2 = np.linalg.norm(q_hi[e2] - q_lo[e2], axis=1)
    ns = np.ceil(np.maximum(len1, len2)).astype(np.int64) + 1
    e, k = runs(ns)
    s = ((k + 0.5) / ns[e])[:, None]

    def texel(edge):
        p0, p1, po = q_lo[edge], q_hi[edge], q_opp[edge]
        p = p0[e] + s * (p1 - p0)[e]
        # Step half a texel into the triangle, so the pair links the texels on
        # each side of the seam rather than the gutter texel the edge crosses.
        d = p1 - p0
        nrm = np.stack([-d[:, 1], d[:, 0]], axis=1)
        nrm *= np.sign(np.sum(nrm * (po - p0), axis=1))[:, None]
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-12)[:, None]
        p = p + 0.5 * nrm[e]
        x = np.floor(p[:, 0] + 0.5).astype(np.int64)
        y = np.floor(p[:, 1] + 0.5).astype(np.int64)
        ok = (x >= 0) & (x < n) & (y >= 0) & (y < n)
        flat = np.where(ok, y * n + x, 0)
        return flat, ok & inside.ravel()[flat]

    fa, oka = texel(e1)
    fb, okb = texel(e2)
    ok = oka & okb & (fa != fb)
    pairs = np.stack([np.minimum(fa[ok], fb[ok]), np.maximum(fa[ok], fb[ok])], axis=1)
    return np.unique(pairs, axis=0).astype(np.intp)


def texel_totals(uvs, masks, weights, valid):
    """Each view's masked pixels on their nearest texels (:func:`nearest_texel`), and their weight per texel.

    Parameters
    ----------
    uvs : list of (H, W, 2) arrays
    masks : list of (H, W) bool arrays
    weights : list of (H, W) arrays or None
        Each pixel's weight (None: 1).
    valid : (N, N) bool array
        The texels a pixel may land on.

    Returns
    -------
    texels : list of (P_v,) intp arrays
        The nearest texel (flat) of each of view v's masked pixels, in mask order.
    pixel_weights : list of (P_v,) float64 arrays
        Its weight, 0 where no valid texel is near.
    total : (N * N,) float64 array
        The weight of all the pixels per texel.
    """
    n = np.asarray(valid).shape[0]
    texels, pixel_weights = [], []
    total = np.zeros(n * n)
    for i, mask in enumerate(masks):
        texel, landed = nearest_texel(masked(uvs[i], mask), valid)
        w = np.ones(texel.size) if weights is None else weights[i][mask].astype(np.float64)
        w = np.where(landed > 0, w, 0.0)
        texels.append(texel)
        pixel_weights.append(w)
        total += np.bincount(texel, weights=w, minlength=n * n)
    return texels, pixel_weights, total


def texture_layout(tri_uv, tri_pos, tri_vert, size, margin=0) -> TextureLayout:
    """Rasterise a UV-mapped triangle mesh into a texture layout.

    Parameters
    ----------
    tri_uv : (T, 3, 2) array_like
        UV coordinates of each triangle corner (Blender's loop-triangle UVs).
    tri_pos : (T, 3, 3) array_like
        World positions of each triangle corner.
    tri_vert : (T, 3) int array_like
        Mesh vertex index of each corner; two triangles that share an edge
        share its two vertex indices, whatever their UVs.
    size : int
        Texture size N.
    margin : float, optional
        Grow every triangle by this many texels in UV before rasterising
        (default 0).

    Returns
    -------
    TextureLayout
        ``texel_pos`` is the world position of every texel used by a
        bilinear lookup somewhere on a triangle (conservative rasterisation:
        the open square of half-side 1 texel around the texel's centre meets
        the triangle grown by ``margin``), NaN elsewhere. A texel whose
        centre lies in a triangle takes that triangle's barycentric
        interpolation; one at an island border, whose centre no triangle
        covers, takes the closest point of the nearest triangle, so that
        every position lies on the surface.
        ``seam_pairs`` links the texels on either side of every UV seam
        (a mesh edge shared by two triangles whose UVs differ), sampled about
        once per texel along the edge, as sorted unique ``(a, b)`` flat
        indices with ``a < b``. Edges shared by more than two triangles are
        ignored.

    Raises
    ------
    ValueError
        On badly shaped or non-finite input, or when no triangle covers a
        texel.
    """
    n = _check_size(size)
    margin = float(margin)
    if not np.isfinite(margin) or margin < 0:
        raise ValueError(f"texture_layout: margin must be >= 0, got {margin}")
    tri_uv, tri_pos, tri_vert = _check_mesh(tri_uv, tri_pos, tri_vert)
    row, col = texel_of_uv(tri_uv, n)
    q = np.stack([col, row], axis=-1)  # (T, 3, 2) as (x, y)
    stretched = uv_stretched(tri_uv, tri_pos)
    pos = _rasterise(q, tri_pos, n, margin, low_priority=stretched)
    inside = _finite(pos)
    if not inside.any():
        raise ValueError(
            f"texture_layout: no triangle covers any texel of the {n}x{n} texture (are the UVs inside [0, 1]?)"
        )
    # A stretched triangle's edges are no seam: its UVs span a gap, not a cut.
    pairs = _seam_pairs(q[~stretched], tri_vert[~stretched], inside, n)
    return TextureLayout(texel_pos=pos, seam_pairs=pairs)


#: The largest size :func:`pixel_matched_size` gives.
MATCHED_SIZE_MAX = 2048


def pixel_matched_size(masks, uvs, n, pixels_per_texel: float = 2.0) -> int:
    """A texture size halved from ``n`` (at most :data:`MATCHED_SIZE_MAX`) until the median view has about
    ``pixels_per_texel`` pixels per texel it reaches, so that a texture made from the photos' pixels has no holes
    between them.
    A view has at least one pixel per texel it reaches at any size, so ``pixels_per_texel`` must be above 1.

    Parameters
    ----------
    masks, uvs : lists of (H, W) bool and (H, W, 2) arrays
        The bake's, one per view.
    n : int
    pixels_per_texel : float
    """
    if pixels_per_texel <= 1:
        raise ValueError(f"pixel_matched_size: pixels_per_texel must be above 1 (every size has 1): {pixels_per_texel}")
    size = min(int(n), MATCHED_SIZE_MAX)
    while size > 16:
        ratios = []
        for m, uv in zip(masks, uvs):
            t = texel_index(masked(uv, m), size)
            reached = np.zeros(size * size, bool)  # counted by marking: np.unique would sort every pixel
            reached[t[t >= 0]] = True
            hit = np.count_nonzero(reached)
            if hit:
                ratios.append(t.size / hit)
        if not ratios or np.median(ratios) >= pixels_per_texel:
            break
        size //= 2
    return size
