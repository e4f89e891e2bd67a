"""The run end to end on a real bpy scene: files, image, material, re-run, cancel, errors."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from conftest import build_scene, new_material  # noqa: E402
from scene_state import files_under, scene_state  # noqa: E402

from blender_addon import pipeline  # noqa: E402
from blender_addon.core.errors import (  # noqa: E402
    Cancelled,
    DelightError,  # noqa: E402
)
from blender_addon.core.io.exr import read_exr  # noqa: E402
from blender_addon.core.io.names import safe_name, unique_names  # noqa: E402

pytestmark = pytest.mark.bpy

N = 32


def options(out, **kw):
    kw.setdefault("method", "project")
    kw.setdefault("texture_size", N)
    kw.setdefault("max_iter", 3)
    return pipeline.Options(out_dir=str(out), **kw)


def original_material(obj):
    """A material whose Base Color comes from an image through a Mapping node (the "original")."""
    mat = new_material("Photo")
    nt = mat.node_tree
    img = bpy.data.images.new("photo_bake", 4, 4)
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.name, tex.image = "Orig Tex", img
    mapping = nt.nodes.new("ShaderNodeMapping")
    mapping.name = "Orig Mapping"
    nt.links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
    nt.links.new(tex.outputs["Color"], nt.nodes["Principled BSDF"].inputs["Base Color"])
    obj.data.materials.append(mat)
    return mat


def snapshot(folder):
    """Every file under ``folder``: relative path -> bytes."""
    return {p: (folder / p).read_bytes() for p in files_under(folder) if (folder / p).is_file()}


def base_color_source(mat):
    links = mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].links
    return links[0].from_node if links else None


def test_project_writes_the_promised_files(tmp_path):
    s = build_scene(str(tmp_path))
    out = tmp_path / "out"
    messages = []
    rep = pipeline.run(s.scene, options(out), progress=lambda f, m: messages.append((f, m)))

    names = [c.name for c in s.cameras]
    assert rep.cameras == names
    assert files_under(out) == sorted(
        ["Target_albedo.exr", "lighting.json", "report.json", "views"] + [f"views/{n}.exr" for n in names]
    )
    albedo, ch = read_exr(out / "Target_albedo.exr")
    assert ch == ["R", "G", "B", "A"] and albedo.shape == (N, N, 4) and albedo.dtype == np.float32
    a = albedo[..., 3]
    assert set(np.unique(a)) == {0.0, 1.0}  # seen / filled
    assert 0.05 < a.mean() < 0.95
    assert np.isfinite(albedo).all()
    # Project = the photos fused: every seen texel lies within the photos' range.
    photos = [np.asarray(img.pixels[:], np.float32).reshape(48, 64, 4)[..., :3] for img in s.images.values()]
    lo, hi = min(p.min() for p in photos), max(p.max() for p in photos)
    seen_rgb = albedo[a == 1, :3]
    assert seen_rgb.min() >= lo - 1e-4 and seen_rgb.max() <= hi + 1e-4

    # The sphere's UV: u wraps around, so the top rows (v near 1, the pole) and
    # the middle band are both mapped; the view maps are on each photo's grid.
    for n in names:
        v, vch = read_exr(out / "views" / f"{n}.exr")
        assert v.shape == (48, 64, 4) and vch == ["R", "G", "B", "A"]
        assert 0 < v[..., 3].sum() < 48 * 64

    light = json.loads((out / "lighting.json").read_text())
    assert [v["name"] for v in light["views"]] == names and len(light["sh_basis"]) == 9
    assert all(v["sh"] is None for v in light["views"])  # project estimates no lighting
    assert light["world"] is None  # and writes no lighting.exr (the file list above)
    report = json.loads((out / "report.json").read_text())
    assert report["method"] == "project" and report["object"] == "Target"
    assert set(report["times_s"]) >= {"gather", "bake", "solve", "fuse", "write"}
    assert all(t >= 0 for t in report["times_s"].values())
    assert report["parameters"]["texture_size"] == N
    assert [c["name"] for c in report["cameras"]] == names
    # Progress went forward from 0 to 1 through every stage.
    fractions = [f for f, _ in messages]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    assert {m.split(":")[0] for _, m in messages} >= {"gather", "bake", "solve", "fuse", "write"}

    # The packed image holds the same pixels, Blender's rows bottom-up.
    img = bpy.data.images[rep.image_name]
    assert rep.image_name == "Target_albedo" and img.packed_file is not None
    assert tuple(img.size) == (N, N) and img.colorspace_settings.name == "Linear Rec.709"
    px = np.empty(N * N * 4, np.float32)
    img.pixels.foreach_get(px)
    np.testing.assert_allclose(px.reshape(N, N, 4)[::-1], albedo, atol=1e-6)


def test_material_gets_our_node_and_keeps_the_original(tmp_path):
    s = build_scene(str(tmp_path))
    mat = original_material(s.obj)
    rep = pipeline.run(s.scene, options(tmp_path / "out"))
    assert rep.materials == ["Photo"]
    nt = mat.node_tree
    ours = base_color_source(mat)
    assert ours.name == "Delight Albedo" and ours.image.name == "Target_albedo"
    uvnode = ours.inputs["Vector"].links[0].from_node
    assert uvnode.bl_idname == "ShaderNodeUVMap" and uvnode.uv_map == "UVMap"
    orig = nt.nodes["Orig Tex"]
    assert orig.image.name == "photo_bake"
    assert not orig.outputs["Color"].links  # unlinked
    assert orig.parent is not None and orig.parent.label == "Delight: original"
    assert nt.nodes["Orig Mapping"].parent == orig.parent
    assert nt.nodes["Orig Mapping"].outputs["Vector"].links[0].to_node == orig  # its own chain is intact


def test_material_is_created_when_the_mesh_has_none(tmp_path):
    s = build_scene(str(tmp_path))
    pipeline.run(s.scene, options(tmp_path / "out"))
    mats = [sl.material for sl in s.obj.material_slots]
    assert [m.name for m in mats] == ["Target_material"]
    assert base_color_source(mats[0]).image.name == "Target_albedo"
    assert not [n for n in mats[0].node_tree.nodes if n.bl_idname == "NodeFrame"]  # nothing to keep


def test_rerun_replaces_our_nodes_instead_of_stacking(tmp_path):
    s = build_scene(str(tmp_path))
    mat = original_material(s.obj)
    pipeline.run(s.scene, options(tmp_path / "out"))
    first = scene_state()
    # Another texture size: a new image replaces the old one under the same name, and the
    # files of the first run are replaced without overwrite (they are Delight's own).
    rep = pipeline.run(s.scene, options(tmp_path / "out", texture_size=16))
    second = scene_state()
    assert first["trees"] == second["trees"] and first["images"] == second["images"]
    assert tuple(bpy.data.images[rep.image_name].size) == (16, 16)
    frames = [n for n in mat.node_tree.nodes if n.bl_idname == "NodeFrame"]
    assert len(frames) == 1 and mat.node_tree.nodes["Orig Tex"].parent == frames[0]
    assert base_color_source(mat).name == "Delight Albedo"


def test_rerun_frames_a_new_source_the_user_linked(tmp_path):
    s = build_scene(str(tmp_path))
    mat = original_material(s.obj)
    pipeline.run(s.scene, options(tmp_path / "out"))
    nt = mat.node_tree
    rgb = nt.nodes.new("ShaderNodeRGB")
    nt.links.new(rgb.outputs[0], nt.nodes["Principled BSDF"].inputs["Base Color"])
    pipeline.run(s.scene, options(tmp_path / "out", overwrite=True))
    frames = [n for n in nt.nodes if n.bl_idname == "NodeFrame"]
    assert len(frames) == 1 and rgb.parent == frames[0] and not rgb.outputs[0].links
    assert base_color_source(mat).name == "Delight Albedo"
    assert len([n for n in nt.nodes if n.get("delight") == "albedo"]) == 1


@pytest.mark.parametrize("stage", ["gather", "bake", "solve", "fuse"])
def test_cancel_leaves_scene_and_folder_unchanged(tmp_path, stage):
    s = build_scene(str(tmp_path))
    original_material(s.obj)
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("user file")
    before = scene_state()
    current = {"stage": None, "seen": []}

    def progress(fraction, message):
        current["stage"] = message.split(":")[0]
        current["seen"].append(current["stage"])

    with pytest.raises(Cancelled):
        pipeline.run(
            s.scene, options(out, method="texture"), progress=progress, cancel=lambda: current["stage"] == stage
        )
    assert current["stage"] == stage  # honoured within that stage
    assert "write" not in current["seen"]
    assert scene_state() == before
    assert files_under(out) == ["keep.txt"]


def test_existing_output_is_not_overwritten(tmp_path):
    s = build_scene(str(tmp_path))
    out = tmp_path / "out"
    out.mkdir()
    (out / "report.json").write_text("mine")
    before = scene_state()
    with pytest.raises(DelightError, match="report.json already exists and was not written by Delight"):
        pipeline.run(s.scene, options(out))
    assert scene_state() == before
    assert files_under(out) == ["report.json"] and (out / "report.json").read_text() == "mine"
    pipeline.run(s.scene, options(out, overwrite=True))
    assert json.loads((out / "report.json").read_text())["object"] == "Target"


def test_a_cancel_while_writing_keeps_the_earlier_outputs(tmp_path):
    s = build_scene(str(tmp_path))
    out = tmp_path / "out"
    pipeline.run(s.scene, options(out))
    earlier = snapshot(out)
    state = scene_state()
    current = {"stage": None, "checks": 0}

    def progress(fraction, message):
        current["stage"] = message.split(":")[0]

    def cancel():  # the third check in the write stage: after some files were staged
        if current["stage"] == "write":
            current["checks"] += 1
        return current["checks"] == 3

    with pytest.raises(Cancelled):
        pipeline.run(s.scene, options(out, texture_size=16), progress=progress, cancel=cancel)
    assert current["checks"] == 3
    assert snapshot(out) == earlier  # the earlier files, byte for byte; no staging folder
    assert scene_state() == state


def test_hostile_camera_names_stay_inside_out(tmp_path):
    s = build_scene(str(tmp_path))
    hostile = ["../../x", "a/b", "A_B", ".hidden"]
    for cam, name in zip(s.cameras, hostile):
        cam.name = name
    out = tmp_path / "deep" / "out"
    rep = pipeline.run(s.scene, options(out))
    assert sorted(rep.cameras) == sorted(hostile)
    everything = files_under(tmp_path)
    views = [p for p in files_under(out) if p.startswith("views/")]
    assert len(views) == 4 and len(set(p.lower() for p in views)) == 4  # unique, even case-insensitively
    for p in files_under(out):
        assert os.path.realpath(out / p).startswith(os.path.realpath(out) + os.sep)
    assert not any(p.endswith("x.exr") and not p.startswith("deep/out/") for p in everything)
    report = json.loads((out / "report.json").read_text())
    assert sorted(c["name"] for c in report["cameras"]) == sorted(hostile)
    assert all((out / c["file"]).is_file() for c in report["cameras"])


def test_no_camera_sees_the_mesh(tmp_path):
    s = build_scene(str(tmp_path))
    s.obj.location = (0.0, 0.0, 50.0)
    bpy.context.view_layer.update()
    before = scene_state()
    with pytest.raises(DelightError, match="no camera sees"):
        pipeline.run(s.scene, options(tmp_path / "out"))
    assert scene_state() == before
    assert not (tmp_path / "out").exists()


def test_a_camera_that_misses_is_skipped_with_a_warning(tmp_path):
    s = build_scene(str(tmp_path))
    s.cameras[1].rotation_euler = (0.0, 0.0, 0.0)  # looks straight down, away from the sphere
    s.cameras[1].location = (0.0, 0.0, -20.0)
    bpy.context.view_layer.update()
    rep = pipeline.run(s.scene, options(tmp_path / "out"))
    assert s.cameras[1].name not in rep.cameras and len(rep.cameras) == 3
    assert any(s.cameras[1].name in w for w in rep.warnings)


def test_bad_options_are_refused_before_reading_the_scene(tmp_path):
    s = build_scene(str(tmp_path))
    for kw, match in (
        (dict(method="magic"), "method must be one of"),
        (dict(texture_size=4), "texture size"),
        (dict(lam=float("nan")), "lambda"),
        (dict(working_res_mp=0.0), "working resolution"),
    ):
        with pytest.raises(DelightError, match=match):
            pipeline.run(s.scene, options(tmp_path / "out", **kw))
    assert not (tmp_path / "out").exists()


def test_texture_method_delights(tmp_path):
    from threadpoolctl import threadpool_info, threadpool_limits

    s = build_scene(str(tmp_path))
    blas = []  # per progress message, its stage and the BLAS libraries' threads
    with threadpool_limits(limits=2, user_api="blas"):  # the tests run with OPENBLAS_NUM_THREADS=1
        rep = pipeline.run(
            s.scene,
            options(tmp_path / "out", method="texture", max_iter=3),
            progress=lambda f, m: blas.append(
                (m.split(":")[0], {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"})
            ),
        )
    # From reading the scene to the fused texture, BLAS keeps to one thread (core.parallel.blas_on_one_thread).
    computing = [b for stage, b in blas if stage != "write"]
    assert {"gather", "bake", "solve", "fuse"} <= {stage for stage, _ in blas}
    assert computing and all(b == {1} for b in computing)
    assert rep.iterations >= 1 and len(rep.energy) >= 2
    light = json.loads((tmp_path / "out" / "lighting.json").read_text())
    assert light["channels"] == ["R", "G", "B"] and np.shape([v["sh"] for v in light["views"]]) == (4, 3, 9)
    assert os.path.join(str(tmp_path / "out"), "lighting.exr") in rep.files
    assert read_exr(tmp_path / "out" / "lighting.exr")[0].shape == (128, 256, 3)
    # The per-view maps are the texture seen through each view's bake.
    albedo, _ = read_exr(tmp_path / "out" / "Target_albedo.exr")
    v0, _ = read_exr(tmp_path / "out" / "views" / f"{s.cameras[0].name}.exr")
    assert np.nanmax(v0[..., :3]) <= albedo[..., :3].max() + 1e-5


def test_a_texture_finer_than_the_photos_is_solved_coarser(tmp_path):
    s = build_scene(str(tmp_path))
    rep = pipeline.run(s.scene, options(tmp_path / "out", method="texture", max_iter=2, texture_size=512))
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["solver_info"]["solved_size"] < 512
    albedo, _ = read_exr(rep.albedo_path)
    assert albedo.shape == (512, 512, 4) and np.isfinite(albedo).all()
    seen = albedo[..., 3] > 0
    assert seen.any() and np.ptp(albedo[seen, :3]) > 0


def test_image_method_fuses_the_solved_views(tmp_path):
    pytest.importorskip("blender_addon.core.geometry.correspondences")
    s = build_scene(str(tmp_path))
    rep = pipeline.run(s.scene, options(tmp_path / "out", method="image", max_iter=2))
    assert rep.iterations >= 1
    albedo, _ = read_exr(tmp_path / "out" / "Target_albedo.exr")
    assert np.isfinite(albedo).all() and albedo[..., 3].any()
    light = json.loads((tmp_path / "out" / "lighting.json").read_text())
    assert np.shape([v["sh"] for v in light["views"]]) == (4, 3, 9)


def test_linked_material_is_refused_before_anything_is_written(tmp_path):
    lib = str(tmp_path / "lib.blend")
    bpy.data.libraries.write(lib, {bpy.data.materials.new("Shared")})
    s = build_scene(str(tmp_path))
    with bpy.data.libraries.load(lib, link=True) as (src, dst):
        dst.materials = ["Shared"]
    s.obj.data.materials.append(dst.materials[0])
    assert s.obj.material_slots[0].material.library is not None
    before = scene_state()
    with pytest.raises(DelightError, match="linked from a library"):
        pipeline.run(s.scene, options(tmp_path / "out"))
    assert scene_state() == before and not (tmp_path / "out").exists()


def test_safe_names():
    assert safe_name("../../x") == "_._.._x"
    assert safe_name("a/b") == "a_b"
    assert safe_name("..") == "_."
    assert safe_name("") == "unnamed"
    assert safe_name("CON") == "_CON"
    assert unique_names(["a/b", "a_b", "A_B", "a:b"]) == ["a_b", "a_b_2", "A_B_3", "a_b_4"]


def test_negated_photos_are_refused_before_the_solve(tmp_path):
    s = build_scene(str(tmp_path), n_cameras=3, kind="exr")
    for img in s.images.values():
        px = np.empty(len(img.pixels), np.float32)
        img.pixels.foreach_get(px)
        img.pixels.foreach_set(-px)
    before = scene_state()
    with pytest.raises(DelightError, match="negative, so it is not a linear image of light"):
        pipeline.run(s.scene, options(tmp_path / "out", method="texture"))
    assert scene_state() == before and not (tmp_path / "out").exists()
