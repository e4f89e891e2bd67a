"""The checked-in stairs_noise (12 flat faces, a sun that casts shadows, fine albedo noise), through real Blender.

A photo of a few flat faces leaves most of its lighting's coefficients undetermined, and a sun's smooth part is
itself SH: the coupled lighting must still delight every channel, and the same each time.
"""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from conftest import ROOT, needs_fixture_blend  # noqa: E402

from bench.accuracy import texture_rmse  # noqa: E402
from blender_addon import pipeline  # noqa: E402
from blender_addon.core.io.exr import read_exr, write_exr  # noqa: E402

pytestmark = [pytest.mark.bpy, needs_fixture_blend]

FIXTURE = os.path.join(ROOT, "blend_fixtures", "stairs_noise")


def _albedo_rmse(fixture_dir, out_dir):
    bpy.ops.wm.open_mainfile(filepath=os.path.join(fixture_dir, "scene.blend"))
    rep = pipeline.run(
        bpy.context.scene, pipeline.Options(object_name="Subject", texture_size=256, out_dir=str(out_dir))
    )
    return np.array(texture_rmse(rep.albedo_path, read_exr(os.path.join(FIXTURE, "albedo_gt.exr"))[0])[0])


def test_few_flat_faces_are_delit_in_every_channel_and_the_same_under_a_little_noise(tmp_path):
    clean = _albedo_rmse(FIXTURE, tmp_path / "clean")
    # The same photos times 1 + 0.001 N(0, 1) per pixel and channel (alpha kept).
    noisy_dir = tmp_path / "stairs_noise"
    shutil.copytree(FIXTURE, noisy_dir)
    rng = np.random.default_rng(0)
    photos = noisy_dir / "photos"
    for name in sorted(os.listdir(photos)):
        pixels, channels = read_exr(str(photos / name))[:2]
        pixels = pixels.copy()
        pixels[..., :3] *= 1 + 0.001 * rng.standard_normal(pixels[..., :3].shape).astype(np.float32)
        os.remove(photos / name)
        write_exr(str(photos / name), pixels, channels=channels)
    noisy = _albedo_rmse(str(noisy_dir), tmp_path / "noisy")
    # Measured (bpy 5.2): 0.078 / 0.062 / 0.074 both times. Before the joint sun-and-SH step and the prior's floor:
    # green 0.206 (its sun strength fell to 0), and the mean moved between 0.089 and 0.142 with such noise.
    assert clean.max() < 0.1 and noisy.max() < 0.1, (clean, noisy)
    assert abs(clean.mean() - noisy.mean()) < 0.005, (clean, noisy)
