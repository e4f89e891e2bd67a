"""A cancel at any step of a run leaves the earlier outputs or the new ones, never a mix; the .blend is saved last."""

from __future__ import annotations

import collections
import json
import sys
import threading
import traceback

import pytest

bpy = pytest.importorskip("bpy")

from conftest import build_scene  # noqa: E402
from scene_state import files_under, scene_state  # noqa: E402

from blender_addon import pipeline  # noqa: E402
from blender_addon.core.errors import Cancelled, DelightError  # noqa: E402
from blender_addon.core.failures import report_failure  # noqa: E402

pytestmark = pytest.mark.bpy


def outputs(folder) -> dict:
    """Every file under ``folder``, hidden ones included: relative path -> bytes."""
    return {p: (folder / p).read_bytes() for p in files_under(folder) if (folder / p).is_file()}


def saved_scene(tmp_path):
    s = build_scene(str(tmp_path))
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    return s, blend


def options(out, cameras, **kw):
    return pipeline.Options(out_dir=str(out), method="texture", texture_size=16, max_iter=2, camera_names=cameras, **kw)


def test_a_cancel_at_every_place_that_checks_leaves_the_earlier_outputs_and_the_save_comes_last(tmp_path):
    s, blend = saved_scene(tmp_path)
    out = tmp_path / "out"
    names = [c.name for c in s.cameras]
    # The earlier run saw cameras 0-2, the new one sees 1-3: the new outputs add a file and drop one.
    pipeline.run(s.scene, options(out, names[:3]))
    earlier = outputs(out)
    state = scene_state()
    blend_bytes = blend.read_bytes()
    new_options = options(out, names[1:], save_blend=True)

    stage = {"now": None, "saving": None}

    def progress(fraction, message):
        stage["now"] = message.split(":")[0]
        if message == "write: saving the .blend":  # the files are in place before the .blend is saved
            stage["saving"] = outputs(out)

    # Each place that checks (its stage and the add-on's frames that called it) is cancelled at its 1st, 2nd,
    # 4th, 8th ... check, and at every check while the files are written: every check one at a time would
    # take a run per iteration of every loop.
    tried = set()
    lock = threading.Lock()
    for _ in range(200):
        seen = collections.Counter()
        at = []

        def cancel(seen=seen, at=at):
            frames = traceback.extract_stack()[:-1]
            place = (stage["now"], *[(f.filename, f.lineno) for f in frames if "blender_addon" in f.filename])
            with lock:
                seen[place] += 1
                n = seen[place]
                if (n & (n - 1) and place[0] != "write") or (place, n) in tried or at:
                    return False
                tried.add((place, n))
                at.append(f"check {n} of {place[0]} at {place[-2:]}")
                return True

        try:
            report = pipeline.run(s.scene, new_options, progress=progress, cancel=cancel)
        except Cancelled:
            assert outputs(out) == earlier, at  # no staging folder either
            assert scene_state() == state, at
            assert blend.read_bytes() == blend_bytes
            assert stage["saving"] is None
            continue
        break
    assert not at  # the run that went through was cancelled at none of its checks
    assert {"gather", "bake", "solve", "fuse", "write"} <= {place[0] for place, _ in tried}, tried

    new = outputs(out)
    assert stage["saving"] == new  # every new file was in place when the save began
    listed = json.loads(new["report.json"])["files"]
    assert sorted(new) == sorted(listed)  # the new run's files, only them
    assert f"views/{names[3]}.exr" in new and f"views/{names[0]}.exr" not in new
    assert all(new[p] != earlier[p] for p in new if p in earlier)
    assert report.saved_blend == str(blend) and blend.read_bytes() != blend_bytes


@pytest.mark.parametrize("at", ["write: material", "write: saving the .blend"])
def test_ctrl_c_after_the_files_are_in_place_says_so(tmp_path, capsys, at):
    s, blend = saved_scene(tmp_path)
    out = tmp_path / "out"
    blend_bytes = blend.read_bytes()

    def progress(fraction, message):
        if message == at:
            raise KeyboardInterrupt

    with pytest.raises(Cancelled) as info:
        pipeline.run(s.scene, options(out, None, save_blend=True), progress=progress)
    assert info.value.written == str(out)
    assert str(info.value) == f"interrupted after the new outputs were written to {out}; the .blend was not saved"
    assert blend.read_bytes() == blend_bytes
    assert sorted(outputs(out)) == sorted(json.loads((out / "report.json").read_text())["files"])
    assert report_failure(info.value, sys.stderr) == 130
    assert capsys.readouterr().err == f"delight: {info.value}\n"


def test_a_blend_that_cannot_be_saved_is_one_error_after_the_files(tmp_path):
    s, blend = saved_scene(tmp_path)
    out = tmp_path / "out"
    blend.unlink()
    blend.mkdir()  # a folder where the .blend was: saving fails, for root too
    # Blender 4.2 would move that folder aside as the .blend1 backup: a non-empty folder there stops it.
    (blend.parent / (blend.name + "1")).mkdir()
    (blend.parent / (blend.name + "1") / "keep").write_bytes(b"")
    with pytest.raises(DelightError) as info:
        pipeline.run(s.scene, options(out, None, save_blend=True))
    assert str(info.value).startswith(f"the new outputs are in {out}, but the .blend could not be saved: ")
    assert "Traceback" not in str(info.value)
    assert (out / "report.json").is_file()
