"""Occlusion-aware SH transfer: how much of each lighting coefficient reaches a surface point.

The paper shades a point with normal n as ``sigma . nu(n)`` (:mod:`core.geometry.sh`),
which is exact for a convex object: every direction of the hemisphere around n
sees the sky. In a concavity (under the chin, in the eye sockets, where the
object meets its base) part of the hemisphere is blocked and the true shading is
lower. Precomputed radiance transfer replaces ``nu(n)`` by

``T_k(x) = (1 / A_l) * integral V(x, w) max(0, n . w) nu_k(w) dw``

where V is 1 when the ray from x in direction w escapes the object, and
``A_l`` (pi, 2 pi / 3, pi / 4 for the bands l = 0, 1, 2) is the cosine lobe's
SH coefficient, so that an unoccluded point has ``T(x) = nu(n)`` exactly
(Funk-Hecke). We compute it as ``nu(n)`` minus the blocked directions' share,
so the open surface keeps the paper's model to the digit and only the blocked
part carries quadrature error.

Visibility is cast by our own ray caster (:func:`core.geometry.raycast.raycast`):
for each of K directions spread evenly over the sphere, one depth map of the
mesh seen along the direction (a shadow map, rays parallel up to 1e-4), and a
point, lifted by a map pixel along its normal, is blocked in that direction when
the map sees geometry in front of it. The transfer is computed on a coarse texel
grid of points (surface position and normal averaged from the views' bakes) and
interpolated bilinearly in UV to each pixel, as a correction ``T - nu`` added to
the pixel's own ``nu(n)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..masks import masked
from ..parallel import thread_map
from .camera import Camera
from .raycast import Triangles, raycast
from .sh import sh_basis, sh_degree, sphere_directions
from .texels import bilinear_texels, texel_index, texel_of_uv

__all__ = [
    "A_BAND",
    "sphere_directions",
    "open_factor",
    "visibility",
    "ShadowMap",
    "occlusion_transfer",
    "OcclusionGrid",
    "occlusion_grid",
    "pixel_transfer",
    "shading_rows",
    "transfer_rows",
]

#: The clamped cosine's SH coefficients per band l = 0..4 (Ramamoorthi and Hanrahan 2001): odd bands above 1
#: vanish, so an open point sees nothing of band 3, and band 4 at -1/6 of its band-2 weight.
A_BAND = np.array([np.pi, 2 * np.pi / 3, np.pi / 4, 0.0, -np.pi / 24])
# Bands above 2 are scaled like band 2 (their A_l is 0 or small).
_NORM_BAND = np.array([np.pi, 2 * np.pi / 3, np.pi / 4, np.pi / 4, np.pi / 4])


def open_factor(k: int) -> np.ndarray:
    """Per coefficient, the transfer of an unoccluded point over its ``sh_basis`` value (1 up to band 2)."""
    b = sh_degree(k)
    return A_BAND[b] / _NORM_BAND[b]


# Below this share of a shadow map's pixels read (points, which may share pixels), only those are cast.
_CAST_READ_SHARE = 0.25


def _shadow_camera(direction, centre, radius, resolution):
    """A distant pinhole camera looking along ``-direction`` at the bounding sphere, nearly orthographic."""
    w = np.asarray(direction, np.float64)
    w = w / np.linalg.norm(w)
    helper = np.array([0.0, 0.0, 1.0]) if abs(w[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, w)
    x /= np.linalg.norm(x)
    y = np.cross(-w, x)
    R = np.stack([x, y, -w])  # rows: camera axes in world coordinates; z looks along -w
    dist = 1e4 * radius
    C = centre + dist * w
    f = 0.5 * resolution * dist / (radius * 1.02)
    c = 0.5 * (resolution - 1)
    K = np.array([[f, 0, c], [0, f, c], [0, 0, 1.0]])
    return Camera(K=K, R=R, t=-R @ C, width=resolution, height=resolution), 2.04 * radius / resolution


def _occluders(tri_pos):
    """The mesh as the ray caster takes it: :class:`Triangles` as they are, corners ``(T, 3, 3)`` as float64."""
    return tri_pos if isinstance(tri_pos, Triangles) else np.asarray(tri_pos, np.float64)


def _bounding_sphere(tri_pos):
    corners = tri_pos.vertices if isinstance(tri_pos, Triangles) else tri_pos.reshape(-1, 3)
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    centre = 0.5 * (lo + hi)
    return centre, float(np.linalg.norm(corners - centre, axis=1).max()) or 1.0


class ShadowMap:
    """One depth map of the mesh seen along a direction, to tell which points see out along it.

    Parameters
    ----------
    direction : (3,) array
        Towards the light.
    tri_pos : (T, 3, 3) array or core.geometry.raycast.Triangles
        The mesh's triangles (world space): the occluders.
    resolution : int
        Side of the depth map.
    lift, bias : float
        In map pixels: how far each point is moved along its normal before
        the test, and the depth tolerance, so that a point never shadows
        itself. Occluders nearer than about ``lift`` are missed.
    sphere : (centre, radius), optional
        The mesh's bounding sphere, if already known.
    only : (points, normals), optional
        The only points the map will be asked about (:meth:`open`): where they read a small share of its
        pixels, only those pixels are cast, and any other point reads as open.
    """

    def __init__(
        self, direction, tri_pos, resolution: int = 512, lift: float = 1.0, bias: float = 0.5, sphere=None, only=None
    ):
        tri_pos = _occluders(tri_pos)
        centre, radius = _bounding_sphere(tri_pos) if sphere is None else sphere
        self.direction = np.asarray(direction, np.float64) / np.linalg.norm(direction)
        self.camera, self.pixel = _shadow_camera(self.direction, centre, radius, resolution)
        self.resolution, self.lift, self.bias = resolution, lift, bias
        pixels = None
        self._only = None if only is None else self._lookup(*only)  # kept for open_only
        if only is not None:
            read = self._only[0]
            if read.size < _CAST_READ_SHARE * resolution * resolution:
                pixels = np.zeros(resolution * resolution, bool)
                pixels[read] = True
        self.depth = raycast(self.camera, tri_pos, pixels=pixels).depth.ravel()

    def _lookup(self, points, normals):
        """The map pixel (flat) and depth of each point, lifted along its unit normal."""
        # Lifted off the surface along its normal by `lift` map pixels, a point is in front of its own
        # surface by lift / cos(angle) at its map pixel, more than the surface's depth varies across
        # half a pixel (tan(angle) / 2): no self-shadowing at any angle, with a constant depth bias.
        pts = np.asarray(points, np.float64) + (self.lift * self.pixel) * np.asarray(normals, np.float64)
        x, y, z = self.camera.pixel_coordinates(pts)
        n = self.resolution
        col = np.clip(np.rint(x).astype(np.intp), 0, n - 1)
        row = np.clip(np.rint(y).astype(np.intp), 0, n - 1)
        row *= n
        row += col
        return row, z

    def open(self, points, normals) -> np.ndarray:
        """``(P,)`` bool: the points (lifted along their unit normals) that the map sees no geometry in front of."""
        return self._open_at(*self._lookup(points, normals))

    def open_only(self) -> np.ndarray:
        """:meth:`open` of the ``only`` points the map was made for, from the lookup it made of them then."""
        if self._only is None:
            raise ValueError("ShadowMap.open_only: the map was made without only=(points, normals)")
        return self._open_at(*self._only)

    def _open_at(self, read, z):
        return self.depth[read] >= z - self.bias * self.pixel


def visibility(
    points, normals, tri_pos, directions, resolution: int = 512, lift: float = 1.0, bias: float = 0.5, threads=None
):
    """Whether each point sees out of the mesh in each direction, ``(P, K)`` bool.

    Parameters
    ----------
    points, normals : (P, 3) arrays
        Surface points and their unit normals (world space).
    tri_pos : (T, 3, 3) array or core.geometry.raycast.Triangles
        The mesh's triangles (world space): the occluders (as shared vertices, each cast the fastest).
    directions : (K, 3) array
        Unit directions from the points towards the light.
    resolution, lift, bias : int, float, float
        Of each direction's :class:`ShadowMap`.
    threads : int or None
        Directions cast at once (None: every available core).

    Returns
    -------
    (P, K) bool array
        True where the direction is open. Directions below the point's
        horizon are reported as the map sees them; callers weight by the
        clamped cosine.
    """
    tri_pos = _occluders(tri_pos)
    pts = np.asarray(points, np.float64)
    nrm = np.asarray(normals, np.float64)
    sphere = _bounding_sphere(tri_pos)

    def open_towards(w):
        return ShadowMap(w, tri_pos, resolution, lift, bias, sphere, only=(pts, nrm)).open_only()

    out = np.ones((pts.shape[0], len(directions)), dtype=bool)
    for k, col in enumerate(thread_map(open_towards, np.asarray(directions, np.float64), threads)):
        out[:, k] = col
    return out


def occlusion_transfer(
    points,
    normals,
    tri_pos,
    n_directions: int = 64,
    resolution: int = 256,
    bounce: float = 0.0,
    order: int = 2,
    threads=None,
):
    """``T(x) - nu(n)`` at each point: the blocked directions' share of the transfer, ``(P, 9)`` float32.

    Zero for a point that sees the whole hemisphere around its normal; see
    the module docstring for T. ``bounce`` approximates one bounce of
    interreflection: the blocked directions are not black but show the
    surface around, taken as a uniform radiance ``bounce`` times the sky's
    mean (an albedo times a shading of about the sky's), which gives back
    that fraction of the blocked constant term. ``order`` 3 or 4 gives
    ``(order + 1)^2`` coefficients (:func:`core.geometry.sh.sh_basis`); bands
    above 2 are scaled as band 2 is. ``threads``: as :func:`visibility`.
    """
    dirs = sphere_directions(n_directions)
    nrm = np.asarray(normals, np.float64)
    vis = visibility(points, nrm, tri_pos, dirs, resolution, threads=threads)
    cos = np.maximum(nrm @ dirs.T, 0.0)  # (P, K)
    blocked = cos * (~vis)
    basis = sh_basis(dirs, np.float64, order)  # (K, (order + 1)^2)
    occ = -(blocked @ basis) * (4 * np.pi / n_directions) / _NORM_BAND[sh_degree(basis.shape[1])]
    occ[:, 3] *= 1.0 - bounce
    return occ.astype(np.float32)


@dataclass
class OcclusionGrid:
    """The occlusion ``T - nu`` on a UV grid (:func:`occlusion_grid`), to be sampled at any pixel's UV."""

    occ: np.ndarray  # (grid * grid, K) float32, zero in cells no pixel landed in
    valid: np.ndarray  # (grid, grid) bool, the cells some pixel landed in

    def transfer(self, uv, normal) -> np.ndarray:
        """The transfer at points of UV ``(P, 2)`` and unit normal ``(P, 3)``: ``nu(n)`` plus the occlusion."""
        k = self.occ.shape[1]
        idx, wts = bilinear_texels(uv, self.valid)
        return sh_basis(normal, order=round(k**0.5) - 1) * open_factor(k).astype(np.float32) + np.einsum(
            "kj,kjc->kc", wts, self.occ[idx]
        )

    def shading(self, uv, normal, sigma) -> np.ndarray:
        """``transfer(uv, normal) @ sigma.T``, ``(P, C)`` float32, for a lighting ``sigma`` ``(C, K)``.

        The lighting goes into the cells first, so each point interpolates C numbers rather than K: the
        occlusion's shading times the cells' validity, and the validity, on a grid with a ring of empty cells
        around it, looked up bilinearly; their ratio is :meth:`transfer`'s lookup over the valid cells only,
        without its (P, 4) index and weight arrays.
        """
        k = self.occ.shape[1]
        sigma = np.asarray(sigma, np.float32)
        c, n = sigma.shape[0], self.valid.shape[0]
        m = n + 2
        grid = np.zeros((c + 1, m, m), np.float32)  # plane by plane: each lookup is over whole arrays
        grid[:c, 1:-1, 1:-1] = ((self.occ @ sigma.T) * self.valid.reshape(-1, 1)).T.reshape(c, n, n)
        grid[c, 1:-1, 1:-1] = self.valid
        grid = grid.reshape(c + 1, m * m)
        row, col = texel_of_uv(uv, n)
        # Beyond the ring, a point takes the ring's (empty) cells.
        x, y = np.clip(col + 1, 0, m - 1), np.clip(row + 1, 0, m - 1)
        x0, y0 = np.minimum(x.astype(np.intp), m - 2), np.minimum(y.astype(np.intp), m - 2)
        fx, fy = (x - x0).astype(np.float32), (y - y0).astype(np.float32)
        gx, gy = 1 - fx, 1 - fy
        at = y0 * m + x0
        right, down, across = at + 1, at + m, at + m + 1  # the other three corners, for every plane
        v = np.empty((c + 1, at.size), np.float32)
        for j, plane in enumerate(grid):  # (a (1 - fx) + b fx) (1 - fy) + (c (1 - fx) + d fx) fy
            top = np.take(plane, at) * gx
            top += np.take(plane, right) * fx
            below = np.take(plane, down) * gx
            below += np.take(plane, across) * fx
            top *= gy
            top += np.multiply(below, fy, out=below)
            v[j] = top
        s = sh_basis(normal, order=round(k**0.5) - 1, planes=True) @ (sigma * open_factor(k).astype(np.float32)).T
        valid = v[c] > 0
        for j in range(c):
            s[:, j] += np.divide(v[j], v[c], out=np.zeros(at.size, np.float32), where=valid)
        return s


def occlusion_grid(
    tri_pos,
    views_uv,
    views_mask,
    views_normal,
    views_position,
    views_weight=None,
    grid: int = 128,
    n_directions: int = 64,
    resolution: int = 256,
    bounce: float = 0.0,
    order: int = 2,
    threads=None,
) -> OcclusionGrid:
    """The occlusion (:func:`occlusion_transfer`) once per cell of a ``grid x grid`` UV grid.

    Each cell that some pixel lands in is computed at the mean position and
    normal of those pixels. The arguments are :func:`pixel_transfer`'s.
    """
    n_cells = grid * grid
    acc = np.zeros((n_cells, 7))
    for i, (uv, mask, nrm, pos) in enumerate(zip(views_uv, views_mask, views_normal, views_position)):
        cell = texel_index(masked(uv, mask), grid)
        w = np.ones(cell.size) if views_weight is None else views_weight[i][mask].astype(np.float64) + 1e-3
        ok = cell >= 0
        vals = np.concatenate(
            [
                w[:, None],
                w[:, None] * masked(pos, mask).astype(np.float64),
                w[:, None] * masked(nrm, mask).astype(np.float64),
            ],
            axis=1,
        )[ok]
        for j in range(7):
            acc[:, j] += np.bincount(cell[ok], weights=vals[:, j], minlength=n_cells)
    used = acc[:, 0] > 0
    p = acc[used, 1:4] / acc[used, :1]
    n = acc[used, 4:7]
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    occ = np.zeros((n_cells, (order + 1) ** 2), np.float32)
    occ[used] = occlusion_transfer(p, n, tri_pos, n_directions, resolution, bounce, order, threads)
    return OcclusionGrid(occ=occ, valid=used.reshape(grid, grid))


def pixel_transfer(
    tri_pos,
    views_uv,
    views_mask,
    views_normal,
    views_position,
    views_weight=None,
    grid: int = 128,
    n_directions: int = 64,
    resolution: int = 256,
    bounce: float = 0.0,
    order: int = 2,
    threads=None,
):
    """Per view, the transfer of every masked pixel: ``nu(n)`` plus the occlusion interpolated in UV.

    The occlusion (:func:`occlusion_transfer`) is computed once per cell of a
    ``grid x grid`` UV grid that some pixel lands in, at the mean position
    and normal of those pixels (:func:`occlusion_grid`), and sampled
    bilinearly at each pixel's UV (:meth:`OcclusionGrid.transfer`).

    Parameters
    ----------
    tri_pos : (T, 3, 3) array or core.geometry.raycast.Triangles
    views_uv, views_mask, views_normal, views_position : lists, one (H, W, ...) array per view
        The bake's UV, mask, unit normal and world position.
    views_weight : list of (H, W) arrays, optional
        Weights of the pixels in the cell means (the bake's view weight).
    grid, n_directions, resolution : int
        UV grid size, directions, depth map side.
    bounce, order, threads : float, int, int or None
        See :func:`occlusion_transfer`.

    Returns
    -------
    list of (P_i, (order + 1)^2) float32 arrays
        Per view, one row per masked pixel (in the order ``image[mask]`` gives them), as
        :class:`core.solve.problem.Problem` takes them.
    """
    cells = occlusion_grid(
        tri_pos,
        views_uv,
        views_mask,
        views_normal,
        views_position,
        views_weight,
        grid,
        n_directions,
        resolution,
        bounce,
        order,
        threads,
    )
    return [
        cells.transfer(masked(uv, mask), masked(nrm, mask)) for uv, mask, nrm in zip(views_uv, views_mask, views_normal)
    ]


def shading_rows(sigma, normal, uv=None, cells=None, sun=None, position=None) -> np.ndarray:
    """``transfer_rows(normal, uv, cells, sun, position) @ sigma.T``: the shading ``(P, C)`` float32 of a lighting
    ``sigma`` ``(C, K)``, without the ``(P, K)`` transfer (:meth:`OcclusionGrid.shading`)."""
    sigma = np.asarray(sigma, np.float32)
    k = sigma.shape[1] - (sun is not None)
    s = cells.shading(uv, normal, sigma[:, :k]) if cells is not None else sh_basis(normal, planes=True) @ sigma[:, :k].T
    if sun is not None:
        s += sun.term(position, normal)[:, None] * sigma[:, k]
    return s


def transfer_rows(normal, uv=None, cells=None, sun=None, position=None, out=None) -> np.ndarray:
    """The transfer of pixels, ``(P, K)`` float32: what the lighting's coefficients multiply.

    ``nu(n)`` of the unit normals (the paper's model), or with ``cells`` (an :class:`OcclusionGrid`) its
    occlusion sampled at the UVs; with ``sun`` (a :class:`core.geometry.sun.SunLight`) one more column last,
    the sun's term at the world ``position``. Written into ``out`` if given (a row block of the problem's
    transfer, :func:`core.solve.problem.row_blocks`).
    """
    t = cells.transfer(uv, normal) if cells is not None else sh_basis(normal)
    k = t.shape[1]
    if out is None:
        out = np.empty((t.shape[0], k + (sun is not None)), np.float32)
    out[:, :k] = t
    if sun is not None:
        out[:, k] = sun.term(position, normal)
    return out
