"""Command line of the core, usable without Blender.

::

    python -m core solve BUNDLE --out DIR [--overwrite] [--domain texture|image]
                         [--lambda L|auto] [--mu M] [--max-iter K] [--delta D]

Run it from the repository root (or with the root on ``PYTHONPATH``).
``solve`` loads a problem bundle (:mod:`core.io.bundle`), runs
:func:`core.solve.stages.solve` with progress on stderr, and writes into DIR:

``views/<name>.exr``
    Per-view reflectance, RGBA: RGB the reflectance (grey images are
    repeated into R, G and B), 0 outside the mask, A = the view's mask.
``albedo.exr``
    Texture domain only: the texture, RGBA, 0 where unseen, A = seen texels.
``lighting.json``
    Each view's lighting, 9 SH coefficients per channel, and the world
    lighting (schema in :mod:`core.io.outputs`).
``lighting.exr``
    The world lighting as an environment image for Blender's World
    (:mod:`core.io.envmap`).
``report.json``
    Parameters, iterations, energy history, solve time and the files written.

``<name>`` is the view name made safe as a file name (:func:`core.io.names.unique_names`).
The files are written all or nothing, only after the solver succeeded, and
never over a file Delight did not write unless ``--overwrite``
(:mod:`core.io.outputs`). Bad input (a missing or invalid bundle, a setting out
of its range, a file in the way or an unwritable DIR, found before the solve),
a failed write and any other failure (out of memory, a bug) end with one
``error:`` line on stderr and exit status 1 (``--debug`` prints the traceback
too), Ctrl+C with 130, a usage error (an unknown option, a word where a number
belongs) with 2. The solver's options are built from :data:`core.options.SPEC`,
as the add-on's.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time

import numpy as np

from .errors import DelightError
from .failures import DEBUG_HELP, report_failure
from .geometry.sh import SH_BASIS_NAMES
from .io.bundle import load_bundle
from .io.outputs import REPORT, channel_names, lighting_files, lighting_outputs, prepare_outputs, rgba, view_files
from .io.outputs import write_outputs as _write_all
from .options import SOLVER_FIELDS, add_arguments, check
from .progress import ProgressPrinter
from .solve.lambda_choice import auto_lambda, describe_lambda
from .solve.params import SolverParams
from .solve.stages import solve

__all__ = ["main", "build_parser", "write_outputs", "SH_BASIS"]

SH_BASIS = list(SH_BASIS_NAMES)


def _output_files(problem, domain) -> dict:
    """The files a solve writes besides report.json, by key (see the module docstring)."""
    files = {"views": view_files(problem.names)}
    if domain == "texture":
        files["albedo"] = "albedo.exr"
    files["lighting"], files["envmap"] = lighting_files()
    return files


def write_outputs(out_dir, problem, result, params, elapsed=None, bundle=None, overwrite=False, cancel=None) -> dict:
    """Write a solver :class:`~core.solve.params.Result` into ``out_dir``, all or nothing.

    See the module docstring for the files and :func:`core.io.outputs.write_outputs`
    for the guarantees (``overwrite`` and ``cancel`` are passed on; the bundle
    is an input that is never written).

    Returns
    -------
    dict
        Relative paths of the written files: ``"views"`` (list, in view order),
        ``"lighting"``, ``"envmap"``, ``"report"`` and, in the texture domain, ``"albedo"``.

    Raises
    ------
    DelightError
        A file in the way, or the write failed; ``out_dir`` is as it was.
    """
    m, c = problem.n_views, problem.channels
    sigma = np.asarray(result.sigma, dtype=np.float64)
    if sigma.shape != (m, c, 9):
        raise ValueError(f"result: sigma has shape {sigma.shape}, expected {(m, c, 9)}")
    if len(result.views) != m:
        raise ValueError(f"result: {len(result.views)} views for {m} in the problem")
    for i, v in enumerate(result.views):
        if np.shape(v) != problem.images[i].shape:
            raise ValueError(f"result: view {i} has shape {np.shape(v)}, expected {problem.images[i].shape}")
    files = _output_files(problem, "image" if result.texture is None else "texture")
    contents = {}
    if result.texture is not None:
        tex = np.asarray(result.texture, dtype=np.float32)
        seen = (
            np.all(np.isfinite(tex if tex.ndim == 3 else tex[..., None]), axis=2)
            if result.seen is None
            else np.asarray(result.seen, dtype=bool)
        )
        contents[files["albedo"]] = rgba(tex, seen)
    for i, rel in enumerate(files["views"]):
        contents[rel] = rgba(result.views[i], problem.masks[i])
    contents.update(lighting_outputs(problem.names, files["views"], sigma, c, params.domain))
    files["report"] = REPORT
    energy = [float(e) for e in result.energy]
    report = {
        "bundle": None if bundle is None else os.path.abspath(bundle),
        "params": dataclasses.asdict(params),
        "n_views": m,
        "channels": channel_names(c),
        "iterations": int(result.iterations),
        "energy": energy,
        "time_s": None if elapsed is None else round(float(elapsed), 3),
        "info": dict(result.info or {}),
    }
    _write_all(out_dir, contents, report, overwrite=overwrite, inputs=[bundle], cancel=cancel, threads=params.threads)
    return files


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m core", description="Multi-view reflectance estimation (Melou et al. 2018) without Blender."
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    s = sub.add_parser(
        "solve",
        help="solve a problem bundle and write reflectance, albedo and lighting",
        description="Solve a problem bundle (.npz, see core.io.bundle) and write views/<name>.exr, "
        "albedo.exr (texture domain), lighting.json, lighting.exr and report.json into DIR.",
    )
    s.add_argument("bundle", metavar="BUNDLE", help="problem bundle (.npz)")
    s.add_argument("--out", required=True, metavar="DIR", help="output folder (created if needed)")
    s.add_argument(
        "--overwrite",
        action="store_true",
        help="replace files in the way that Delight did not write (its own are always replaced)",
    )
    s.add_argument(
        "--domain",
        choices=("texture", "image"),
        help="unknowns per texel or per pixel (default: texture if the bundle has a texture layout, else image)",
    )
    add_arguments(s, SOLVER_FIELDS)
    s.add_argument("--debug", action="store_true", help=DEBUG_HELP)
    return parser


def _solve(args) -> int:
    for name in SOLVER_FIELDS:
        check(name, getattr(args, name))
    try:
        problem = load_bundle(args.bundle)
    except (OSError, ValueError) as exc:
        raise DelightError(str(exc)) from exc
    domain = args.domain or ("texture" if problem.texture is not None else "image")
    if domain == "texture" and problem.texture is None:
        raise DelightError(
            f"bundle {args.bundle}: the texture domain needs a texture layout "
            "(texel_pos), which the bundle lacks; use --domain image"
        )
    files = _output_files(problem, domain)
    # Before the solve: a file in the way or an unwritable folder.
    prepare_outputs(
        args.out,
        [*([files["albedo"]] if "albedo" in files else []), *files["views"], *lighting_files()],
        args.overwrite,
        inputs=[args.bundle],
    )
    lam = args.lam
    if lam is None:
        lam, variation = auto_lambda(problem)
        print(describe_lambda(lam, variation, auto=True), file=sys.stderr, flush=True)
    params = SolverParams(
        domain=domain,
        lam=lam,
        mu=args.mu,
        delta=args.delta,
        max_iter=args.max_iter,
        data_model=args.data_model,
        gauss_newton=args.gauss_newton,
        threads=args.threads,
    )
    print(f"solving {problem.n_views} views, {domain} domain", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    try:
        result = solve(problem, params, progress=ProgressPrinter(sys.stderr))
    except ValueError as exc:  # the solver's own checks of the problem
        raise DelightError(f"bundle {args.bundle}: {exc}") from exc
    elapsed = time.perf_counter() - t0
    write_outputs(args.out, problem, result, params, elapsed=elapsed, bundle=args.bundle, overwrite=args.overwrite)
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
    except (Exception, KeyboardInterrupt) as exc:  # one line for any failure; the traceback with --debug
        return report_failure(exc, sys.stderr, debug=args.debug, front="core")
