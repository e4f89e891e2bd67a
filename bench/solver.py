"""Solver benchmark: ours against a faithful reference, side by side in one process.

Run by hand (not a test)::

    .venv/bin/python bench/solver.py --scale 0.25 --tol 1e-3   # 13 views of 135x240, the issue's stopping rule
    .venv/bin/python bench/solver.py --scale 1             # the paper's size, 13 x 540x960 (slow)

The problem is a sphere seen by 13 perspective cameras (``core.evaluate.synthetic``),
with correspondences from ``core.geometry.correspondences``. Rows:

* ``reference``: the paper's algorithm as written: each outer iteration
  assembles the normal equations from scratch with scipy.sparse and solves
  them with ``scipy.sparse.linalg.cg`` (30 iterations per step, unpreconditioned), in float64;
* ``image``: our image-domain solver (fixed sparsity, matrix-free PCG with
  the multigrid preconditioner of ``core.solve.multigrid``, float32, channels in
  threads, coarse-to-fine);
* ``texture``: our texture-domain solver on the same photos.

A row ``name@K`` caps the finest level at K iterations. ``iterations`` are
those of the finest level; the coarse levels' are listed apart, and their time
is in the total (``s/iter`` is total / finest iterations).

Prints time per outer iteration, total time, iterations, final energy, scaled
RMSE against the known albedo and peak memory (ru_maxrss of a fresh child
process per row, so rows do not inherit each other's peak), and for image
rows the time until their finest level first reaches the reference's final
energy: the speed-up at equal energy.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import resource
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402

from core.evaluate.metrics import scaled_rmse  # noqa: E402
from core.evaluate.synthetic import sphere_scene  # noqa: E402
from core.geometry.correspondences import find_correspondences  # noqa: E402
from core.geometry.sh import DIFFUSE, sh_basis  # noqa: E402
from core.solve.discretization import image_domain  # noqa: E402
from core.solve.huber import mm_weight  # noqa: E402
from core.solve.params import SolverParams
from core.solve.problem import Problem  # noqa: E402
from core.solve.solver import energy  # noqa: E402
from core.solve.stages import solve  # noqa: E402

#: CG iterations per rho-step of the reference (the paper does not say; our Jacobi default).
REFERENCE_CG_ITER = 30


def make_scene(scale, max_pairs, seed=0):
    h, w = int(round(540 * scale)), int(round(960 * scale))
    sc = sphere_scene(
        n_views=13,
        height=h,
        width=w,
        texture_size=max(64, int(1024 * scale)),
        n_cells=60,
        varying_light=False,
        noise=0.005,
        seed=seed,
        distance=2.2,
    )
    p = sc.problem
    corr = find_correspondences(
        sc.cameras, sc.positions, p.masks, p.normals, max_pairs=max_pairs, neighbours=12, seed=seed
    )
    problem = Problem(
        p.images,
        p.masks,
        p.normals,
        correspondences=corr,
        uv=p.uv,
        texture=p.texture,
        view_weight=p.view_weight,
        names=p.names,
    )
    return sc, problem


def reference_solve(problem, params):
    """The paper's alternating MM as written: normal equations assembled each iteration, scipy CG."""
    d = image_domain(problem, normalise_correspondences=params.normalise_correspondences)
    C = problem.channels
    rho = d.rho0.astype(np.float64).copy()
    sigma = np.tile(DIFFUSE, (d.n_views, C, 1))
    s = d.row_scale(params.lam, params.mu)
    B = d.B.astype(np.float64)
    nu = sh_basis(np.concatenate([n[m] for n, m in zip(problem.normals, problem.masks)]), np.float64)
    view = np.repeat(np.arange(d.n_views), np.diff(d.pixel_offsets))
    t0 = time.perf_counter()
    history = [energy(d, rho, sigma, params.lam, params.mu, params.delta)]
    elapsed = [time.perf_counter() - t0]
    it = 0
    for it in range(1, params.max_iter + 1):
        for c in range(C):
            a = np.einsum("pk,pk->p", nu, sigma[view, c])
            r = rho[:, c] * a - d.values[:, c]
            wd = mm_weight(r, params.delta)
            wr = s * mm_weight(B @ rho[:, c], params.delta)
            A = sp.diags(wd * a * a) + B.T @ sp.diags(wr) @ B
            b = wd * a * d.values[:, c]
            rho[:, c] = spla.cg(A, b, x0=rho[:, c], maxiter=REFERENCE_CG_ITER, rtol=1e-10)[0]
            a_rho = rho[:, c]
            r = a_rho * a - d.values[:, c]
            wd = mm_weight(r, params.delta)
            for v in range(d.n_views):
                sel = view == v
                X = nu[sel] * a_rho[sel, None]
                W = wd[sel]
                sigma[v, c] = np.linalg.lstsq(
                    (X * W[:, None]).T @ X, (X * W[:, None]).T @ d.values[sel, c], rcond=None
                )[0]
        history.append(energy(d, rho, sigma, params.lam, params.mu, params.delta))
        elapsed.append(time.perf_counter() - t0)
        if it >= params.min_iter and abs(history[-2] - history[-1]) <= params.tol * abs(history[-2]):
            break
    views = []
    for v in range(d.n_views):
        out = np.full(problem.masks[v].shape + (C,), np.nan, np.float32)
        out[problem.masks[v]] = rho[d.pixel_offsets[v] : d.pixel_offsets[v + 1]]
        views.append(out)
    return views, history, elapsed, it


def run_row(args):
    name, scale, max_pairs, params = args
    coarse = []  # iterations of each coarse level, finest first
    sc, problem = make_scene(scale, max_pairs)
    t0 = time.perf_counter()
    if name == "reference":
        views, history, elapsed, it = reference_solve(problem, params)
    else:
        r = solve(problem, params)
        views, history, elapsed, it = r.views, r.energy, r.info["elapsed"], r.iterations
        c = r.info["coarse"]
        while c is not None:
            coarse.append(c["iterations"])
            c = c["info"]["coarse"]
    total = time.perf_counter() - t0
    est = np.concatenate([v[m] for v, m in zip(views, problem.masks)])
    gt = np.concatenate([g[m] for g, m in zip(sc.albedo_views, problem.masks)])
    base = np.concatenate([im[m] for im, m in zip(problem.images, problem.masks)])
    reference = name == "reference"
    return {
        "row": name,
        "domain": params.domain,
        "preconditioner": "none" if reference else params.preconditioner,
        "cg_iter": REFERENCE_CG_ITER if reference else params.cg_iter,
        "iterations": it,
        "coarse_iterations": coarse,
        "coarse_iter": params.coarse_iter,
        "levels": params.levels,
        "total_s": total,
        "s_per_iter": total / max(it, 1),
        "final_energy": float(history[-1]),
        "energy_history": [float(e) for e in history],
        "elapsed_s": elapsed,
        "rmse": scaled_rmse(est, gt).tolist(),
        "rmse_rho_eq_I": scaled_rmse(base, gt).tolist(),
        "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "pixels": int(sum(m.sum() for m in problem.masks)),
        "pairs": len(problem.correspondences),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scale", type=float, default=0.25, help="fraction of 540x960 per view")
    ap.add_argument("--pairs", type=float, default=1.5e7, help="correspondences at scale 1 (scaled by scale^2)")
    ap.add_argument("--lam", type=float, default=5.0)
    ap.add_argument("--mu", type=float, default=1000.0)
    ap.add_argument("--delta", type=float, default=SolverParams.delta)
    ap.add_argument("--max-iter", type=int, default=50)
    ap.add_argument(
        "--tol",
        type=float,
        default=SolverParams.tol,
        help="stopping rule for every row: relative energy change (the issue's rule is 1e-3)",
    )
    ap.add_argument(
        "--coarse-iter",
        type=int,
        default=SolverParams.coarse_iter,
        help="iterations at most on each coarse level (our rows)",
    )
    ap.add_argument("--levels", type=int, default=SolverParams.levels, help="pyramid levels (our rows)")
    ap.add_argument(
        "--preconditioner",
        default=SolverParams.preconditioner,
        help="of our rows' rho-step: auto (multigrid in the image domain), multigrid or jacobi",
    )
    ap.add_argument(
        "--rows",
        nargs="+",
        default=["reference", "image", "texture", "texture@5"],
        help="reference, image, texture; name@K caps the finest level at K iterations",
    )
    ap.add_argument("--json", help="also write the rows here")
    a = ap.parse_args(argv)
    pairs = int(a.pairs * a.scale**2)
    rows = []
    for name in a.rows:
        # "texture@5": the texture row with at most 5 iterations at the finest level.
        base, _, iters = name.partition("@")
        domain = "texture" if base == "texture" else "image"
        max_iter = int(iters) if iters else a.max_iter
        params = SolverParams(
            domain=domain,
            lam=a.lam,
            mu=a.mu,
            delta=a.delta,
            max_iter=max_iter,
            min_iter=min(SolverParams.min_iter, max_iter),
            coarse_iter=a.coarse_iter,
            levels=a.levels,
            tol=a.tol,
            preconditioner=a.preconditioner,
        ).resolved()
        with mp.get_context("spawn").Pool(1) as pool:
            row = pool.map(run_row, [(name, a.scale, pairs, params)])[0]
        row.update(lam=a.lam, mu=a.mu, delta=a.delta, tol=a.tol)
        rows.append(row)
        print(json.dumps(row), flush=True)
    print()
    print(
        "| row | domain | pixels | pairs | s/iter | total s | iterations | coarse iterations | final energy "
        "| RMSE R/G/B | peak MB |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['row']} | {r['domain']} | {r['pixels']} | {r['pairs']} | {r['s_per_iter']:.2f} | "
            f"{r['total_s']:.1f} | {r['iterations']} | {'+'.join(map(str, r.get('coarse_iterations', []))) or '-'} | "
            f"{r['final_energy']:.4g} | "
            f"{'/'.join(f'{x:.3f}' for x in r['rmse'])} | {r['peak_mb']:.0f} |"
        )
    print(f"\nrho = I: {'/'.join(f'{x:.3f}' for x in rows[0]['rmse_rho_eq_I'])}")
    ref = next((r for r in rows if r["row"] == "reference"), None)
    if ref:
        for r in rows:
            if r is not ref:
                # A speed-up only counts at an energy no higher than the reference's.
                cmp = "<=" if r["final_energy"] <= ref["final_energy"] else "HIGHER than"
                same = (
                    f"final energy {r['final_energy']:.4g} {cmp} the reference's {ref['final_energy']:.4g}"
                    if r["domain"] == "image"
                    else "energy of another discretisation"
                )
                print(
                    f"{r['row']}: {ref['total_s'] / r['total_s']:.1f}x faster in total, "
                    f"{ref['s_per_iter'] / r['s_per_iter']:.1f}x per finest iteration than the reference; {same}"
                )
                if r["domain"] == "image":
                    # Time until the finest level first reaches the reference's final energy
                    # (coarse levels and the build included), against the reference's total.
                    hit = [t for t, e in zip(r["elapsed_s"], r["energy_history"]) if e <= ref["final_energy"]]
                    if hit:
                        print(
                            f"    reaches the reference's final energy after {hit[0]:.1f} s: "
                            f"{ref['elapsed_s'][-1] / hit[0]:.1f}x faster at equal energy"
                        )
                    else:
                        print("    never reaches the reference's final energy")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
