"""Cast one ray per pixel centre against a triangle soup, vectorised in NumPy.

This is the bake's ray caster. It gives the same answer as tracing a ray from
the camera centre through every pixel centre and keeping the nearest hit
(which is what Cycles does for a 1-sample render with a tiny box filter), but
it works triangle by triangle like a z-buffer rasteriser:

1. each triangle is moved to camera space and clipped to the half space in
   front of the camera; on each pixel row of its projection, the pixel
   centres within the triangle's exact span (its bounding box if it crosses
   the camera plane) become candidates;
2. each candidate is tested exactly against the triangle with signed volumes
   (the ray from the origin through the pixel hits the triangle iff the three
   triple products ``d . (Vi x Vj)`` share the sign of ``d . N``);
3. a depth buffer keeps the nearest hit per pixel.

Triangles of many pixels each (a photo of the mesh, not a shadow map of a fine scan) are cast in passes, the
side of the mesh that faces the camera first; a triangle of a later pass whose nearest corner lies behind every
hit in its box of pixels is left out before step 1's spans. On a closed mesh that is most of its far side, about
half of the candidates; the hits are the same.

Both faces of a triangle are hit (as in Cycles), and no clipping distance
applies: a photo sees everything in front of the lens.

A mesh given as :class:`Triangles` (its corners as shared vertices) has each
vertex moved to camera space and projected once, not once per triangle that
shares it: on a mesh finer than the pixels (a shadow map of a scan), that is
most of the work.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from .runs import runs

__all__ = ["RayHits", "Triangles", "raycast", "at_hits", "nan_min_max"]

# Inclusive edge test with a tiny tolerance so that a pixel centre exactly on a
# shared edge is not lost to rounding in both triangles.
_EDGE_EPS = 1e-9


@dataclass
class RayHits:
    """Nearest hit of the ray through every pixel centre.

    Attributes
    ----------
    tri : (H, W) intp
        Index of the triangle hit, -1 where the ray misses.
    bary : (H, W, 3) float64
        Barycentric weights of the triangle's three corners at the hit (0 where
        the ray misses): a view of three (H, W) planes, so ``bary[..., c]`` is contiguous.
    depth : (H, W) float64
        Camera-space depth z of the hit (inf where the ray misses).
    """

    tri: np.ndarray
    bary: np.ndarray
    depth: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool: pixels whose ray hit a triangle."""
        return self.tri >= 0

    def interpolate(self, corner_values, fill=0.0) -> np.ndarray:
        """Interpolate per-corner values ``(T, 3, k)`` at the hits; ``(H, W, k)``.

        Pixels without a hit get ``fill``.
        """
        vals = np.asarray(corner_values)
        if vals.ndim == 2:
            vals = vals[:, :, None]
        h, w = self.tri.shape
        out = np.full((h, w, vals.shape[2]), fill, dtype=np.result_type(vals.dtype, np.float32))
        m = self.mask
        out[m] = at_hits([self.bary[..., c][m] for c in range(3)], vals, self.tri[m])
        return out


def at_hits(weights, corner_values, tri) -> np.ndarray:
    """Corner values ``(T, 3, k)`` at hits on triangles ``tri`` ``(P,)``: ``(P, k)`` float64.

    ``weights``: the hits' barycentric weights, as three ``(P,)`` arrays. The sum is einsum's
    ``"nc,nck->nk"`` (the same order, so the same bits), component by component over whole columns: einsum's
    loops over three corners and a few components are several times slower.
    """
    # A mesh larger than the hits: each hit's rows gathered at once, not its corners column by column from far
    # apart in memory. Few triangles, each hit many times: their columns, which stay in the cache.
    rows = np.take(corner_values, tri, axis=0) if tri.size < len(corner_values) else None
    if rows is None:  # read many times each: as float64 once, which the products are in either way
        corner_values = np.asarray(corner_values, np.float64)

    def column(c, j):
        return rows[:, c, j] if rows is not None else np.take(corner_values[:, c, j], tri)

    out = np.empty((tri.size, corner_values.shape[2]))
    for j in range(out.shape[1]):
        o = column(0, j) * weights[0]
        o += column(1, j) * weights[1]
        o += column(2, j) * weights[2]
        out[:, j] = o
    return out


@dataclass
class Triangles:
    """A triangle mesh as shared vertices: what :func:`raycast` takes in place of the corners ``(T, 3, 3)``.

    Attributes
    ----------
    vertices : (V, 3) float64
        World positions, each used by some triangle.
    faces : (T, 3) intp
        Each triangle's vertices.
    """

    vertices: np.ndarray
    faces: np.ndarray

    @classmethod
    def of(cls, tri_pos, tri_vert=None) -> Triangles:
        """The triangles ``tri_pos`` ``(T, 3, 3)`` with their corners shared as ``tri_vert`` ``(T, 3)`` says.

        Where ``tri_vert`` is not given or does not match ``tri_pos`` (two corners of one index at two places),
        every corner is a vertex of its own: the same triangles, nothing shared.
        """
        tri_pos = np.asarray(tri_pos, np.float64).reshape(-1, 3, 3)
        corners = tri_pos.reshape(-1, 3)
        if tri_vert is not None and len(corners):
            used, faces = np.unique(np.asarray(tri_vert).ravel(), return_inverse=True)
            vertices = np.empty((used.size, 3))
            vertices[faces] = corners
            if faces.size == len(corners) and np.array_equal(vertices[faces], corners):
                return cls(vertices, faces.reshape(-1, 3).astype(np.intp))
        return cls(corners.copy(), np.arange(len(corners), dtype=np.intp).reshape(-1, 3))

    @functools.cached_property
    def corners(self) -> np.ndarray:
        """``faces.T`` with contiguous rows ``(3, T)`` (kept): each corner's vertices, read once per cast."""
        return np.ascontiguousarray(self.faces.T)

    @property
    def tri_pos(self) -> np.ndarray:
        """``(T, 3, 3)``: each triangle's corners."""
        return self.vertices[self.faces]

    def __len__(self):
        return len(self.faces)


def _vertex_boxes(camera, vv, corners):
    """:func:`_pixel_boxes` of triangles over camera-space vertices ``vv`` that are all in front, for a camera
    without skew; ``corners`` ``(3, T)`` the triangles' vertices, corner by corner (:attr:`Triangles.corners`).

    Each vertex's first and last pixel column and row are worked out once, and a triangle's box is their extremes
    over its corners: the same numbers as from the triangle's projected bounds, as every step from a corner's
    coordinate to a pixel index keeps its order. On a mesh finer than the pixels (a shadow map of a scan) this is
    most of the cast.
    """
    h, w = camera.height, camera.width
    fx, _, cx, fy, cy = _intrinsics(camera)
    z = vv[:, 2]
    # As _bounds and _pixel_boxes work them out, with skew * Y/Z, zero, left out.
    x = fx * (vv[:, 0] / z) + cx
    y = fy * (vv[:, 1] / z) + cy
    # A vertex's first column and row side by side, and its last: one gather of 8 bytes reads both.
    first, last = np.empty((len(vv), 2), np.int32), np.empty((len(vv), 2), np.int32)
    for k, (p, n) in enumerate(((x, w), (y, h))):
        first[:, k] = np.clip(np.ceil(p - _MARGIN), 0, n)
        last[:, k] = np.clip(np.floor(p + _MARGIN), -1, n - 1)
    (c0, r0), (c1, r1) = _corner_extreme(first, corners, np.minimum).T, _corner_extreme(last, corners, np.maximum).T
    nr = np.where(c1 >= c0, np.maximum(r1 - r0 + 1, 0), 0)
    return c0, c1, r0, nr


def _corner_extreme(pairs, corners, op):
    """``op`` over each triangle's three corners of its vertices' ``(V, 2)`` int32 pairs, ``(T, 2)``.

    ``corners`` is :attr:`Triangles.corners` (contiguous: a strided column of faces reads all three columns'
    memory); each pair is read as one int64.
    """
    packed = pairs.view(np.int64).ravel()
    out = np.take(packed, corners[0]).view(np.int32).reshape(-1, 2)
    for c in corners[1:]:
        op(out, np.take(packed, c).view(np.int32).reshape(-1, 2), out=out)
    return out


def _bounds(vc, z_near):
    """Projected bounds of each camera-space triangle clipped to ``z >= z_near``.

    Returns (xmin, xmax, ymin, ymax) in normalised image coordinates
    ``(X/Z, Y/Z)`` and a bool array of triangles with some part in front.
    """
    z = vc[:, :, 2]
    front = z >= z_near
    if front.all():  # the common case, without the NaNs
        px, py = vc[:, :, 0] / z, vc[:, :, 1] / z
        (xmin, xmax), (ymin, ymax) = (nan_min_max([p[:, 0], p[:, 1], p[:, 2]]) for p in (px, py))
        return xmin, xmax, ymin, ymax, np.ones(len(vc), bool)
    keep = front.any(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        px = np.where(front, vc[:, :, 0] / z, np.nan)
        py = np.where(front, vc[:, :, 1] / z, np.nan)
    xs, ys = [px[:, k] for k in range(3)], [py[:, k] for k in range(3)]
    # Where an edge crosses the near plane, its crossing point bounds the clipped polygon.
    crossing = keep & ~front.all(axis=1)
    if crossing.any():
        for i, j in ((0, 1), (1, 2), (2, 0)):
            a, b = vc[:, i], vc[:, j]
            cut = crossing & (front[:, i] != front[:, j])
            s = np.zeros(len(vc))
            s[cut] = (z_near - a[cut, 2]) / (b[cut, 2] - a[cut, 2])
            p = a + s[:, None] * (b - a)
            xs.append(np.where(cut, p[:, 0] / z_near, np.nan))
            ys.append(np.where(cut, p[:, 1] / z_near, np.nan))
    (xmin, xmax), (ymin, ymax) = nan_min_max(xs), nan_min_max(ys)
    return (*(np.where(keep, b, 0.0) for b in (xmin, xmax, ymin, ymax)), keep)


def nan_min_max(columns):
    """Elementwise min and max over equal-shaped arrays, ignoring NaN (NaN where all are).

    Column by column: ``np.nanmin(..., axis=1)`` over a few columns reduces each short row on its own, several
    times slower.
    """
    lo = hi = columns[0]
    for c in columns[1:]:
        lo, hi = np.fmin(lo, c), np.fmax(hi, c)
    return lo, hi


def raycast(camera, tri_pos, batch=1_000_000, pixels=None) -> RayHits:
    """Nearest triangle hit by the ray through each pixel centre of ``camera``.

    Parameters
    ----------
    camera : core.geometry.camera.Camera
        Pinhole camera; pixel centre ``(row r, col c)`` is at ``(x, y) = (c, r)``.
    tri_pos : (T, 3, 3) array or Triangles
        World positions of the triangles' corners, or the triangles as shared vertices (the same hits).
    batch : int
        Number of (pixel, triangle) candidates tested at once; bounds memory
        (about 120 bytes per candidate).
    pixels : (H * W,) bool array, optional
        Only the rays through these pixels (flat, row by row), each hit as without it; every other pixel is a
        miss. A triangle whose box of pixels holds none of them is left out, so a few pixels cost a few
        triangles' work.

    Returns
    -------
    RayHits
    """
    if not isinstance(tri_pos, Triangles):
        tri_pos = np.asarray(tri_pos, dtype=np.float64).reshape(-1, 3, 3)
    h, w = camera.height, camera.width
    depth = np.full(h * w, np.inf)
    best = np.full(h * w, -1, dtype=np.intp)
    bary = np.zeros((3, h * w))  # plane by plane: each weight is written and read over whole arrays
    if len(tri_pos):
        shared = isinstance(tri_pos, Triangles)
        vc = camera.to_camera(tri_pos.vertices if shared else tri_pos)
        scale = max(float(vc.max()), -float(vc.min())) or 1.0  # no abs copy over every corner
        z_near = 1e-9 * scale
        # Some corner behind (each triangle clipped on its own), or a skewed camera: the triangles' own corners.
        if shared and (float(vc[:, 2].min()) < z_near or _intrinsics(camera)[1]):
            vc, shared = vc[tri_pos.faces], False
        # Only the triangles whose box holds a pixel centre go on: on a mesh finer than the pixels, a few.
        boxes = _vertex_boxes(camera, vc, tri_pos.corners) if shared else _pixel_boxes(camera, _bounds(vc, z_near))
        tris = np.flatnonzero(boxes[3] > 0)
        boxes = [b[tris].astype(np.int64, copy=False) for b in boxes]
        if pixels is not None:
            keep = _holds_any(pixels.reshape(h, w), boxes)
            tris, boxes = tris[keep], [b[keep] for b in boxes]
        vc = np.take(vc, np.take(tri_pos.faces, tris, axis=0) if shared else tris, axis=0)
        n_corner, vol = _edge_planes(vc)
        z_lo = np.maximum(np.minimum(np.minimum(vc[:, 0, 2], vc[:, 1, 2]), vc[:, 2, 2]), z_near)
        # A few pixels leave the depths elsewhere at inf, which hides nothing: one pass.
        passes = _passes(vol, z_lo, boxes) if pixels is None else [slice(None)]
        wanted = None if pixels is None else _wanted_ends(pixels)
        for k, sel in enumerate(passes):
            if k:  # what the passes before hide is left out
                sel = sel[~_hidden(depth.reshape(h, w), z_lo[sel], [b[sel] for b in boxes])]
            spans = _row_spans(camera, vc[sel], z_near, [b[sel] for b in boxes], wanted)
            if spans[0].size:
                _nearest_hits(camera, n_corner[sel], vol[sel], tris[sel], z_near, spans, batch, depth, best, bary)
    if pixels is not None:  # a run's pixels between two wanted ones are hit as well
        off = ~pixels
        depth[off], best[off], bary[:, off] = np.inf, -1, 0.0
    return RayHits(best.reshape(h, w), np.moveaxis(bary.reshape(3, h, w), 0, -1), depth.reshape(h, w))


def _wanted_ends(pixels):
    """For each pixel (flat), the first wanted pixel at or after it and the last at or before it (-1: none)."""
    n = pixels.size
    at = np.flatnonzero(pixels)
    first = np.full(n, n)
    first[at] = at
    first = np.minimum.accumulate(first[::-1])[::-1]
    last = np.full(n, -1)
    last[at] = at
    return first, np.maximum.accumulate(last)


def _holds_any(wanted, boxes):
    """Whether each box of pixels (non-empty, :func:`_pixel_boxes`) holds a pixel of ``wanted`` (H, W) bool: by a
    summed-area table, four lookups a box."""
    h, w = wanted.shape
    table = np.zeros((h + 1, w + 1), np.int32)
    rows, sums = np.cumsum(wanted, axis=1, dtype=np.int32), table[1:, 1:]
    sums[0] = rows[0]
    for r in range(1, h):  # row by row: a cumsum down the columns strides, ten times slower
        np.add(sums[r - 1], rows[r], out=sums[r])
    table = table.ravel()
    c0, c1, r0, nr = boxes
    top, bottom, left, right = r0 * (w + 1), (r0 + nr) * (w + 1), c0, c1 + 1
    return (table[bottom + right] - table[top + right] - table[bottom + left] + table[top + left]) > 0


def _edge_planes(vc):
    """Per camera-space triangle ``vc`` (T, 3, 3): the edge-plane normals ``Vj x Vk`` (one per corner) and the
    signed volume ``V0 . (V1 x V2)``, whose sign says which side of the triangle faces the camera."""
    v0, v1, v2 = vc[:, 0], vc[:, 1], vc[:, 2]
    n_corner = np.empty_like(vc)
    for k, (a, b) in enumerate(((v1, v2), (v2, v0), (v0, v1))):
        _cross_into(a, b, n_corner[:, k])
    return n_corner, np.einsum("ij,ij->i", v0, n_corner[:, 0])


def _passes(vol, z_lo, boxes):
    """The triangles in the order they are cast, as index arrays (each in the triangles' own order) or one slice.

    The near half of the side of the mesh that faces the camera (the side whose nearest corners are nearer),
    then its far half, then the other side: on a closed mesh, what the first pass hits hides most of the rest.
    Triangles of a few pixels each (a shadow map of a fine mesh) are cast in one pass: hiding them would cost
    about what it saves. The order decides nothing but speed (and which of two triangles at exactly the same
    depth wins a pixel).
    """
    c0, c1, _, nr = boxes
    if float(np.dot((c1 - c0 + 1).astype(np.float64), nr)) < _PASS_PIXELS * vol.size:
        return [slice(None)]  # views, not copies
    side = [np.flatnonzero(vol < 0), np.flatnonzero(vol >= 0)]
    if not side[0].size or (side[1].size and np.median(z_lo[side[1]]) < np.median(z_lo[side[0]])):
        side.reverse()  # the side that faces the camera first, whichever sign it has (one side only: that one)
    near = z_lo[side[0]] <= np.median(z_lo[side[0]]) if side[0].size else np.zeros(0, bool)
    return [p for p in (side[0][near], side[0][~near], side[1]) if p.size]


def _hidden(depth, z_lo, boxes):
    """Triangles whose nearest corner (``z_lo``) lies behind every hit in their box of pixels (``boxes``, as
    :func:`_pixel_boxes` gives them): the ray caster leaves them out, as none of their pixels could take them.

    The largest depth of each tile of ``_TILE`` x ``_TILE`` pixels (inf where a pixel is not hit yet), and of
    each 2 x 2 of those and so on up: a box is looked up at the level where it spans at most two cells each way.
    """
    levels = [_tile_max(depth, _TILE)]
    while max(levels[-1].shape) > 2:
        levels.append(_tile_max(levels[-1], 2))
    c0, c1, r0, nr = boxes
    x0, x1, y0, y1 = c0 // _TILE, c1 // _TILE, r0 // _TILE, (r0 + nr - 1) // _TILE
    level = np.zeros(z_lo.size, np.intp)
    while True:
        wide = ((x1 >> level) - (x0 >> level) > 1) | ((y1 >> level) - (y0 >> level) > 1)
        wide &= level < len(levels) - 1
        if not wide.any():
            break
        level[wide] += 1
    far = np.full(z_lo.size, np.inf)
    for k in np.unique(level):
        at, a = np.flatnonzero(level == k), levels[k]
        xa, xb, ya, yb = x0[at] >> k, x1[at] >> k, y0[at] >> k, y1[at] >> k
        far[at] = np.maximum(np.maximum(a[ya, xa], a[ya, xb]), np.maximum(a[yb, xa], a[yb, xb]))
    # A hit's depth is the ratio vol / s, which may round a little below the corner's own z.
    return z_lo > far * (1 + 1e-9)


# Pixels of slack on the projected bounds; the exact test decides.
_MARGIN = 1e-3
# Pixels per side of the tiles of depth that tell which triangles are hidden (:func:`_hidden`).
_TILE = 8
# Candidate pixels per triangle (of its box) below which the triangles are cast in one pass (:func:`_passes`).
_PASS_PIXELS = 4


def _intrinsics(camera):
    """``fx, skew, cx, fy, cy``: pixel ``x = fx X/Z + skew Y/Z + cx``, ``y = fy Y/Z + cy``."""
    K = camera.K
    return K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]


def _pixel_boxes(camera, bounds):
    """Each triangle's box of candidate pixel centres: first column c0, last c1, first row r0, row count nr.

    ``bounds``: the triangles' projected bounds and which are in front (:func:`_bounds`).
    """
    h, w = camera.height, camera.width
    fx, skew, cx, fy, cy = _intrinsics(camera)
    xmin, xmax, ymin, ymax, keep = bounds
    # Normalised bounds to pixel bounds: y = fy * Y/Z + cy, x = fx * X/Z + skew * Y/Z + cx.
    # (With skew the x range needs both Y/Z extremes.)
    sk = np.stack([skew * ymin, skew * ymax])
    c_lo = fx * xmin + sk.min(axis=0) + cx
    c_hi = fx * xmax + sk.max(axis=0) + cx
    r_lo = fy * ymin + cy
    r_hi = fy * ymax + cy
    with np.errstate(invalid="ignore"):
        c0 = np.clip(np.ceil(c_lo - _MARGIN), 0, w).astype(np.int64)
        c1 = np.clip(np.floor(c_hi + _MARGIN), -1, w - 1).astype(np.int64)
        r0 = np.clip(np.ceil(r_lo - _MARGIN), 0, h).astype(np.int64)
        r1 = np.clip(np.floor(r_hi + _MARGIN), -1, h - 1).astype(np.int64)
    nr = np.where(keep & (c1 >= c0), np.maximum(r1 - r0 + 1, 0), 0)
    return c0, c1, r0, nr


def _row_spans(camera, vc, z_near, boxes, wanted=None):
    """Candidate pixels as runs on rows: triangle, row, first column and length of each run.

    One run per row of each triangle's box (``boxes``, :func:`_pixel_boxes`); its columns are the exact span
    of the projected triangle on that row (the box's for triangles that cross the camera plane), so few
    candidates miss. With ``wanted`` (:func:`_wanted_ends`), a run first goes from the first to the last wanted
    pixel of its row of the box, and a row of the box without one has no run.
    """
    c0, c1, r0, nr = boxes
    tris = np.flatnonzero(nr > 0)
    run, place = runs(nr[tris])
    pt = np.take(tris, run)
    prow = np.take(r0[tris], run) + place
    if wanted is None:
        lo, hi = c0[pt].astype(np.float64), c1[pt].astype(np.float64)
    else:
        first, last = wanted
        w = camera.width
        at = prow * w
        a, b = first[at + c0[pt]], last[at + c1[pt]]
        keep = a <= b  # both on the row, as the box's ends are
        pt, prow, a, b = pt[keep], prow[keep], a[keep] - at[keep], b[keep] - at[keep]
        lo, hi = a.astype(np.float64), b.astype(np.float64)
    # A run of one column is left to the exact test: finding its span would cost as much.
    z = vc[:, :, 2]
    in_front = np.minimum(np.minimum(z[:, 0], z[:, 1]), z[:, 2]) >= z_near  # per triangle, then per run
    front = (hi > lo) & in_front[pt]
    if front.any():
        f = np.flatnonzero(front)
        px, py = _projected(camera, vc)  # per triangle, then per run: a triangle has a run per row
        at = pt[f]
        x_lo, x_hi = _row_extent([c[at] for c in px], [c[at] for c in py], prow[f].astype(np.float64))
        empty = ~np.isfinite(x_lo)
        lo[f] = np.where(empty, 1.0, np.maximum(lo[f], np.ceil(x_lo - _MARGIN)))
        hi[f] = np.where(empty, 0.0, np.minimum(hi[f], np.floor(x_hi + _MARGIN)))
    plen = np.maximum(hi - lo + 1, 0).astype(np.int64)
    keep = plen > 0
    return pt[keep], prow[keep], lo[keep].astype(np.int64), plen[keep]


def _projected(camera, v):
    """The pixel ``x`` and ``y`` of each corner of camera-space triangles ``v`` (T, 3, 3), as three (T,) arrays
    each (corner by corner); not finite at corners on or behind the camera plane."""
    fx, skew, cx, fy, cy = _intrinsics(camera)
    with np.errstate(divide="ignore", invalid="ignore"):
        py = [fy * v[:, k, 1] / v[:, k, 2] + cy for k in range(3)]
        px = [fx * v[:, k, 0] / v[:, k, 2] + skew * v[:, k, 1] / v[:, k, 2] + cx for k in range(3)]
    return px, py


def _row_extent(px, py, y):
    """Leftmost and rightmost x where row ``y`` meets each projected triangle (in front of the camera), whose
    corners are at ``px``, ``py`` (:func:`_projected`, one array per corner).

    NaN where the row misses the triangle.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        xs = []
        for i, j in ((0, 1), (1, 2), (2, 0)):
            y_lo, y_hi = np.minimum(py[i], py[j]), np.maximum(py[i], py[j])
            on = (y >= y_lo - _MARGIN) & (y <= y_hi + _MARGIN)
            dy_e = py[j] - py[i]
            s_e = np.clip(np.where(dy_e != 0, (y - py[i]) / dy_e, 0.0), 0.0, 1.0)
            x_e = px[i] + s_e * (px[j] - px[i])
            xs.append(np.where(on, x_e, np.nan))
            # A horizontal edge on the row contributes both ends.
            flat = on & (dy_e == 0)
            xs.append(np.where(flat, px[j], np.nan))
    return nan_min_max(xs)


def _tile_max(a, k):
    """The largest value of each k x k tile of ``a`` (H, W), tiles at the far edges padded with inf."""
    h, w = a.shape
    th, tw = -(-h // k), -(-w // k)
    padded = np.full((th * k, tw * k), np.inf)
    padded[:h, :w] = a
    # Slice by slice, not .max(axis=...) over a reshaped view: several times faster on short tiles.
    rows = padded.reshape(th, k, tw * k)
    out = rows[:, 0].copy()
    for i in range(1, k):
        np.maximum(out, rows[:, i], out=out)
    cols = out.reshape(th, tw, k)
    out = cols[:, :, 0].copy()
    for i in range(1, k):
        np.maximum(out, cols[:, :, i], out=out)
    return out


def _nearest_hits(camera, n_corner, vol, ids, z_near, spans, batch, depth, best, bary):
    """Test the candidates of ``spans`` exactly, about ``batch`` at a time, keeping the nearest hit per pixel.

    ``n_corner`` and ``vol``: the triangles' :func:`_edge_planes`; ``ids`` their indices, which ``best`` takes.
    ``depth``, ``best`` (flat per pixel) and ``bary`` (3, pixels) are the outputs, updated in place.
    """
    pt, prow, plo, plen = spans
    cum = np.cumsum(plen)
    start = 0
    while start < pt.size:
        base = cum[start - 1] if start else 0
        stop = max(int(np.searchsorted(cum, base + batch, side="right")), start + 1)
        sl = slice(start, stop)
        start = stop
        run, place = runs(plen[sl])  # each candidate's run: its row and triangle, where it hits
        c = np.take(plo[sl], run) + place
        wts, s, hit = _edge_test(camera, n_corner[pt[sl]], run, prow[sl], c)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.take(vol[pt[sl]], run) / s
        hit &= t > z_near
        if not hit.any():
            continue
        # np.take and 1-D targets: the same elements, about twice as fast as fancy indexing here.
        sel = np.flatnonzero(hit)
        at = np.take(run, sel)
        pix = np.take(prow[sl], at) * camera.width + np.take(c, sel)
        t = np.take(t, sel)
        np.minimum.at(depth, pix, t)
        win = np.flatnonzero(t <= np.take(depth, pix))
        sel, at, pix = np.take(sel, win), np.take(at, win), np.take(pix, win)
        best[pix] = np.take(ids[pt[sl]], at)
        s = np.take(s, sel)
        for k in range(3):
            bary[k][pix] = np.take(wts[k], sel) / s


def _cross_into(a, b, out):
    """``out[:] = np.cross(a, b)`` for (n, 3) arrays, the same products and differences without its temporaries."""
    for k, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):
        np.multiply(a[:, i], b[:, j], out=out[:, k])
        out[:, k] -= a[:, j] * b[:, i]


def _edge_test(camera, n_corner, run, row, c):
    """Signed-volume test of the rays through pixel centres against their triangles, run by run.

    ``n_corner`` (k, 3, 3) holds each run's triangle's edge-plane normals and ``row`` (k,) its row; ``run``
    (n,) is each candidate's run (:func:`core.geometry.runs.runs`) and ``c`` (n,) its column. Returns the
    unnormalised barycentric weights (3, n), their sum, and whether the ray passes inside the triangle.
    """
    fx, skew, cx, fy, cy = _intrinsics(camera)
    # Normalised ray directions d = (dx, dy, 1) through the pixel centres. dy, and each plane's term in it, is
    # one number per run: worked out per run, then repeated (the same values as per candidate).
    dy = (row - cy) / fy
    dx = c - cx
    if skew:
        dx -= skew * np.take(dy, run)
    dx /= fx
    # 1-D per-component arrays, read per candidate from per-run columns: far faster than fancy-indexing an
    # (n, 3, 3) array.
    wts = np.empty((3, c.size))
    for k in range(3):
        nk = n_corner[:, k]
        np.multiply(np.take(nk[:, 0], run), dx, out=wts[k])
        wts[k] += np.take(nk[:, 1] * dy, run)
        wts[k] += np.take(nk[:, 2], run)
    s = wts[0] + wts[1]  # the order of wts.sum(axis=0)
    s += wts[2]
    sign = np.sign(s)
    tol = _EDGE_EPS * np.abs(s)
    hit = s != 0
    for k in range(3):
        hit &= wts[k] * sign >= -tol
    return wts, s, hit
