"""The demo's three pictures, from a headless run's output folder and the fixture it delit.

    .venv/bin/python tools/demo_pictures.py OUT_DIR --fixture blend_fixtures/lambert_sky [--view cam_00]
        [--dest DIR]

Writes into ``DEST`` (default ``OUT_DIR/pictures``):

* ``before_after.png``: one input photo, our reflectance for that view (``views/<camera>.exr``) and, if the
  fixture has per-view ground truth (``gt_views/``), the true albedo seen by that view;
* ``lighting.png``: the estimated lighting of every view (``lighting.json``) as a shaded sphere seen from the
  front (from -Y, +Z up), all on one exposure;
* ``convergence.png``: the energy per iteration (``report.json``), log-scale y.

The view is the one with the most pixels on the mesh unless ``--view`` names one. Prints the paths written.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from core.io.exr import read_exr  # noqa: E402
from core.evaluate.pictures import energy_plot, lighting_spheres, strip, to_srgb8  # noqa: E402
from core.evaluate.png import write_png  # noqa: E402

FILES = ("before_after.png", "lighting.png", "convergence.png")


def _load(path):
    with open(path) as fh:
        return json.load(fh)


def _read_photo(path):
    """Linear RGB of a photo file: EXR as stored, 8-bit files decoded from sRGB (through Blender)."""
    if path.lower().endswith(".exr"):
        return read_exr(path)[0][..., :3]
    import bpy

    from blender_addon.photos import image_pixels
    img = bpy.data.images.load(path, check_existing=False)
    try:
        return image_pixels(img, os.path.basename(path))
    finally:
        bpy.data.images.remove(img)


def _masked(rgba, threshold):
    """RGB divided by A where A > threshold, NaN elsewhere (the fixture's premultiplied per-view truth)."""
    a = rgba[..., 3:4]
    return np.where(a > threshold, rgba[..., :3] / np.maximum(a, 1e-6), np.nan)


def _one_exposure(estimate, truth):
    """The single factor (all channels) that brings ``estimate`` closest to ``truth`` (for display only)."""
    ok = np.all(np.isfinite(estimate), axis=-1) & np.all(np.isfinite(truth), axis=-1)
    e, t = estimate[ok], truth[ok]
    return float(np.sum(e * t) / max(np.sum(e * e), 1e-30)) if ok.any() else 1.0


def before_after(out_dir, report, fixture_dir, view):
    """(uint8 picture, labels) of photo | ours | truth for one view."""
    cam = next(c for c in report["cameras"] if c["name"] == view)
    ours = read_exr(os.path.join(out_dir, cam["file"]))[0]
    ours = np.where(ours[..., 3:4] > 0, ours[..., :3], np.nan)
    pics, labels = [], []
    if fixture_dir:
        record = _load(os.path.join(fixture_dir, "scene.json"))
        fx = next((c for c in record["cameras"] if c["name"] == view), None)
        if fx is not None:
            pics.append(to_srgb8(_read_photo(os.path.join(fixture_dir, fx["photo"]))))
            labels.append("PHOTO")
        truth = None
        if fx is not None and fx.get("albedo_view"):
            truth = _masked(read_exr(os.path.join(fixture_dir, fx["albedo_view"]))[0], 0.5)
        if truth is not None and truth.shape == ours.shape:
            # Albedo is known up to scale: show ours at the one exposure that fits the truth best.
            pics.append(to_srgb8(ours * _one_exposure(ours, truth)))
            pics.append(to_srgb8(truth))
            labels += ["OURS", "TRUTH"]
            return strip(pics, labels)
    return strip(pics + [to_srgb8(ours)], labels + ["OURS"])


def make_pictures(out_dir, fixture_dir=None, view=None, dest=None) -> list:
    """Write the three pictures; return their paths (see the module docstring)."""
    out_dir = os.path.abspath(out_dir)
    dest = os.path.abspath(dest or os.path.join(out_dir, "pictures"))
    os.makedirs(dest, exist_ok=True)
    report = _load(os.path.join(out_dir, "report.json"))
    lighting = _load(os.path.join(out_dir, "lighting.json"))
    if view is None:
        view = max(report["cameras"], key=lambda c: c["pixels_on_mesh"])["name"]
    elif view not in [c["name"] for c in report["cameras"]]:
        raise SystemExit(f"error: no view {view!r} in {out_dir}/report.json")
    views = [v for v in lighting["views"] if v["sh"] is not None]
    if not views or not report["energy"]:
        raise SystemExit(f"error: {out_dir} has no lighting or energy (method 'project'?)")
    sigmas = np.array([v["sh"] for v in views])   # (views, channels, 9), schema in core.io.outputs
    paths = [os.path.join(dest, f) for f in FILES]
    write_png(paths[0], before_after(out_dir, report, fixture_dir, view))
    write_png(paths[1], lighting_spheres(sigmas, [v["name"] for v in views], columns=5))
    write_png(paths[2], energy_plot(report["energy"]))
    return paths


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out_dir", help="the run's output folder (report.json, lighting.json, views/)")
    p.add_argument("--fixture", help="the fixture folder (scene.json, photos/, gt_views/)")
    p.add_argument("--view", help="camera for the before/after strip (default: the one seeing most of the mesh)")
    p.add_argument("--dest", help="where to write the pictures (default OUT_DIR/pictures)")
    a = p.parse_args(argv)
    for path in make_pictures(a.out_dir, a.fixture, a.view, a.dest):
        print(f"wrote {os.path.relpath(path)}")


if __name__ == "__main__":
    main()
