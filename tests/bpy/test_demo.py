"""The demo's picture step (tools/demo_pictures.py, as tools/demo.sh calls it) on a small run: every promised file."""
from __future__ import annotations

import os
import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from conftest import ROOT, needs_fixture_maker  # noqa: E402

from blender_addon import pipeline  # noqa: E402
from blender_addon.core.evaluate.pictures import BACKGROUND  # noqa: E402

pytestmark = [pytest.mark.bpy, needs_fixture_maker]

RES, N_CAMS = (96, 72), 4
GAP = 6        # core.evaluate.pictures.strip's gap


def read_png(path):
    """Decode the PNGs core.evaluate.png writes (8-bit RGB, filter 0 on every row) into (H, W, 3) uint8."""
    with open(path, "rb") as fh:
        data = fh.read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, header = 8, b"", None
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        assert struct.unpack(">I", data[pos + 8 + n:pos + 12 + n])[0] == zlib.crc32(kind + body) & 0xFFFFFFFF
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    w, h, depth, colour = header[:4]
    assert depth == 8 and colour == 2
    raw = np.frombuffer(zlib.decompress(idat), dtype=np.uint8).reshape(h, 1 + 3 * w)
    assert np.all(raw[:, 0] == 0)
    return raw[:, 1:].reshape(h, w, 3)


def test_demo_pictures_writes_every_promised_file(tmp_path):
    sys.path.insert(0, os.path.join(ROOT, "blend_fixtures"))
    try:
        import make_fixtures
    finally:
        sys.path.remove(os.path.join(ROOT, "blend_fixtures"))
    make_fixtures.generate("lambert_sky", str(tmp_path), resolution=RES, n_cameras=N_CAMS, samples=4,
                           texture_size=64, view_gt=True)
    fixture = tmp_path / "lambert_sky"
    bpy.ops.wm.open_mainfile(filepath=str(fixture / "scene.blend"))
    out = tmp_path / "demo"
    pipeline.run(bpy.context.scene, pipeline.Options(object_name="Subject", texture_size=64, max_iter=4,
                                                     out_dir=str(out)))

    # The same command line as tools/demo.sh, on this small output.
    with open(os.path.join(ROOT, "tools", "demo.sh")) as fh:
        assert 'tools/demo_pictures.py out/demo --fixture "$(dirname "$scene")"' in fh.read()
    p = subprocess.run([sys.executable, "tools/demo_pictures.py", str(out), "--fixture", str(fixture)], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    names = ["before_after.png", "lighting.png", "convergence.png"]
    assert sorted(os.listdir(out / "pictures")) == sorted(names)
    assert len(p.stdout.splitlines()) == 3 and all(n in p.stdout for n in names)
    assert sorted(os.listdir(out)) == sorted(["Subject_albedo.exr", "lighting.json", "report.json", "views",
                                              "pictures"])

    # Photo | ours | truth, each a full view under a label row.
    strip = read_png(out / "pictures" / "before_after.png")
    assert strip.shape[1] == GAP + 3 * (RES[0] + GAP)
    panels = [strip[-RES[1] - GAP:-GAP, GAP + k * (RES[0] + GAP):(k + 1) * (RES[0] + GAP)] for k in range(3)]
    on_mesh = [np.any(p != np.array(BACKGROUND, np.uint8), axis=2).mean() for p in panels]
    assert all(f > 0.1 for f in on_mesh), on_mesh
    # One sphere per camera (at most 5 in a row).
    spheres = read_png(out / "pictures" / "lighting.png")
    assert spheres.shape[1] == GAP + N_CAMS * (96 + GAP)
    # The curve (red) is drawn, over white.
    curve = read_png(out / "pictures" / "convergence.png")
    red = (curve[..., 0] > 150) & (curve[..., 1] < 90) & (curve[..., 2] < 90)
    assert red.sum() > 100 and (curve == 255).all(axis=2).mean() > 0.5
