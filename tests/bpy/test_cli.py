"""The headless contract, run as real subprocesses: ``python -m blender_addon`` and the ``-P`` script path."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from conftest import ROOT, build_scene, make_image, needs_fixture_maker, set_background, synth_photo, write_exr  # noqa: E402
from scene_state import files_under  # noqa: E402

from blender_addon.core.io.exr import read_exr  # noqa: E402

pytestmark = pytest.mark.bpy

FAST = ["--method", "project", "--texture-size", "16"]


def save_scene(tmp_path, **kw):
    """The tiny scene saved as ``scene.blend``; return its path."""
    s = build_scene(str(tmp_path), **kw)
    path = str(tmp_path / "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    return path, s


def digest(path):
    with open(path, "rb") as fh:
        return hashlib.sha256(fh.read()).hexdigest()


def run_cli(*args, cwd=ROOT):
    env = dict(os.environ, PYTHONPATH=ROOT, OPENBLAS_NUM_THREADS="1")
    return subprocess.run(
        [sys.executable, "-m", "blender_addon", *map(str, args)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


SCRIPT = os.path.join(ROOT, "blender_addon", "cli.py")


def run_script(blend, *args, script=SCRIPT):
    """As ``blender -b BLEND -P blender_addon/cli.py -- ARGS``: Blender opens the file, then runs the script."""
    code = (
        "import runpy, sys, bpy\n"
        f"bpy.ops.wm.open_mainfile(filepath={str(blend)!r})\n"
        f"sys.argv = ['blender', '-b', {str(blend)!r}, '-P', {script!r}, '--', *{list(map(str, args))!r}]\n"
        f"runpy.run_path({script!r}, run_name='__main__')\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}  # the script must find the package itself
    return subprocess.run([sys.executable, "-c", code], cwd="/", env=env, capture_output=True, text=True, timeout=300)


def error_lines(proc):
    return [line for line in proc.stderr.splitlines() if line.startswith("error:")]


def test_python_m_writes_the_promised_files_and_leaves_the_blend(tmp_path):
    blend, s = save_scene(tmp_path)
    before = digest(blend)
    out = tmp_path / "out"
    p = run_cli(blend, *FAST, "--out", out)
    assert p.returncode == 0, p.stderr
    names = [c.name for c in s.cameras]
    assert files_under(out) == sorted(
        ["Target_albedo.exr", "lighting.json", "report.json", "views"] + [f"views/{n}.exr" for n in names]
    )
    a, ch = read_exr(out / "Target_albedo.exr")
    assert a.shape == (16, 16, 4) and ch == ["R", "G", "B", "A"]
    progress = [line for line in p.stdout.splitlines() if line.startswith("delight:")]
    assert len(progress) >= 5 and any("bake" in line for line in progress) and "wrote" in progress[-1]
    assert digest(blend) == before and not os.path.exists(blend + "1")


def test_blender_P_script_path_takes_the_same_options(tmp_path):
    blend, s = save_scene(tmp_path)
    before = digest(blend)
    out = tmp_path / "out"
    p = run_script(blend, *FAST, "--cameras", s.cameras[0].name, s.cameras[2].name, "--lambda", "2.5", "--out", out)
    assert p.returncode == 0, p.stderr
    report = json.loads((out / "report.json").read_text())
    assert [c["name"] for c in report["cameras"]] == [s.cameras[0].name, s.cameras[2].name]
    assert report["parameters"]["lambda"] == 2.5
    assert digest(blend) == before


def test_blender_P_script_path_runs_from_an_installed_extension_folder(tmp_path):
    # Blender installs the extension under its id (extensions/user_default/<id>/), not as blender_addon.
    blend, s = save_scene(tmp_path)
    installed = tmp_path / "extensions" / "delight"
    shutil.copytree(os.path.join(ROOT, "blender_addon"), installed, symlinks=False)
    out = tmp_path / "out"
    p = run_script(blend, *FAST, "--out", out, script=str(installed / "cli.py"))
    assert p.returncode == 0, p.stderr
    assert (out / "Target_albedo.exr").is_file()


def photos_in_views(tmp_path):
    """A saved scene whose cameras cam_00.. have their photos in ``<blend dir>/views/cam_00.exr`` (as
    importers lay them out); return the .blend path and the photos' bytes."""
    s = build_scene(str(tmp_path), photo=None, prefix="cam_0", suffix="")
    (tmp_path / "views").mkdir()
    for i, cam in enumerate(s.cameras):
        set_background(
            cam, make_image(cam.name, synth_photo(64, 48, seed=i), kind="exr", folder=str(tmp_path / "views"))
        )
    blend = str(tmp_path / "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    return blend, {p: (tmp_path / p).read_bytes() for p in files_under(tmp_path) if p.startswith("views/")}


def test_default_out_is_a_folder_of_its_own_and_reruns_replace_it(tmp_path):
    blend, photos = photos_in_views(tmp_path)
    for _ in range(2):  # the second run replaces Delight's own files without --overwrite
        p = run_cli(blend, *FAST)
        assert p.returncode == 0, p.stderr
    out = tmp_path / "delight_Target"
    assert files_under(out) == sorted(
        ["Target_albedo.exr", "lighting.json", "report.json", "views"] + [f"views/cam_0{i}.exr" for i in range(4)]
    )
    assert {p: (tmp_path / p).read_bytes() for p in photos} == photos
    assert sorted(files_under(tmp_path / "views")) == sorted(p[len("views/") :] for p in photos)


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]])
def test_outputs_over_the_photos_are_refused(tmp_path, overwrite):
    blend, photos = photos_in_views(tmp_path)
    before = digest(blend)
    p = run_cli(blend, *FAST, "--out", tmp_path, *overwrite)
    assert p.returncode == 1, p.stdout + p.stderr
    errors = error_lines(p)
    photo = str(tmp_path / "views" / "cam_00.exr")
    assert len(errors) == 1 and "would overwrite the input" in errors[0] and errors[0].count(photo) == 2, errors
    assert not any("bake" in line for line in p.stdout.splitlines())  # refused before the bake
    assert sorted(files_under(tmp_path)) == sorted(["scene.blend", "views", *photos])
    assert {p: (tmp_path / p).read_bytes() for p in photos} == photos and digest(blend) == before


def test_photos_from_the_images_folder_are_inputs_too(tmp_path):
    build_scene(str(tmp_path), photo=None, prefix="cam_0", suffix="")
    blend = str(tmp_path / "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    (tmp_path / "views").mkdir()
    for i in range(4):
        write_exr(str(tmp_path / "views" / f"cam_0{i}.exr"), synth_photo(64, 48, seed=i))
    photos = {p: (tmp_path / p).read_bytes() for p in files_under(tmp_path) if p.startswith("views/")}
    p = run_cli(blend, *FAST, "--images", tmp_path / "views", "--out", tmp_path, "--overwrite")
    assert p.returncode == 1, p.stdout + p.stderr
    errors = error_lines(p)
    assert len(errors) == 1 and "would overwrite the input" in errors[0], errors
    assert {p: (tmp_path / p).read_bytes() for p in photos} == photos


def test_unwritable_out_is_one_error_before_the_bake(tmp_path):
    blend, _ = save_scene(tmp_path)
    locked = tmp_path / "locked"
    locked.mkdir()
    os.chmod(locked, 0o500)
    try:
        try:
            (locked / "probe").write_text("")
            chmod_works = False  # root ignores folder permissions
            (locked / "probe").unlink()
        except PermissionError:
            chmod_works = True
        if chmod_works:
            out, message = locked / "out", "permission denied; choose another output folder"
        else:  # a path under a regular file fails for anyone
            out, message = tmp_path / "scene.blend" / "out", "is a file, not a folder"
        p = run_cli(blend, *FAST, "--out", out)
    finally:
        os.chmod(locked, 0o700)
    assert p.returncode == 1, p.stdout + p.stderr
    errors = error_lines(p)
    assert len(errors) == 1 and "cannot write to" in errors[0] and message in errors[0], errors
    assert not any("bake" in line for line in p.stdout.splitlines())
    assert files_under(locked) == []


def test_lighting_json_schema_is_that_of_python_m_core(tmp_path):
    """The same keys, value types and fixed values from the add-on and from ``python -m core solve``."""
    sys.path.insert(0, os.path.join(ROOT, "tests"))
    try:
        from test_bundle_cli import make_problem
    finally:
        sys.path.remove(os.path.join(ROOT, "tests"))
    from core.io.bundle import save_bundle  # the package test_bundle_cli builds problems with

    save_bundle(tmp_path / "p.npz", make_problem())
    env = dict(os.environ, PYTHONPATH=ROOT, OPENBLAS_NUM_THREADS="1")
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "core",
            "solve",
            str(tmp_path / "p.npz"),
            "--out",
            str(tmp_path / "core"),
            "--max-iter",
            "1",
            "--domain",
            "texture",
        ],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert p.returncode == 0, p.stderr
    blend, _ = save_scene(tmp_path)
    # Without the sun, which python -m core has no way to find (no mesh): its keys are checked in test_sun_shadows.
    args = ("--method", "texture", "--texture-size", "16", "--max-iter", "1", "--no-sun")
    p = run_cli(blend, *args, "--out", tmp_path / "addon")
    assert p.returncode == 0, p.stderr
    core = json.loads((tmp_path / "core" / "lighting.json").read_text())
    addon = json.loads((tmp_path / "addon" / "lighting.json").read_text())

    def schema(x):
        if isinstance(x, dict):
            return {k: schema(v) for k, v in x.items()}
        if isinstance(x, list):
            return [schema(v) for v in x[:1]]
        return "number" if isinstance(x, (int, float)) else type(x).__name__

    assert schema(addon) == schema(core)
    assert list(addon) == ["sh_basis", "channels", "normals", "method", "world", "views"]
    for key in ("sh_basis", "channels", "normals", "method"):
        assert addon[key] == core[key]
    for light, folder in ((core, tmp_path / "core"), (addon, tmp_path / "addon")):
        assert np.shape([v["sh"] for v in light["views"]]) == (len(light["views"]), 3, 9)
        assert all(v["file"].startswith("views/") and v["file"].endswith(".exr") for v in light["views"])
        assert light["world"]["file"] == "lighting.exr" and (folder / "lighting.exr").is_file()


def test_save_writes_the_material_into_the_blend(tmp_path):
    blend, _ = save_scene(tmp_path)
    before = digest(blend)
    p = run_cli(blend, *FAST, "--out", tmp_path / "out", "--save")
    assert p.returncode == 0, p.stderr
    assert digest(blend) != before
    bpy.ops.wm.open_mainfile(filepath=blend)
    obj = bpy.data.objects["Target"]
    mat = obj.material_slots[0].material
    src = mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].links[0].from_node
    assert src.name == "Delight Albedo"
    img = bpy.data.images["Target_albedo"]
    assert img.packed_file is not None and tuple(img.size) == (16, 16)


def test_existing_output_needs_overwrite(tmp_path):
    blend, _ = save_scene(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "Target_albedo.exr").write_bytes(b"precious")
    before = digest(blend)
    p = run_cli(blend, *FAST, "--out", out)
    assert p.returncode == 1
    errors = error_lines(p)
    assert len(errors) == 1 and "Target_albedo.exr" in errors[0] and "already exists" in errors[0]
    assert files_under(out) == ["Target_albedo.exr"] and (out / "Target_albedo.exr").read_bytes() == b"precious"
    assert digest(blend) == before
    p = run_cli(blend, *FAST, "--out", out, "--overwrite")
    assert p.returncode == 0, p.stderr
    assert read_exr(out / "Target_albedo.exr")[0].shape == (16, 16, 4)


def test_hostile_camera_names_stay_inside_out(tmp_path):
    s = build_scene(str(tmp_path))
    s.cameras[0].name, s.cameras[1].name = "../../x", "a/b"
    blend = str(tmp_path / "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    out = tmp_path / "sub" / "out"
    p = run_cli(blend, *FAST, "--out", out)
    assert p.returncode == 0, p.stderr
    views = [f for f in files_under(out) if f.startswith("views/")]
    assert len(views) == 4
    outside = [f for f in files_under(tmp_path) if not f.startswith("sub")]
    assert sorted(outside) == ["scene.blend"]
    assert not (tmp_path.parent / "x.exr").exists() and not (tmp_path / "x.exr").exists()


@pytest.mark.parametrize(
    "args, message",
    [
        (["--object", "Nope"], "Nope"),
        (["--cameras", "nocam"], "nocam"),
        (["--images", "/no/such/folder"], "/no/such/folder"),
        (["--texture-size", "3"], "texture size"),
    ],
)
def test_bad_input_exits_nonzero_with_one_line_and_writes_nothing(tmp_path, args, message):
    blend, _ = save_scene(tmp_path)
    before = digest(blend)
    out = tmp_path / "out"
    p = run_cli(blend, *FAST, *args, "--out", out)
    assert p.returncode == 1, p.stdout + p.stderr
    errors = error_lines(p)
    assert len(errors) == 1 and message in errors[0], p.stderr
    assert "Traceback" not in p.stderr
    assert not out.exists() and digest(blend) == before


def test_missing_blend_and_usage_errors(tmp_path):
    p = run_cli(tmp_path / "missing.blend")
    assert p.returncode == 1 and len(error_lines(p)) == 1 and "missing.blend" in p.stderr
    p = run_cli(tmp_path / "x.blend", "--method", "magic")
    assert p.returncode == 2 and "invalid choice" in p.stderr
    p = run_cli(tmp_path / "x.blend", "--lambda", "soft")
    assert p.returncode == 2 and "--lambda" in p.stderr, p.stderr
    # A number out of range is bad input, checked before the .blend is opened (tests/bpy/test_option_properties.py).
    for bad in ("-1", "nan"):
        p = run_cli(tmp_path / "x.blend", "--lambda", bad)
        assert p.returncode == 1 and error_lines(p) == [line for line in p.stderr.splitlines() if line], p.stderr
        assert error_lines(p)[0].startswith("error: lambda must be"), p.stderr
    assert files_under(tmp_path) == []


def test_a_camera_without_photo_fails_cleanly(tmp_path):
    blend, s = save_scene(tmp_path, photo=None)
    before = digest(blend)
    p = run_cli(blend, *FAST, "--out", tmp_path / "out")
    assert p.returncode == 1 and len(error_lines(p)) == 1 and "Traceback" not in p.stderr
    assert not (tmp_path / "out").exists() and digest(blend) == before


@pytest.mark.parametrize(
    "exc, line",
    [
        (
            MemoryError(),
            (
                "error: out of memory: lower the working resolution (--working-res), the working total "
                "(--working-total) or the texture size (--texture-size)"
            ),
        ),
        (RuntimeError("boom"), "error: unexpected RuntimeError: boom (run with --debug for the traceback)"),
    ],
)
def test_any_failure_is_one_error_line_and_a_traceback_only_with_debug(tmp_path, monkeypatch, capsys, exc, line):
    from blender_addon import cli, pipeline

    blend, _ = save_scene(tmp_path)
    before = digest(blend)

    def fail(*args, **kwargs):  # the run fails as it would on a machine out of memory, or with a bug
        raise exc

    monkeypatch.setattr(pipeline, "run", fail)
    argv = [blend, *FAST, "--out", str(tmp_path / "out")]
    assert cli.main(argv) == 1
    err = capsys.readouterr().err
    assert [l for l in err.splitlines() if l] == [line]
    assert cli.main([*argv, "--debug"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("Traceback") and "in fail" in err and err.splitlines()[-1] == line
    assert not (tmp_path / "out").exists() and digest(blend) == before


@pytest.mark.slow
@needs_fixture_maker
def test_fixture_scene_is_delit_better_than_plain_projection(tmp_path):
    """A small Cycles render of blend_fixtures' lambert_sky, both ways of running, the paper's RMSE protocol."""
    sys.path.insert(0, os.path.join(ROOT, "blend_fixtures"))
    try:
        import make_fixtures
    finally:
        sys.path.remove(os.path.join(ROOT, "blend_fixtures"))
    from blender_addon.core.evaluate.metrics import scaled_rmse

    info = make_fixtures.generate(
        "lambert_sky", str(tmp_path), resolution=(128, 96), n_cameras=8, samples=8, texture_size=64
    )
    obj = info["mesh"]["object"]
    blend = tmp_path / "lambert_sky" / "scene.blend"
    gt = read_exr(tmp_path / "lambert_sky" / "albedo_gt.exr")[0]
    common = ["--object", obj, "--texture-size", "64"]
    p = run_cli(blend, *common, "--method", "project", "--out", tmp_path / "project")
    assert p.returncode == 0, p.stderr
    p = run_script(blend, *common, "--method", "texture", "--max-iter", "10", "--out", tmp_path / "texture")
    assert p.returncode == 0, p.stderr
    rmse = {}
    for m in ("project", "texture"):
        est = read_exr(tmp_path / m / f"{obj}_albedo.exr")[0]
        seen = (est[..., 3] > 0) & (gt[..., 3] > 0)
        assert seen.sum() > 0.5 * (gt[..., 3] > 0).sum()
        rmse[m] = float(np.mean(scaled_rmse(est[..., :3], gt[..., :3], seen)))
    # Measured: project 0.223, texture 0.134 (default levels, 10 iterations at the finest).
    assert rmse["texture"] < 0.7 * rmse["project"], rmse


def test_a_photogrammetry_importer_scene_runs_with_no_options(tmp_path):
    # As the importer leaves it: image planes beside the cameras, the last camera active, no mesh named.
    s = build_scene(str(tmp_path), n_cameras=3, size=(32, 24), photo="plane", kind="exr")
    bpy.context.view_layer.objects.active = s.cameras[-1]
    blend = str(tmp_path / "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    before = digest(blend)
    p = run_cli(blend)
    assert p.returncode == 0, p.stderr
    assert (tmp_path / "delight_Target" / "Target_albedo.exr").is_file()
    assert digest(blend) == before
