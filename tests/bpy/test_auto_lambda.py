"""Auto lambda on the checked-in fixtures: the photos alone tell one lighting from a lighting per shot."""

from __future__ import annotations

import json
import os

import pytest

bpy = pytest.importorskip("bpy")

from conftest import ROOT, needs_fixture_blend  # noqa: E402

from blender_addon import pipeline  # noqa: E402
from blender_addon.core.solve.lambda_choice import (  # noqa: E402
    LAMBDA_FIXED,
    LAMBDA_VARYING,
    LIGHT_LAMBDA,
    VARYING_THRESHOLD,
)

pytestmark = [pytest.mark.bpy, needs_fixture_blend]


@pytest.mark.parametrize(
    "name,lam,lighting",
    [
        ("lambert_sky", LAMBDA_FIXED, "coupled"),
        ("photo_sun", LAMBDA_FIXED, "coupled"),
        ("varying_light", LAMBDA_VARYING, "per_view"),
    ],
)
@pytest.mark.parametrize("stages", [1, 2])
def test_auto_lambda_follows_the_lighting(name, lam, lighting, stages, tmp_path):
    fixture = os.path.join(ROOT, "blend_fixtures", name)
    bpy.ops.wm.open_mainfile(filepath=os.path.join(fixture, "scene.blend"))
    # A 32^2 texture has no coarse level, so one iteration is cheap; lambda is chosen before solving.
    options = pipeline.Options(
        object_name="Subject", texture_size=32, max_iter=1, working_res_mp=0.05, out_dir=str(tmp_path), occlusion=False
    )
    if stages == 1:
        options.albedo_lam = None
    rep = pipeline.run(bpy.context.scene, options)
    with open(tmp_path / "report.json") as fh:
        params = json.load(fh)["parameters"]
    # With two stages the lighting stage always takes the strong TV weight; the photos choose the lighting
    # model instead: one light held in common when it is fixed, free per photo when it moves.
    lam = lam if stages == 1 else LIGHT_LAMBDA
    assert params["lambda_auto"] is True and params["lambda"] == lam, params
    assert params["lighting"] == lighting, params
    assert rep.lam == lam and rep.lighting_variation == params["lighting_variation"]
    assert rep.lambda_text.startswith(f"lambda {lam:g} (auto: lighting varies")
    # Measured at full resolution: 0.013 (lambert_sky), 0.13 (photo_sun), 0.45 (varying_light).
    variation = params["lighting_variation"]
    assert (variation > VARYING_THRESHOLD) == (lighting == "per_view"), variation


def test_a_given_lambda_is_used_as_is(tmp_path):
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, "blend_fixtures", "varying_light", "scene.blend"))
    # With the lighting model given too, nothing is measured on the photos.
    rep = pipeline.run(
        bpy.context.scene,
        pipeline.Options(
            object_name="Subject",
            texture_size=32,
            max_iter=1,
            lam=2.0,
            working_res_mp=0.05,
            out_dir=str(tmp_path),
            lighting="shared",
            occlusion=False,
        ),
    )
    with open(tmp_path / "report.json") as fh:
        params = json.load(fh)["parameters"]
    assert params["lambda"] == 2.0 and params["lambda_auto"] is False and params["lighting_variation"] is None
    assert params["lighting"] == "shared"
    assert rep.lambda_text == "lambda 2"
