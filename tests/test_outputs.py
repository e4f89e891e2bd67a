"""core.io.outputs: one lighting.json schema, all-or-nothing writes, Delight's own files, inputs never written."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest
from test_bundle_cli import ROOT, make_problem

from core.errors import Cancelled, DelightError
from core.geometry.sh import SH_BASIS_NAMES
from core.io import outputs
from core.io.bundle import save_bundle
from core.io.exr import read_exr
from core.io.outputs import (
    check_inputs,
    check_writable,
    lighting_json,
    lighting_outputs,
    own_files,
    plan_outputs,
    prepare_outputs,
    rgba,
    view_files,
    write_outputs,
)


def chmod_stops_writes(tmp_path) -> bool:
    """Whether a folder made read-only refuses new files here (not for root, which ignores it)."""
    d = tmp_path / "chmod-probe"
    d.mkdir()
    os.chmod(d, 0o500)
    try:
        (d / "x").write_text("")
    except PermissionError:
        return True
    finally:
        os.chmod(d, 0o700)
        if (d / "x").exists():
            (d / "x").unlink()
        d.rmdir()
    return False


def snapshot(folder):
    """Every file under ``folder`` (relative path -> bytes), hidden ones included."""
    out = {}
    for d, _, fs in os.walk(folder):
        for f in fs:
            p = os.path.join(d, f)
            with open(p, "rb") as fh:
                out[os.path.relpath(p, folder)] = fh.read()
    return out


def run_files(names=("a", "b"), value=0.25, sigma_value=1.0):
    """The contents of a small run: two views, an albedo, lighting."""
    files = view_files(names)
    contents = {"thing_albedo.exr": rgba(np.full((4, 4, 3), value), np.ones((4, 4)))}
    for f in files:
        contents[f] = rgba(np.full((3, 5, 3), value), np.eye(3, 5, dtype=bool))
    sigma = None if sigma_value is None else np.full((len(names), 3, 9), sigma_value)
    contents.update(lighting_outputs(list(names), files, sigma, method="texture"))
    return contents


def test_lighting_json_schema():
    light = lighting_json(
        ["cam/1", "cam 2"], view_files(["cam/1", "cam 2"]), np.arange(54.0).reshape(2, 3, 9), method="image"
    )
    assert list(light) == ["sh_basis", "channels", "normals", "method", "world", "views"]
    assert light["sh_basis"] == list(SH_BASIS_NAMES) and len(light["sh_basis"]) == 9
    # The world lighting: the views' mean, and the radiance that gives it (pi / A_l per band).
    mean = np.arange(54.0).reshape(2, 3, 9).mean(axis=0)
    assert light["world"]["file"] == "lighting.exr"
    np.testing.assert_allclose(light["world"]["sh"], mean)
    np.testing.assert_allclose(light["world"]["radiance_sh"], mean * [1.5, 1.5, 1.5, 1, 4, 4, 4, 4, 4])
    assert light["channels"] == ["R", "G", "B"] and light["normals"] == "world space, unit length"
    assert light["views"][1] == {
        "name": "cam 2",
        "file": "views/cam_2.exr",
        "sh": np.arange(27.0, 54.0).reshape(3, 9).tolist(),
    }
    none = lighting_json(["a"], ["views/a.exr"], None, 3, "project")
    assert none["views"] == [{"name": "a", "file": "views/a.exr", "sh": None}] and none["channels"] == ["R", "G", "B"]
    assert none["world"] is None
    assert lighting_json(["a"], ["views/a.exr"], np.zeros((1, 1, 9)))["channels"] == ["Y"]
    with pytest.raises(ValueError, match="sigma has shape"):
        lighting_json(["a", "b"], ["views/a.exr", "views/b.exr"], np.zeros((1, 3, 9)))


def test_lighting_json_with_the_sun():
    sigma = np.arange(60.0).reshape(2, 3, 10)
    light = lighting_json(["a", "b"], ["views/a.exr", "views/b.exr"], sigma, sun=[0.0, 0.0, 2.0])
    np.testing.assert_allclose(light["world"]["sh"], sigma[..., :9].mean(axis=0))
    assert light["world"]["sun"] == {"direction": [0.0, 0.0, 1.0], "strength": [24.0, 34.0, 44.0]}
    assert light["views"][0]["sh"] == sigma[0, :, :9].tolist() and light["views"][1]["sun_strength"] == [39, 49, 59]
    with pytest.raises(ValueError, match=r"expected \(2, C, 10\)"):
        lighting_json(["a", "b"], ["views/a.exr", "views/b.exr"], sigma[..., :9], sun=[0.0, 0.0, 1.0])


def test_rgba_packs_grey_nan_and_alpha():
    v = np.array([[1.0, np.nan], [np.inf, 2.0]])
    a = np.array([[True, True], [True, False]])
    out = rgba(v, a)
    assert out.dtype == np.float32 and out.shape == (2, 2, 4)
    np.testing.assert_array_equal(out[..., 0], [[1, 0], [0, 0]])
    np.testing.assert_array_equal(out[..., 3], a)
    assert (out[..., 0] == out[..., 2]).all()
    assert rgba(v, a, zero_outside=False)[1, 1, 1] == 2.0  # filled texels keep their colour


def test_write_lists_its_files_and_a_rerun_replaces_them_without_overwrite(tmp_path):
    out = tmp_path / "out"
    written = write_outputs(out, run_files(), {"run": 1})
    rels = ["thing_albedo.exr", "views/a.exr", "views/b.exr", "lighting.json", "lighting.exr", "report.json"]
    assert written == [str(out / r) for r in rels]
    assert sorted(snapshot(out)) == sorted(rels)  # no staging folder left
    report = json.loads((out / "report.json").read_text())
    assert report == {"run": 1, "files": rels}
    assert own_files(out) == set(rels)

    # Same names, new contents; and one view fewer: its old file goes, the folder holds one run.
    (out / "notes.txt").write_text("the user's")
    write_outputs(out, run_files(names=("a",), value=0.5, sigma_value=2.0), lambda: {"run": 2})
    assert sorted(snapshot(out)) == sorted(
        ["thing_albedo.exr", "views/a.exr", "lighting.json", "lighting.exr", "report.json", "notes.txt"]
    )
    assert read_exr(out / "views" / "a.exr")[0][0, 0, 0] == 0.5
    assert json.loads((out / "lighting.json").read_text())["views"][0]["sh"][0][0] == 2.0
    assert json.loads((out / "report.json").read_text())["run"] == 2
    assert (out / "notes.txt").read_text() == "the user's"


@pytest.mark.parametrize("threads", [1, 3])
def test_files_are_written_on_the_threads_given(tmp_path, threads):
    import threading

    writers = []

    def writer(value):
        def write(path):
            writers.append(threading.get_ident())
            outputs.write_exr(path, np.full((2, 2, 3), value, np.float32))

        return write

    files = {f"views/v{i}.exr": writer(i / 10) for i in range(6)}
    write_outputs(tmp_path / "out", files, {}, threads=threads)
    assert [read_exr(tmp_path / "out" / "views" / f"v{i}.exr")[0][0, 0, 0] for i in range(6)] == pytest.approx(
        [i / 10 for i in range(6)]
    )
    if threads == 1:  # --threads 1: everything in the calling thread
        assert set(writers) == {threading.get_ident()}


def test_the_environment_image_is_written_replaced_and_removed_with_the_lighting(tmp_path):
    out = tmp_path / "out"
    write_outputs(out, run_files(sigma_value=1.0), {"run": 1})
    env, channels = read_exr(out / "lighting.exr")
    # The lighting 1 in every coefficient, as a radiance at the top row (+Z): 1 + 1.5 + 4 * 2.
    assert channels == ["R", "G", "B"] and env.shape == (128, 256, 3) and env.dtype == np.float32
    assert abs(env[0].mean() - 10.5) < 0.05
    assert "lighting.exr" in json.loads((out / "report.json").read_text())["files"]

    write_outputs(out, run_files(sigma_value=2.0), {"run": 2})  # Delight's own: replaced, no --overwrite
    np.testing.assert_allclose(read_exr(out / "lighting.exr")[0], 2 * env, rtol=1e-6)

    write_outputs(out, run_files(sigma_value=None), {"run": 3})  # no lighting estimated: the old image goes
    assert "lighting.exr" not in snapshot(out)
    assert json.loads((out / "lighting.json").read_text())["world"] is None
    assert "lighting.exr" not in json.loads((out / "report.json").read_text())["files"]


def test_an_environment_image_of_the_users_is_never_written(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "lighting.exr").write_bytes(b"the user's sky")
    with pytest.raises(DelightError, match="lighting.exr already exists and was not written by Delight"):
        write_outputs(out, run_files(), {})
    # An input (the HDRI the scene's world uses) is refused even with overwrite.
    with pytest.raises(DelightError, match="would overwrite the input"):
        write_outputs(out, run_files(), {}, overwrite=True, inputs=[str(out / "lighting.exr")])
    assert snapshot(out) == {"lighting.exr": b"the user's sky"}


def test_a_foreign_file_is_refused_unless_overwrite(tmp_path):
    out = tmp_path / "out"
    (out / "views").mkdir(parents=True)
    (out / "views" / "b.exr").write_bytes(b"precious")
    with pytest.raises(
        DelightError,
        match=r"views/b.exr already exists and was not written by Delight; "
        r"choose another output folder or pass --overwrite",
    ):
        write_outputs(out, run_files(), {})
    assert snapshot(out) == {"views/b.exr": b"precious"}
    write_outputs(out, run_files(), {}, overwrite=True)
    assert read_exr(out / "views" / "b.exr")[0].shape == (3, 5, 4)


def test_a_report_that_lists_odd_names_owns_nothing_outside(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (tmp_path / "secret.txt").write_text("keep")
    (out / ".hidden").write_text("keep")
    (out / "report.json").write_text(
        json.dumps({"files": ["report.json", "../secret.txt", ".hidden", "/etc/passwd", "views/../../x", 7]})
    )
    assert own_files(out) == {"report.json"}
    (out / "report.json").write_text(json.dumps({"files": ["lighting.json"]}))  # not a Delight report
    assert own_files(out) == set()
    (out / "report.json").write_text("not json")
    assert own_files(out) == set()


def test_folders_in_the_way_are_refused(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(DelightError, match="is a file, not a folder"):
        plan_outputs(tmp_path / "file", ["a.exr"])
    (tmp_path / "out" / "lighting.json").mkdir(parents=True)
    with pytest.raises(DelightError, match="a folder of that name exists"):
        plan_outputs(tmp_path / "out", ["lighting.json"], overwrite=True)
    (tmp_path / "v").mkdir()
    (tmp_path / "v" / "views").write_text("")
    with pytest.raises(DelightError, match="views is a file"):
        plan_outputs(tmp_path / "v", ["views/a.exr"])


def test_an_output_that_is_an_input_is_refused_even_with_overwrite(tmp_path):
    blend_dir = tmp_path / "scan"
    (blend_dir / "views").mkdir(parents=True)
    photo = blend_dir / "views" / "a.exr"
    photo.write_bytes(b"photo bytes")
    blend = blend_dir / "scene.blend"
    blend.write_bytes(b"blend")
    for overwrite in (False, True):
        with pytest.raises(DelightError) as e:
            write_outputs(blend_dir, run_files(), {}, overwrite=overwrite, inputs=[str(blend), str(photo)])
        assert str(photo) in str(e.value) and str(blend_dir / "views" / "a.exr") in str(e.value)
        assert "would overwrite the input" in str(e.value)
    assert snapshot(blend_dir) == {"views/a.exr": b"photo bytes", "scene.blend": b"blend"}
    # The same file under another path: a symlinked folder, a hard link.
    os.symlink(blend_dir, tmp_path / "alias")
    with pytest.raises(DelightError, match="would overwrite the input"):
        check_inputs([str(tmp_path / "alias" / "views" / "a.exr")], [str(photo)])
    os.link(photo, tmp_path / "hard.exr")
    with pytest.raises(DelightError, match="hard.exr"):
        check_inputs([str(tmp_path / "hard.exr")], [str(photo)])
    check_inputs([str(photo), "", None], [str(blend_dir / "views" / "b.exr")])  # no clash


def count_checks(out, **kw):
    calls = []

    def cancel():
        calls.append(1)
        return False

    write_outputs(out, run_files(), {}, cancel=cancel, **kw)
    return len(calls)


def test_cancel_at_any_check_keeps_the_earlier_outputs(tmp_path):
    out = tmp_path / "out"
    write_outputs(out, run_files(), {"run": 1})
    (out / "user.txt").write_text("mine")
    before = snapshot(out)
    n = count_checks(tmp_path / "probe")
    assert n >= len(run_files()) + 2
    for k in range(1, n + 1):
        calls = []

        def cancel(calls=calls, k=k):
            calls.append(1)
            return len(calls) == k

        with pytest.raises(Cancelled):
            write_outputs(out, run_files(value=0.75), {"run": 2}, cancel=cancel)
        assert snapshot(out) == before, k  # nothing new, nothing lost, no staging folder
    # A cancel into a new folder leaves no folder behind.
    with pytest.raises(Cancelled):
        write_outputs(tmp_path / "new" / "deep", run_files(), {}, cancel=lambda: True)
    assert not (tmp_path / "new").exists()


def test_a_full_disk_midway_is_a_delight_error_and_changes_nothing(tmp_path):
    out = tmp_path / "out"
    write_outputs(out, run_files(), {"run": 1})
    before = snapshot(out)
    files = run_files(value=0.75)

    def full_disk(path):
        with open(path, "wb") as fh:
            fh.write(b"half")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), path)

    files["views/b.exr"] = full_disk
    with pytest.raises(DelightError, match=r"cannot write to .*out: the disk is full"):
        write_outputs(out, files, {"run": 2})
    assert snapshot(out) == before


def test_a_failed_move_aside_is_undone(tmp_path):
    out = tmp_path / "out"
    write_outputs(out, run_files(), {"run": 1})
    before = snapshot(out)

    def report():
        # The staging folder loses its backup place for views: moving the old views aside fails
        # after the albedo was moved, and the swap must put the albedo back.
        (staging,) = [d for d in os.listdir(out) if d.startswith(".delight-")]
        os.rmdir(out / staging / "old" / "views")
        return {"run": 2}

    with pytest.raises(DelightError, match="cannot write to"):
        write_outputs(out, run_files(value=0.75), report)
    assert snapshot(out) == before


def test_a_failed_move_into_place_is_undone(tmp_path):
    if not chmod_stops_writes(tmp_path):
        pytest.skip("folder permissions do not stop this user (root)")
    out = tmp_path / "out"
    write_outputs(out, run_files(), {"run": 1})
    before = snapshot(out)

    def report():
        # Moving the old views aside now fails (no write permission in views/), after the
        # albedo was moved: the swap must put it back.
        os.chmod(out / "views", 0o500)
        return {"run": 2}

    try:
        with pytest.raises(DelightError, match="permission denied"):
            write_outputs(out, run_files(value=0.75), report)
    finally:
        os.chmod(out / "views", 0o700)
    assert snapshot(out) == before


def test_unwritable_folder_is_found_before_writing(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(DelightError, match=r"cannot write to .*file.*: .*file is a file, not a folder"):
        check_writable(tmp_path / "file" / "out")
    check_writable(tmp_path / "new" / "deep")
    assert sorted(os.listdir(tmp_path)) == ["file"]  # the probe created nothing
    if chmod_stops_writes(tmp_path):
        locked = tmp_path / "locked"
        locked.mkdir()
        os.chmod(locked, 0o500)
        try:
            for where in (locked, locked / "out"):
                with pytest.raises(DelightError, match="permission denied; choose another output folder"):
                    check_writable(where)
        finally:
            os.chmod(locked, 0o700)
        assert os.listdir(locked) == []


def test_ctrl_c_is_held_during_the_swap_and_raised_after():
    # Python's own handler, as `python -m` and the bpy module have it: a shell that starts pytest in the
    # background starts it with Ctrl-C ignored, and then Delight rightly leaves it alone.
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        done = []
        with pytest.raises(KeyboardInterrupt):
            with outputs._ctrl_c_held() as held:
                signal.raise_signal(signal.SIGINT)  # its handler runs before it returns
                done.append(bool(held))
        assert done == [True]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, before)


def test_an_ignored_ctrl_c_is_left_alone():
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with outputs._ctrl_c_held() as held:
            signal.raise_signal(signal.SIGINT)
        assert held == []
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, before)


# ---------------------------------------------------------------- python -m core solve


def solve_cli(*args):
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    return subprocess.run(
        [sys.executable, "-m", "core", "solve", *map(str, args), "--max-iter", "1"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_cli_reruns_refuses_foreign_files_and_unwritable_folders_before_the_solve(tmp_path):
    bundle = tmp_path / "problem.npz"
    save_bundle(bundle, make_problem(sizes=((24, 32),) * 2, names=["left", "right"]))
    out = tmp_path / "out"
    for _ in range(2):  # the second run replaces the first's files without --overwrite
        r = solve_cli(bundle, "--out", out)
        assert r.returncode == 0, r.stderr
    assert sorted(snapshot(out)) == [
        "albedo.exr",
        "lighting.exr",
        "lighting.json",
        "report.json",
        "views/left.exr",
        "views/right.exr",
    ]
    light = json.loads((out / "lighting.json").read_text())
    assert list(light) == ["sh_basis", "channels", "normals", "method", "world", "views"]
    assert [(v["name"], v["file"]) for v in light["views"]] == [
        ("left", "views/left.exr"),
        ("right", "views/right.exr"),
    ]

    other = tmp_path / "other"
    (other / "views").mkdir(parents=True)
    (other / "views" / "left.exr").write_bytes(b"precious")
    r = solve_cli(bundle, "--out", other)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1 and lines[0].startswith("error: ")
    assert "left.exr already exists and was not written by Delight" in lines[0]
    assert snapshot(other) == {"views/left.exr": b"precious"}
    assert solve_cli(bundle, "--out", other, "--overwrite").returncode == 0

    r = solve_cli(bundle, "--out", tmp_path / "problem.npz" / "out")
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1 and "cannot write to" in lines[0] and "solving" not in r.stderr
    if chmod_stops_writes(tmp_path):
        locked = tmp_path / "locked"
        locked.mkdir()
        os.chmod(locked, 0o500)
        try:
            r = solve_cli(bundle, "--out", locked / "out")
        finally:
            os.chmod(locked, 0o700)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 1 and len(lines) == 1 and "permission denied" in lines[0], r.stderr


def test_outputs_larger_than_the_free_space_are_refused_before_anything_is_written(tmp_path):
    import shutil

    out = tmp_path / "out"
    free = shutil.disk_usage(tmp_path).free
    with pytest.raises(DelightError, match=r"cannot write to .*the outputs need about .* MB free; free some space"):
        prepare_outputs(out, ["albedo.exr"], need_bytes=free * 2)
    assert not out.exists()
    prepare_outputs(out, ["albedo.exr"], need_bytes=1)


@pytest.mark.parametrize("channels", [None, 1, 3])
@pytest.mark.parametrize("zero_outside", [True, False])
def test_rgba_made_in_blocks_of_rows_is_its_definition(monkeypatch, channels, zero_outside):
    from core.io import outputs

    rng = np.random.default_rng(2)
    shape = (23, 17) if channels is None else (23, 17, channels)
    values = (rng.random(shape) - 0.3).astype(np.float32)  # negative values too: -0.0 where zeroed, as before
    values[rng.random(shape) > 0.8] = np.nan
    values.flat[:3] = [np.inf, -np.inf, np.nan]
    alpha = (rng.random((23, 17)) > 0.4).astype(np.float32)
    grey = values.reshape(23, 17, -1)
    colour = np.repeat(grey, 3, axis=2) if grey.shape[2] == 1 else grey
    expect = np.nan_to_num(colour, nan=0.0, posinf=0.0, neginf=0.0)
    if zero_outside:
        expect = expect * (alpha != 0)[..., None]
    monkeypatch.setattr(outputs, "_RGBA_ROWS", 5)  # several blocks, the last one short
    got = outputs.rgba(values, alpha, zero_outside)
    assert got.shape == (23, 17, 4) and got.dtype == np.float32
    np.testing.assert_array_equal(got[..., :3].view(np.uint32), expect.astype(np.float32).view(np.uint32))
    np.testing.assert_array_equal(got[..., 3], alpha)
