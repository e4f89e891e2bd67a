"""Command line of the core, usable without Blender.

::

    python -m core solve BUNDLE --out DIR [--domain texture|image]
                         [--lambda L|auto] [--mu M] [--max-iter K] [--delta D]

Run it from the repository root (or with the root on ``PYTHONPATH``).
``solve`` loads a problem bundle (:mod:`core.io.bundle`), runs
:func:`core.solve.solver.solve` with progress on stderr, and writes into DIR:

``views/<name>.exr``
    Per-view reflectance, RGBA: RGB the reflectance (grey images are
    repeated into R, G and B), 0 outside the mask, A = the view's mask.
``albedo.exr``
    Texture domain only: the texture, RGBA, 0 where unseen, A = seen texels.
``lighting.json``
    ``{"sh_basis": ["n1", "n2", "n3", "1", "n1*n2", ...],
    "channels": [...], "views": [{"name", "file", "sh": [[9 floats] per
    channel]}]}``.
``report.json``
    Parameters, iterations, energy history, solve time and output files.

``<name>`` is the view name made safe as a file name (:func:`core.io.names.unique_names`).
Files are written atomically, and only after the solver succeeded. Bad input
(a missing or invalid bundle, a setting out of its range) and a failed write
end with one ``error:`` line on stderr and exit status 1, Ctrl+C with 130, a
usage error (an unknown option, a word where a number belongs) with 2. The
solver's options are built from :data:`core.options.SPEC`, as the add-on's.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time

import numpy as np

from .errors import REPORTED, DelightError, report_failure
from .io.atomic import atomic_path
from .io.bundle import load_bundle
from .io.exr import write_exr
from .io.jsonio import json_value
from .options import SOLVER_FIELDS, add_arguments, check
from .progress import ProgressPrinter
from .solve.lambda_choice import auto_lambda, describe_lambda
from .io.names import unique_names
from .solve.sh import SH_BASIS_NAMES
from .solve.solver import SolverParams, solve

__all__ = ["main", "build_parser", "write_outputs", "SH_BASIS"]

SH_BASIS = list(SH_BASIS_NAMES)



def _write_json(path, obj):
    with atomic_path(path, suffix=".json") as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(json_value(obj), fh, indent=2, allow_nan=False)
            fh.write("\n")


def _rgba(values, alpha):
    """(H, W, C) values and (H, W) bool alpha -> RGBA with 0 colour where alpha is 0."""
    v = np.asarray(values, dtype=np.float32)
    if v.shape[2] == 1:
        v = np.repeat(v, 3, axis=2)
    rgb = np.where(alpha[:, :, None], v, 0.0).astype(np.float32)
    return np.concatenate([rgb, alpha[:, :, None].astype(np.float32)], axis=2)


def write_outputs(out_dir, problem, result, params, elapsed=None, bundle=None) -> dict:
    """Write a solver :class:`~core.solve.solver.Result` into ``out_dir``.

    See the module docstring for the files. ``out_dir`` and ``out_dir/views``
    are created if needed.

    Returns
    -------
    dict
        Relative paths of the written files: ``"views"`` (list, in view order),
        ``"lighting"``, ``"report"`` and, in the texture domain, ``"albedo"``.
    """
    m, c = problem.n_views, problem.channels
    sigma = np.asarray(result.sigma, dtype=np.float64)
    if sigma.shape != (m, c, 9):
        raise ValueError(f"result: sigma has shape {sigma.shape}, expected {(m, c, 9)}")
    if len(result.views) != m:
        raise ValueError(f"result: {len(result.views)} views for {m} in the problem")
    for i, v in enumerate(result.views):
        if np.shape(v) != problem.images[i].shape:
            raise ValueError(f"result: view {i} has shape {np.shape(v)}, "
                             f"expected {problem.images[i].shape}")
    os.makedirs(os.path.join(out_dir, "views"), exist_ok=True)
    stems = unique_names(problem.names)
    files = {"views": [f"views/{s}.exr" for s in stems]}
    for i, rel in enumerate(files["views"]):
        write_exr(os.path.join(out_dir, rel), _rgba(result.views[i], problem.masks[i]))
    if result.texture is not None:
        tex = np.asarray(result.texture, dtype=np.float32)
        tex = tex[:, :, None] if tex.ndim == 2 else tex
        seen = (np.all(np.isfinite(tex), axis=2) if result.seen is None
                else np.asarray(result.seen, dtype=bool))
        files["albedo"] = "albedo.exr"
        write_exr(os.path.join(out_dir, files["albedo"]), _rgba(tex, seen))
    channels = ["Y"] if c == 1 else ["R", "G", "B"]
    files["lighting"] = "lighting.json"
    _write_json(os.path.join(out_dir, files["lighting"]), {
        "sh_basis": SH_BASIS,
        "channels": channels,
        "views": [{"name": str(problem.names[i]), "file": files["views"][i],
                   "sh": sigma[i].tolist()} for i in range(m)],
    })
    files["report"] = "report.json"
    energy = [float(e) for e in result.energy]
    _write_json(os.path.join(out_dir, files["report"]), {
        "bundle": None if bundle is None else os.path.abspath(bundle),
        "params": dataclasses.asdict(params),
        "n_views": m,
        "channels": channels,
        "iterations": int(result.iterations),
        "energy": energy,
        "time_s": None if elapsed is None else round(float(elapsed), 3),
        "files": files,
        "info": dict(result.info or {}),
    })
    return files


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m core",
        description="Multi-view reflectance estimation (Melou et al. 2018) without Blender.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    s = sub.add_parser(
        "solve", help="solve a problem bundle and write reflectance, albedo and lighting",
        description="Solve a problem bundle (.npz, see core.io.bundle) and write views/<name>.exr, "
                    "albedo.exr (texture domain), lighting.json and report.json into DIR.")
    s.add_argument("bundle", metavar="BUNDLE", help="problem bundle (.npz)")
    s.add_argument("--out", required=True, metavar="DIR", help="output folder (created if needed)")
    s.add_argument("--domain", choices=("texture", "image"),
                   help="unknowns per texel or per pixel (default: texture if the bundle has a "
                        "texture layout, else image)")
    add_arguments(s, SOLVER_FIELDS)
    return parser


def _check_out_dir(out):
    if os.path.exists(out) and not os.path.isdir(out):
        raise DelightError(f"--out {out}: exists and is not a folder")
    parent = os.path.abspath(out)
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent) or not os.access(parent, os.W_OK | os.X_OK):
        raise DelightError(f"--out {out}: cannot write in {parent}")


def _solve(args) -> int:
    for name in SOLVER_FIELDS:
        check(name, getattr(args, name))
    _check_out_dir(args.out)
    try:
        problem = load_bundle(args.bundle)
    except (OSError, ValueError) as exc:
        raise DelightError(str(exc)) from exc
    domain = args.domain or ("texture" if problem.texture is not None else "image")
    if domain == "texture" and problem.texture is None:
        raise DelightError(f"bundle {args.bundle}: the texture domain needs a texture layout "
                           "(texel_pos), which the bundle lacks; use --domain image")
    lam = args.lam
    if lam is None:
        lam, variation = auto_lambda(problem)
        print(describe_lambda(lam, variation, auto=True), file=sys.stderr, flush=True)
    params = SolverParams(domain=domain, lam=lam, mu=args.mu, delta=args.delta,
                          max_iter=args.max_iter, data_model=args.data_model, gauss_newton=args.gauss_newton)
    print(f"solving {problem.n_views} views, {domain} domain", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    try:
        result = solve(problem, params, progress=ProgressPrinter(sys.stderr))
    except ValueError as exc:  # the solver's own checks of the problem
        raise DelightError(f"bundle {args.bundle}: {exc}") from exc
    elapsed = time.perf_counter() - t0
    try:
        os.makedirs(args.out, exist_ok=True)
        write_outputs(args.out, problem, result, params, elapsed=elapsed, bundle=args.bundle)
    except OSError as exc:
        print(f"error: writing results to {args.out}: {exc}", file=sys.stderr)
        return 1
    print(f"{result.iterations} iterations in {elapsed:.1f} s; wrote {args.out}")
    return 0


def main(argv=None) -> int:
    """Run the command line; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2
    try:
        return _solve(args)
    except (*REPORTED, KeyboardInterrupt) as exc:
        return report_failure(exc, sys.stderr)
