"""Bake every view: per pixel, what the ray through it hits on the target mesh.

The rays are cast by :func:`core.geometry.raycast.raycast`, a vectorised NumPy caster
over the target's triangles only, so image planes and other objects never
occlude the mesh. It agrees with a Cycles render of the same camera (see
tests/bpy/test_scene_bake.py) and is faster than rendering Cycles passes or
calling ``BVHTree.ray_cast`` per pixel. Shading follows Cycles: the normal is
the interpolated corner normal, flipped when the ray hits a face's back side.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..errors import DelightError
from ..parallel import thread_map
from ..progress import check_cancel
from ..scene import MeshArrays
from .camera import Camera
from .raycast import at_hits, nan_min_max, raycast

__all__ = ["ViewBake", "PixelBake", "bake_pixels", "bake_view", "bake_views", "bake_rows", "row_bands", "mesh_normals"]


@dataclass
class ViewBake:
    """What one view sees of the target mesh, per pixel (row 0 at the top)."""

    mask: np.ndarray  # (H, W) bool, the ray hits the target mesh
    normal: np.ndarray  # (H, W, 3) float32 unit shading normal, world space (0 outside)
    uv: np.ndarray  # (H, W, 2) float32 active UV at the hit (0 outside)
    position: np.ndarray  # (H, W, 3) float32 world hit point (NaN outside)
    view_weight: np.ndarray  # (H, W) float32 cos(normal, direction to the camera) in [0, 1] (0 outside)


def _corner_normals(mesh):
    if mesh.tri_normal is not None:
        return np.asarray(mesh.tri_normal, dtype=np.float32)
    e1 = mesh.tri_pos[:, 1] - mesh.tri_pos[:, 0]
    e2 = mesh.tri_pos[:, 2] - mesh.tri_pos[:, 0]
    n = np.cross(e1, e2)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    return np.repeat(n[:, None, :], 3, axis=1).astype(np.float32)


def _face_normals(mesh, corner_normals):
    """Geometric face normals, oriented like the corner normals (winding-agnostic)."""
    e1 = mesh.tri_pos[:, 1] - mesh.tri_pos[:, 0]
    e2 = mesh.tri_pos[:, 2] - mesh.tri_pos[:, 0]
    ng = np.cross(e1, e2)
    side = np.einsum("ij,ij->i", ng, corner_normals.sum(axis=1))
    ng[side < 0] *= -1
    return ng


def mesh_normals(mesh):
    """The mesh's corner normals ``(T, 3, 3)`` and face normals ``(T, 3)``, as :func:`bake_view` takes them."""
    corner = _corner_normals(mesh)
    return corner, _face_normals(mesh, corner)


@dataclass
class PixelBake:
    """What one view sees of the target mesh, at the pixels whose ray hits it only (in row order).

    :class:`ViewBake`'s values without the pixels that miss, for a loop over the hits of a large photo.
    """

    shape: tuple  # (H, W) of the view
    pixel: np.ndarray  # (P,) intp flat index (row * W + column) of each pixel hit, increasing
    normal: np.ndarray  # (P, 3) float32
    uv: np.ndarray  # (P, 2) float32
    position: np.ndarray  # (P, 3) float32
    view_weight: np.ndarray  # (P,) float32

    def image(self) -> ViewBake:
        """The same as a :class:`ViewBake`: every pixel of the view."""
        h, w = self.shape
        mask = np.zeros(h * w, bool)
        mask[self.pixel] = True
        out = []
        for values, fill in ((self.normal, 0.0), (self.uv, 0.0), (self.position, np.nan), (self.view_weight, 0.0)):
            img = np.full((h * w, *values.shape[1:]), fill, np.float32)
            img[self.pixel] = values
            out.append(img.reshape(h, w, *values.shape[1:]))
        normal, uv, position, weight = out
        return ViewBake(mask=mask.reshape(h, w), normal=normal, uv=uv, position=position, view_weight=weight)


def bake_pixels(camera, mesh, corner_normals=None, face_normals=None) -> PixelBake:
    """Bake one :class:`core.geometry.camera.Camera` against :class:`scene.MeshArrays`, at the pixels hit."""
    if corner_normals is None:
        corner_normals = _corner_normals(mesh)
    if face_normals is None:
        face_normals = _face_normals(mesh, corner_normals)
    hits = raycast(camera, mesh.tri_pos)
    pixel = np.flatnonzero(hits.tri >= 0)
    tri = hits.tri.ravel()[pixel]
    b = [np.take(hits.bary[..., c].ravel(), pixel) for c in range(3)]  # contiguous planes: no copies
    del hits
    p = at_hits(b, mesh.tri_pos, tri)
    n = at_hits(b, corner_normals, tri)
    n /= np.maximum(np.sqrt(_dot(n, n)), 1e-30)[:, None]
    to_cam = camera.center - p
    to_cam /= np.maximum(np.sqrt(_dot(to_cam, to_cam)), 1e-30)[:, None]
    # Cycles flips the shading normal of a back-facing hit.
    back = _dot(np.take(face_normals, tri, axis=0), to_cam) < 0
    n *= np.where(back, -1.0, 1.0)[:, None]  # the same numbers as n[back] *= -1, twice as fast
    return PixelBake(
        shape=(camera.height, camera.width),
        pixel=pixel,
        normal=n.astype(np.float32),
        uv=at_hits(b, mesh.tri_uv, tri).astype(np.float32),
        position=p.astype(np.float32),
        view_weight=np.clip(_dot(n, to_cam), 0.0, 1.0).astype(np.float32),
    )


def _dot(a, b):
    """Row by row dot products of ``(P, 3)`` arrays, over whole columns: several times faster than
    ``einsum("ij,ij->i")``, which adds the three products in another order (a last-bit difference in about a
    quarter of the rows)."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def bake_view(camera, mesh, corner_normals=None, face_normals=None) -> ViewBake:
    """Bake one :class:`core.geometry.camera.Camera` against :class:`scene.MeshArrays`."""
    return bake_pixels(camera, mesh, corner_normals, face_normals).image()


def row_bands(camera, mesh, max_pixels: int = 2_000_000, corner_normals=None, face_normals=None, shared=None):
    """The bands of whole rows of about ``max_pixels`` pixels that :func:`bake_rows` bakes, each still to bake.

    ``shared``: the mesh as :class:`core.geometry.raycast.Triangles` (its corners as shared vertices), if made:
    each vertex is then projected once to tell which rows a triangle reaches, not once per corner.

    Yields
    ------
    first_row : int
    bake : callable() -> PixelBake
        The band's rows baked: :func:`bake_pixels` of the camera cropped to them, against the triangles whose
        projection reaches them (all triangles that cross the camera plane).
    """
    if corner_normals is None or face_normals is None:
        corner_normals, face_normals = mesh_normals(mesh)
    h, w = camera.height, camera.width
    rows = max(1, int(max_pixels) // w)
    if shared is None:
        vc = camera.to_camera(np.asarray(mesh.tri_pos, np.float64))  # as the ray caster transforms them
        corners = [np.s_[:, k] for k in range(3)]
    else:  # each vertex once; a corner's numbers are its vertex's
        vc = camera.to_camera(shared.vertices)
        corners = list(shared.corners)
    z = vc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        y = camera.K[1, 1] * vc[..., 1] / z + camera.K[1, 2]
    z_lo, z_hi = nan_min_max([z[at] for at in corners])
    front = z_lo > 0
    y_lo, y_hi = nan_min_max([y[at] for at in corners])
    y_lo, y_hi = np.where(front, y_lo, -np.inf), np.where(front, y_hi, np.inf)
    behind = z_hi <= 0  # no ray reaches these
    del vc, z, y
    for r0 in range(0, h, rows):
        r1 = min(h, r0 + rows)
        sel = np.flatnonzero(~behind & (y_hi >= r0 - 1) & (y_lo <= r1))
        k = camera.K.copy()
        k[1, 2] -= r0
        band = Camera(K=k, R=camera.R, t=camera.t, width=w, height=r1 - r0)
        # np.take: rows by index several times faster than fancy indexing.
        tri_pos, tri_uv, tri_vert, corner, face = (
            np.take(a, sel, axis=0) for a in (mesh.tri_pos, mesh.tri_uv, mesh.tri_vert, corner_normals, face_normals)
        )
        part = MeshArrays(tri_pos=tri_pos, tri_uv=tri_uv, tri_vert=tri_vert, uv_map="")
        yield r0, functools.partial(bake_pixels, band, part, corner, face)


def bake_rows(camera, mesh, max_pixels: int = 2_000_000, corner_normals=None, face_normals=None):
    """Bake ``camera`` in bands of whole rows of about ``max_pixels`` pixels, to bound the memory of a large photo.

    Each band (:func:`row_bands`) equals the same rows of the whole view's bake.

    Yields
    ------
    first_row : int
    bake : ViewBake
        The band's rows.
    """
    for r0, bake in row_bands(camera, mesh, max_pixels, corner_normals, face_normals):
        yield r0, bake().image()


def bake_views(scene, inputs, progress=None, cancel=None, threads=None) -> list:
    """Bake each view of :class:`scene.SceneInputs`; one :class:`ViewBake` per view, in order.

    Parameters
    ----------
    scene : bpy.types.Scene
        Unused by the NumPy ray caster; kept so the bake can read scene
        settings later.
    inputs : SceneInputs
    progress : callable(fraction, message), optional
    cancel : callable() -> bool, optional
        Checked between views; when it returns True, :class:`core.errors.Cancelled`
        is raised.
    threads : int or None
        Views baked at once (None: every available core). ``progress`` and
        ``cancel`` are called from the calling thread only.

    Raises
    ------
    DelightError
        No view sees the mesh. (A single view that misses it keeps an empty
        mask; the caller drops it.)
    Cancelled
    """
    mesh = inputs.mesh
    corner = _corner_normals(mesh)
    face = _face_normals(mesh, corner)
    m = len(inputs.views)

    def report(i):  # the view waited for next (views finish in order)
        if progress is not None and i < m:
            progress(i / max(m, 1), f"baking {inputs.views[i].name} ({i + 1}/{m})")

    check_cancel(cancel)
    report(0)

    def done(i):
        check_cancel(cancel)
        report(i + 1)

    out = thread_map(lambda view: bake_view(view.camera, mesh, corner, face), inputs.views, threads, done)
    if progress is not None:
        progress(1.0, "baked")
    if not any(b.mask.any() for b in out):
        names = ", ".join(repr(v.name) for v in inputs.views)
        raise DelightError(f"no camera sees the mesh {inputs.object_name!r} (cameras: {names})")
    return out
