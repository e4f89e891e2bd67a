"""Shared fixtures and scene builders for the bpy tests (real Blender, no mocks).

Every test in this folder starts from an empty scene (``fresh_scene``, autouse)
and ends on one, so tests never see each other's data.

Builders (plain functions, import them with ``from conftest import ...`` or use
the ``tiny_scene`` fixture):

* :func:`add_uv_sphere`, :func:`add_camera`, :func:`ring_cameras` build geometry;
* :func:`set_render` sets the render frame;
* :func:`make_image` turns a linear array into a ``bpy.types.Image`` (generated
  float, 8-bit sRGB PNG file or EXR file);
* :func:`new_material` makes a material with nodes on every Blender;
* :func:`set_background`, :func:`add_image_plane` attach a photo to a camera the
  ways photogrammetry importers do;
* :func:`render_cycles` renders passes of a camera with Cycles into arrays;
* :func:`build_scene` puts it all together; :func:`data_counts` snapshots the
  datablock counts to check that a failed run changed nothing.
"""

from __future__ import annotations

import math
import os
import sys
from types import SimpleNamespace

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

bpy = pytest.importorskip("bpy")
import bmesh  # noqa: E402  (only exists once bpy is imported)
from mathutils import Vector  # noqa: E402

from core.io.exr import exr_parts, read_exr, write_exr  # noqa: E402
from core.io.photos import linear_to_srgb  # noqa: E402

pytestmark = pytest.mark.bpy

#: Skips a test that opens a checked-in fixture .blend on a Blender that cannot read it.
needs_fixture_blend = pytest.mark.skipif(
    bpy.app.version < (4, 5, 0),
    reason="the checked-in fixture .blend files are saved by Blender 5.0, whose file format Blender < 4.5 cannot read",
)
#: Skips a test that renders a scene with blend_fixtures/make_fixtures.py on a Blender older than its API.
needs_fixture_maker = pytest.mark.skipif(
    bpy.app.version < (5, 0, 0),
    reason="blend_fixtures/make_fixtures.py uses the Blender 5.0 API (image_settings.media_type)",
)


@pytest.fixture(autouse=True)
def fresh_scene():
    """An empty scene before the test, and again after it."""
    bpy.ops.wm.read_homefile(use_empty=True)
    yield bpy.context.scene
    bpy.ops.wm.read_homefile(use_empty=True)


def data_counts():
    """Counts of the datablocks a run could create or remove."""
    d = bpy.data
    return {
        k: len(getattr(d, k))
        for k in (
            "images",
            "objects",
            "meshes",
            "scenes",
            "materials",
            "cameras",
            "collections",
            "node_groups",
            "textures",
        )
    }


def link(obj, scene=None):
    (scene or bpy.context.scene).collection.objects.link(obj)
    return obj


def add_uv_sphere(
    name="Target", radius=1.0, segments=24, rings=12, location=(0.0, 0.0, 0.0), smooth=True, flat_faces=()
):
    """A UV-mapped sphere mesh object (UV map "UVMap"), smooth-shaded unless told.

    ``flat_faces``: polygon indices to leave flat-shaded.
    """
    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bm.loops.layers.uv.new("UVMap")  # create_uvsphere fills the existing UV layer
    bmesh.ops.create_uvsphere(bm, u_segments=segments, v_segments=rings, radius=radius, calc_uvs=True)
    bm.to_mesh(me)
    bm.free()
    flags = [smooth] * len(me.polygons)
    for i in flat_faces:
        flags[i] = False
    me.polygons.foreach_set("use_smooth", flags)
    obj = link(bpy.data.objects.new(name, me))
    obj.location = location
    return obj


def add_camera(
    name, location, look_at=(0.0, 0.0, 0.0), lens=50.0, sensor_fit="AUTO", shift=(0.0, 0.0), sensor=(36.0, 24.0)
):
    """A perspective camera at ``location`` looking at ``look_at`` (+Y up-ish)."""
    cam = bpy.data.cameras.new(name)
    cam.lens = lens
    cam.sensor_fit = sensor_fit
    cam.sensor_width, cam.sensor_height = sensor
    cam.shift_x, cam.shift_y = shift
    cam.clip_start, cam.clip_end = 0.01, 1000.0
    obj = link(bpy.data.objects.new(name, cam))
    obj.location = location
    direction = Vector(look_at) - Vector(location)
    obj.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()
    return obj


def ring_cameras(n=4, radius=6.0, height=1.5, prefix="view", suffix="_cam", **kw):
    """``n`` cameras on a circle around the origin, looking at it."""
    cams = []
    for i in range(n):
        a = 2 * math.pi * i / n
        cams.append(add_camera(f"{prefix}{i}{suffix}", (radius * math.cos(a), radius * math.sin(a), height), **kw))
    bpy.context.view_layer.update()
    return cams


def set_render(width, height, pixel_aspect=(1.0, 1.0), scene=None):
    scene = scene or bpy.context.scene
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
    r.pixel_aspect_x, r.pixel_aspect_y = pixel_aspect
    return scene


def write_png(path, codes):
    """Write an 8-bit PNG of ``codes`` ``(H, W, 3)`` (RGB) or ``(H, W, 4)`` (RGBA, straight alpha) uint8, row 0
    at the top, through Blender's image API.

    The temporary image is removed again, so the file is all that is left.
    """
    codes = np.asarray(codes, dtype=np.uint8)
    h, w, c = codes.shape
    img = bpy.data.images.new("_write_png", w, h, alpha=c == 4)
    try:
        px = np.ones((h, w, 4), dtype=np.float32)
        px[..., :c] = codes[::-1] / np.float32(255)  # a byte image stores code/255, bottom row first
        img.pixels.foreach_set(px.ravel())
        img.filepath_raw = path
        img.file_format = "PNG"
        img.save()
    finally:
        bpy.data.images.remove(img)
    return path


def make_image(name, linear, kind="float", folder=None):
    """A ``bpy.types.Image`` holding ``linear`` ``(H, W, 3)`` (row 0 at the top).

    kind: ``"float"`` (generated float image, pixels set in memory), ``"png"``
    (8-bit sRGB file in ``folder``, loaded) or ``"exr"`` (float file, loaded).
    """
    linear = np.asarray(linear, dtype=np.float32)
    h, w = linear.shape[:2]
    if kind == "float":
        img = bpy.data.images.new(name, w, h, float_buffer=True)
        rgba = np.concatenate([linear, np.ones((h, w, 1), np.float32)], axis=2)[::-1]
        img.pixels.foreach_set(np.ascontiguousarray(rgba).ravel())
        img.pack()
        return img
    path = os.path.join(folder, name + (".png" if kind == "png" else ".exr"))
    if kind == "png":
        write_png(path, np.round(linear_to_srgb(linear) * 255).astype(np.uint8))
    else:
        write_exr(path, linear)
    return bpy.data.images.load(path)


def set_background(cam, img):
    bg = cam.data.background_images.new()
    bg.image = img
    return bg


def new_material(name):
    """A new material with its node tree (Blender 4 makes one only with ``use_nodes``)."""
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:
        mat.use_nodes = True
    return mat


def add_image_plane(cam, img):
    """A Photogrammetry-Importer-style image plane ``<stem>_image_plane`` in front of ``cam``."""
    stem = cam.name[:-4] if cam.name.endswith("_cam") else cam.name
    me = bpy.data.meshes.new(stem + "_image_plane")
    me.from_pydata([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [], [(0, 1, 2, 3)])
    mat = new_material(stem + "_image_plane")
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = img
    me.materials.append(mat)
    plane = link(bpy.data.objects.new(stem + "_image_plane", me))
    # In front of the camera, between it and the target: it must not occlude.
    plane.matrix_world = cam.matrix_world.copy()
    plane.location = cam.matrix_world @ Vector((0.0, 0.0, -1.0))
    plane.scale = (0.5, 0.5, 0.5)
    return plane


def synth_photo(width, height, seed=0):
    """A smooth, non-constant linear RGB image."""
    yy, xx = np.mgrid[0:height, 0:width] / max(width, height)
    rng = np.random.default_rng(seed)
    a = rng.uniform(0.2, 0.6, 3)
    img = a + 0.3 * np.stack([xx, yy, 0.5 * (xx + yy)], axis=2)
    return img.astype(np.float32)


def render_cycles(scene, cam, folder, passes=("position", "normal", "uv"), samples=1, name="render"):
    """Render ``cam`` with Cycles (CPU, ``samples`` spp, box filter 0.01, no bounces).

    Returns a dict: ``"rgba"`` (H, W, 4) and one array per pass (row 0 at the top).
    The scene's render settings are changed.
    """
    scene.camera = cam
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.samples = samples
    c.use_denoising = False
    c.use_adaptive_sampling = False
    c.max_bounces = 0
    c.pixel_filter_type = "BOX"
    c.filter_width = 0.01
    scene.render.film_transparent = True
    scene.render.threads_mode = "FIXED"
    scene.render.threads = 2
    vl = scene.view_layers[0]
    vl.use_pass_position = "position" in passes
    vl.use_pass_normal = "normal" in passes
    vl.use_pass_uv = "uv" in passes
    if hasattr(scene.render.image_settings, "media_type"):  # 5.0+
        scene.render.image_settings.media_type = "MULTI_LAYER_IMAGE"
    else:
        scene.render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
    path = os.path.join(folder, name + ".exr")
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    out = {"rgba": read_render_pass(path, f"{vl.name}.Combined")}
    for p, part in (("position", "Position"), ("normal", "Normal"), ("uv", "UV")):
        if p in passes:
            out[p] = read_render_pass(path, f"{vl.name}.{part}")
    return out


def read_render_pass(path, name):
    """Pass ``name`` (``"ViewLayer.Normal"``) of a multilayer EXR that Blender rendered.

    Blender 5 writes each pass as a part of its own; Blender 4 writes one part
    whose channels are named ``"<name>.<channel>"``.
    """
    if name in [n for n, _ in exr_parts(path)]:
        return read_exr(path, part=name)[0]
    arr, channels = read_exr(path, part=0)
    mine = {c[len(name) + 1 :]: i for i, c in enumerate(channels) if c.startswith(name + ".")}
    order = [c for c in "RGBA" if c in mine] + [c for c in mine if c not in "RGBA"]
    return arr[:, :, [mine[c] for c in order]]


def build_scene(folder=None, n_cameras=4, size=(64, 48), photo="background", kind="float", radius=6.0, **camera_kw):
    """A UV sphere "Target" and ``n_cameras`` ring cameras ``view<i>_cam`` with photos.

    photo: ``"background"`` (camera background image), ``"plane"`` (image plane),
    ``"dir"`` (files ``view<i>.<ext>`` in ``folder``, not loaded) or ``None``.
    kind: ``"float"``, ``"png"`` or ``"exr"`` (files need ``folder``).
    Returns a namespace with scene, obj, cameras, images (dict camera -> Image or path).
    """
    scene = set_render(*size)
    obj = add_uv_sphere()
    bpy.context.view_layer.objects.active = obj
    cams = ring_cameras(n_cameras, radius=radius, **camera_kw)
    scene.camera = cams[0]
    images = {}
    for i, cam in enumerate(cams):
        linear = synth_photo(*size, seed=i)
        stem = cam.name[:-4]
        if photo == "dir":
            path = os.path.join(folder, stem + (".png" if kind == "png" else ".exr"))
            if kind == "png":
                write_png(path, np.round(linear_to_srgb(linear) * 255).astype(np.uint8))
            else:
                write_exr(path, linear)
            images[cam.name] = path
        elif photo in ("background", "plane"):
            img = make_image(stem, linear, kind=kind, folder=folder)
            (set_background if photo == "background" else add_image_plane)(cam, img)
            images[cam.name] = img
    return SimpleNamespace(scene=scene, obj=obj, cameras=cams, images=images)


@pytest.fixture
def tiny_scene(tmp_path):
    """:func:`build_scene` with 4 cameras, 64x48 float background photos."""
    return build_scene(str(tmp_path))
