"""Build the Linux extension zip as the README does, install it into the running bpy (Blender 4.2 or 5.2)
under a temporary BLENDER_USER_RESOURCES, enable it and run the operator, in a subprocess."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile

import pytest

bpy = pytest.importorskip("bpy")

from conftest import ROOT, build_scene  # noqa: E402

pytestmark = [pytest.mark.bpy, pytest.mark.slow]

sys.path.insert(0, os.path.join(ROOT, "tools"))
import build_extension  # noqa: E402

# Runs in a fresh interpreter. scipy, OpenEXR and threadpoolctl must come from the
# wheels the extension installed, not from this venv: a finder refuses them elsewhere.
CHILD = r"""
import importlib.machinery, json, os, sys

SHIPPED = ("scipy", "OpenEXR", "Imath", "threadpoolctl")

class OnlyFromExtensions:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] not in SHIPPED or "." in name:
            return None
        where = [p for p in sys.path if os.sep + "extensions" + os.sep in p]
        spec = importlib.machinery.PathFinder.find_spec(name, where)
        if spec is None:
            raise ImportError(f"{name} is not installed by the extension")
        return spec

sys.meta_path.insert(0, OnlyFromExtensions())

import bpy
zip_path, blend, out = sys.argv[1:4]
assert bpy.utils.resource_path("USER") == os.environ["BLENDER_USER_RESOURCES"]
res = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
assert res == {"FINISHED"}, res
bpy.ops.wm.open_mainfile(filepath=blend)
res = bpy.ops.delight.run(method="texture", texture_size=16, max_iter=2, out_dir=out)
import scipy, OpenEXR, threadpoolctl
mod = sys.modules["bl_ext.user_default.delight"]
print("RESULT " + json.dumps({
    "run": sorted(res), "addon": mod.__file__, "scipy": scipy.__file__, "openexr": OpenEXR.__file__,
    "threadpoolctl": threadpoolctl.__file__,
    "scipy_version": scipy.__version__,
    "core": sys.modules["bl_ext.user_default.delight.core.solve.solver"].__file__,
    "files": sorted(os.listdir(out)),
    "base_color": bpy.data.objects["Target"].material_slots[0].material.node_tree.nodes["Principled BSDF"]
        .inputs["Base Color"].links[0].from_node.name,
}))
"""


def builder_python():
    """The interpreter the README builds the extension with (.venv), so every Blender tests the same zip."""
    venv = os.path.join(ROOT, ".venv", "bin", "python")
    return venv if os.path.exists(venv) else sys.executable


@pytest.fixture(scope="module")
def extension_zip(tmp_path_factory):
    out = tmp_path_factory.mktemp("dist")
    # Downloaded wheels are cached in the git-ignored build folder (the default --wheels-dir).
    p = subprocess.run(
        [
            builder_python(),
            os.path.join(ROOT, "tools", "build_extension.py"),
            "--platforms",
            "linux-x64",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    zips = sorted(str(x) for x in out.glob("*.zip"))
    assert [os.path.basename(z) for z in zips] == ["delight-0.1.0-linux_x64.zip"]
    assert p.stdout.splitlines()[-1] == zips[0]  # the path comes last
    return zips[0]


def test_zip_holds_the_add_on_the_real_core_and_the_wheels(extension_zip):
    with zipfile.ZipFile(extension_zip) as z:
        names = z.namelist()
        manifest = z.read("blender_manifest.toml").decode()
        infos = {i.filename: i for i in z.infolist()}
    assert {"__init__.py", "operator.py", "pipeline.py", "core/__init__.py", "core/solve/solver.py"} <= set(names)
    # core is real files, not a symlink entry (mode bits 0o120000).
    assert (infos["core/solve/solver.py"].external_attr >> 16) & 0o170000 != 0o120000
    wheels = sorted(n[len("wheels/") :] for n in names if n.startswith("wheels/"))
    # One wheel per package and Blender Python (3.11: Blender 4.2-5.0; 3.13: 5.1-5.2), all for Linux x64,
    # at the versions requirements.txt pins; one pure-Python wheel for both.
    pins = dict(r.split("==") for r in build_extension.shipped_requirements())
    expected = sorted(
        [f"{name}-{pins[name]}-{tag}" for name in ("openexr", "scipy") for tag in ("cp311", "cp313")]
        + [f"threadpoolctl-{pins['threadpoolctl']}-py3"]
    )
    assert sorted("-".join(w.split("-")[:3]) for w in wheels) == expected
    compiled = [w for w in wheels if not w.endswith("-none-any.whl")]
    assert len(compiled) == 4 and all(w.endswith("_x86_64.whl") and "linux" in w for w in compiled), wheels
    assert 'id = "delight"' in manifest and 'blender_version_min = "4.2.0"' in manifest
    generated = manifest.split("[build.generated]")[1]
    assert 'platforms = ["linux-x64"]' in generated
    for w in wheels:
        assert f'"./wheels/{w}"' in generated


def test_installed_extension_runs_the_operator(extension_zip, tmp_path):
    build_scene(str(tmp_path))
    blend = str(tmp_path / "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=blend)
    user = tmp_path / "user"
    user.mkdir()
    out = tmp_path / "out"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(BLENDER_USER_RESOURCES=str(user), OPENBLAS_NUM_THREADS="1")
    p = subprocess.run(
        [sys.executable, "-c", CHILD, extension_zip, blend, str(out)],
        cwd=str(tmp_path),
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    line = next(x for x in p.stdout.splitlines() if x.startswith("RESULT "))
    r = json.loads(line[len("RESULT ") :])
    assert r["run"] == ["FINISHED"]
    ext = str(user / "extensions")
    for key in ("addon", "scipy", "openexr", "threadpoolctl", "core"):
        assert r[key].startswith(ext), (key, r[key])
    # Blender installed the wheels of its own Python, the pinned ones.
    assert f"python{sys.version_info[0]}.{sys.version_info[1]}" in r["scipy"]
    pins = dict(q.split("==") for q in build_extension.shipped_requirements())
    assert r["scipy_version"] == pins["scipy"]
    assert {"Target_albedo.exr", "lighting.json", "report.json", "views"} <= set(r["files"])
    assert r["base_color"] == "Delight Albedo"
