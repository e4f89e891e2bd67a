"""Accuracy on the smallest fixture: a reduced lambert_sky rendered with Cycles, scored as bench/accuracy.py does.

Our default (texture domain, default lambda and iterations) must beat plain projection by the margin measured
here, under both protocols (the albedo texture, and the paper's per-view maps).
"""

from __future__ import annotations

import json
import os
import sys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from conftest import ROOT, needs_fixture_maker  # noqa: E402

from bench.accuracy import texture_rmse, views_rmse  # noqa: E402
from bench.accuracy_quick import _scored, run_project, truth  # noqa: E402
from bench.shading_ceiling import least_squares_albedo, shading_views  # noqa: E402
from blender_addon import pipeline  # noqa: E402
from blender_addon.core.io.exr import read_exr  # noqa: E402
from core.evaluate.metrics import scaled_rmse  # noqa: E402

pytestmark = [pytest.mark.bpy, needs_fixture_maker]

RES, N_CAMS, SAMPLES, TEX = (160, 120), 8, 16, 128


def make_fixtures():
    sys.path.insert(0, os.path.join(ROOT, "blend_fixtures"))
    try:
        import make_fixtures as mf
    finally:
        sys.path.remove(os.path.join(ROOT, "blend_fixtures"))
    return mf


def reduced_fixture(tmp_path_factory, name, resolution, **extra):
    """The fixture ``name`` rendered at ``resolution`` with N_CAMS cameras, SAMPLES samples, a TEX^2 truth (and
    ``extra`` outputs of make_fixtures.generate); its folder."""
    out = tmp_path_factory.mktemp(name)
    make_fixtures().generate(
        name, str(out), resolution=resolution, n_cameras=N_CAMS, samples=SAMPLES, texture_size=TEX, **extra
    )
    return os.path.join(str(out), name)


@pytest.fixture(scope="module")
def small_sky(tmp_path_factory):
    """lambert_sky at 160x120, 8 cameras, 16 samples, 128^2 truth, with per-view truth and shading (~10 s of
    Cycles)."""
    return reduced_fixture(tmp_path_factory, "lambert_sky", RES, view_gt=True, shading_views=True)


def run_fixture(fixture_dir, out_dir, **kw):
    """Run the pipeline in-process on the fixture at TEX (or ``texture_size``); return (run report, report.json,
    scene.json, truth)."""
    kw.setdefault("texture_size", TEX)
    with open(os.path.join(fixture_dir, "scene.json")) as fh:
        record = json.load(fh)
    bpy.ops.wm.open_mainfile(filepath=os.path.join(fixture_dir, "scene.blend"))
    rep = pipeline.run(
        bpy.context.scene,
        pipeline.Options(object_name=record["mesh"]["object"], out_dir=str(out_dir), **kw),
    )
    with open(os.path.join(out_dir, "report.json")) as fh:
        report = json.load(fh)
    return rep, report, record, read_exr(os.path.join(fixture_dir, "albedo_gt.exr"))[0]


def run_rmse(fixture_dir, out_dir, **kw):
    """Run the pipeline on the fixture; (texture RMSE per channel, report.json, scene.json)."""
    rep, report, record, gt = run_fixture(fixture_dir, out_dir, **kw)
    return np.array(texture_rmse(rep.albedo_path, gt)[0]), report, record


def score(fixture_dir, out_dir, **kw):
    """Run the pipeline in-process on the fixture; return (texture RMSE, views RMSE, texels compared)."""
    rep, report, record, gt = run_fixture(fixture_dir, out_dir, **kw)
    tex, n = texture_rmse(rep.albedo_path, gt)
    return np.array(tex), np.array(views_rmse(str(out_dir), report, fixture_dir, record)), n, gt


def test_default_beats_projection_on_the_smallest_fixture(small_sky, tmp_path):
    proj_tex, proj_views, n_proj, gt = score(small_sky, tmp_path / "project", method="project")
    ours_tex, ours_views, n_ours, _ = score(small_sky, tmp_path / "texture")  # the defaults
    inside = int(np.count_nonzero(gt[..., 3] > 0.5))
    # Measured: 7022 (project) and 7251 (texture: the bilinear splat reaches a few more) of 8600 inside texels.
    assert min(n_proj, n_ours) > 0.75 * inside
    # Measured with the issue-13 defaults (occlusion-aware transfer, two stages, lighting coupled), R / G / B:
    #   texture protocol: project 0.289 / 0.208 / 0.171, ours 0.062 / 0.053 / 0.035 (ratio of means 0.23);
    #   views protocol:   project 0.259 / 0.183 / 0.154, ours 0.062 / 0.051 / 0.034 (ratio 0.25).
    # (At 85eeb89, with the paper's model in one stage, ours was 0.098 / 0.089 / 0.051, ratio 0.36.)
    for ours, proj in ((ours_tex, proj_tex), (ours_views, proj_views)):
        assert ours.mean() < 0.3 * proj.mean(), (ours, proj)
        assert np.all(ours < 0.35 * proj), (ours, proj)
    assert ours_tex.mean() < 0.06 and ours_views.mean() < 0.06, (ours_tex, ours_views)


def test_occlusion_and_two_stages_beat_the_papers_model(small_sky, tmp_path):
    # The same scene with the paper's model and schedule (nu(n), one stage, lighting free per view):
    # measured 0.089 / 0.085 / 0.049 against the default's 0.062 / 0.053 / 0.035. The sky is hidden from the
    # plinth and the eye sockets, and one stage lets the lighting take part of the albedo.
    paper, _, _, _ = score(small_sky, tmp_path / "paper", albedo_lam=None, occlusion=False, lighting="per_view")
    ours, _, _, _ = score(small_sky, tmp_path / "texture")
    assert ours.mean() < 0.8 * paper.mean(), (ours, paper)
    assert np.all(ours < paper), (ours, paper)


def test_the_shading_known_gives_back_the_albedo(small_sky, tmp_path):
    """bench/shading_ceiling.py's bound: the photos divided by Cycles' own shading give the albedo back."""
    with open(os.path.join(small_sky, "scene.json")) as fh:
        record = json.load(fh)
    bpy.ops.wm.open_mainfile(filepath=os.path.join(small_sky, "scene.blend"))
    opt = pipeline.Options(object_name=record["mesh"]["object"], out_dir=str(tmp_path), align_photos=False)
    prepared = pipeline.prepare(bpy.context.scene, opt)
    inputs, bakes = prepared.inputs, prepared.bakes
    gt, inside = truth(small_sky, record, TEX)
    clean, shadings, _ = shading_views(small_sky, record, inputs)

    def rmse(photos, shading):
        albedo = least_squares_albedo(inputs, bakes, photos, shading, TEX)
        return scaled_rmse(albedo, gt, np.isfinite(albedo[..., 0]) & inside)

    known = rmse(clean, shadings)
    project = np.array(_scored(run_project(inputs, bakes, TEX), gt, inside))
    # Measured: project 0.288 / 0.207 / 0.170, the shading known 0.034 / 0.024 / 0.018 (what is left: render
    # noise and the 160x120 photos' resolution), a shading flat per photo 0.205 / 0.156 / 0.137.
    assert np.all(known < 0.2 * project), (known, project)
    assert known.mean() < 0.04, known
    flat = [np.broadcast_to(s[b.mask].mean(axis=0), s.shape) for s, b in zip(shadings, bakes)]
    assert rmse(clean, flat).mean() > 4 * known.mean()
