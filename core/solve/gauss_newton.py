"""The joint Gauss-Newton step on rho and sigma (``SolverParams.gauss_newton``, off by default).

Plain alternation crawls along the valley where rho and sigma trade off; this step moves both at once on the
current majorant. It ties or loses on the rendered scenes and is what recovers a textured surface exactly in the
well-posed synthetic case (:mod:`core.solve.solver`'s docstring).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .cg import pcg
from .discretization import Discretization
from .huber import mm_weight
from .lighting import shading, view_normal_equations

__all__ = ["gauss_newton_step"]


def gauss_newton_step(ch) -> bool:
    """One Gauss-Newton step on rho and sigma together, on the current majorant.

    Plain alternation crawls along the valley where rho and sigma trade off.
    Here both move at once: the data residual ``(A rho) a(sigma) - I`` is
    linearised in both, the TV and correspondence terms enter exactly, and
    the joint normal equations are solved by CG with a Jacobi (rho) and 9x9
    block (sigma) preconditioner. A backtracking search on the true energy
    keeps the MM guarantee: a step is taken only if it lowers the energy.
    """
    d = ch.d
    if d.nu.shape[1] != 9:
        raise ValueError("solver: the Gauss-Newton step needs the 9-coefficient shading model")
    n = d.n_unknowns
    rho = ch.rho.astype(np.float64)
    matvec, precondition, rhs, free = _joint_system(ch, rho)
    step = pcg(matvec, rhs, np.zeros(rhs.size), precondition, 2 * ch.cg_iter)
    drho, dsig = step[:n], (step[n:] * free).reshape(d.n_views, 9)
    for t in (1.0, 0.5, 0.25, 0.125):
        sigma = ch.sigma + t * dsig
        shade = shading(d, sigma, ch.ft)
        new = (rho + t * drho).astype(ch.ft)
        e = ch.energy(rho=new, obs_shade=d.from_pixels(shade))
        if e < ch.e:
            ch.rho, ch.e = new, e
            ch._set_sigma(sigma, shade)
            return True
    return False


def _joint_system(ch, rho: np.ndarray):
    """The Gauss-Newton normal equations in ``(rho, sigma)`` at ``rho`` and the channel's sigma.

    Returns
    -------
    matvec, precondition : callables on ``(n + 9m,)`` vectors
    rhs : (n + 9m,) array
    free : (9m,) array
        1 for the sigma coefficients that may move, 0 for view 0's pinned constant term.
    """
    d = ch.d
    m, n = d.n_views, d.n_unknowns
    A, AT, A2T = d.observation_matrices()
    a = ch.obs_shade.astype(np.float64)
    vals = ch.obs_values.astype(np.float64)
    rho_o = A @ rho
    r = rho_o * a - vals
    w = d.obs_weight * mm_weight(r, ch.delta)
    data = w * a * a
    C, CT = _sigma_coupling(d, AT, w * a * rho_o)
    S, g_sigma = _sigma_blocks(d, w, r, rho_o)
    g_rho = AT @ (w * r * a)
    jacobi = A2T @ data
    if d.B.shape[0]:
        B, BT = d.B.astype(np.float64), d.BT.astype(np.float64)
        sw = ch.s_ft.astype(np.float64) * mm_weight(B @ rho, ch.delta)
        g_rho += BT @ (sw * (B @ rho))
        jacobi += d.B2T.astype(np.float64) @ sw
    free = np.ones(9 * m)
    free[3] = 0.0  # the pinned constant term of view 0
    S_inv = np.empty_like(S)
    for v in range(m):
        M = S[v] * np.outer(free[9 * v : 9 * v + 9], free[9 * v : 9 * v + 9])
        S_inv[v] = np.linalg.pinv(M + np.diag(1.0 - free[9 * v : 9 * v + 9]))

    def matvec(x):
        xr, xs = x[:n], x[n:] * free
        yr = AT @ (data * (A @ xr)) + C @ xs
        if d.B.shape[0]:
            yr += BT @ (sw * (B @ xr))
        ys = CT @ xr + np.einsum("vij,vj->vi", S, xs.reshape(m, 9)).ravel()
        return np.concatenate([yr, ys * free])

    def precondition(x):
        return np.concatenate(
            [
                np.where(jacobi > 0, x[:n] / np.maximum(jacobi, 1e-300), 0.0),
                np.einsum("vij,vj->vi", S_inv, (x[n:] * free).reshape(m, 9)).ravel() * free,
            ]
        )

    return matvec, precondition, -np.concatenate([g_rho, g_sigma * free]), free


def _sigma_coupling(d: Discretization, AT, coef: np.ndarray):
    """The (n, 9m) rho-sigma block of the joint normal equations and its transpose.

    ``d r_o / d sigma_v(o) = rho_o nu_o``: an (O, 9m) matrix with 9 entries
    per row, scaled by ``coef`` (``w a rho_o``) and coupled to rho through ``A^T``.
    """
    nu_o = d.from_pixels(d.nu).astype(np.float64)
    O = nu_o.shape[0]
    N = sp.csr_matrix(
        ((coef[:, None] * nu_o).ravel(), (9 * d.obs_view[:, None] + np.arange(9)).ravel(), np.arange(0, 9 * O + 1, 9)),
        shape=(O, 9 * d.n_views),
    )
    C = (AT @ N).tocsr()
    return C, C.T.tocsr()


def _sigma_blocks(d: Discretization, w, r, rho_o):
    """The 9x9 sigma-sigma block of each view, (m, 9, 9), and the gradient in sigma, (9m,)."""
    npix = d.nu.shape[0]
    p_w = np.bincount(d.obs_pixel, weights=w * rho_o * rho_o, minlength=npix)
    p_r = np.bincount(d.obs_pixel, weights=w * r * rho_o, minlength=npix)
    S, g_sigma = view_normal_equations(d.nu, d.pixel_offsets, p_w, p_r)
    return S, g_sigma.ravel()
