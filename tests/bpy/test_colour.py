"""Photos come in through Blender's colour management, into the file's linear working space."""

import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bpy  # noqa: E402
from conftest import build_scene  # noqa: E402

from blender_addon import pipeline  # noqa: E402
from blender_addon.core.io.exr import read_exr, write_exr  # noqa: E402

pytestmark = [
    pytest.mark.bpy,
    pytest.mark.skipif(
        not hasattr(getattr(bpy.data, "colorspace", None), "working_space"),
        reason="Blender 4.x has one working space (Linear Rec.709)",
    ),
]


def set_working_space(name):
    if bpy.data.colorspace.working_space != name:
        bpy.ops.wm.set_working_color_space(working_space=name, convert_colors=False)
    assert bpy.data.colorspace.working_space == name


def rec709_to_working(folder):
    """3x3 matrix from Linear Rec.709 to the working space, as Blender converts an image."""
    path = os.path.join(folder, "primaries.exr")
    write_exr(path, np.eye(3, dtype=np.float32).reshape(1, 3, 3))
    img = bpy.data.images.load(path)
    img.colorspace_settings.name = "Linear Rec.709"
    px = np.empty(12, np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(3, 4)[:, :3].T  # column j: primary j in the working space


def albedo_under(space, kind, folder):
    bpy.ops.wm.read_homefile(use_empty=True)
    set_working_space(space)
    os.makedirs(folder, exist_ok=True)
    s = build_scene(folder, n_cameras=4, size=(48, 36), kind=kind)
    report = pipeline.run(
        s.scene, pipeline.Options(out_dir=os.path.join(folder, "out"), method="project", texture_size=32)
    )
    rgba = read_exr(report.albedo_path)[0]
    assert bpy.data.images[report.image_name].colorspace_settings.name == space
    matrix = rec709_to_working(folder)
    bpy.ops.wm.read_homefile(use_empty=True)
    return rgba, matrix


@pytest.mark.parametrize("kind", ["png", "exr"])
def test_acescg_working_space_gives_the_same_albedo(tmp_path, kind):
    ref, eye = albedo_under("Linear Rec.709", kind, str(tmp_path / "rec709"))
    aces, to_aces = albedo_under("ACEScg", kind, str(tmp_path / "acescg"))
    np.testing.assert_allclose(eye, np.eye(3), atol=1e-6)
    assert np.abs(to_aces - np.eye(3)).max() > 0.05  # really another space
    seen = (ref[..., 3] > 0) & (aces[..., 3] > 0)
    assert seen.sum() > 100
    expected = ref[..., :3][seen] @ to_aces.T
    np.testing.assert_allclose(aces[..., :3][seen], expected, atol=1e-3)
