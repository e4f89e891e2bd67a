"""Scene -> arrays -> bake, against real Blender (and Cycles as the reference)."""

from __future__ import annotations

import os

import bpy
import numpy as np
import pytest
from conftest import (
    add_camera,
    add_image_plane,
    add_uv_sphere,
    build_scene,
    data_counts,
    make_image,
    render_cycles,
    set_background,
    set_render,
    synth_photo,
    write_png,
)

from blender_addon.core.errors import DelightError
from blender_addon.core.geometry.bake import bake_views
from blender_addon.core.io.photos import CodedPhoto, downscale, srgb_to_linear
from blender_addon.photos import _byte_image_linear, _code_tables, image_pixels
from blender_addon.scene import gather
from core.io.exr import write_exr

pytestmark = pytest.mark.bpy


# --- the camera model and the ray caster agree with Cycles ------------------------------------------

CYCLES_CASES = {
    # name: (render size, pixel aspect, sensor fit, shift)
    "horizontal-shift": ((80, 60), (1.0, 1.0), "HORIZONTAL", (0.12, -0.07)),
    "vertical-shift-portrait": ((56, 80), (1.0, 1.0), "VERTICAL", (-0.09, 0.11)),
    "auto-portrait": ((48, 72), (1.0, 1.0), "AUTO", (0.05, 0.05)),
    "sharp-edges": ((80, 60), (1.0, 1.0), "HORIZONTAL", (0.0, 0.0)),
}
# (Blender 5.0 cannot write a multilayer EXR with a pixel aspect other than 1 --
# "Conflicting attributes ... pixelAspectRatio" -- so pixel aspect is checked
# against the camera's view frame below instead.)


@pytest.mark.parametrize("case", list(CYCLES_CASES))
def test_bake_matches_cycles_passes(case, tmp_path):
    (w, h), aspect, fit, shift = CYCLES_CASES[case]
    scene = set_render(w, h, pixel_aspect=aspect)
    # Smooth sphere with some flat faces (or sharp edges), moved, rotated and non-uniformly scaled: Cycles
    # shades these with vertex or corner normals depending on its version.
    if case == "sharp-edges":
        obj = add_uv_sphere(segments=20, rings=10)
        sharp = obj.data.attributes.new("sharp_edge", "BOOLEAN", "EDGE")
        sharp.data.foreach_set("value", np.arange(len(obj.data.edges)) % 4 == 0)
    else:
        obj = add_uv_sphere(segments=20, rings=10, flat_faces=range(0, 200, 3))
    obj.location = (0.2, -0.1, 0.3)
    obj.rotation_euler = (0.3, 0.2, 0.5)
    obj.scale = (1.0, 1.2, 0.9)
    bpy.context.view_layer.objects.active = obj
    cam = add_camera("probe_cam", (4.0, -3.0, 1.5), look_at=(0.3, 0.0, 0.4), lens=45, sensor_fit=fit, shift=shift)
    set_background(cam, make_image("probe", synth_photo(w, h)))
    # An image plane and an occluder: our rays must ignore them (hidden from Cycles too).
    plane = add_image_plane(cam, make_image("plane_photo", synth_photo(w, h)))
    plane.hide_render = True
    bpy.context.view_layer.update()

    inputs = gather(scene, object_name=obj.name)
    assert inputs.views[0].photo.shape == (h, w, 3)
    ours = bake_views(scene, inputs)[0]
    ref = render_cycles(scene, cam, str(tmp_path), passes=("position", "normal", "uv"))

    hit = ref["rgba"][:, :, 3] > 0.5
    assert 0.15 < hit.mean() < 0.9  # the mesh fills part of the frame, not all of it
    assert (hit == ours.mask).mean() >= 0.99
    both = hit & ours.mask
    pos_err = np.linalg.norm(ref["position"][both] - ours.position[both], axis=1)
    assert np.percentile(pos_err, 99) < 2e-3 and np.median(pos_err) < 2e-4
    nrm_err = np.linalg.norm(ref["normal"] - ours.normal, axis=2)
    assert np.median(nrm_err[both]) < 1e-3
    # At grazing angles Cycles bends the shading normal towards the viewer (its
    # fix for smooth normals that face away); away from them, the normals agree,
    # but for a pixel here and there on an edge of a flat face, where the normal
    # jumps and Cycles' sample may land 0.005 px across.
    facing = both & (ours.view_weight > 0.3)
    assert facing.sum() > 0.5 * both.sum()
    assert (nrm_err[facing] > 2e-3).mean() < 0.01
    # The UV pass's channels are U, V and a constant third one.
    uv_ref = ref["uv"][:, :, [1, 2]] if ref["uv"].shape[2] == 3 else ref["uv"][:, :, :2]
    uv_err = np.abs(uv_ref[both] - ours.uv[both]).max(axis=1)
    assert np.percentile(uv_err, 99) < 2e-3

    # Outside the mask: the documented fill values.
    assert np.isnan(ours.position[~ours.mask]).all()
    assert not ours.normal[~ours.mask].any() and not ours.view_weight[~ours.mask].any()
    # view_weight is the cosine between the normal and the direction to the camera.
    to_cam = inputs.views[0].camera.center - ours.position[ours.mask]
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
    cos = np.clip(np.sum(to_cam * ours.normal[ours.mask], axis=1), 0, 1)
    np.testing.assert_allclose(ours.view_weight[ours.mask], cos, atol=1e-5)


@pytest.mark.parametrize("fit", ["AUTO", "HORIZONTAL", "VERTICAL"])
@pytest.mark.parametrize("size,aspect", [((64, 48), (1.0, 1.0)), ((48, 64), (1.3, 1.0)), ((60, 40), (1.0, 1.5))])
def test_camera_frame_matches_blender_view_frame(fit, size, aspect):
    """The frame corners Blender draws project onto the outer pixel edges of the photo."""
    from mathutils import Vector

    scene = set_render(*size, pixel_aspect=aspect)
    bpy.context.view_layer.objects.active = add_uv_sphere()
    cam = add_camera("f_cam", (3.0, -4.0, 2.0), lens=40, sensor_fit=fit, shift=(0.07, -0.11), sensor=(30.0, 21.0))
    set_background(cam, make_image("f", synth_photo(*size)))
    bpy.context.view_layer.update()
    camera = gather(scene).views[0].camera
    corners = [cam.matrix_world @ Vector(c) for c in cam.data.view_frame(scene=scene)]
    xy, depth = camera.project(np.array([tuple(c) for c in corners]))
    assert (depth > 0).all()
    w, h = size
    expected = np.array(sorted([(w - 0.5, -0.5), (w - 0.5, h - 0.5), (-0.5, h - 0.5), (-0.5, -0.5)]))
    dist = np.linalg.norm(expected[:, None] - xy[None], axis=2)
    assert dist.min(axis=1).max() < 1e-4  # each corner found (mathutils works in float32)


def test_mesh_arrays_are_evaluated_world_space():
    set_render(32, 24)
    obj = add_uv_sphere(radius=1.0, segments=12, rings=6)
    obj.location, obj.scale = (1.0, 2.0, 3.0), (2.0, 2.0, 2.0)
    mod = obj.modifiers.new("subdiv", "SUBSURF")
    mod.levels = 1
    bpy.context.view_layer.objects.active = obj
    cam = add_camera("a_cam", (10.0, 2.0, 3.0), look_at=(1.0, 2.0, 3.0))
    set_background(cam, make_image("a", synth_photo(32, 24)))
    inputs = gather(bpy.context)
    mesh = inputs.mesh
    # Subdivision turns an n-gon into n quads, i.e. 2n triangles.
    assert mesh.tri_pos.shape[0] == sum(2 * len(p.vertices) for p in obj.data.polygons)
    r = np.linalg.norm(mesh.tri_pos - np.array([1.0, 2.0, 3.0]), axis=2)
    assert 1.8 < r.min() and r.max() < 2.0 + 1e-6  # world space, scaled by 2 (subdivision shrinks)
    assert mesh.tri_uv.shape == mesh.tri_pos.shape[:2] + (2,) and mesh.tri_uv.dtype == np.float32
    assert mesh.uv_map == "UVMap"
    np.testing.assert_allclose(np.linalg.norm(mesh.tri_normal, axis=2), 1.0, atol=1e-5)
    assert inputs.object_name == obj.name and [v.name for v in inputs.views] == ["a_cam"]


# --- photos -----------------------------------------------------------------------------------------


def one_camera_on_a_sphere():
    """A 16 x 12 render of a UV sphere through one camera, "p_cam", which has no photo yet: (scene, camera)."""
    scene = set_render(16, 12)
    bpy.context.view_layer.objects.active = add_uv_sphere()
    return scene, add_camera("p_cam", (6.0, 0.0, 0.0))


def test_png_photo_is_decoded_through_its_colour_space(tmp_path):
    scene, cam = one_camera_on_a_sphere()
    codes = np.full((12, 16, 3), 188, np.uint8)
    codes[0, 0] = (255, 0, 10)  # top-left pixel: checks the row order
    codes[5, 7] = (4, 100, 250)
    path = write_png(str(tmp_path / "p.png"), codes)
    img = bpy.data.images.load(path)
    set_background(cam, img)
    images_before = len(bpy.data.images)
    scenes_before = len(bpy.data.scenes)
    assert img.colorspace_settings.name == "sRGB"
    photo = gather(scene).views[0].photo
    assert len(bpy.data.images) == images_before and len(bpy.data.scenes) == scenes_before
    assert photo.dtype == np.float32 and photo.shape == (12, 16, 3)
    assert abs(photo[6, 3, 0] - 0.5029) < 1e-3  # code 188 is linear 0.5029
    np.testing.assert_allclose(photo, srgb_to_linear(codes / 255.0), rtol=1e-4, atol=1e-5)
    # The user's choice of colour space is respected: Non-Color means the codes are the values.
    img.colorspace_settings.name = "Non-Color"
    np.testing.assert_allclose(gather(scene).views[0].photo, codes / 255.0, atol=2e-5)
    img.colorspace_settings.name = "sRGB"
    np.testing.assert_allclose(photo[0, 0], [1.0, 0.0, 0.0030353], rtol=1e-4, atol=1e-5)
    # An 8-bit photo knows where it clipped: the two pixels with a channel at 250 or more.
    assert gather(scene).views[0].clipped.tolist() == np.any(codes >= 250, axis=2).tolist()


def test_a_photo_with_alpha_gives_its_straight_colour(tmp_path):
    scene, cam = one_camera_on_a_sphere()
    codes = np.full((12, 16, 4), 255, np.uint8)
    codes[..., :3] = 188
    codes[2, 3] = (40, 200, 120, 128)  # half covered: its colour, not its colour times one half
    codes[7, 9] = (90, 90, 90, 0)  # not covered at all: nothing
    img = bpy.data.images.load(write_png(str(tmp_path / "a.png"), codes))
    set_background(cam, img)
    photo = gather(scene).views[0].photo
    expect = srgb_to_linear(codes[..., :3] / 255.0)
    expect[7, 9] = 0.0
    np.testing.assert_allclose(photo, expect, rtol=1e-3, atol=1e-5)


def test_an_opaque_photo_is_converted_without_its_alpha_to_the_same_colours(tmp_path):
    # Every alpha code 255: Blender's conversion writes RGB only. The colours must be those of the RGBA path.
    codes = np.random.default_rng(3).integers(0, 256, (12, 16, 3)).astype(np.uint8)
    img = bpy.data.images.load(write_png(str(tmp_path / "o.png"), codes))
    try:
        rgb = _byte_image_linear(img, opaque=True)
        assert rgb.shape == (12, 16, 3) and rgb.dtype == np.float32
        assert np.array_equal(rgb, _byte_image_linear(img, opaque=False))
        np.testing.assert_allclose(rgb, srgb_to_linear(codes / 255.0), rtol=1e-4, atol=1e-5)
    finally:
        bpy.data.images.remove(img)


@pytest.mark.parametrize(
    "space", ["sRGB", "Non-Color", "Linear Rec.2020", "ACEScg", "Filmic Log", "Khronos PBR Neutral sRGB"]
)
def test_an_8bit_photo_gets_the_colours_of_blenders_conversion_of_the_whole_photo(tmp_path, space):
    # Each code's colour comes from a small probe image that Blender converts; the photo's pixels must be those
    # Blender gives the whole photo, in a colour space with a curve per channel, a matrix, a log curve, and one
    # that mixes the channels (which tables cannot follow: converted whole).
    codes = np.random.default_rng(5).integers(0, 256, (30, 44, 3)).astype(np.uint8)
    codes[4, 5] = (255, 252, 3)
    img = bpy.data.images.load(write_png(str(tmp_path / "c.png"), codes))
    try:
        img.colorspace_settings.name = space
        whole = _byte_image_linear(img, opaque=True)
        info = {}
        got = image_pixels(img, "cam", info=info)
        assert got.shape == whole.shape and got.dtype == np.float32
        np.testing.assert_allclose(got, whole, rtol=0, atol=1e-6 * max(1.0, float(np.abs(whole).max())))
        assert info["clipped"].tolist() == np.any(codes >= 250, axis=2).tolist()
        assert (_code_tables(img) is None) == (space == "Khronos PBR Neutral sRGB")
    finally:
        bpy.data.images.remove(img)


def test_photos_read_beside_their_conversion_give_the_same_views(tmp_path):
    # The conversions run on threads of their own while the next photo is read: the views, their order and the
    # camera skipped for its NaN pixels must be those of reading one photo after the other.
    s = build_scene(str(tmp_path), n_cameras=5, size=(40, 30), photo="dir", kind="exr")
    bad = synth_photo(40, 30)
    bad[3, 4, 1] = np.nan
    write_exr(str(tmp_path / "view2.exr"), bad)
    one, two = (gather(s.scene, images_dir=str(tmp_path), working_res_mp=0.0004, threads=t) for t in (1, 2))
    assert [v.name for v in one.views] == [v.name for v in two.views] == [f"view{i}_cam" for i in (0, 1, 3, 4)]
    assert one.skipped == two.skipped and len(one.skipped) == 1 and "NaN" in one.skipped[0]
    for a, b in zip(one.views, two.views):
        assert a.photo.shape == (17, 23, 3) and np.array_equal(a.photo, b.photo)
        assert np.array_equal(a.camera.K, b.camera.K)


def test_float_photo_has_no_clipped_pixels(tmp_path):
    s = build_scene(str(tmp_path), n_cameras=1, size=(16, 12), kind="exr")
    assert gather(s.scene).views[0].clipped is None


def test_photo_sources_background_plane_and_folder(tmp_path):
    folder = tmp_path / "photos"
    folder.mkdir()
    s = build_scene(str(tmp_path), n_cameras=3, size=(40, 30), photo="dir", kind="exr")
    cam_bg, cam_plane, cam_dir = s.cameras
    # Folder files exist for all three; background and plane must win over them.
    for cam in s.cameras:
        os.replace(s.images[cam.name], folder / os.path.basename(s.images[cam.name]))
    expected = {c.name: synth_photo(40, 30, seed=i) for i, c in enumerate(s.cameras)}
    other = synth_photo(40, 30, seed=7)
    set_background(cam_bg, make_image("bg", other, kind="exr", folder=str(tmp_path)))
    plane_img = make_image("pl", other[::-1].copy(), kind="exr", folder=str(tmp_path))
    add_image_plane(cam_plane, plane_img)
    # Background images win over planes: give the first camera a plane too.
    add_image_plane(cam_bg, make_image("decoy", expected[cam_bg.name], kind="exr", folder=str(tmp_path)))
    bpy.context.view_layer.update()

    before = data_counts()
    inputs = gather(s.scene, images_dir=str(folder))
    assert data_counts() == before  # the folder's image was loaded and removed again
    views = {v.name: v for v in inputs.views}
    np.testing.assert_allclose(views[cam_bg.name].photo, other, atol=1e-6)
    assert "background image 'bg.exr'" in views[cam_bg.name].source
    np.testing.assert_allclose(views[cam_plane.name].photo, other[::-1], atol=1e-6)
    assert "image plane 'view1_image_plane'" in views[cam_plane.name].source
    np.testing.assert_allclose(views[cam_dir.name].photo, expected[cam_dir.name], atol=1e-6)
    assert views[cam_dir.name].source == str(folder / "view2.exr")
    # The image plane stands between its camera and the mesh, yet does not occlude it.
    bake = bake_views(s.scene, inputs)[1]
    assert bake.mask[15, 20]


def test_working_resolution_downscales_photo_and_camera(tmp_path):
    scene = set_render(300, 200)
    obj = add_uv_sphere()
    bpy.context.view_layer.objects.active = obj
    cam = add_camera("w_cam", (5.0, 1.0, 0.5), shift=(0.1, -0.05))
    photo = synth_photo(300, 200)
    set_background(cam, make_image("w", photo))
    full = gather(scene, working_res_mp=None).views[0]
    small = gather(scene, working_res_mp=0.01).views[0]  # 60000 px -> at most 10000
    h2, w2 = small.photo.shape[:2]
    assert h2 * w2 <= 10000 and (w2, h2) == (122, 81)
    assert (small.camera.width, small.camera.height) == (w2, h2)
    np.testing.assert_allclose(small.photo.mean(axis=(0, 1)), photo.mean(axis=(0, 1)), rtol=2e-3)
    # The same world point lands on the same place of the frame, in edge coordinates.
    pts = np.array([[0.0, 0.0, 0.0], [0.3, -0.4, 0.5]])
    xy_full, _ = full.camera.project(pts)
    xy_small, _ = small.camera.project(pts)
    np.testing.assert_allclose((xy_small + 0.5) / [w2, h2], (xy_full + 0.5) / [300, 200], atol=1e-9)
    # Box filter: a 2x2 block average for an exact factor 2.
    img = np.random.default_rng(0).random((8, 6, 3)).astype(np.float32)
    out, scale = downscale(img, 12e-6)
    assert out.shape == (4, 3, 3) and scale == (0.5, 0.5)
    np.testing.assert_allclose(out, img.reshape(4, 2, 3, 2, 3).mean(axis=(1, 3)), atol=1e-6)


def test_the_working_total_shares_its_megapixels_among_the_photos(tmp_path):
    scene = set_render(300, 200)
    bpy.context.view_layer.objects.active = add_uv_sphere()
    for k in range(4):
        cam = add_camera(f"t_cam{k}", (5.0, 1.0 + k, 0.5))
        set_background(cam, make_image(f"t{k}", synth_photo(300, 200)))
    messages = []
    capped = gather(scene, working_res_mp=0.03, working_total_mp=0.04, progress=lambda f, m: messages.append(m))
    # 4 photos of 60000 px: 0.03 MP each would make 0.12 MP, so each gets 0.01 MP.
    assert [v.photo.shape[:2] for v in capped.views] == [(81, 122)] * 4
    assert [(v.camera.width, v.camera.height) for v in capped.views] == [(122, 81)] * 4
    assert any("each at most 0.01 MP, 0.04 MP in all (working total)" in m for m in messages), messages
    # Photos within the working resolution have no detail beyond it: none is kept for the detail stage.
    kept = gather(scene, working_res_mp=0.1, working_total_mp=0.04, keep_full=lambda photo, clipped: None).views
    assert [v.photo.shape[:2] for v in kept] == [(81, 122)] * 4 and all(v.full is None for v in kept)
    kept = gather(scene, working_res_mp=0.03, working_total_mp=0.04, keep_full=lambda photo, clipped: None).views
    assert all(v.full is not None and v.full.camera.width == 300 for v in kept)
    # Photos kept whole (no working resolution) are brought to the total as well, and, all within it, kept
    # for no detail stage.
    whole = gather(scene, working_res_mp=None, working_total_mp=0.04, keep_full=lambda photo, clipped: None).views
    assert [v.photo.shape[:2] for v in whole] == [(81, 122)] * 4 and all(v.full is None for v in whole)
    # A total the photos fit in, or none, leaves the working resolution as it is.
    for total in (0.5, 0, None):
        assert [v.photo.shape[:2] for v in gather(scene, working_res_mp=0.03, working_total_mp=total).views] == [
            (141, 212)
        ] * 4


def test_a_downscaled_8bit_photo_is_kept_as_its_codes_and_a_float_one_as_floats(tmp_path):
    scene = set_render(300, 200)
    bpy.context.view_layer.objects.active = add_uv_sphere()
    cam = add_camera("k_cam", (5.0, 1.0, 0.5))
    codes = np.random.default_rng(3).integers(0, 256, (200, 300, 3)).astype(np.uint8)
    set_background(cam, bpy.data.images.load(write_png(str(tmp_path / "k.png"), codes)))
    kept = []

    def keep(photo, clipped):
        kept.append((photo, clipped))
        return lambda: (photo, clipped)

    assert gather(scene, working_res_mp=0.01, keep_full=keep).views[0].full is not None
    whole = gather(scene, working_res_mp=None).views[0]
    photo, clipped = kept.pop()
    assert isinstance(photo, CodedPhoto) and photo.shape == (200, 300, 3)
    np.testing.assert_array_equal(photo.codes, codes)  # the file's codes, row 0 at the top: a byte a channel
    np.testing.assert_array_equal(photo.colours(), whole.photo)  # the colours of the photo read whole, to the bit
    np.testing.assert_array_equal(clipped, whole.clipped)
    cam.data.background_images[0].image = make_image("k_float", synth_photo(300, 200))
    gather(scene, working_res_mp=0.01, keep_full=keep)
    photo, clipped = kept.pop()
    assert isinstance(photo, np.ndarray) and photo.dtype == np.float32 and clipped is None


def test_camera_selection(tmp_path):
    s = build_scene(str(tmp_path), n_cameras=4, size=(24, 18))
    names = [c.name for c in s.cameras]
    assert [v.name for v in gather(s.scene).views] == sorted(names)
    assert [v.name for v in gather(s.scene, camera_names=[names[2], names[0]]).views] == [names[2], names[0]]
    for c in s.cameras:
        c.select_set(False)
    s.cameras[1].select_set(True)
    assert [v.name for v in gather(s.scene, selected_only=True).views] == [names[1]]


# --- errors: one clear message, nothing changed ------------------------------------------------------


def _expect_error(match, fn, *args, **kw):
    before = data_counts()
    with pytest.raises(DelightError, match=match) as info:
        fn(*args, **kw)
    assert data_counts() == before
    assert "\n" not in str(info.value)
    return str(info.value)


def test_error_no_mesh_and_not_a_mesh(tmp_path):
    s = build_scene(str(tmp_path), n_cameras=1, size=(16, 12))
    bpy.data.objects.remove(s.obj)
    bpy.context.view_layer.objects.active = None
    _expect_error("has no mesh to delight", gather, s.scene)


def test_the_mesh_the_cameras_see_is_found(tmp_path):
    # As Photogrammetry Importer leaves a scene: a camera active, image planes beside the mesh.
    s = build_scene(str(tmp_path), n_cameras=3, size=(16, 12), photo="plane")
    far = add_uv_sphere("Unseen", location=(0.0, 0.0, 60.0))
    bpy.context.view_layer.update()
    bpy.context.view_layer.objects.active = s.cameras[0]
    assert gather(s.scene).object_name == "Target"
    bpy.context.view_layer.objects.active = None
    assert gather(s.scene).object_name == "Target"
    # Two meshes in every camera's view: no guess, the candidates are named.
    far.location = (0.0, 0.0, 0.2)
    bpy.context.view_layer.update()
    msg = _expect_error("several meshes could be the target", gather, s.scene)
    assert "'Target'" in msg and "'Unseen'" in msg and "--object NAME" in msg
    assert "_image_plane" not in msg


def test_named_object_errors(tmp_path):
    s = build_scene(str(tmp_path), n_cameras=1, size=(16, 12))
    _expect_error("no object named 'Nope'", gather, s.scene, object_name="Nope")
    _expect_error("'view0_cam' is a camera, not a mesh", gather, s.scene, object_name="view0_cam")


def test_error_mesh_without_uvs(tmp_path):
    s = build_scene(str(tmp_path), n_cameras=1, size=(16, 12))
    s.obj.data.uv_layers.remove(s.obj.data.uv_layers[0])
    _expect_error("mesh 'Target' has no UV map", gather, s.scene)


def test_error_no_cameras():
    set_render(16, 12)
    bpy.context.view_layer.objects.active = add_uv_sphere()
    _expect_error("has no cameras", gather, bpy.context.scene)
    _expect_error("no camera named 'x'", gather, bpy.context.scene, camera_names=["x"])


def test_error_camera_without_photo(tmp_path):
    s = build_scene(str(tmp_path), n_cameras=2, size=(16, 12), photo=None)
    msg = _expect_error("camera 'view0_cam' has no photo", gather, s.scene, images_dir=str(tmp_path))
    assert "background" in msg and "view0_image_plane" in msg and str(tmp_path) in msg
    _expect_error("images folder .* does not exist", gather, s.scene, images_dir=str(tmp_path / "nope"))


def test_error_missing_image_file(tmp_path):
    s = build_scene(str(tmp_path), n_cameras=2, size=(16, 12), kind="exr")
    img = s.images["view1_cam"]
    os.remove(bpy.path.abspath(img.filepath))
    _expect_error("camera 'view1_cam': cannot read its photo 'view1.exr' \\(.*view1.exr\\) \\(missing", gather, s.scene)


def test_an_empty_photo_in_the_images_folder_is_named_by_its_path(tmp_path):
    s = build_scene(str(tmp_path), n_cameras=2, size=(16, 12), photo="dir", kind="exr")
    (tmp_path / "view1.exr").write_bytes(b"")
    msg = _expect_error("camera 'view1_cam': cannot read its photo", gather, s.scene, images_dir=str(tmp_path))
    assert str(tmp_path / "view1.exr") in msg and ".001" not in msg


def test_error_nan_in_exr_photo(tmp_path):
    for where in ("background", "dir"):
        bpy.ops.wm.read_homefile(use_empty=True)
        folder = tmp_path / where
        folder.mkdir()
        s = build_scene(str(folder), n_cameras=2, size=(16, 12), photo=where, kind="exr")
        bad = synth_photo(16, 12)
        bad[3, 4, 1] = np.nan
        write_exr(str(folder / "view1.exr"), bad)
        if where == "background":
            s.images["view1_cam"].reload()
        _expect_error(
            "camera 'view1_cam': its photo .* has 1 NaN or infinite pixels", gather, s.scene, images_dir=str(folder)
        )


def test_error_photo_aspect_does_not_match(tmp_path):
    s = build_scene(str(tmp_path), n_cameras=2, size=(64, 48))
    s.cameras[1].data.background_images[0].image = make_image("square", synth_photo(48, 48))
    msg = _expect_error("camera 'view1_cam': its photo is 48x48", gather, s.scene)
    assert "64x48" in msg
    # One pixel of rounding is fine.
    s.cameras[1].data.background_images[0].image = make_image("rounded", synth_photo(65, 48))
    assert gather(s.scene).views[1].photo.shape == (48, 65, 3)


def test_error_non_perspective_cameras_are_all_named(tmp_path):
    s = build_scene(str(tmp_path), n_cameras=4, size=(16, 12))
    s.cameras[0].data.type = "ORTHO"
    s.cameras[2].data.type = "PANO"
    msg = _expect_error(
        "only perspective cameras are supported", gather, s.scene, camera_names=[c.name for c in s.cameras]
    )
    assert "'view0_cam' (ortho)" in msg and "'view2_cam' (pano)" in msg
    # With all cameras, they are left out while two perspective ones remain.
    inputs = gather(s.scene)
    assert [v.name for v in inputs.views] == ["view1_cam", "view3_cam"] and len(inputs.skipped) == 2
    s.cameras[1].data.type = "ORTHO"
    _expect_error("only perspective cameras are supported", gather, s.scene)


def test_error_mesh_no_camera_sees(tmp_path):
    s = build_scene(str(tmp_path), n_cameras=2, size=(16, 12))
    for cam in s.cameras:  # look away from the mesh
        cam.rotation_euler.z += np.pi
    bpy.context.view_layer.update()
    inputs = gather(s.scene)
    _expect_error("no camera sees the mesh 'Target'", bake_views, s.scene, inputs)


def test_bake_cancel_and_progress(tmp_path):
    from blender_addon.core.errors import Cancelled  # the add-on's own copy of core

    s = build_scene(str(tmp_path), n_cameras=3, size=(16, 12))
    inputs = gather(s.scene)
    seen = []
    bakes = bake_views(s.scene, inputs, progress=lambda f, m: seen.append(f))
    assert len(bakes) == 3 and all(b.mask.any() for b in bakes)
    assert seen[0] == 0.0 and seen[-1] == 1.0 and seen == sorted(seen)
    calls = []
    with pytest.raises(Cancelled):
        bake_views(s.scene, inputs, cancel=lambda: calls.append(1) or len(calls) > 1)
    assert len(calls) == 2


# --- background kinds and unusable cameras ------------------------------------------------------------


def test_image_sequence_background_gives_each_camera_its_frame(tmp_path):
    from blender_addon.core.io.exr import write_exr

    s = build_scene(str(tmp_path), n_cameras=3, size=(16, 12), photo=None)
    frames = [np.full((12, 16, 3), 0.1 * (k + 1), np.float32) for k in range(3)]
    for k, f in enumerate(frames):
        write_exr(str(tmp_path / f"shot_{k + 1:04d}.exr"), f)
    seq = bpy.data.images.load(str(tmp_path / "shot_0001.exr"))
    seq.source = "SEQUENCE"
    for k, cam in enumerate(s.cameras):
        bg = set_background(cam, seq)
        bg.image_user.frame_start, bg.image_user.frame_duration = 1, 3
        bg.image_user.frame_offset = k  # camera k shows frame k + 1 at the scene's frame 1
    s.scene.frame_current = 1
    counts = data_counts()
    views = gather(s.scene).views
    assert data_counts() == counts
    for k, v in enumerate(views):
        np.testing.assert_allclose(v.photo, frames[k], atol=1e-6)
        assert f"shot_{k + 1:04d}.exr" in v.source


def test_movie_and_movie_clip_backgrounds_say_what_to_do(tmp_path):
    from blender_addon.core.io.exr import write_exr

    s = build_scene(str(tmp_path), n_cameras=2, size=(16, 12))
    movie = s.cameras[0].data.background_images[0].image
    movie.source = "MOVIE"
    msg = _expect_error("is a movie", gather, s.scene, camera_names=[s.cameras[0].name])
    assert "export the frames as images" in msg
    write_exr(str(tmp_path / "clip_0001.exr"), np.zeros((12, 16, 3), np.float32))
    cam = s.cameras[1]
    cam.data.background_images.clear()
    bg = cam.data.background_images.new()
    bg.source = "MOVIE_CLIP"
    bg.clip = bpy.data.movieclips.load(str(tmp_path / "clip_0001.exr"))
    msg = _expect_error("movie clip", gather, s.scene, camera_names=[cam.name])
    assert "one camera per photo" in msg


def test_with_all_cameras_an_unusable_one_is_skipped_while_two_remain(tmp_path):
    s = build_scene(str(tmp_path), n_cameras=3, size=(16, 12))
    bad = s.cameras[1]
    bad.data.background_images.clear()
    inputs = gather(s.scene)
    assert [v.name for v in inputs.views] == [s.cameras[0].name, s.cameras[2].name]
    assert len(inputs.skipped) == 1 and repr(bad.name) in inputs.skipped[0] and "has no photo" in inputs.skipped[0]
    # Named cameras: the user asked for this one, so it is an error.
    _expect_error("has no photo", gather, s.scene, camera_names=[c.name for c in s.cameras])
    # Fewer than two usable cameras left: an error, not a one-view solve.
    s.cameras[2].data.background_images.clear()
    _expect_error("has no photo", gather, s.scene)
