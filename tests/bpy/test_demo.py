"""The demo's picture step (tools/demo_pictures.py, as tools/demo.sh calls it) on a small run: every promised file."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
from conftest import ROOT, needs_fixture_maker  # noqa: E402
from matplotlib.image import imread  # noqa: E402

from blender_addon import pipeline  # noqa: E402
from blender_addon.core.evaluate.pictures import BACKGROUND  # noqa: E402

sys.path.insert(0, os.path.join(ROOT, "tools"))
import demo_pictures as dp  # noqa: E402

sys.path.remove(os.path.join(ROOT, "tools"))

pytestmark = [pytest.mark.bpy, needs_fixture_maker]

RES, N_CAMS = (96, 72), 4


def read_png(path):
    """(H, W, 3) uint8 of a PNG file, read by matplotlib."""
    with open(path, "rb") as fh:
        assert fh.read(8) == b"\x89PNG\r\n\x1a\n"
    px = imread(path)
    assert px.dtype == np.float32 and px.ndim == 3
    return np.round(px[..., :3] * 255).astype(np.uint8)


def coloured(rgb, margin=40):
    """Pixels far from grey (the lines of the plot; axes, text and grid are black or grey)."""
    rgb = rgb.astype(int)
    return rgb.max(axis=2) - rgb.min(axis=2) > margin


def test_demo_pictures_writes_every_promised_file(tmp_path):
    sys.path.insert(0, os.path.join(ROOT, "blend_fixtures"))
    try:
        import make_fixtures
    finally:
        sys.path.remove(os.path.join(ROOT, "blend_fixtures"))
    make_fixtures.generate(
        "lambert_sky", str(tmp_path), resolution=RES, n_cameras=N_CAMS, samples=4, texture_size=64, view_gt=True
    )
    fixture = tmp_path / "lambert_sky"
    bpy.ops.wm.open_mainfile(filepath=str(fixture / "scene.blend"))
    out = tmp_path / "demo"
    pipeline.run(
        bpy.context.scene, pipeline.Options(object_name="Subject", texture_size=64, max_iter=4, out_dir=str(out))
    )

    # The same command line as tools/demo.sh, on this small output.
    with open(os.path.join(ROOT, "tools", "demo.sh")) as fh:
        assert 'tools/demo_pictures.py out/demo --fixture "$(dirname "$scene")"' in fh.read()
    p = subprocess.run(
        [sys.executable, "tools/demo_pictures.py", str(out), "--fixture", str(fixture)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 0, p.stderr
    names = ["before_after.png", "lighting.png", "convergence.png"]
    assert sorted(os.listdir(out / "pictures")) == sorted(names)
    assert len(p.stdout.splitlines()) == 3 and all(n in p.stdout for n in names)
    assert sorted(os.listdir(out)) == sorted(
        ["Subject_albedo.exr", "lighting.json", "lighting.exr", "report.json", "views", "pictures"]
    )

    # Photo | ours | truth, each PANEL pixels wide at the photos' aspect, under a title row.
    pad, title, panel = dp.PAD, dp.TITLE, dp.PANEL
    ph = round(panel * RES[1] / RES[0])
    strip = read_png(out / "pictures" / "before_after.png")
    assert strip.shape == (title + ph + pad, pad + 3 * (panel + pad), 3)
    for k in range(3):  # a title (dark text on white) above each picture
        row = strip[:title, pad + k * (panel + pad) : (k + 1) * (panel + pad)]
        assert (row.max(axis=2) < 100).sum() > 30 and (row == 255).all(axis=2).mean() > 0.7
    assert not (strip[title : title + ph, pad : pad + panel] == 255).all(axis=2).any()  # the photo fills its box
    for k in (1, 2):  # ours and the truth: the mesh over the background grey
        box = strip[title + 4 : title + ph - 4, pad + k * (panel + pad) + 4 : (k + 1) * (panel + pad) - 4].astype(int)
        off = np.abs(box - np.array(BACKGROUND)).max(axis=2) > 3
        assert 0.1 < off.mean() < 0.9, (k, off.mean())
    # One sphere per camera (at most COLUMNS in a row), each under its name.
    spheres = read_png(out / "pictures" / "lighting.png")
    assert spheres.shape == (title + title + dp.SPHERE + pad, pad + N_CAMS * (dp.SPHERE + pad), 3)
    # The curve is drawn (coloured), mostly over white.
    curve = read_png(out / "pictures" / "convergence.png")
    assert curve.shape == (dp.PLOT[1], dp.PLOT[0], 3)
    assert coloured(curve).sum() > 200 and (curve == 255).all(axis=2).mean() > 0.5


def test_convergence_has_one_line_per_level(tmp_path):
    """The coarse levels nested in the solver info each get a line; log y only when the energy spans decades."""
    report = {
        "energy": [1e5, 3e3, 2e3],
        "solver_info": {
            "solved_size": 64,
            "coarse": {
                "size": 32,
                "energy": [5e4, 1e3],
                "info": {"coarse": {"size": 16, "energy": [2e4, 9e2, 8e2, 7e2], "info": {"coarse": None}}},
            },
        },
    }
    levels = dp.energy_levels(report)
    assert levels == [("64² texels", [1e5, 3e3, 2e3]), ("32² texels", [5e4, 1e3]), ("16² texels", [2e4, 9e2, 8e2, 7e2])]
    # The bundle CLI's report keeps the solver's info under "info"; an image-domain level is named by its size.
    image = {
        "energy": [3.0, 2.0],
        "info": {"coarse": {"size": None, "shapes": [[24, 32], [24, 32]], "energy": [4.0, 1.0], "info": {}}},
    }
    assert dp.energy_levels(image) == [("full size", [3.0, 2.0]), ("32x24 pixels (first view)", [4.0, 1.0])]

    def line_colours(levels_):
        path = str(tmp_path / "c.png")
        dp.draw_convergence(path, levels_)
        rgb = read_png(path)
        assert rgb.shape == (dp.PLOT[1], dp.PLOT[0], 3)
        c = rgb[coloured(rgb)].astype(int) // 32  # coarse colour bins
        bins, counts = np.unique(c, axis=0, return_counts=True)
        return len(bins[counts > 50])

    assert line_colours(levels) > line_colours(levels[:1]) >= 1
    assert dp.log_scale([1e5, 2e3]) and not dp.log_scale([12.0, 9.0]) and not dp.log_scale([1e5, 0.0])
