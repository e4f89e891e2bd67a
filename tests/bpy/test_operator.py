"""The operator and panel, registered in real Blender (background mode: INVOKE runs in-line)."""

from __future__ import annotations

import contextlib
import errno
import json

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from conftest import build_scene  # noqa: E402
from scene_state import files_under, scene_state  # noqa: E402

import blender_addon  # noqa: E402
from blender_addon import pipeline  # noqa: E402
from blender_addon.core.errors import Cancelled  # noqa: E402
from blender_addon.operator import (  # noqa: E402
    Job,
    begin_progress,
    draw_status_bar,
    end_progress,
    get_status,  # noqa: E402
    progress_bar,
)
from blender_addon.panel import VIEW3D_PT_delight, operator_settings  # noqa: E402

pytestmark = pytest.mark.bpy


@pytest.fixture(autouse=True)
def addon():
    blender_addon.register()
    yield
    blender_addon.unregister()


@pytest.mark.parametrize("call", ["EXEC_DEFAULT", "INVOKE_DEFAULT"])
def test_operator_writes_files_and_wires_the_material(tmp_path, call):
    s = build_scene(str(tmp_path))
    out = tmp_path / "out"
    res = bpy.ops.delight.run(call, method="project", texture_size=16, out_dir=str(out))
    assert res == {"FINISHED"}
    assert {"Target_albedo.exr", "lighting.json", "report.json"} <= set(files_under(out))
    assert len([p for p in files_under(out) if p.startswith("views/")]) == len(s.cameras)
    mat = s.obj.material_slots[0].material
    src = mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].links[0].from_node
    assert src.name == "Delight Albedo" and src.image.name == "Target_albedo"
    assert "Target_albedo" in get_status()


def test_operator_options_reach_the_pipeline(tmp_path):
    s = build_scene(str(tmp_path))
    coll = bpy.data.collections.new("Cams")
    s.scene.collection.children.link(coll)
    for cam in s.cameras[:2]:
        coll.objects.link(cam)
    out = tmp_path / "out"
    res = bpy.ops.delight.run(
        object_name="Target",
        cameras="COLLECTION",
        camera_collection="Cams",
        method="project",
        texture_size=16,
        working_res=0.001,
        out_dir=str(out),
    )
    assert res == {"FINISHED"}
    report = json.loads((out / "report.json").read_text())
    assert [c["name"] for c in report["cameras"]] == [c.name for c in s.cameras[:2]]
    assert report["parameters"]["working_res_mp"] == pytest.approx(0.001)
    assert all(c["size"][0] * c["size"][1] <= 1000 for c in report["cameras"])


def test_operator_error_reports_and_changes_nothing(tmp_path):
    s = build_scene(str(tmp_path))
    for cam in s.cameras:
        bpy.data.objects.remove(cam)
    before = scene_state()
    with pytest.raises(RuntimeError, match="(?i)camera"):
        bpy.ops.delight.run(method="project", texture_size=16, out_dir=str(tmp_path / "out"))
    assert scene_state() == before
    assert not (tmp_path / "out").exists()
    assert get_status().startswith("Error:")


def test_operator_out_dir_relative_to_an_unsaved_file_is_refused(tmp_path):
    build_scene(str(tmp_path))
    before = scene_state()
    with pytest.raises(RuntimeError, match="not saved"):
        bpy.ops.delight.run(method="project", texture_size=16)  # default out_dir: beside the .blend
    assert scene_state() == before


def test_operator_default_out_is_a_folder_beside_the_saved_blend(tmp_path):
    build_scene(str(tmp_path))
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    assert bpy.ops.delight.run(method="project", texture_size=16) == {"FINISHED"}
    out = tmp_path / "delight_Target"
    assert (out / "Target_albedo.exr").is_file() and (out / "report.json").is_file()
    assert not (tmp_path / "Target_albedo.exr").exists()


def test_worker_job_runs_and_cancels_without_touching_the_scene(tmp_path):
    s = build_scene(str(tmp_path))
    opts = pipeline.Options(method="texture", texture_size=16, max_iter=3, out_dir=str(tmp_path / "out"))
    before = scene_state()

    job = Job(pipeline.prepare(s.scene, opts))
    job.cancel()  # Esc before the worker starts its first check
    job.start().join(60)
    assert job.done and isinstance(job.error, Cancelled) and job.computed is None
    assert scene_state() == before and not (tmp_path / "out").exists()

    job = Job(pipeline.prepare(s.scene, opts)).start()
    job.join(120)
    assert job.done and job.error is None
    messages = job.poll()
    stages = job.prepared.stages  # the bar's spans, set once the photos were read
    assert messages and messages[-1][0] == pytest.approx(stages["fuse"][1])
    # The worker's share: solve and fuse.
    assert all(stages["solve"][0] <= f <= stages["fuse"][1] for f, _ in messages)
    assert scene_state() == before  # the worker never writes
    rep = pipeline.finish(s.scene, job.prepared, job.computed)
    assert rep.iterations >= 1 and (tmp_path / "out" / "Target_albedo.exr").is_file()


def test_worker_job_cancelled_mid_solve(tmp_path):
    s = build_scene(str(tmp_path))
    opts = pipeline.Options(method="texture", texture_size=16, max_iter=50, out_dir=str(tmp_path / "out"))
    job = Job(pipeline.prepare(s.scene, opts))
    # Esc as soon as the solver reports: the progress queue is what the modal timer drains.
    real_put = job.messages.put

    def put(item):
        real_put(item)
        if item[1].startswith("solve:") and job.messages.qsize() > 1:
            job.cancel()

    job.messages.put = put
    job.start().join(120)
    assert isinstance(job.error, Cancelled)
    assert any(m.startswith("solve:") for _, m in job.poll())


def test_panel_and_settings_are_registered():
    assert VIEW3D_PT_delight.bl_space_type == "VIEW_3D" and VIEW3D_PT_delight.bl_region_type == "UI"
    assert VIEW3D_PT_delight.bl_category == "Delight"
    assert hasattr(bpy.types, "VIEW3D_PT_delight")
    s = bpy.context.scene.delight
    assert s.method == "texture" and s.texture_size == 1024 and s.out_dir == ""
    mesh = bpy.data.objects.new("M", bpy.data.meshes.new("M"))
    s.target = mesh
    assert s.auto_lambda
    s.method, s.auto_lambda, s.lam, s.overwrite = "image", False, 7.5, True
    kw = operator_settings(s)
    assert kw["object_name"] == "M" and kw["method"] == "image" and kw["lam"] == 7.5 and kw["overwrite"]
    assert kw["auto_lambda"] is False
    # Every setting the panel hands over is a property of the operator.
    props = bpy.ops.delight.run.get_rna_type().properties.keys()
    assert set(kw) <= set(props)


def test_unregister_removes_everything():
    blender_addon.unregister()
    try:
        assert not hasattr(bpy.types, "VIEW3D_PT_delight")
        assert not hasattr(bpy.types.Scene, "delight")
        assert "run" not in dir(bpy.ops.delight)
    finally:
        blender_addon.register()


def test_working_res_downscales_the_photos(tmp_path):
    build_scene(str(tmp_path))
    out = tmp_path / "out"
    assert bpy.ops.delight.run(method="project", texture_size=16, working_res=0.001, out_dir=str(out)) == {"FINISHED"}
    from blender_addon.core.io.exr import read_exr

    v, _ = read_exr(out / "views" / "view0_cam.exr")
    assert v.shape[0] * v.shape[1] <= 1000 and np.isclose(v.shape[1] / v.shape[0], 64 / 48, rtol=0.1)


# -- the progress bar ---------------------------------------------------------------------------------


def status_bar_hooked() -> bool:
    """Whether the status bar draws our bar (the draw functions appended to its header)."""
    return draw_status_bar in getattr(bpy.types.STATUSBAR_HT_header.draw, "_draw_funcs", [])


def test_progress_bar_follows_a_run_and_leaves_the_status_bar_after_it(tmp_path):
    # Background mode has no UILayout to draw into; the panel and the status bar draw what progress_bar() gives.
    s = build_scene(str(tmp_path))
    assert progress_bar() is None and not status_bar_hooked()
    opts = pipeline.Options(method="texture", texture_size=16, max_iter=3, out_dir=str(tmp_path / "out"))
    begin_progress(max_iter=opts.max_iter)
    state = begin_progress(max_iter=opts.max_iter)  # a second start replaces the first: one bar
    assert status_bar_hooked()
    assert bpy.types.STATUSBAR_HT_header.draw._draw_funcs.count(draw_status_bar) == 1
    assert progress_bar() == (0.0, "starting")

    # As the modal operator does: the scene is read on the main thread, the worker's messages are drained.
    bars = []
    job = Job(pipeline.prepare(s.scene, opts, progress=lambda f, m="": (state(f, m), bars.append(progress_bar()))))
    job.start().join(120)
    assert job.error is None
    for fraction, message in job.poll():
        state(fraction, message)
        bars.append(progress_bar())
    texts = [t for _, t in bars]
    assert any(t.startswith("bake: baking view1_cam") for t in texts)
    assert "solve: albedo: iteration 2/3" in [t.split(" —")[0] for t in texts]
    assert not any("energy" in t for t in texts)
    factors = [f for f, _ in bars]
    assert np.all(np.diff(factors) > -1e-9) and factors[-1] == pytest.approx(job.prepared.stages["fuse"][1])

    end_progress()
    assert progress_bar() is None and not status_bar_hooked()
    end_progress()  # twice is harmless


def test_unregister_removes_the_status_bar_hook_of_a_run_that_goes():
    begin_progress(max_iter=5)
    assert status_bar_hooked()
    blender_addon.unregister()
    try:
        assert not status_bar_hooked() and progress_bar() is None
    finally:
        blender_addon.register()


def test_a_failed_or_cancelled_in_line_run_leaves_no_bar(tmp_path):
    build_scene(str(tmp_path))
    with pytest.raises(RuntimeError):
        bpy.ops.delight.run("INVOKE_DEFAULT", method="project", texture_size=3)
    assert progress_bar() is None and not status_bar_hooked()


# -- re-running, undo and Adjust Last Operation --------------------------------------------------------


@contextlib.contextmanager
def in_the_3d_view():
    """A window, a 3D view and its region as the context: undo needs them (they exist in background too)."""
    win = bpy.context.window_manager.windows[0]
    area = next(a for a in win.screen.areas if a.type == "VIEW_3D")
    region = next(r for r in area.regions if r.type == "WINDOW")
    with bpy.context.temp_override(window=win, area=area, region=region):
        yield


def press_delight(**props):
    """The button, as Blender runs an undoable operator: the run, then an undo step for it."""
    assert bpy.ops.delight.run("INVOKE_DEFAULT", **props) == {"FINISHED"}
    bpy.ops.ed.undo_push(message="Delight")


def delight_state():
    """Our image and nodes, by name (Python references die with an undo)."""
    mat = bpy.data.objects["Target"].material_slots[0].material
    nodes = [n.name for n in mat.node_tree.nodes if n.get("delight")]
    return sorted(i.name for i in bpy.data.images if i.get("delight")), nodes


def test_pressing_delight_twice_with_the_panels_defaults_replaces_the_first_run(tmp_path):
    build_scene(str(tmp_path))
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    bpy.context.scene.delight.target = bpy.data.objects["Target"]
    settings = operator_settings(bpy.context.scene.delight)  # what the panel's button passes
    out = tmp_path / "delight_Target"
    assert bpy.ops.delight.run("INVOKE_DEFAULT", **settings) == {"FINISHED"}
    first = json.loads((out / "report.json").read_text())
    (out / "notes.txt").write_text("mine")
    assert bpy.ops.delight.run("INVOKE_DEFAULT", **settings) == {"FINISHED"}
    second = json.loads((out / "report.json").read_text())
    assert second["files"] == first["files"] and second["times_s"] != first["times_s"]
    assert sorted(files_under(out)) == sorted(first["files"] + ["notes.txt", "views"])
    assert (out / "notes.txt").read_text() == "mine"
    assert delight_state() == (["Target_albedo"], ["Delight Albedo", "Delight UV"])
    assert "Target_albedo" in get_status()


def test_undo_then_run_again(tmp_path):
    build_scene(str(tmp_path))
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    out = tmp_path / "delight_Target"
    with in_the_3d_view():
        bpy.ops.ed.undo_push(message="before")
        before = scene_state()
        press_delight(method="texture", texture_size=16, max_iter=3)
        ran = delight_state()
        assert ran[0] == ["Target_albedo"]
        bpy.ops.ed.undo()
        assert scene_state() == before  # the run is undone; its files stay
        assert (out / "report.json").is_file()
        press_delight(method="texture", texture_size=16, max_iter=3)
        assert delight_state() == ran
    assert json.loads((out / "report.json").read_text())["parameters"]["max_iter"] == 3


def test_adjust_last_operation_reruns_with_the_changed_setting(tmp_path):
    build_scene(str(tmp_path))
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    out = tmp_path / "delight_Target"
    props = dict(method="texture", texture_size=16, max_iter=3)
    with in_the_3d_view():
        bpy.ops.ed.undo_push(message="before")
        press_delight(**props)
        ran = delight_state()
        # Adjust Last Operation: undo the run, then execute() again with the changed properties.
        for max_iter in (4, 2):
            bpy.ops.ed.undo()
            assert bpy.ops.delight.run("EXEC_DEFAULT", **{**props, "max_iter": max_iter}) == {"FINISHED"}
            bpy.ops.ed.undo_push(message="Delight")
            assert delight_state() == ran
            report = json.loads((out / "report.json").read_text())
            assert report["parameters"]["max_iter"] == max_iter and report["iterations"] <= max_iter


# -- failures -------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "exc,message,traceback_on_console",
    [
        (RuntimeError("boom"), "Delight: unexpected RuntimeError: boom (the traceback is in the system console)", True),
        (
            MemoryError(),
            "Delight: out of memory: lower the Working resolution (MP), the Working total (MP) or the "
            "Texture size (px)",
            False,
        ),
        (
            PermissionError(errno.EACCES, "Permission denied", "/some/photo.exr"),
            "Delight: /some/photo.exr: permission denied",
            False,
        ),
    ],
)
@pytest.mark.parametrize("call", ["EXEC_DEFAULT", "INVOKE_DEFAULT"])
def test_any_failure_is_one_line_in_the_report(tmp_path, monkeypatch, capsys, exc, message, traceback_on_console, call):
    build_scene(str(tmp_path))
    before = scene_state()

    def fail(*args, **kwargs):  # the run fails as it would on a machine out of memory, or with a bug
        raise exc

    monkeypatch.setattr(pipeline, "run", fail)
    with pytest.raises(RuntimeError) as info:
        bpy.ops.delight.run(call, method="project", texture_size=16, out_dir=str(tmp_path / "out"))
    report = str(info.value).strip()
    assert report == f"Error: {message}"
    assert "Traceback" not in report and "Python" not in report
    assert get_status() == f"Error: {message.removeprefix('Delight: ')}"
    console = capsys.readouterr().err
    assert ("Traceback" in console and "in fail" in console) == traceback_on_console
    assert scene_state() == before
