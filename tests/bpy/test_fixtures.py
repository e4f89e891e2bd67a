"""blend_fixtures/make_fixtures.py: render a small lambert_sky with real Cycles and check what the user gets.

Also checks that the checked-in fixtures are complete and consistent with their scene.json (no rendering).
"""

from __future__ import annotations

import importlib.util
import json
import os

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.bpy

from conftest import needs_fixture_blend, needs_fixture_maker  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
FIXTURES = os.path.join(ROOT, "blend_fixtures")

N_CAMS = 4
RES = (160, 120)
TEX = 256


def _load_script():
    spec = importlib.util.spec_from_file_location("make_fixtures", os.path.join(FIXTURES, "make_fixtures.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def mf():
    return _load_script()


@pytest.fixture(scope="module")
def small_scene(mf, tmp_path_factory):
    out = tmp_path_factory.mktemp("fixtures")
    record = mf.generate(
        "lambert_sky", str(out), resolution=RES, n_cameras=N_CAMS, samples=8, texture_size=TEX, shading_views=True
    )
    bpy.ops.wm.read_homefile(use_empty=True)
    return os.path.join(str(out), "lambert_sky"), record


def _open(path):
    bpy.ops.wm.open_mainfile(filepath=path)
    return bpy.context.scene


def _cameras(scene):
    return sorted((o for o in scene.objects if o.type == "CAMERA"), key=lambda o: o.name)


@needs_fixture_maker
def test_user_file_has_mesh_cameras_photos_and_no_ground_truth(small_scene, mf):
    scene_dir, record = small_scene
    scene = _open(os.path.join(scene_dir, "scene.blend"))

    mesh_objs = [o for o in scene.objects if o.type == "MESH"]
    assert [o.name for o in mesh_objs] == [mf.MESH_OBJECT]
    me = mesh_objs[0].data
    assert me.uv_layers.active is not None and me.uv_layers.active.name == record["mesh"]["uv_map"]
    uv = np.empty(len(me.loops) * 2)
    me.uv_layers.active.data.foreach_get("uv", uv)
    assert uv.min() >= 0.0 and uv.max() <= 1.0 and np.ptp(uv) > 0.5
    assert len(me.polygons) == record["mesh"]["faces"]

    # No lights, no world lighting, no ground-truth material anywhere in the user's file.
    assert not [o for o in bpy.data.objects if o.type == "LIGHT"]
    assert len(bpy.data.lights) == 0
    assert scene.world is None and len(bpy.data.worlds) == 0
    assert len(bpy.data.materials) == 0 and len(me.materials) == 0
    assert not [i for i in bpy.data.images if "albedo" in i.name or "albedo" in i.filepath]

    cams = _cameras(scene)
    assert len(cams) == N_CAMS == len(record["cameras"])
    assert (scene.render.resolution_x, scene.render.resolution_y) == RES
    photo_of = {rec["name"]: rec["photo"] for rec in record["cameras"]}
    for cam in cams:
        assert cam.data.show_background_images
        assert len(cam.data.background_images) == 1
        img = cam.data.background_images[0].image
        assert img is not None and img.packed_file is None
        assert img.filepath == "//" + photo_of[cam.name], img.filepath  # its own photo, relative to the .blend
        path = bpy.path.abspath(img.filepath)
        assert os.path.isfile(path)
        assert tuple(img.size) == RES  # it loads, at the photo size
        assert img.has_data
        assert img.colorspace_settings.name == "Linear Rec.709"


@needs_fixture_maker
def test_photos_attached_by_camera_name(mf, tmp_path):
    # Names sorted as strings put cam_100 before cam_11: each camera must still get its own photo.
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    names = ["cam_09", "cam_10", "cam_11", "cam_99", "cam_100", "cam_101"]
    photos = {}
    for i, name in enumerate(names):
        scene.collection.objects.link(bpy.data.objects.new(name, bpy.data.cameras.new(name)))
        img = bpy.data.images.new(f"made_{i}", 4, 3)
        img.filepath_raw = str(tmp_path / "photos" / f"{name}.png")
        img.file_format = "PNG"
        os.makedirs(tmp_path / "photos", exist_ok=True)
        img.save()
        photos[name] = f"photos/{name}.png"
    mf._attach_photos(scene, dict(reversed(list(photos.items()))), str(tmp_path))
    for name in names:
        img = scene.objects[name].data.background_images[0].image
        assert os.path.basename(img.filepath) == f"{name}.png"
    bpy.ops.wm.read_homefile(use_empty=True)


@needs_fixture_maker
def test_ground_truth_texture(small_scene, mf):
    scene_dir, record = small_scene
    gt_info = record["albedo_gt"]
    assert gt_info["size"] == [TEX, TEX]
    gt = mf.read_exr(os.path.join(scene_dir, gt_info["file"]))
    assert gt.shape == (TEX, TEX, 4)
    inside = gt[..., 3] > 0.5
    assert set(np.unique(gt[..., 3])) == {0.0, 1.0}
    assert 0.3 < inside.mean() < 0.9  # the UV islands fill a fair part of the map
    assert gt_info["overlapping_texels"] == 0
    # Piecewise constant: inside the islands, exactly the region albedos (stored as half floats).
    regions = np.array(list(mf.REGION_ALBEDO.values()), dtype=np.float16).astype(np.float32)
    colours = np.unique(gt[inside][:, :3], axis=0)
    assert len(colours) == len(regions)
    assert all(np.any(np.all(regions == c, axis=1)) for c in colours)
    # The padding holds real albedo values too (no black bleeding into islands).
    assert np.all(np.any(np.all(gt[~inside][:, None, :3] == regions[None], axis=2), axis=1))


@needs_fixture_maker
def test_photos_are_plausible(small_scene, mf):
    scene_dir, record = small_scene
    for cam in record["cameras"]:
        photo = mf.read_exr(os.path.join(scene_dir, cam["photo"]))
        assert photo.shape == (RES[1], RES[0], 4)  # RGBA, transparent film
        alpha = photo[..., 3]
        obj = alpha > 0.99
        assert 0.05 < obj.mean() < 0.8, f"{cam['name']}: the object covers {obj.mean():.2f} of the frame"
        rgb = photo[obj][:, :3]
        assert np.all(np.isfinite(rgb))
        assert 0.03 < rgb.mean() < 1.0, f"{cam['name']}: mean radiance {rgb.mean():.3f}"
        assert (rgb.max(axis=1) <= 0.005).mean() < 0.05  # not black
        assert (rgb.min(axis=1) >= 1.0).mean() < 0.05  # not burnt out


@needs_fixture_maker
def test_shading_views_are_the_photo_split_into_albedo_and_shading(small_scene, mf):
    """shading_views/ (bench/shading_ceiling.py): from the photo's own render; albedo x shading = the photo."""
    scene_dir, record = small_scene
    assert record["files"]["shading_views"] == "shading_views/"
    for cam in record["cameras"]:
        photo = mf.read_exr(os.path.join(scene_dir, cam["photo"]))
        albedo = mf.read_exr(os.path.join(scene_dir, cam["albedo_view"]))
        with np.load(os.path.join(scene_dir, "shading_views", cam["name"] + ".npz")) as z:
            s, col, comb = z["diffuse_shading"], z["diffuse_colour"], z["combined"]
        obj = photo[..., 3] > 0.999
        assert obj.mean() > 0.05
        # The photo is the combined pass in half floats; the Diffuse Color pass is the albedo AOV.
        np.testing.assert_allclose(comb[obj], photo[obj][:, :3], rtol=2e-3, atol=1e-4)
        np.testing.assert_allclose(col[obj], albedo[obj][:, :3], rtol=2e-3, atol=1e-4)
        # Lambertian: the photo is albedo x diffuse shading, and the shading is lit, not flat.
        np.testing.assert_allclose(col[obj] * s[obj], comb[obj], rtol=1e-3, atol=1e-4)
        assert np.ptp(s[obj].mean(axis=1)) > 0.1


@needs_fixture_maker
def test_scene_json_cameras_match_the_blend_file(small_scene):
    """K_core / R_core / t_core in scene.json project like Blender's own camera."""
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Vector

    scene_dir, record = small_scene
    scene = _open(os.path.join(scene_dir, "scene.blend"))
    me = scene.objects["Subject"].data
    pts = np.array([v.co for v in list(me.vertices)[::97]], dtype=np.float64)
    w, h = RES
    for cam, rec in zip(_cameras(scene), record["cameras"]):
        assert cam.name == rec["name"]
        np.testing.assert_allclose(np.array(cam.matrix_world), rec["matrix_world"], atol=1e-5)
        K, R, t = (np.array(rec[k]) for k in ("K_core", "R_core", "t_core"))
        pc = pts @ R.T + t
        assert np.all(pc[:, 2] > 0)  # the object is in front of every camera
        proj = pc @ K.T
        xy = proj[:, :2] / proj[:, 2:]
        ref = []
        for p in pts:
            ndc = world_to_camera_view(scene, cam, Vector(p))  # (0,0) bottom-left, (1,1) top-right
            ref.append((ndc.x * w - 0.5, (1.0 - ndc.y) * h - 0.5))  # core: pixel centres at integers, y down
        np.testing.assert_allclose(xy, np.array(ref), atol=2e-3)


@needs_fixture_maker
def test_per_view_ground_truth_is_the_texture_through_the_uv_map(small_scene, mf):
    """The render's material sampled albedo_gt.exr through the mesh's UV map with the recorded conventions.

    gt_views/ holds the albedo each pixel saw (an AOV of the texture colour). Fully covered pixels show only the
    region albedos; and front-facing mesh vertices, projected with scene.json's cameras, see the texel that their
    UV picks in albedo_gt.exr (row 0 = top = v 1, "Closest" lookup).
    """
    scene_dir, record = small_scene
    gt = mf.read_exr(os.path.join(scene_dir, "albedo_gt.exr"))
    regions = np.array(list(mf.REGION_ALBEDO.values()), dtype=np.float16).astype(np.float32)
    scene = _open(os.path.join(scene_dir, "scene.blend"))
    me = scene.objects[mf.MESH_OBJECT].data
    n_loops = len(me.loops)
    uv = np.empty(n_loops * 2)
    me.uv_layers.active.data.foreach_get("uv", uv)
    uv = uv.reshape(-1, 2)
    lv = np.empty(n_loops, dtype=np.int64)
    me.loops.foreach_get("vertex_index", lv)
    co = np.empty(len(me.vertices) * 3)
    me.vertices.foreach_get("co", co)
    nrm = np.empty(len(me.vertices) * 3)
    me.vertices.foreach_get("normal", nrm)
    co, nrm = co.reshape(-1, 3), nrm.reshape(-1, 3)
    # Loops well inside a texel and away from texel edges: the "Closest" lookup is then unambiguous.
    fx, fy = uv[:, 0] * TEX, (1.0 - uv[:, 1]) * TEX
    rows, cols = np.clip(fy.astype(int), 1, TEX - 2), np.clip(fx.astype(int), 1, TEX - 2)
    tex_rgb = gt[rows, cols, :3]
    # Keep loops whose 5x5 texel neighbourhood has one colour (away from region edges).
    same = np.ones(len(rows), dtype=bool)
    for dr in (-2, -1, 0, 1, 2):
        for dc in (-2, -1, 0, 1, 2):
            rr, cc = np.clip(rows + dr, 0, TEX - 1), np.clip(cols + dc, 0, TEX - 1)
            same &= np.all(gt[rr, cc, :3] == tex_rgb, axis=1)
    agree = total = 0
    for cam in record["cameras"]:
        view = mf.read_exr(os.path.join(scene_dir, cam["albedo_view"]))
        assert view.shape == (RES[1], RES[0], 4)
        a = view[..., 3]
        full = a > 0.999
        assert full.mean() > 0.05
        rgb = view[full][:, :3] / a[full][:, None]
        exact = np.any(np.all(np.abs(rgb[:, None] - regions[None]) < 2e-3, axis=2), axis=1)
        assert exact.mean() > 0.85, f"{cam['name']}: only {exact.mean():.2f} of the pixels show a region albedo"
        # Project loops of front-facing vertices.
        K, R, t = (np.array(cam[k]) for k in ("K_core", "R_core", "t_core"))
        centre = -R.T @ t
        p = co[lv]
        facing = np.einsum("ij,ij->i", nrm[lv], centre - p) > 0.5 * np.linalg.norm(centre - p, axis=1)
        pc = p @ R.T + t
        xy = (pc @ K.T)[:, :2] / pc[:, 2:]
        px = np.round(xy).astype(int)
        ok = same & facing & (px[:, 0] >= 0) & (px[:, 0] < RES[0]) & (px[:, 1] >= 0) & (px[:, 1] < RES[1])
        px = px[ok]
        seen = view[px[:, 1], px[:, 0]]
        # Pixels whose 3x3 neighbourhood is fully covered and of one colour (away from silhouettes and edges).
        covered = seen[:, 3] > 0.999
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                nb = view[np.clip(px[:, 1] + dy, 0, RES[1] - 1), np.clip(px[:, 0] + dx, 0, RES[0] - 1)]
                covered &= (nb[:, 3] > 0.999) & np.all(np.abs(nb[:, :3] - seen[:, :3]) < 2e-3, axis=1)
        diff = np.abs(seen[covered, :3] / seen[covered, 3:] - tex_rgb[ok][covered]).max(axis=1)
        agree += int((diff < 2e-3).sum())
        total += int(covered.sum())
    assert total > 200
    assert agree / total > 0.9, f"only {agree}/{total} projected vertices see their own texel's albedo"


SCENES = (
    "lambert_sky",
    "photo_sun",
    "photo_sun_coarse",
    "varying_light",
    "torus_patches",
    "bowl_checker",
    "rock_photo",
    "rock_coarse",
    "stairs_noise",
    "suzanne_exposure",
    "torus_varying_sun",
    "bowl_jitter",
    "stairs_capture",
)


def test_every_scene_is_checked(mf):
    assert set(SCENES) == set(mf.SCENES) and len(SCENES) >= 12


@needs_fixture_blend
@pytest.mark.parametrize("name", SCENES)
def test_checked_in_fixture_is_complete(name, mf):
    scene_dir = os.path.join(FIXTURES, name)
    if not os.path.isfile(os.path.join(scene_dir, "scene.json")):
        pytest.fail(f"blend_fixtures/{name} is missing: run blend_fixtures/make_fixtures.py --only {name}")
    with open(os.path.join(scene_dir, "scene.json")) as f:
        record = json.load(f)
    n = record["albedo_gt"]["size"][0]
    gt = mf.read_exr(os.path.join(scene_dir, "albedo_gt.exr"))
    assert gt.shape == (n, n, 4)
    assert np.all(np.isfinite(gt)) and 0.0 <= gt[..., :3].min() and gt[..., :3].max() < 1.0
    w, h = record["render"]["resolution"]
    ext = {"EXR": ".exr", "PNG": ".png", "JPEG": ".jpg"}[record["photo"]["format"].replace("OpenEXR", "EXR")]
    for cam in record["cameras"]:
        path = os.path.normpath(os.path.join(scene_dir, cam["photo"]))
        assert os.path.isfile(path) and path.endswith(ext), path
        photo = mf.read_exr(path) if ext == ".exr" else mf.load_png_linear(path)
        assert photo.shape[:2] == (h, w)
        rgb = photo[..., :3] if photo.shape[2] == 3 else photo[photo[..., 3] > 0.99][:, :3]
        assert 0.02 < rgb.mean() < 0.6, f"{path}: mean linear value {rgb.mean():.3f}"
        # (Bright windows of the 'interior' HDRI clip in the background, as in real photos.)
        assert (rgb.max(axis=-1) >= 0.999).mean() < 0.3, f"{path}: too many clipped pixels"
    scene = _open(os.path.join(scene_dir, "scene.blend"))
    cams = _cameras(scene)
    assert [c.name for c in cams] == [c["name"] for c in record["cameras"]]
    assert 8 <= len(cams) <= 16
    assert len(bpy.data.lights) == 0 and len(bpy.data.materials) == 0 and scene.world is None
    for cam, rec in zip(cams, record["cameras"]):
        img = cam.data.background_images[0].image
        assert os.path.isfile(bpy.path.abspath(img.filepath)) and tuple(img.size) == (w, h)
        # The saved camera is the one scene.json describes; where the capture jittered it, about a pixel off
        # the camera that rendered the photo.
        np.testing.assert_allclose(np.array(cam.matrix_world), rec["matrix_world"], atol=1e-5)
        if "render_camera" in rec:
            assert 0.3 < rec["jitter"]["reprojection_px"]["mean"] < 2.0
            assert not np.allclose(rec["render_camera"]["matrix_world"], rec["matrix_world"], atol=1e-5)
    me = scene.objects[record["mesh"]["object"]].data
    assert len(me.vertices) == record["mesh"]["vertices"] and me.uv_layers.active.name == "UVMap"
