"""Pixels of different views that see the same surface point (image-domain consistency).

Each view's baked hit positions are reprojected into its nearest other views.
A pair (pixel p of view a, sub-pixel position q in view b) is kept only if the
point is really visible at q in view b:

* the 4 pixels around q (bilinear support) all lie in b's mask, so the pair
  never straddles b's silhouette;
* the point's depth in b agrees, within a relative tolerance, with b's own
  depth at q (bilinear), so occluded points are rejected;
* the normals of the two views agree there, and the surface faces camera b.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..masks import masked
from .bilinear import clamped_corners, interpolate

__all__ = ["Correspondences", "find_correspondences", "neighbour_views"]


def _fail(msg):
    raise ValueError(msg)


@dataclass
class Correspondences:
    """Pairs of pixels in two views that see the same surface point.

    Pair k links pixel ``pixel_a[k]`` (a flat index ``row * W + col``) of view
    ``view_a[k]`` with the continuous position ``xy_b[k]`` in view
    ``view_b[k]``. Integer positions give exact pixel pairs; fractional ones
    are sub-pixel and are interpolated bilinearly from the masked pixels.

    Parameters
    ----------
    view_a, pixel_a, view_b : (K,) int arrays
    xy_b : (K, 2) float array
        ``(x, y)`` in view ``view_b``'s continuous pixel coordinates.
    weight : (K,) float array, optional
        Non-negative per-pair weights (default 1).
    """

    view_a: np.ndarray
    pixel_a: np.ndarray
    view_b: np.ndarray
    xy_b: np.ndarray
    weight: np.ndarray | None = None

    def __post_init__(self):
        self.view_a = np.asarray(self.view_a, dtype=np.intp).ravel()
        self.pixel_a = np.asarray(self.pixel_a, dtype=np.intp).ravel()
        self.view_b = np.asarray(self.view_b, dtype=np.intp).ravel()
        self.xy_b = np.asarray(self.xy_b, dtype=np.float64).reshape(-1, 2)
        k = self.view_a.size
        if not (self.pixel_a.size == self.view_b.size == self.xy_b.shape[0] == k):
            _fail(
                f"correspondences: view_a, pixel_a, view_b and xy_b must have the same length "
                f"(got {k}, {self.pixel_a.size}, {self.view_b.size}, {self.xy_b.shape[0]})"
            )
        if self.weight is None:
            self.weight = np.ones(k, dtype=np.float64)
        else:
            self.weight = np.asarray(self.weight, dtype=np.float64).ravel()
            if self.weight.size != k:
                _fail(f"correspondences: {self.weight.size} weights for {k} pairs")
            if not np.all(np.isfinite(self.weight)) or np.any(self.weight < 0):
                _fail("correspondences: weights must be finite and non-negative")
        if not np.all(np.isfinite(self.xy_b)):
            _fail("correspondences: xy_b holds NaN or infinite coordinates")

    def __len__(self):
        return int(self.view_a.size)


def _view_dirs(cameras, positions, masks):
    """Unit directions from the centroid of each view's hits towards every camera."""
    centres = np.array([c.center for c in cameras])
    out = []
    for p, m in zip(positions, masks):
        pts = masked(p, m)
        g = pts.mean(axis=0) if len(pts) else np.zeros(3)
        d = centres - g
        out.append(d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-30))
    return out


def neighbour_views(cameras, positions, masks, neighbours):
    """For each view, the indices of the ``neighbours`` views closest in viewing direction.

    The direction of a view is taken from the centroid of what it sees
    towards its camera centre; closeness is the angle between directions.
    """
    m = len(cameras)
    dirs = _view_dirs(cameras, positions, masks)
    out = []
    for a in range(m):
        cos = dirs[a] @ dirs[a][a]
        cos[a] = -np.inf
        order = np.argsort(-cos, kind="stable")
        out.append([int(b) for b in order[: max(0, min(neighbours, m - 1))]])
    return out


def find_correspondences(
    cameras, positions, masks, normals, max_pairs=2_000_000, depth_tol=0.01, neighbours=4, seed=0, min_normal_cos=0.8
) -> Correspondences:
    """Pairs of pixels of different views that see the same surface point.

    Parameters
    ----------
    cameras : list of core.geometry.camera.Camera
    positions : list of (H, W, 3) arrays
        World hit point of every pixel (anything outside the mask).
    masks : list of (H, W) bool arrays
    normals : list of (H, W, 3) arrays
        Unit world normals inside the masks.
    max_pairs : int
        At most this many pairs; pixels are subsampled at random (seeded).
    depth_tol : float
        Relative depth agreement: ``|z - z_b| <= depth_tol * z``.
    neighbours : int
        Each pixel is paired with at most this many other views, those with
        the closest viewing directions.
    seed : int
    min_normal_cos : float
        The two views' normals at the pair must agree to this cosine.

    Returns
    -------
    Correspondences
        Pairs sorted by (view_a, pixel_a); ``xy_b`` sub-pixel, in view b's
        pixel coordinates (centre of pixel (r, c) at (c, r)).
    """
    m = len(cameras)
    if not (len(positions) == len(masks) == len(normals) == m):
        raise ValueError(
            f"find_correspondences: {m} cameras, {len(positions)} positions, {len(masks)} masks, {len(normals)} normals"
        )
    masks = [np.asarray(mk, dtype=bool) for mk in masks]
    empty = Correspondences(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros((0, 2)))
    if m < 2 or max_pairs <= 0 or neighbours <= 0:
        return empty
    rng = np.random.default_rng(seed)
    nbrs = neighbour_views(cameras, positions, masks, neighbours)
    candidates = sum(int(mk.sum()) * len(nb) for mk, nb in zip(masks, nbrs))
    # Subsample before testing so memory stays bounded, with a margin for the
    # pairs the tests reject (typically half); the surplus is trimmed at the end.
    keep_frac = min(1.0, 3.0 * max_pairs / max(candidates, 1))
    views = _flat_views(cameras, positions, masks, normals)
    out = []
    for a in range(m):
        pix = np.flatnonzero(views[a][2])
        if keep_frac < 1.0:
            pix = np.sort(rng.choice(pix, size=int(round(len(pix) * keep_frac)), replace=False))
        if pix.size == 0:
            continue
        p = np.asarray(positions[a], dtype=np.float64).reshape(-1, 3)[pix]
        n_a = views[a][1][pix]
        for b in nbrs[a]:
            sel, xy = _visible_in(cameras[b], views[b], p, n_a, depth_tol, min_normal_cos)
            if sel is not None:
                out.append(
                    (
                        np.full(sel.size, a, dtype=np.int32),
                        pix[sel].astype(np.int64),
                        np.full(sel.size, b, dtype=np.int32),
                        xy,
                    )
                )
    return _trimmed(out, max_pairs, rng) if out else empty


def _trimmed(parts, max_pairs, rng) -> Correspondences:
    """The ``(view_a, pixel_a, view_b, xy_b)`` parts joined, cut to ``max_pairs`` at random, and sorted."""
    va, pa, vb, xyb = (np.concatenate(p) for p in zip(*parts))
    if va.size > max_pairs:
        keep = np.sort(rng.choice(va.size, size=max_pairs, replace=False))
        va, pa, vb, xyb = va[keep], pa[keep], vb[keep], xyb[keep]
    order = np.lexsort((vb, pa, va))
    return Correspondences(view_a=va[order], pixel_a=pa[order], view_b=vb[order], xy_b=xyb[order])


def _flat_views(cameras, positions, masks, normals):
    """Per view: its depth map (camera-space z of its hits, NaN off the mask), normals and mask, flattened."""
    out = []
    for cam, pos, mk, nrm in zip(cameras, positions, masks, normals):
        pos = np.asarray(pos, dtype=np.float64).reshape(-1, 3)
        z = np.full(mk.size, np.nan)
        sel = mk.ravel()
        z[sel] = pos[sel] @ cam.R[2] + cam.t[2]
        out.append((z, np.asarray(nrm, dtype=np.float64).reshape(-1, 3), sel))
    return out


def _visible_in(cam, view, p, n_a, depth_tol, min_normal_cos):
    """Which points ``p`` (normals ``n_a``) view b sees, and where: ``(sel, xy)``, or ``(None, None)``.

    ``view`` is b's ``(depth, normals, mask)`` from :func:`_flat_views`; see
    the module docstring for the tests.
    """
    depth, flat_n, flat_m = view
    w, h = cam.width, cam.height
    xy, z = cam.project(p)
    ok = (z > 0) & (xy[:, 0] >= 0) & (xy[:, 1] >= 0) & (xy[:, 0] <= w - 1) & (xy[:, 1] <= h - 1)
    ok &= np.einsum("ij,ij->i", n_a, cam.center - p) > 0  # faces camera b
    if not ok.any():
        return None, None
    sel = np.flatnonzero(ok)
    idx, wts = clamped_corners(xy[sel, 0], xy[sel, 1], w, h)
    inside = flat_m[idx].all(axis=1)
    sel, idx, wts = sel[inside], idx[inside], wts[inside]
    zb = interpolate(depth, idx, wts)
    vis = np.abs(z[sel] - zb) <= depth_tol * z[sel]
    nb = interpolate(flat_n, idx, wts)
    nb /= np.maximum(np.linalg.norm(nb, axis=1, keepdims=True), 1e-30)
    vis &= np.einsum("ij,ij->i", nb, n_a[sel]) >= min_normal_cos
    sel = sel[vis]
    return sel, xy[sel]
