"""Quick accuracy harness: texture rows only, in one process, on baked scenes cached on disk.

Run by hand (not a test)::

    .venv/bin/python bench/accuracy_quick.py [--only lambert_sky photo_sun] [--texture-size 256]
        [--set lighting=shared --set lam=2] [--no-ceiling] [--json out.json]

The first run of a fixture reads its .blend through bpy and bakes it exactly as the add-on does
(:func:`blender_addon.pipeline.prepare`); the gathered photos, cameras and bakes are pickled under
``build/bench/quick/`` and reused while the fixture's files are unchanged. Then, in this process:

* ``project``: the photos fused onto the texture (no delighting), the baseline;
* ``ours``: :func:`core.pipeline.compute` with the default options, or with ``--set`` overrides
  (``lam``, ``max_iter`` go to the options, every other key to :class:`core.solve.params.SolverParams`);
* ``ceiling`` (unless ``--no-ceiling``): the true-lighting ceiling: the lighting fitted by least squares to
  the photos and the true albedo (per view, the shading model the run used: the occlusion-aware transfer by
  default, with the sun's term at the direction the run found where it found one), then the albedo solved
  again with that lighting held fixed and the albedo stage's TV weight (as the run adapted it) and edges
  (:func:`core.solve.stages.solve_albedo`); ``ceiling_nu`` the same with the paper's ``nu(n)``, and
  ``ceiling_divide`` the photos divided by the fitted shading, without TV;
* ``light err``: how far our estimated shading is from that best-fitting shading, relative RMS over the
  observations after one scale per channel (the albedo's scale is free).

RMSE is ``core.evaluate.metrics.scaled_rmse`` over the texels inside the UV islands that both ``project`` and
``ours`` saw (the ceilings: those of them they saw), truth in [0, 1], as in ``bench/accuracy.py``; a result
larger than the truth is box-averaged down to it. ``ours_own_texels`` scores ours on all the texels it saw.
"""

from __future__ import annotations

import argparse
import ast
import datetime
import hashlib
import json
import os
import pickle
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from bench.accuracy import fixtures, improvement  # noqa: E402
from bench.headless import ROOT, commit, machine  # noqa: E402
from core.evaluate.metrics import scaled_rmse  # noqa: E402
from core.io.exr import read_exr  # noqa: E402

CACHE = os.path.join(ROOT, "build", "bench", "quick")
_CACHE_VERSION = 2  # raise when what prepare() returns changes


def _fingerprint(fixture_dir):
    """Hash of the names, sizes and times of the fixture's files (photos included; a derived scene's photos are
    its base scene's, so the base's files too)."""
    with open(os.path.join(fixture_dir, "scene.json")) as fh:
        base = json.load(fh).get("base_scene")
    folders = [fixture_dir] + ([os.path.join(os.path.dirname(fixture_dir), base)] if base else [])
    h = hashlib.sha1()
    for folder in folders:
        for root, _, files in sorted(os.walk(folder)):
            for f in sorted(files):
                st = os.stat(os.path.join(root, f))
                h.update(f"{root}/{f}:{st.st_size}:{st.st_mtime_ns}".encode())
    return h.hexdigest()[:16]


def _bake_with_bpy(fixture_dir, object_name):
    import bpy

    from blender_addon.pipeline import Options, prepare

    bpy.ops.wm.open_mainfile(filepath=os.path.join(fixture_dir, "scene.blend"), load_ui=False)
    # The cameras as the scene has them: run_ours aligns the photos as the add-on does, `project` does not.
    opt = Options(object_name=object_name, out_dir=os.path.join(CACHE, "unused"), overwrite=True, align_photos=False)
    return prepare(bpy.context.scene, opt)


def load_case(name, fixture_dir):
    """``(record, inputs, bakes, photo_depths)`` of a fixture, baked once and cached."""
    with open(os.path.join(fixture_dir, "scene.json")) as fh:
        record = json.load(fh)
    path = os.path.join(CACHE, f"{name}-{_fingerprint(fixture_dir)}-{_CACHE_VERSION}.pkl")
    if os.path.exists(path):
        with open(path, "rb") as fh:
            inputs, bakes = pickle.load(fh)
    else:
        prepared = _bake_with_bpy(fixture_dir, record["mesh"]["object"])
        inputs, bakes = prepared.inputs, prepared.bakes
        os.makedirs(CACHE, exist_ok=True)
        with open(path, "wb") as fh:
            pickle.dump((inputs, bakes), fh, protocol=pickle.HIGHEST_PROTOCOL)
    return record, inputs, bakes


def truth(fixture_dir, record, size):
    """The true albedo (RGB, clipped to [0, 1]) and its inside mask at ``size``, box-averaged if larger."""
    gt = read_exr(os.path.join(fixture_dir, record["albedo_gt"]["file"]))[0]
    n = gt.shape[0]
    if n != size:
        if n % size:
            raise SystemExit(f"error: truth size {n} is not a multiple of {size}")
        k = n // size
        gt = gt.reshape(size, k, size, k, -1).mean(axis=(1, 3))
    return np.clip(gt[..., :3], 0, 1), gt[..., 3] > 0.5


def parse_sets(items):
    out = {}
    for item in items or []:
        key, _, val = item.partition("=")
        try:
            out[key] = ast.literal_eval(val)
        except (ValueError, SyntaxError):
            out[key] = val
    return out


def run_ours(inputs, bakes, size, sets):
    import dataclasses

    from core.pipeline import Options, compute

    sets = dict(sets)
    fields = {f.name for f in dataclasses.fields(Options)} - {"solver"}
    opt_keys = {k: sets.pop(k) for k in list(sets) if k in fields}
    opt = Options(texture_size=size, method="texture", solver=sets or None, **opt_keys)
    t = time.perf_counter()
    c = compute(opt, inputs, bakes)
    return c, time.perf_counter() - t


def run_project(inputs, bakes, size):
    from core.pipeline import Options, compute

    return compute(Options(texture_size=size, method="project"), inputs, bakes)


def _fmt(v):
    return "/".join(f"{x:.3f}" for x in v)


def box_down(albedo, seen, size):
    """A texture larger than ``size`` as the mean of its seen texels over each k x k box, and where any is seen."""
    n = seen.shape[0]
    if n == size:
        return albedo, seen
    k = n // size
    a = np.where(seen[..., None], albedo, 0).reshape(size, k, size, k, -1).sum(axis=(1, 3))
    count = seen.reshape(size, k, size, k).sum(axis=(1, 3))
    return a / np.maximum(count, 1)[..., None], count > 0


def _seen(result, size):
    """The texels ``result`` saw, at the truth's ``size``."""
    return box_down(result.albedo, result.seen, size)[1]


def _scored(result, gt, inside):
    """RMSE per channel of ``result`` on the texels it saw inside ``inside``."""
    albedo, seen = box_down(result.albedo, result.seen, gt.shape[0])
    return scaled_rmse(albedo, gt, seen & inside).tolist()


def evaluate(name, fixture_dir, size, sets, ceiling=True):
    from core.geometry.align import align_views
    from core.pipeline import Options

    record, inputs, bakes = load_case(name, fixture_dir)
    truth_size = min(size, record["albedo_gt"]["size"][0])
    gt, inside = truth(fixture_dir, record, truth_size)
    row = {"fixture": name, "texture_size": size, "set": {k: repr(v) for k, v in sets.items()}}
    proj = run_project(inputs, bakes, size)
    if sets.get("align_photos", Options.align_photos):
        # Our run and its ceiling on the cameras as the add-on moves them.
        inputs, bakes, alignment = align_views(inputs, bakes)
        row["cameras_moved"] = int(alignment.applied.sum())
    ours, secs = run_ours(inputs, bakes, size, sets)
    # Both on the texels both saw: projection puts a pixel on one texel and leaves texels between sparse pixels
    # unseen, which the solve's splat sees; those are the hardest, and each on its own texels would not be fair.
    proj_seen, ours_seen = _seen(proj, truth_size) & inside, _seen(ours, truth_size) & inside
    scored = proj_seen & ours_seen
    row["project"] = _scored(proj, gt, scored)
    row["ours"] = _scored(ours, gt, scored)
    row["ours_own_texels"] = _scored(ours, gt, inside)
    row["texels"] = {"scored": int(scored.sum()), "project": int(proj_seen.sum()), "ours": int(ours_seen.sum())}
    row["ours_seconds"] = secs
    row["lam"] = ours.info.get("lam")
    row["lighting_variation"] = ours.info.get("lighting_variation")
    row["albedo_lam"] = ours.info.get("albedo_lam")
    row["colour_texture"] = ours.info.get("colour_texture")
    row["colour_sparsity"] = ours.info.get("colour_sparsity")
    for key in ("lighting_mode", "stages"):
        if key in ours.info:
            row[key] = ours.info[key]
    if ceiling:
        row.update(true_lighting(inputs, bakes, gt, scored, size, ours, sets))
    return row


def problem_of(inputs, bakes, size, occlusion=False, sun_direction=None):
    """The texture-domain problem :func:`core.pipeline.compute` builds (without clipped-pixel masking; with the
    clipped pixels, whose highlights the albedo stage leaves out).

    With ``sun_direction`` the transfer has the sun's term as its last column, as the pipeline's has where
    it found a sun there.
    """
    from core.geometry.sun import SunLight
    from core.geometry.texels import texture_layout
    from core.geometry.transfer import occlusion_grid, transfer_rows
    from core.solve.problem import Problem

    m = inputs.mesh
    layout = texture_layout(m.tri_uv, m.tri_pos, m.tri_vert, size)
    transfer = None
    if occlusion or sun_direction is not None:
        uvs, masks = [b.uv for b in bakes], [b.mask for b in bakes]
        normals, positions = [b.normal for b in bakes], [b.position for b in bakes]
        cells = None
        if occlusion:
            cells = occlusion_grid(m.tri_pos, uvs, masks, normals, positions, [b.view_weight for b in bakes])
        sun = None if sun_direction is None else SunLight(np.asarray(sun_direction, np.float64), m.tri_pos)
        transfer = [transfer_rows(n[k], uv[k], cells, sun, p[k]) for n, uv, k, p in zip(normals, uvs, masks, positions)]
    return Problem(
        images=[v.photo for v in inputs.views],
        masks=[b.mask for b in bakes],
        normals=[b.normal for b in bakes],
        uv=[b.uv for b in bakes],
        texture=layout,
        view_weight=[b.view_weight for b in bakes],
        names=[v.name for v in inputs.views],
        transfer=transfer,
        clipped=[v.clipped for v in inputs.views],
    )


def true_lighting(inputs, bakes, gt, texels, size, ours, sets):
    """The true-lighting ceilings, scored on ``texels``, and the error of our lighting (see the module docstring)."""
    from core.pipeline import Options
    from core.solve.albedo_weight import ALBEDO_LAMBDA
    from core.solve.discretization import data_model_for, texture_domain
    from core.solve.lighting import division_start, fit_lighting, shading_error
    from core.solve.params import SolverParams
    from core.solve.stages import solve_albedo

    # The albedo stage's weight as our run had it (adapted to the colour texture by default).
    lam = ours.info.get("albedo_lam") or sets.get("albedo_lam", ALBEDO_LAMBDA) or ALBEDO_LAMBDA
    occlusion = sets.get("occlusion", Options.occlusion)
    out = {"ceiling_lam": lam}
    for label, occ in (("", occlusion), ("_nu", False)):
        if label and not occlusion:
            continue
        # Our own model: with the sun's term at the direction our run found, where it found one.
        problem = problem_of(inputs, bakes, size, occ, None if label else ours.sun_direction)
        d = texture_domain(problem)
        sigma = fit_lighting(d, gt.reshape(-1, 3)[d.texel_index], "per_view")
        if not label:
            out["lighting_error"] = float(np.mean(shading_error(d, ours.sigma, sigma)))
            div = np.full((size * size, 3), np.nan, np.float32)
            div[d.texel_index] = division_start(d, sigma)
            seen = np.isfinite(div[:, 0]).reshape(size, size) & texels
            out["ceiling_divide"] = scaled_rmse(div.reshape(size, size, 3), gt, seen).tolist()
        edges = sets.get("albedo_edges", SolverParams.albedo_edges)
        # The albedo stage's data model as our run had it.
        model = data_model_for(problem, sets.get("data_model", SolverParams.data_model))
        if model != d.data_model:
            d = texture_domain(problem, data_model=model)
        r = solve_albedo(problem, sigma, SolverParams(lam=lam, albedo_edges=edges, data_model=model), d=d)
        out["ceiling" + label] = scaled_rmse(r.texture, gt, r.seen & texels).tolist()
    return out


def line(row):
    p, o = np.mean(row["project"]), np.mean(row["ours"])
    s = (
        f"{row['fixture']:<22} project {_fmt(row['project'])} ({p:.3f})  ours {_fmt(row['ours'])} ({o:.3f})"
        f"  x{p / o:.2f}  {row['ours_seconds']:.0f}s  lam {row['lam']}"
    )
    if row.get("albedo_lam") is not None:
        s += f"  albedo lam {row['albedo_lam']:.3g}"
        if row.get("colour_texture") is not None:
            s += f" (colour texture {row['colour_texture']:.4f}"
            if row.get("colour_sparsity") is not None:
                s += f", sparsity {row['colour_sparsity']:.3f}"
            s += ")"
    if "ceiling" in row:
        s += (
            f"  ceiling {_fmt(row['ceiling'])} ({np.mean(row['ceiling']):.3f})"
            + (f"  nu {np.mean(row['ceiling_nu']):.3f}" if "ceiling_nu" in row else "")
            + f"  light err {row['lighting_error']:.3f}"
        )
    if "lighting_mode" in row:
        s += f"  mode {row['lighting_mode']}"
    return s


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fixtures", default=os.path.join(ROOT, "blend_fixtures"))
    p.add_argument("--only", nargs="*", help="fixture names (default: all)")
    p.add_argument("--texture-size", type=int, default=256, help="0: the truth's size")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override an option or solver parameter")
    p.add_argument("--no-ceiling", action="store_true", help="skip the true-lighting ceiling")
    p.add_argument("--json", help="write the rows here")
    a = p.parse_args(argv)
    found = fixtures(a.fixtures, a.only)
    if not found:
        raise SystemExit(f"error: no fixture in {a.fixtures}")
    sets = parse_sets(a.set)
    rows = []
    for name, d in found:
        size = a.texture_size
        if not size:
            with open(os.path.join(d, "scene.json")) as fh:
                size = json.load(fh)["albedo_gt"]["size"][0]
        row = evaluate(name, d, size, sets, ceiling=not a.no_ceiling)
        print(line(row), flush=True)
        rows.append(row)
    proj = [np.mean(r["project"]) for r in rows]
    ours = [np.mean(r["ours"]) for r in rows]
    mean, _, least = improvement(proj, ours)
    print(
        f"mean: project {np.mean(proj):.4f}  ours {np.mean(ours):.4f}  mean ratio x{mean:.2f}  min ratio x{least:.2f}",
        flush=True,
    )
    if a.json:
        out = {
            "started": datetime.datetime.now().isoformat(timespec="seconds"),
            "commit": commit(),
            "machine": machine(),
            "rows": rows,
        }
        os.makedirs(os.path.dirname(os.path.abspath(a.json)), exist_ok=True)
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
