"""The demo's three pictures, from a headless run's output folder and the fixture it delit (drawn with matplotlib).

    .venv/bin/python tools/demo_pictures.py OUT_DIR --fixture blend_fixtures/lambert_sky [--view cam_00]
        [--dest DIR]

Writes into ``DEST`` (default ``OUT_DIR/pictures``):

* ``before_after.png``: one input photo, our reflectance for that view (``views/<camera>.exr``) and, if the
  fixture has per-view ground truth (``gt_views/``), the true albedo seen by that view, each under a title;
* ``lighting.png``: the estimated lighting of every view (``lighting.json``) as a shaded sphere seen from the
  front (from -Y, +Z up), all on one exposure, each under its view's name;
* ``convergence.png``: the energy per iteration (``report.json``), one line per multigrid level, log-scale y
  when it spans more than a decade.

The view is the one with the most pixels on the mesh unless ``--view`` names one. Prints the paths written.
matplotlib is a development dependency (requirements.txt); the add-on does not need it.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from core.evaluate.pictures import lighting_spheres, to_srgb8  # noqa: E402
from core.io.exr import read_exr  # noqa: E402

FILES = ("before_after.png", "lighting.png", "convergence.png")
#: Figures are laid out in pixels at this resolution, so a picture's size follows from the sizes below.
DPI = 100
#: Width of each image of the before/after picture, in pixels (its height keeps the photo's aspect).
PANEL = 320
#: Diameter of each lighting sphere, in pixels.
SPHERE = 128
#: Spheres per row of the lighting picture.
COLUMNS = 5
#: Margin around and between panels, and the height of a title row, in pixels.
PAD, TITLE = 8, 28
#: Size of the convergence plot, in pixels.
PLOT = (720, 440)


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


def _figure(width, height):
    """A white figure of ``width`` x ``height`` pixels (at :data:`DPI`)."""
    return Figure(figsize=(width / DPI, height / DPI), dpi=DPI, facecolor="white")


def _image_axes(fig, picture, left, top, width, height, title):
    """Show a uint8 picture in a box given in pixels from the figure's top left, with a title above it."""
    fw, fh = fig.get_size_inches() * DPI
    ax = fig.add_axes((left / fw, 1 - (top + height) / fh, width / fw, height / fh))
    ax.imshow(picture, aspect="auto", interpolation="antialiased")
    ax.set_axis_off()
    ax.text(0.5, 1 + 4 / height, title, transform=ax.transAxes, ha="center", va="bottom", fontsize=10)
    return ax


def _save(fig, path):
    fig.savefig(path, dpi=DPI, facecolor=fig.get_facecolor())


def before_after_pictures(out_dir, report, fixture_dir, view):
    """[(uint8 picture, title)] of photo, ours and (if known) truth for one view."""
    cam = next(c for c in report["cameras"] if c["name"] == view)
    ours = read_exr(os.path.join(out_dir, cam["file"]))[0]
    ours = np.where(ours[..., 3:4] > 0, ours[..., :3], np.nan)
    panels = []
    if fixture_dir:
        record = _load(os.path.join(fixture_dir, "scene.json"))
        fx = next((c for c in record["cameras"] if c["name"] == view), None)
        if fx is not None:
            panels.append((to_srgb8(_read_photo(os.path.join(fixture_dir, fx["photo"]))), f"Photo ({view})"))
        truth = None
        if fx is not None and fx.get("albedo_view"):
            truth = _masked(read_exr(os.path.join(fixture_dir, fx["albedo_view"]))[0], 0.5)
        if truth is not None and truth.shape == ours.shape:
            # Albedo is known up to scale: show ours at the one exposure that fits the truth best.
            return panels + [
                (to_srgb8(ours * _one_exposure(ours, truth)), "Our reflectance (scale fitted)"),
                (to_srgb8(truth), "True albedo"),
            ]
    return panels + [(to_srgb8(ours), "Our reflectance")]


def draw_before_after(path, panels):
    """Side by side, each :data:`PANEL` pixels wide under its title."""
    h, w = panels[-1][0].shape[:2]
    ph = int(round(PANEL * h / w))
    fig = _figure(PAD + len(panels) * (PANEL + PAD), TITLE + ph + PAD)
    for k, (picture, title) in enumerate(panels):
        _image_axes(fig, picture, PAD + k * (PANEL + PAD), TITLE, PANEL, ph, title)
    _save(fig, path)


def draw_lighting(path, sigmas, names, sun=None):
    """One sphere per view, :data:`COLUMNS` to a row, each under its view's name (``sun``: its direction)."""
    spheres = lighting_spheres(sigmas, size=SPHERE, sun=sun)
    cols = min(COLUMNS, len(spheres))
    rows = -(-len(spheres) // cols)
    # At least wide enough for the heading.
    fig = _figure(max(PAD + cols * (SPHERE + PAD), 420), TITLE + rows * (TITLE + SPHERE) + PAD)
    fig.text(
        PAD / fig.bbox.width,
        1 - (TITLE - 6) / fig.bbox.height,
        "Lighting per view (seen from -Y, +Z up; one exposure)",
        fontsize=11,
        va="baseline",
    )
    for k, (picture, name) in enumerate(zip(spheres, names)):
        r, c = divmod(k, cols)
        _image_axes(fig, picture, PAD + c * (SPHERE + PAD), TITLE + r * (TITLE + SPHERE) + TITLE, SPHERE, SPHERE, name)
    _save(fig, path)


def energy_levels(report):
    """[(label, energies)] of the solve, finest level first; the coarse levels are in the solver info."""
    info = report.get("solver_info") or report.get("info") or {}
    size = info.get("solved_size")
    out = [(f"{size}² texels" if size else "full size", report["energy"])]
    coarse = info.get("coarse")
    while coarse:
        if coarse.get("size"):
            label = f"{coarse['size']}² texels"
        else:
            h, w = coarse["shapes"][0][:2]
            label = f"{w}x{h} pixels (first view)"
        out.append((label, coarse["energy"]))
        coarse = (coarse.get("info") or {}).get("coarse")
    return [(label, e) for label, e in out if e]


def log_scale(values) -> bool:
    """Whether energies are drawn on a log axis: all positive and spanning more than a decade."""
    v = np.asarray(values, dtype=np.float64)
    return bool(np.all(v > 0) and v.max() > 10 * v.min())


def draw_convergence(path, levels):
    """Energy against iteration, one line per ``(label, energies)`` level; y on a log axis if :func:`log_scale`."""
    fig = _figure(*PLOT)
    fig.set_layout_engine("constrained")
    ax = fig.add_subplot()
    if log_scale(np.concatenate([np.asarray(e, dtype=np.float64) for _, e in levels])):
        ax.set_yscale("log")
    for k, (label, e) in enumerate(levels):
        ax.plot(
            np.arange(len(e)),
            e,
            marker="o",
            markersize=3,
            linewidth=1.5,
            label=label if k else f"{label} (final level)",
        )
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("iteration (0: the starting point)")
    ax.set_ylabel("energy")
    ax.set_title("Energy per iteration")
    ax.grid(True, which="major", alpha=0.5)
    ax.grid(True, which="minor", alpha=0.15)
    if len(levels) > 1:
        ax.legend(title="level")
    _save(fig, path)


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
    sigmas = np.array([v["sh"] for v in views])  # (views, channels, 9), schema in core.io.outputs
    sun = (lighting["world"] or {}).get("sun")
    if sun is not None:  # each view's sun strength as a tenth coefficient
        sigmas = np.concatenate([sigmas, np.array([v["sun_strength"] for v in views])[..., None]], axis=2)
    paths = [os.path.join(dest, f) for f in FILES]
    draw_before_after(paths[0], before_after_pictures(out_dir, report, fixture_dir, view))
    draw_lighting(paths[1], sigmas, [v["name"] for v in views], None if sun is None else sun["direction"])
    draw_convergence(paths[2], energy_levels(report))
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
