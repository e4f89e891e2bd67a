"""Scene -> arrays: the target mesh, the cameras and their photos.

:func:`gather` only reads the scene. Everything it returns is plain NumPy, so
the rest of the run can happen off the main thread.
"""

from __future__ import annotations

import collections
from concurrent.futures import wait

import numpy as np

from . import photos as _photos
from .camera import to_core_camera
from .core.errors import DelightError
from .core.io.photos import downscale, photo_working_mp, working_size
from .core.parallel import resolve_threads, start
from .core.scene import FullPhoto, MeshArrays, SceneInputs, ViewInput

__all__ = ["gather", "mesh_arrays", "target_object", "PHOTOS_AT_WORK"]

#: Photos converted and downscaled at once while the next is read: each holds its pixels twice over (a 24 MP
#: photo about 0.7 GB), and with two the main thread's reading is no longer what waits.
PHOTOS_AT_WORK = 2


def _scene_and_view_layer(context_or_scene):
    import bpy

    if isinstance(context_or_scene, bpy.types.Scene):
        scene = context_or_scene
        ctx = bpy.context
        if getattr(ctx, "scene", None) == scene and getattr(ctx, "view_layer", None) is not None:
            return scene, ctx.view_layer
        return scene, scene.view_layers[0]
    ctx = context_or_scene
    return ctx.scene, ctx.view_layer


def _depsgraph(scene, view_layer):
    import bpy

    ctx = bpy.context
    if getattr(ctx, "scene", None) == scene and getattr(ctx, "view_layer", None) == view_layer:
        return ctx.evaluated_depsgraph_get()
    dg = view_layer.depsgraph
    dg.update()
    return dg


def _is_image_plane(obj, cameras):
    """A photo's image plane (Photogrammetry Importer), never a target."""
    if obj.name.endswith("_image_plane"):
        return True
    parent = obj.parent
    return parent is not None and parent in cameras


def _cameras_seeing(scene, obj, cameras):
    """How many of ``cameras`` have the centre of ``obj``'s bounding box inside their frame."""
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    corners = [obj.matrix_world @ Vector(c) for c in obj.bound_box]
    centre = sum(corners, Vector((0.0, 0.0, 0.0))) / 8.0
    seen = 0
    for cam in cameras:
        x, y, z = world_to_camera_view(scene, cam, centre)
        seen += int(z > 0 and 0.0 <= x <= 1.0 and 0.0 <= y <= 1.0)
    return seen


def _seen_mesh(scene, view_layer):
    """The one mesh that the scene's cameras look at, when there is exactly one best candidate."""
    cameras = [o for o in scene.objects if o.type == "CAMERA"]
    meshes = [o for o in scene.objects if o.type == "MESH" and not _is_image_plane(o, cameras) and len(o.data.polygons)]
    if not meshes:
        raise DelightError(f"scene {scene.name!r} has no mesh to delight")
    if len(meshes) == 1:
        return meshes[0]
    counts = sorted(((_cameras_seeing(scene, o, cameras), o.name) for o in meshes), reverse=True)
    if counts[0][0] > 0 and counts[0][0] > counts[1][0]:
        return scene.objects[counts[0][1]]
    names = ", ".join(repr(n) for _, n in counts[:8]) + (" ..." if len(counts) > 8 else "")
    raise DelightError(
        f"several meshes could be the target ({names}): name one (--object NAME on the command "
        "line, the Object field in the panel) or make it the active object"
    )


def _target(scene, view_layer, object_name):
    if object_name:
        obj = scene.objects.get(object_name)
        if obj is None:
            raise DelightError(f"no object named {object_name!r} in scene {scene.name!r}")
    else:
        # Photogrammetry importers leave a camera active: fall back to the mesh the cameras see.
        obj = view_layer.objects.active
        if obj is None or obj.type != "MESH":
            obj = _seen_mesh(scene, view_layer)
    if obj.type != "MESH":
        raise DelightError(f"object {obj.name!r} is a {obj.type.lower()}, not a mesh")
    if not obj.data.uv_layers:
        raise DelightError(f"mesh {obj.name!r} has no UV map: unwrap it first (UV > Smart UV Project)")
    return obj


def _has_sharp_edges(mesh):
    attr = mesh.attributes.get("sharp_edge")
    if attr is None or attr.domain != "EDGE" or len(attr.data) == 0:
        return False
    flags = np.zeros(len(attr.data), dtype=bool)
    attr.data.foreach_get("value", flags)
    return bool(flags.any())


def _cycles_uses_corner_normals(mesh):
    """Whether Cycles shades ``mesh`` with its corner normals rather than its vertex normals.

    Checked against Cycles' Normal pass: Blender 5.2 shades every mesh with
    its corner normals (a smooth face next to a flat one leaves the flat
    face's normal out). Blender 4.2 to 5.1 interpolate the *vertex* normals on
    smooth faces, even next to flat faces, and split only for custom normals
    and sharp edges.
    """
    import bpy

    if bpy.app.version >= (5, 2, 0):
        return True
    return mesh.has_custom_normals or _has_sharp_edges(mesh)


def _shading_normals(mesh, tri_loop):
    """Object-space shading normals of each triangle corner, ``(T * 3, 3)``, as Cycles shades.

    Either the corner normals, or (see :func:`_cycles_uses_corner_normals`)
    the vertex normals on smooth faces and the face normal on flat faces.
    """
    nt = len(tri_loop)
    if _cycles_uses_corner_normals(mesh):
        cn = np.empty(len(mesh.loops) * 3, dtype=np.float32)
        mesh.corner_normals.foreach_get("vector", cn)
        return cn.reshape(-1, 3)[tri_loop.ravel()]
    vn = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
    mesh.vertex_normals.foreach_get("vector", vn)
    tv = np.empty(nt * 3, dtype=np.int32)
    mesh.loop_triangles.foreach_get("vertices", tv)
    out = vn.reshape(-1, 3)[tv]
    smooth = np.empty(nt, dtype=bool)
    mesh.loop_triangles.foreach_get("use_smooth", smooth)
    if not smooth.all():
        pn = np.empty(len(mesh.polygons) * 3, dtype=np.float32)
        mesh.polygon_normals.foreach_get("vector", pn)
        poly = np.empty(nt, dtype=np.int32)
        mesh.loop_triangles.foreach_get("polygon_index", poly)
        flat = np.repeat(~smooth, 3)
        out[flat] = np.repeat(pn.reshape(-1, 3)[poly], 3, axis=0)[flat]
    return out


def mesh_arrays(obj, depsgraph) -> MeshArrays:
    """Loop triangles of the evaluated mesh in world space (see :class:`MeshArrays`)."""
    ev = obj.evaluated_get(depsgraph)
    mesh = ev.to_mesh()
    try:
        if mesh.uv_layers.active is None:
            raise DelightError(f"mesh {obj.name!r} has no UV map after its modifiers")
        uv_map = obj.data.uv_layers.active.name if obj.data.uv_layers.active else mesh.uv_layers.active.name
        mesh.calc_loop_triangles()
        nt = len(mesh.loop_triangles)
        if nt == 0:
            raise DelightError(f"mesh {obj.name!r} has no faces")
        tri_vert = np.empty(nt * 3, dtype=np.int32)
        tri_loop = np.empty(nt * 3, dtype=np.int32)
        mesh.loop_triangles.foreach_get("vertices", tri_vert)
        mesh.loop_triangles.foreach_get("loops", tri_loop)
        co = np.empty(len(mesh.vertices) * 3, dtype=np.float32)
        mesh.vertices.foreach_get("co", co)
        uv = np.empty(len(mesh.loops) * 2, dtype=np.float32)
        mesh.uv_layers.active.data.foreach_get("uv", uv)
        cn = _shading_normals(mesh, tri_loop.reshape(nt, 3))
        mw = np.array(ev.matrix_world, dtype=np.float64)
    finally:
        ev.to_mesh_clear()
    tri_vert = tri_vert.reshape(nt, 3).astype(np.intp)
    tri_loop = tri_loop.reshape(nt, 3)
    pos = co.reshape(-1, 3).astype(np.float64) @ mw[:3, :3].T + mw[:3, 3]
    # Normals transform with the inverse transpose (non-uniform scale, mirrors).
    nmat = np.linalg.inv(mw[:3, :3]).T
    nrm = cn.reshape(-1, 3).astype(np.float64) @ nmat.T
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30)
    return MeshArrays(
        tri_pos=pos[tri_vert],
        tri_uv=uv.reshape(-1, 2)[tri_loop],
        tri_vert=tri_vert,
        uv_map=uv_map,
        tri_normal=nrm.reshape(nt, 3, 3).astype(np.float32),
    )


def _cameras(scene, view_layer, camera_names, selected_only):
    if camera_names:
        cams = []
        for name in camera_names:
            obj = scene.objects.get(name)
            if obj is None:
                raise DelightError(f"no camera named {name!r} in scene {scene.name!r}")
            if obj.type != "CAMERA":
                raise DelightError(f"object {name!r} is a {obj.type.lower()}, not a camera")
            if obj not in cams:
                cams.append(obj)
        return cams
    cams = [o for o in scene.objects if o.type == "CAMERA"]
    if selected_only:
        cams = [o for o in cams if o.select_get(view_layer=view_layer)]
        if not cams:
            raise DelightError("no camera is selected")
    if not cams:
        raise DelightError(f"scene {scene.name!r} has no cameras")
    return sorted(cams, key=lambda o: o.name)


def target_object(context_or_scene, object_name=None):
    """The mesh object a run delights (as :func:`gather` finds it).

    Raises
    ------
    DelightError
        No such object, not a mesh, no UV map, or no single mesh the cameras look at.
    """
    scene, view_layer = _scene_and_view_layer(context_or_scene)
    return _target(scene, view_layer, object_name)


def gather(
    context_or_scene,
    object_name=None,
    camera_names=None,
    images_dir=None,
    working_res_mp=1.0,
    selected_only=False,
    keep_full=None,
    progress=None,
    threads=None,
    working_total_mp=None,
) -> SceneInputs:
    """Read the mesh, the cameras and their photos from the scene.

    Parameters
    ----------
    context_or_scene : bpy.types.Context or bpy.types.Scene
    object_name : str, optional
        The mesh; default the active object.
    camera_names : list of str, optional
        The cameras; default every camera in the scene (or the selected ones).
    images_dir : str, optional
        Folder searched for a photo named after the camera when it has no
        background image or image plane.
    working_res_mp : float
        Photos larger than this many megapixels are area-averaged down to fit,
        and their cameras' intrinsics scaled to match. ``0`` or ``None``: keep.
    working_total_mp : float, optional
        With more photos than this many megapixels hold at ``working_res_mp`` each, each is brought down to its
        share of it instead (:func:`core.io.photos.photo_working_mp`). ``0`` or ``None``: no limit.
    selected_only : bool
        Without ``camera_names``, take only the selected cameras.
    keep_full : callable(photo, clipped) -> load, optional
        Called with each photo that is downscaled, at its full resolution (an 8-bit one as its codes, a
        :class:`core.io.photos.CodedPhoto`, where tables give its colours) and its clipped pixels or None;
        what it returns becomes ``ViewInput.full.load`` (:class:`core.io.photo_cache.PhotoCache.put`). Without
        it the full-resolution photos are let go.
    progress : callable(fraction, message), optional
        Called before each photo is read.
    threads : int or None
        1: every photo read and converted on the calling thread in turn; else (None: as
        :func:`core.parallel.resolve_threads`) each photo's conversion beside the reading of the next.

    Returns
    -------
    SceneInputs
        Views sorted by camera name unless ``camera_names`` gives the order.

    Raises
    ------
    DelightError
        No mesh, no UVs, no cameras, a camera without a readable photo, a photo
        that does not fit its camera, or a non-perspective camera (with all
        cameras, such a camera is skipped instead while two others remain; see
        ``SceneInputs.skipped``). Nothing in the scene or on disk is changed.
    """
    scene, view_layer = _scene_and_view_layer(context_or_scene)
    obj = _target(scene, view_layer, object_name)
    cams = _cameras(scene, view_layer, camera_names, selected_only)
    all_cameras = not camera_names and not selected_only
    skipped = []
    # Cheap checks first, before reading any photo.
    other = [c for c in cams if c.data.type != "PERSP"]
    if other:
        kinds = ", ".join(f"{c.name!r} ({c.data.type.lower()})" for c in other)
        if not all_cameras or len(cams) - len(other) < 2:
            raise DelightError(f"only perspective cameras are supported; these are not: {kinds}")
        skipped += [f"skipped camera {c.name!r}: it is {c.data.type.lower()}, not perspective" for c in other]
        cams = [c for c in cams if c.data.type == "PERSP"]
    depsgraph = _depsgraph(scene, view_layer)
    mesh = mesh_arrays(obj, depsgraph)
    views, errors = [], []
    per_photo = photo_working_mp(working_res_mp, working_total_mp, len(cams))
    if per_photo != working_res_mp and progress is not None:
        total = f"{working_total_mp:g} MP in all (working total)"
        progress(0.0, f"{len(cams)} photos: each at most {per_photo:.2g} MP, {total}")

    def unusable(cam, exc):
        if not all_cameras:
            raise exc
        errors.append(exc)
        skipped.append(f"skipped camera {cam.name!r}: {exc}")

    # Blender reads each photo here, on the main thread, while threads of their own convert, downscale and keep
    # the ones before (NumPy's work): at most PHOTOS_AT_WORK photos at work, and one being read.
    at_work = collections.deque()  # (camera, the Future of its ViewInput), in the cameras' order
    room = min(resolve_threads(threads), PHOTOS_AT_WORK)

    def settle():
        cam, job = at_work.popleft()
        try:
            views.append(job.result())
        except DelightError as exc:
            unusable(cam, exc)

    try:
        for i, cam in enumerate(cams):
            if progress is not None:
                progress(i / len(cams), f"reading the photo of {cam.name} ({i + 1}/{len(cams)})")
            try:
                make = _read_view(scene, depsgraph, cam, images_dir, per_photo, working_res_mp, keep_full)
            except DelightError as exc:
                while at_work:  # the views stay in the cameras' order
                    settle()
                unusable(cam, exc)
                continue
            while len(at_work) >= room:
                settle()
            at_work.append((cam, start(make, threads=room)))
        while at_work:
            settle()
    finally:
        wait([job for _, job in at_work])  # stopped early: no thread left at work
    # With "all cameras", an unusable camera is left out as long as two others remain.
    if errors and len(views) < 2:
        raise errors[0]
    return SceneInputs(object_name=obj.name, mesh=mesh, views=views, skipped=skipped)


def _read_view(scene, depsgraph, cam, images_dir, working_res_mp, keep_above, keep_full=None):
    """Blender's part of a view (main thread): its photo read and its cameras; returns ``make() -> ViewInput``.

    ``make`` is the NumPy part, for any thread: the photo converted, downscaled to ``working_res_mp`` and, if it
    is also larger than ``keep_above`` megapixels (the user's working resolution; ``None`` or ``0``: no limit),
    kept at its full resolution by ``keep_full``. (A photo within the user's working resolution, downscaled only
    to keep the photos' total, has no detail beyond it to restore.)
    """
    info = {}
    finish, (w, h), source = _photos.find_photo(scene, cam, images_dir, info)
    h2, w2 = working_size(h, w, working_res_mp)
    scale = (w2 / w, h2 / h) if (h2, w2) != (h, w) else (1.0, 1.0)
    matrix = cam.evaluated_get(depsgraph).matrix_world
    camera = to_core_camera(cam, scene, w, h, matrix_world=matrix, scale=scale)
    larger = working_size(h, w, keep_above) != (h, w)
    full_camera = to_core_camera(cam, scene, w, h, matrix_world=matrix) if scale != (1.0, 1.0) and larger else None
    name = cam.name

    def make():
        # An 8-bit photo as its codes: downscaled a few rows at a time, and kept in place of its colours.
        photo = finish(coded=True)
        small = downscale(photo, working_res_mp)[0]
        clipped = full_clipped = info.get("clipped")
        if clipped is not None and scale != (1.0, 1.0):  # a working pixel is clipped if any photo pixel in it is
            clipped = downscale(clipped[..., None].astype(np.float32), working_res_mp)[0][..., 0] > 0
        full = None
        if keep_full is not None and full_camera is not None:
            full = FullPhoto(camera=full_camera, load=keep_full(photo, full_clipped))
        return ViewInput(name=name, camera=camera, photo=small, source=source, clipped=clipped, full=full)

    return make
