import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from core.evaluate.synthetic import sphere_scene
from core.geometry.correspondences import find_correspondences
from core.geometry.sh import DIFFUSE
from core.solve import multigrid
from core.solve.cg import pcg
from core.solve.discretization import image_domain
from core.solve.huber import mm_weight
from core.solve.multigrid import Hierarchy, block_grid, surface_grid
from core.solve.params import SolverParams
from core.solve.problem import Problem
from core.solve.stages import solve


@pytest.fixture(scope="module")
def stiff():
    """The benchmark's kind of rho-step: a sphere in 6 views, mu = 1000 and delta = 1e-3, at a flat rho.

    At the true (piecewise-constant) albedo the TV and correspondence weights are at their stiffest,
    lambda / delta and mu / delta, as they become once the solver has flattened rho.
    """
    sc = sphere_scene(
        n_views=6,
        height=90,
        width=120,
        texture_size=64,
        n_cells=20,
        varying_light=False,
        noise=0.005,
        seed=5,
        distance=2.2,
    )
    p = sc.problem
    corr = find_correspondences(sc.cameras, sc.positions, p.masks, p.normals, max_pairs=60000, neighbours=5, seed=5)
    problem = Problem(p.images, p.masks, p.normals, correspondences=corr, uv=p.uv, texture=p.texture)
    d = image_domain(problem)
    rho = np.concatenate([a[m][:, 0] for a, m in zip(sc.albedo_views, p.masks)]).astype(np.float64)
    shade = d.nu.astype(np.float64) @ DIFFUSE
    D = mm_weight(rho * shade - d.values[:, 0], 1e-3) * shade * shade
    w = d.row_scale(5.0, 1000.0) * mm_weight(d.B @ rho, 1e-3)
    A = (sp.diags(D) + d.BT @ sp.diags(w) @ d.B).tocsc()
    b = mm_weight(rho * shade - d.values[:, 0], 1e-3) * shade * d.values[:, 0]
    return problem, d, A, b, D, w


def _error_after(A, b, x_star, precondition, iters):
    """A-norm error of PCG from zero after ``iters`` iterations, relative to the start."""
    x = pcg(lambda v: A @ v, b, np.zeros_like(b), precondition, iters)
    e, e0 = x - x_star, x_star
    return float(np.sqrt(e @ (A @ e) / (e0 @ (A @ e0))))


def test_surface_blocks_hold_a_few_points_each():
    uv = np.random.default_rng(0).random((40000, 2))
    grid = surface_grid(uv, per_block=4.0)
    blocks = np.unique(grid[:, 1:] // 2, axis=0).shape[0]
    assert 40000 / 16 < blocks <= 40000 / 4


def test_multigrid_solves_the_stiff_rho_step_far_better_than_jacobi(stiff):
    problem, d, A, b, D, w = stiff
    x_star = spla.spsolve(A, b)
    H = Hierarchy(block_grid(problem, d), d.B, d.BT)
    assert len(H.agg) >= 2
    A32 = A.astype(np.float32).tocsr()
    mg = H.preconditioner(lambda v: A32 @ v, D.astype(np.float32), w.astype(np.float32), np.float64)
    jacobi = 1.0 / A.diagonal()
    err_mg = _error_after(A, b, x_star, mg, 10)
    err_jacobi = _error_after(A, b, x_star, jacobi, 10)
    # Measured: 0.13 against 0.83 (and 0.58 after 100 Jacobi iterations).
    assert err_mg < 0.2 * err_jacobi, (err_mg, err_jacobi)
    assert err_mg < _error_after(A, b, x_star, jacobi, 60)


def test_the_levels_are_the_galerkin_products(stiff):
    # The levels are rebuilt from fixed maps of the weights; they must equal P^T A P, level by level.
    problem, d, A, b, D, w = stiff
    H = Hierarchy(block_grid(problem, d), d.B, d.BT)
    levels = H.level_matrices(D, w)
    assert len(levels) == len(H.agg) >= 2
    for agg, size, L in zip(H.agg, H.sizes, levels):
        P = sp.csr_matrix((np.ones(agg.size), (np.arange(agg.size), agg)), shape=(agg.size, size))
        A = (P.T @ A @ P).tocsr()
        # To float32 round-off: B is stored in float32, and so is B P.
        assert abs(L - A).max() <= 1e-6 * abs(A).max()


def test_the_v_cycle_is_symmetric_positive_definite(stiff):
    # CG needs it.
    problem, d, A, b, D, w = stiff
    H = Hierarchy(block_grid(problem, d), d.B, d.BT)
    A32 = A.astype(np.float32).tocsr()
    mg = H.preconditioner(lambda v: A32 @ v, D.astype(np.float32), w.astype(np.float32), np.float64)
    rng = np.random.default_rng(1)
    u, v = rng.standard_normal((2, A.shape[0]))
    assert abs(u @ mg(v) - v @ mg(u)) < 1e-4 * np.sqrt(abs(u @ mg(u)) * abs(v @ mg(v)))
    assert u @ mg(u) > 0 and v @ mg(v) > 0


def test_surface_blocks_beat_view_blocks(stiff, monkeypatch):
    # Blocks of one view's pixels leave the views' coupling to the smoother. The difference grows with
    # the number of levels, so coarsen this small problem as deep as a large one.
    monkeypatch.setattr(multigrid, "COARSEST", 100)
    problem, d, A, b, D, w = stiff
    x_star = spla.spsolve(A, b)
    without_uv = Problem(problem.images, problem.masks, problem.normals, correspondences=problem.correspondences)
    view_grid = block_grid(without_uv, d)
    A32 = A.astype(np.float32).tocsr()
    errs = []
    for grid in (block_grid(problem, d), view_grid):
        pre = Hierarchy(grid, d.B, d.BT).preconditioner(
            lambda v: A32 @ v, D.astype(np.float32), w.astype(np.float32), np.float64
        )
        errs.append(_error_after(A, b, x_star, pre, 20))
    # Measured: 0.08 against 0.16.
    assert errs[0] < 0.7 * errs[1], errs


@pytest.mark.parametrize("with_uv", [True, False])
def test_multigrid_solver_lowers_the_energy_faster(stiff, with_uv):
    problem = stiff[0]
    if not with_uv:
        problem = Problem(problem.images, problem.masks, problem.normals, correspondences=problem.correspondences)
    common = dict(domain="image", lam=5.0, mu=1000.0, max_iter=6, min_iter=6, levels=1)
    plain = solve(problem, SolverParams(**common, cg_iter=10, preconditioner="jacobi"))
    mg = solve(problem, SolverParams(**common, cg_iter=10, preconditioner="multigrid"))
    e = np.asarray(mg.energy)
    assert np.all(np.diff(e) <= 0), np.diff(e)
    assert e[-1] < plain.energy[-1]


def test_auto_is_multigrid_in_the_image_domain_only():
    assert SolverParams(domain="image").resolved().preconditioner == "multigrid"
    assert SolverParams(domain="image").resolved().cg_iter == 10
    assert SolverParams(domain="texture").resolved().preconditioner == "jacobi"
    assert SolverParams(domain="texture").resolved().cg_iter == 30
    assert SolverParams(domain="image", cg_iter=7, preconditioner="jacobi").resolved().cg_iter == 7
