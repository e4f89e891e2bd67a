"""The lighting models of the sigma-step (per view, shared, coupled, with a sun), and fitting a lighting."""

import numpy as np
import pytest

from core.solve import lighting
from core.solve.discretization import texture_domain
from core.solve.lighting import division_start, fit_lighting, shading_error, shared_lighting_step, split_gains
from core.solve.params import SolverParams
from core.solve.problem import Problem
from core.solve.stages import (
    solve,
)


def _objective(Ms, bs, sig):
    return float(np.einsum("vi,vij,vj->", sig, Ms, sig) - 2 * np.einsum("vi,vi->", sig, bs))


def test_shared_step_descends_and_finds_the_gains():
    rng = np.random.default_rng(0)
    m = 5
    s_true = rng.standard_normal(9)
    g_true = np.exp(0.3 * rng.standard_normal(m))
    g_true[0] = 1
    X = [rng.standard_normal((200, 9)) for _ in range(m)]
    Ms = np.stack([x.T @ x for x in X])
    bs = np.stack([x.T @ (x @ (g * s_true)) for x, g in zip(X, g_true)])  # noiseless: b = M g s
    start = np.tile(s_true * 1.0, (m, 1))
    start[:, 0] += 0.5  # wrong lighting, gains 1
    before = _objective(Ms, bs, start)
    one = shared_lighting_step(Ms, bs, start, rounds=1, pin_constant=False)
    assert _objective(Ms, bs, one) <= before
    fit = shared_lighting_step(Ms, bs, start, rounds=200, pin_constant=False)
    s, g = split_gains(fit)
    assert np.allclose(g, g_true, rtol=1e-4), (g, g_true)
    assert np.allclose(s, s_true, rtol=1e-4)
    # Pinned, the constant term stays where it was and the rest still descends.
    pinned = shared_lighting_step(Ms, bs, start, rounds=3)
    assert np.allclose(pinned[0, 3], start[0, 3])
    assert _objective(Ms, bs, pinned) <= before


def test_fit_lighting_recovers_gains_and_light_from_the_true_albedo(exposed):
    scene, problem, gains = exposed
    d = texture_domain(problem)
    rho = scene.albedo_texture.reshape(-1, 3)[d.texel_index]
    sigma = fit_lighting(d, rho, "shared")
    truth = scene.sigma * gains[:, :, None]
    assert np.all(shading_error(d, sigma, truth) < 0.02)
    # Per view, each fit sees half the normals and the splat's blur at the albedo's edges weighs more.
    assert np.all(shading_error(d, fit_lighting(d, rho, "per_view"), truth) < 0.05)
    # A wrong lighting is measurably off.
    wrong = truth.copy()
    wrong[:, :, 0] += 0.3
    assert np.all(shading_error(d, wrong, truth) > 0.1)


def test_division_under_the_true_lighting_recovers_the_albedo(exposed):
    scene, problem, gains = exposed
    d = texture_domain(problem)
    rho = scene.albedo_texture.reshape(-1, 3)[d.texel_index]
    truth = scene.sigma * gains[:, :, None]
    err = np.abs(division_start(d, truth) - rho)
    # Texels away from the albedo's edges (the splat blurs across them) come back to the noise (0.002).
    assert np.median(err) < 0.005 and np.mean(err) < 0.04
    # A lighting tilted towards one side is measurably off.
    tilted = truth.copy()
    tilted[:, :, 1:4] += 0.3 * truth[:, :, [0]]
    assert np.median(np.abs(division_start(d, tilted) - rho)) > 5 * np.median(err)
    # One channel at a time, the same; unfloored, the dark texels come back too.
    one = division_start(d, truth[:, [1]], channels=[1])
    assert np.array_equal(one[:, 0], division_start(d, truth)[:, 1])
    unfloored = np.abs(division_start(d, truth[:, [1]], channels=[1], floor=1e-6)[:, 0] - rho[:, 1])
    assert np.median(unfloored) < 0.005
    # The lighting doubled halves it.
    assert np.allclose(division_start(d, 2 * truth), division_start(d, truth) / 2, rtol=1e-4)


def test_bad_lighting_params():
    with pytest.raises(ValueError, match="lighting"):
        SolverParams(lighting="world").check()
    with pytest.raises(ValueError, match="albedo_lam"):
        SolverParams(albedo_lam=-1.0).check()


@pytest.mark.parametrize("lighting", ["per_view", "coupled"])
def test_a_25_coefficient_transfer_solves(exposed, lighting):
    from core.geometry.sh import sh_basis
    from core.geometry.transfer import open_factor

    _, problem, _ = exposed
    p = problem
    transfer = [sh_basis(n[m], order=4) * open_factor(25).astype(np.float32) for n, m in zip(p.normals, p.masks)]
    q = Problem(p.images, p.masks, p.normals, uv=p.uv, texture=p.texture, view_weight=p.view_weight, transfer=transfer)
    r = solve(q, SolverParams(lam=2.0, lighting=lighting, levels=2, max_iter=6, min_iter=6))
    assert r.sigma.shape == (6, 3, 25)
    assert np.all(np.diff(r.energy) <= 0)
    with pytest.raises(ValueError, match="9-coefficient"):
        solve(q, SolverParams(lam=2.0, gauss_newton=True, levels=1, max_iter=1))


def _with_sun_column(problem, scene, strength):
    """The problem with a sun-like last transfer column ``max(0, n . w)``, its photos lit by it at ``strength``."""
    from core.geometry.sh import sh_basis

    w = np.array([0.5, -0.3, 0.8]) / np.linalg.norm([0.5, -0.3, 0.8])
    images, transfer = [], []
    for img, m, n, rho in zip(problem.images, problem.masks, problem.normals, scene.albedo_views):
        col = np.where(m, np.maximum(n @ w, 0.0), 0.0).astype(np.float32)
        lit = img + strength * np.where(m[..., None], np.nan_to_num(rho), 0.0) * col[..., None]
        images.append(np.maximum(lit, 0.0).astype(np.float32))
        transfer.append(np.concatenate([sh_basis(n[m]), col[m][:, None]], axis=1))
    p = problem
    return Problem(images, p.masks, p.normals, uv=p.uv, texture=p.texture, view_weight=p.view_weight, transfer=transfer)


@pytest.mark.parametrize("lighting", ["shared", "coupled", "per_view"])
def test_a_sun_column_is_never_given_a_negative_sun(exposed, lighting):
    # Photos darker where the column is large: the best fit wants a negative sun, which no light can be.
    scene, problem, _ = exposed
    q = _with_sun_column(problem, scene, -0.3)
    r = solve(q, SolverParams(lam=2.0, lighting=lighting, levels=2, max_iter=8, min_iter=8))
    assert r.sigma.shape == (6, 3, 10) and np.all(r.sigma[..., 9] >= 0)
    assert np.all(np.diff(r.energy) <= 0)


def _joint_minimum(As, rs, pinned, g):
    """The exact minimiser of ``sum_v x_v^T A_v x_v / 2 - r_v^T x_v`` over every view's SH and one sun strength t,
    with ``x_v[-1] = g_v t`` and view 0's constant term held at ``pinned``: one linear system over all of them."""
    m, k = rs.shape
    free0 = [i for i in range(k - 1) if i != 3]
    n = len(free0) + (m - 1) * (k - 1) + 1
    P, c = np.zeros((m, k, n)), np.zeros((m, k))
    P[0, free0, range(len(free0))] = 1
    c[0, 3] = pinned
    for v in range(1, m):
        start = len(free0) + (v - 1) * (k - 1)
        P[v, : k - 1, start : start + k - 1] = np.eye(k - 1)
    P[:, k - 1, n - 1] = g
    H = np.einsum("vki,vkl,vlj->ij", P, As, P)
    b = np.einsum("vki,vk->i", P, rs - np.einsum("vkl,vl->vk", As, c))
    z = np.linalg.solve(H, b)
    return np.einsum("vki,i->vk", P, z) + c


@pytest.mark.parametrize("sun", [0.7, -0.7])
def test_the_coupled_step_minimises_the_sh_and_the_sun_together(sun):
    # The sun column is nearly a combination of the SH columns (as a sun's smooth part is): minimising the two in
    # turn crawls along that valley; the step is the exact minimum of both, the sun kept >= 0.
    from core.solve.lighting import Coupling, _free

    rng = np.random.default_rng(3)
    m = 4
    g = np.exp(0.2 * rng.standard_normal(m))
    g[0] = 1.0
    As, rs = [], []
    for v in range(m):
        X = rng.standard_normal((300, 10))
        X[:, 9] = X[:, :9] @ rng.standard_normal(9) + 0.2 * rng.standard_normal(300)
        x = np.append(rng.standard_normal(9), g[v] * sun)
        if v == 0:
            x[3] = 1.3  # the constant term held
        As.append(X.T @ X)
        rs.append(X.T @ (X @ x + 0.01 * rng.standard_normal(300)))
    As, rs = np.stack(As), np.stack(rs)
    start = np.zeros((m, 10))
    start[0, 3] = 1.3
    got = Coupling._with_sun(As, rs, start, g, _free(9))
    if sun > 0:
        want = _joint_minimum(As, rs, 1.3, g)
    else:  # the unconstrained minimum has a negative sun: at t = 0 each view's SH is its own minimum
        want = np.zeros((m, 10))
        for v in range(m):
            idx = _free(9) if v == 0 else np.arange(9)
            r = rs[v, :9] - (As[v, :9, 3] * 1.3 if v == 0 else 0)
            want[v, idx] = np.linalg.solve(As[v][np.ix_(idx, idx)], r[idx])
        want[0, 3] = 1.3
        assert _joint_minimum(As, rs, 1.3, g)[0, 9] < 0
    np.testing.assert_allclose(got, want, rtol=1e-7, atol=1e-9)
    assert got[0, 3] == 1.3 and np.allclose(got[:, 9] / g, got[0, 9])


@pytest.mark.parametrize("floor", [lighting.PRIOR_FLOOR, 0.0])
def test_what_a_view_does_not_see_is_held_to_the_world_lighting(floor):
    # View 1 sees the normals of a few flat faces: its pixels leave 5 of its 9 coefficients undetermined.
    from core.solve.lighting import Coupling, prior_metric

    rng = np.random.default_rng(4)
    s = rng.standard_normal(9)
    g = np.array([1.0, 0.8, 1.2])
    X = [rng.standard_normal((200, 9)) for _ in range(3)]
    X[1] = X[1] @ np.linalg.qr(rng.standard_normal((9, 4)))[0] @ rng.standard_normal((4, 9))
    Ms = np.stack([x.T @ x for x in X])
    bs = np.stack([M @ (gv * s) for M, gv in zip(Ms, g)])  # every view's pixels agree with g_v s
    coupling = Coupling.__new__(Coupling)
    coupling.kappa, coupling.G, coupling.world = 10.0, prior_metric(Ms, floor), (s, g)
    start = np.zeros((3, 9))
    start[0, 3] = s[3]
    sigma, _ = coupling.step(Ms, bs, start)
    assert np.allclose(sigma[[0, 2]], g[[0, 2], None] * s, atol=1e-6)
    held = np.allclose(sigma[1], g[1] * s, atol=1e-6)
    assert held == (floor > 0), sigma[1] - g[1] * s


def test_the_floor_keeps_a_shadow_the_photo_shows_and_holds_a_dark_mistake():
    rng = np.random.default_rng(3)
    rho = rng.uniform(0.3, 0.7, 1000)
    shade = np.ones(1000)
    shade[:100] = 0.12  # a sun's shadow the lighting draws, and the photo shows
    photo = rho * shade
    shade[100:150] = 0.02  # a dark mistake: the photo there is lit (shading 1)
    new = lighting.floored_where_dark(shade, photo)
    old = lighting.floored(shade)
    # The fixed floor (0.2) lifts the shadow and darkens its albedo by 0.12 / 0.2; the new one keeps it.
    assert np.allclose(old[:100], 0.2)
    assert np.allclose(new[:100], 0.12)
    assert np.allclose(photo[:100] / new[:100], rho[:100])
    # Under a bright pixel the mistake is held as before.
    assert np.allclose(new[100:150], old[100:150])
    # Never lower than half the old floor, nor above it; lit pixels untouched.
    shade[:100] = 0.01
    assert np.allclose(lighting.floored_where_dark(shade, rho * shade)[:100], 0.1)
    assert np.array_equal(new[150:], shade[150:])
    # A black photo gives no brightest albedo: the fixed floor.
    assert np.array_equal(lighting.floored_where_dark(shade, np.zeros(1000)), lighting.floored(shade))
