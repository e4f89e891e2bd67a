"""The panel's pictures of the last run: made by a run, saved with the .blend, replaced on re-run, not made on
cancel."""

from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from conftest import build_scene  # noqa: E402

from blender_addon import pipeline, previews  # noqa: E402
from blender_addon.core.errors import Cancelled  # noqa: E402
from blender_addon.core.evaluate.pictures import BACKGROUND  # noqa: E402

pytestmark = pytest.mark.bpy


def options(out, **kw):
    kw.setdefault("method", "texture")
    kw.setdefault("texture_size", 32)
    kw.setdefault("max_iter", 3)
    return pipeline.Options(out_dir=str(out), **kw)


def pixels(img):
    w, h = img.size
    px = np.empty(w * h * 4, dtype=np.float32)
    img.pixels.foreach_get(px)
    return np.round(px.reshape(h, w, 4)[::-1, :, :3] * 255).astype(np.uint8)


def not_background(rgb):
    return np.any(rgb != np.array(BACKGROUND, dtype=np.uint8), axis=2)


def test_run_adds_compare_and_lighting_images_that_are_saved_with_the_file(tmp_path):
    s = build_scene(str(tmp_path))  # 4 cameras, 64 x 48 photos
    pipeline.run(s.scene, options(tmp_path / "out"))
    compare, lighting = previews.find("Target")
    assert (
        (compare.name, lighting.name)
        == previews.image_names("Target")
        == ("Target_delight_compare", "Target_delight_lighting")
    )
    # Photo | reflectance side by side, each 64 x 48, no text in the pixels: the caption says what they are.
    c = pixels(compare)
    assert c.shape == (6 + 48 + 6, 6 + 2 * (64 + 6), 3)
    photo_half, ours_half = not_background(c[6:54, 6:70]), not_background(c[6:54, 76:140])
    assert photo_half.mean() > 0.9 and 0.05 < ours_half.mean() < 0.9  # the reflectance only on the mesh
    best = previews.caption(compare).split(":")[0]
    assert best in [cam.name for cam in s.cameras] and previews.caption(compare) == f"{best}: photo | reflectance"
    # One sphere per camera, 4 in a row, each a lit disc; the caption names the views in that order.
    lit = not_background(pixels(lighting))
    assert tuple(lighting.size) == (6 + 4 * (64 + 6), 6 + 64 + 6) and 0.3 < lit.mean() < 0.8
    assert previews.caption(lighting) == "Lighting, left to right: " + ", ".join(cam.name for cam in s.cameras)
    for img in (compare, lighting):
        assert img.packed_file is not None and img.use_fake_user
    # They survive a save and reload (fake user + packed).
    names = [compare.name, lighting.name]
    path = str(tmp_path / "saved.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    again = previews.find("Target")
    assert [i.name for i in again] == names
    np.testing.assert_array_equal(pixels(again[0]), c)
    assert previews.caption(again[0]) == f"{best}: photo | reflectance"


def test_rerun_replaces_the_images_and_project_drops_the_lighting(tmp_path):
    s = build_scene(str(tmp_path))
    pipeline.run(s.scene, options(tmp_path / "out"))
    names = sorted(i.name for i in bpy.data.images)
    pipeline.run(s.scene, options(tmp_path / "out", overwrite=True, max_iter=2))
    assert sorted(i.name for i in bpy.data.images) == names  # no .001 copies
    pipeline.run(s.scene, options(tmp_path / "out", overwrite=True, method="project"))
    assert [i.name for i in previews.find("Target")] == ["Target_delight_compare"]
    assert previews.caption(previews.find("Target")[0]).endswith(": photo | projected")


def test_cancelled_run_adds_no_pictures(tmp_path):
    s = build_scene(str(tmp_path))
    before = sorted(i.name for i in bpy.data.images)
    calls = []

    def cancel():
        calls.append(1)
        return len(calls) > 3  # after gather and bake, in the solve

    with pytest.raises(Cancelled):
        pipeline.run(s.scene, options(tmp_path / "out"), cancel=cancel)
    assert previews.find("Target") == [] and sorted(i.name for i in bpy.data.images) == before
