"""Where the sun is: the direction whose cast shadows and terminator match the photos' brightness changes.

Second-order SH shading (with or without occlusion, :mod:`core.geometry.transfer`)
cannot draw the sharp shadow of a small sun, so under a sun the shadows stay in
the albedo. A sun term ``s * V(x, w) max(0, n . w)`` (V: does x see the sun
along w) can, once its direction w is known. This module finds w from the
photos and the mesh alone.

Across a shadow's edge the photo's brightness changes by the sun's share of
the light, wherever the albedo is; across a change of albedo it changes
whatever the lighting. So over pairs of neighbouring pixels of every photo,
the change of log brightness correlates with the change of the sun term
``f_w = V(x, w) max(0, n . w)`` for the true w and for no other: for each of
``n_directions`` candidate directions spread over the sphere we cast one
shadow map (:func:`core.geometry.transfer.visibility`) and score

``score(w) = sum_pairs d(log I) * d(f_w) / |d(f_w)|``,

the changes of log brightness clipped to +-1 so that albedo edges weigh no
more than a hard shadow. The best candidate is then refined on finer sets
of directions around it: the score peaks sharply at hard shadows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .transfer import ShadowMap, sphere_directions, visibility

__all__ = ["SunSearch", "SunNotFound", "find_sun", "SunLight", "SUN_MAP_RESOLUTION"]

#: Side of the shadow map of the sun term: fine enough that its shadows' edges fall within a pixel or two of the
#: working resolution's photos.
SUN_MAP_RESOLUTION = 1024


class SunNotFound(ValueError):
    """The photos hold too little to search for a sun (no two neighbouring pixels on the mesh)."""


@dataclass
class SunSearch:
    """The result of :func:`find_sun`."""

    direction: np.ndarray  # (3,) unit vector towards the sun, world space
    score: float  # the correlation of the best direction, in [-1, 1]
    directions: np.ndarray  # (K, 3) every candidate scored, coarse then refined
    scores: np.ndarray  # (K,) their correlations


def _pairs(photos, masks, positions, normals, step, max_pairs=0):
    """Neighbouring masked pixels (right and down) on every ``step``-th row and column of each photo; with
    ``max_pairs``, every k-th of them in that order, no more than that many.

    Returns the points and normals of both ends, stacked (first ends, then second ends), and the change of
    log luminance from the first to the second, clipped to +-1. Only the pairs kept are read from the photos.
    """
    found = []  # per photo and direction: the first ends' rows and columns, and the step to the second
    for mask in masks:
        h, w = mask.shape
        r, c = (a.ravel() for a in np.mgrid[0 : h - 1 : step, 0 : w - 1 : step])
        for dr, dc in ((0, 1), (1, 0)):
            ok = mask[r, c] & mask[r + dr, c + dc]
            found.append((r[ok], c[ok], dr, dc))
    n = sum(r0.size for r0, _, _, _ in found)
    stride = -(-n // max_pairs) if max_pairs and n > max_pairs else 1
    ends, dlog = [[], [], [], []], []

    def log_lum(photo, r, c):  # at the pairs' ends only, not over the whole photo
        lum = np.asarray(photo[r, c], np.float64)[:, :3].mean(axis=-1)
        return np.log(np.maximum(lum, 1e-3))

    first = 0  # the index, over all pairs, of this block's first
    for k, (r0, c0, dr, dc) in enumerate(found):
        v = k // 2
        if stride > 1:  # the global every stride-th pair, from 0
            at = np.arange(-first % stride, r0.size, stride)
            first += r0.size
            r0, c0 = r0[at], c0[at]
        r1, c1 = r0 + dr, c0 + dc
        pos, nrm = positions[v], normals[v]
        for j, a in enumerate((pos[r0, c0], nrm[r0, c0], pos[r1, c1], nrm[r1, c1])):
            ends[j].append(a)
        dlog.append(log_lum(photos[v], r1, c1) - log_lum(photos[v], r0, c0))
    p0, n0, p1, n1 = (np.concatenate(e).astype(np.float64) for e in ends)
    return np.concatenate([p0, p1]), np.concatenate([n0, n1]), np.clip(np.concatenate(dlog), -1.0, 1.0)


def _correlations(points, normals, dlog, tri_pos, directions, resolution, threads):
    n = dlog.size
    vis = visibility(points, normals, tri_pos, directions, resolution, threads=threads)
    f = vis * np.maximum(normals @ directions.T, 0.0)
    df = f[n:] - f[:n]
    norm = np.sqrt((df * df).sum(axis=0)) * max(float(np.sqrt(dlog @ dlog)), 1e-12)
    return np.where(norm > 0, (dlog @ df) / np.maximum(norm, 1e-300), 0.0)


def _cone(axis, half_angle, k):
    """``k`` directions spread evenly over the cap of ``half_angle`` radians around ``axis``."""
    local = sphere_directions(k, np.cos(half_angle))
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    helper = np.array([0.0, 0.0, 1.0]) if abs(a[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, a)
    x /= np.linalg.norm(x)
    y = np.cross(a, x)
    return local @ np.stack([x, y, a])


def find_sun(
    photos,
    masks,
    positions,
    normals,
    tri_pos,
    n_directions: int = 400,
    n_refine: int = 30,
    rounds: int = 3,
    step: int = 3,
    max_pairs: int = 0,
    resolution: int = 256,
    threads=None,
) -> SunSearch:
    """The direction towards the sun that best explains the photos' brightness changes (module docstring).

    Parameters
    ----------
    photos : list of (H, W, C) arrays
        Linear photos (C >= 1; the mean of the first three channels is used).
    masks, positions, normals : lists of (H, W), (H, W, 3), (H, W, 3) arrays
        Per photo, the pixels on the mesh and their world position and unit normal (the bake's).
    tri_pos : (T, 3, 3) array or core.geometry.raycast.Triangles
        The mesh's triangles, world space: the shadow casters.
    n_directions : int
        Candidates spread over the whole sphere (no "up" is assumed).
    n_refine, rounds : int
        Refinement: ``rounds`` times, ``n_refine`` candidates in a cap of 1.5 spacings around the best so far,
        cast at twice the resolution (each round's candidates about half as far apart; 0: none).
    step : int
        Pairs are taken on every ``step``-th row and column.
    max_pairs : int
        At most this many pairs (every k-th), 0: all.
    resolution : int
        Side of each coarse shadow map.
    threads : int or None
        As :func:`core.geometry.transfer.visibility`.
    """
    # Every k-th pair at most max_pairs: the cost is pairs x directions.
    points, nrm, dlog = _pairs(photos, masks, positions, normals, step, max_pairs)
    if dlog.size == 0:
        raise SunNotFound("sun search: no two neighbouring pixels on the mesh in any photo")
    dirs = sphere_directions(n_directions)
    scores = _correlations(points, nrm, dlog, tri_pos, dirs, resolution, threads)
    spacing = np.sqrt(4 * np.pi / n_directions)
    for _ in range(rounds if n_refine > 0 else 0):
        # A cap of 1.5 spacings around the best so far, its candidates about half as far apart.
        fine = _cone(dirs[np.argmax(scores)], 1.5 * spacing, n_refine)
        fine_scores = _correlations(points, nrm, dlog, tri_pos, fine, 2 * resolution, threads)
        dirs, scores = np.concatenate([dirs, fine]), np.concatenate([scores, fine_scores])
        spacing *= 1.5 * np.sqrt(np.pi / n_refine)
    best = int(np.argmax(scores))
    return SunSearch(direction=dirs[best], score=float(scores[best]), directions=dirs, scores=scores)


# Above this share of points facing the sun, all are looked up in its shadow map.
_LOOKUP_ALL = 0.8


class SunLight:
    """The sun term of the shading, ``V(x, w) max(0, n . w)``, for one direction ``w`` over one mesh.

    The shading is ``sigma . T(x)`` with this term as the last column of the
    transfer T (:class:`core.solve.problem.Problem`), so its coefficient is the
    sun's strength in the units of the shading.
    """

    def __init__(self, direction, tri_pos, resolution: int = SUN_MAP_RESOLUTION):
        self.shadow = ShadowMap(direction, tri_pos, resolution)
        self.direction = self.shadow.direction

    def term(self, points, normals) -> np.ndarray:
        """``(P,)`` float32 at surface points and their unit normals (world space)."""
        nrm = np.asarray(normals, np.float64)
        lit = np.maximum(nrm @ self.direction, 0.0)
        on = np.flatnonzero(lit > 0)
        if on.size > _LOOKUP_ALL * lit.size:  # nearly all: the copies would cost more than the lookups they save
            return (self.shadow.open(points, nrm) * lit).astype(np.float32)
        # Only the points that face the sun are looked up in its shadow map: the rest are 0 either way.
        out = np.zeros(lit.size, np.float32)
        out[on] = self.shadow.open(np.take(points, on, axis=0), np.take(nrm, on, axis=0)) * np.take(lit, on)
        return out
