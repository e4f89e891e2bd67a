"""The option ``sun`` (on by default) on a reduced photo_sun (a sun with cast shadows), through real Blender: found,
used, written.

The sun's shadows leave the albedo, and lighting.json and lighting.exr carry the sun.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from conftest import needs_fixture_maker  # noqa: E402
from test_accuracy import TEX, make_fixtures, run_fixture  # noqa: E402

from bench.accuracy import texture_rmse  # noqa: E402
from blender_addon.core.io.envmap import equirect_directions  # noqa: E402
from blender_addon.core.io.exr import read_exr  # noqa: E402

pytestmark = [pytest.mark.bpy, needs_fixture_maker]


@pytest.fixture(scope="module")
def small_sun(tmp_path_factory):
    """photo_sun at 240x180, 8 cameras, 16 samples, 128^2 truth."""
    out = tmp_path_factory.mktemp("sun")
    make_fixtures().generate("photo_sun", str(out), resolution=(240, 180), n_cameras=8, samples=16, texture_size=TEX)
    return os.path.join(str(out), "photo_sun")


def run(fixture_dir, out_dir, **kw):
    rep, report, record, gt = run_fixture(fixture_dir, out_dir, **kw)
    return np.array(texture_rmse(rep.albedo_path, gt)[0]), report, record


def test_sun_shadows_leave_the_albedo(small_sun, tmp_path):
    plain, _, _ = run(small_sun, tmp_path / "plain", sun=False)
    ours, report, record = run(small_sun, tmp_path / "sun", sun=True)
    # Measured (bpy 5.2): R / G / B 0.119 / 0.105 / 0.108 without, 0.086 / 0.076 / 0.068 with the sun (0.69x).
    assert ours.mean() < 0.85 * plain.mean(), (ours, plain)

    sun = report["parameters"]["sun"]
    true = np.array(record["lighting"]["direction_to_sun"])
    angle = np.degrees(np.arccos(np.clip(np.dot(sun["direction"], true / np.linalg.norm(true)), -1, 1)))
    # Measured: 2.3 degrees from the sun, found in 3.5 s.
    assert sun["used"] and angle < 10.0, (sun, angle)
    assert report["parameters"]["lighting"] == "coupled"

    with open(tmp_path / "sun" / "lighting.json") as fh:
        lighting = json.load(fh)
    world = lighting["world"]["sun"]
    assert np.allclose(world["direction"], sun["direction"]) and min(world["strength"]) > 0
    assert all(len(v["sun_strength"]) == 3 for v in lighting["views"])
    # The environment image has the sun as its brightest spot, where the sun is.
    env = read_exr(str(tmp_path / "sun" / "lighting.exr"))[0][..., :3]
    dirs, _ = equirect_directions(env.shape[1], env.shape[0])
    brightest = dirs.reshape(-1, 3)[np.argmax(env.sum(axis=2))]
    assert np.dot(brightest, sun["direction"]) > np.cos(np.radians(3.0))
