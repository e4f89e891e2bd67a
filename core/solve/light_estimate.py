"""Lighting estimates that do not start from ``rho = I``, for the two-stage schedule.

**From neighbouring pixels** (:func:`estimate_lighting`). Two neighbouring
pixels i, j of one photo that see the same albedo satisfy
``I_i / s_i = I_j / s_j`` with the shading ``s = sigma . T`` (T the pixel's
transfer: the paper's ``nu(n)`` or the occlusion-aware one), so
``log(I_j / I_i) = log(s_j / s_i)`` whatever the albedo and whatever the
photo's gain (exposure, white balance), which cancels. Every pair of pixels a
few steps apart along a row or a column gives one equation in the lighting;
with its constant coefficient (index 3) pinned to 1 they are a small
nonlinear least-squares problem (:func:`pair_lighting`). Pairs that straddle
an albedo edge, a highlight, a cast shadow or a depth step break the equation;
they are the outliers of a reweighted fit (Tukey's biweight). Because the
gains cancel view by view, the pairs of all photos fit ONE world lighting per
channel (``model="shared"``) without knowing the gains; a light that moves
between shots is fitted per view (``model="per_view"``). The gains come
afterwards (:func:`view_gains`).

**The lighting stage with its albedo edges freed** (:func:`reweighted_lighting`).
The MM of the lighting stage minimises data + TV; TV charges an albedo edge by
its height, so the lighting it settles on lowers the edges between flat
regions. Run again with each TV row weighted down where the first run found an
edge (:func:`edge_weights`), the lighting is left to explain the variation
inside the regions.
"""

from __future__ import annotations

import numpy as np

from .sh import sh_basis

__all__ = [
    "neighbour_pairs",
    "pair_lighting",
    "view_gains",
    "estimate_lighting",
    "edge_weights",
    "reweighted_lighting",
]

# Tukey's biweight cut-off, in robust standard deviations of the normalised residual.
_TUKEY = 4.685


def _pixel_transfer(problem):
    """Per view, the transfer of the masked pixels (row-major), ``(P_v, K)`` float64."""
    out = []
    for v in range(problem.n_views):
        mask = problem.masks[v]
        t = problem.transfer[v][mask] if problem.transfer is not None else sh_basis(problem.normals[v][mask])
        out.append(np.asarray(t, np.float64))
    return out


def neighbour_pairs(mask: np.ndarray, uv=None, steps=(1, 2), max_uv_ratio: float = 4.0):
    """Pairs of masked pixels of one photo, ``steps`` apart along rows and columns: ``(a, b)`` indices.

    Indices count the masked pixels in row-major order (as
    :meth:`core.solve.problem.Problem.pixel_index`). With ``uv``, a pair whose
    UV distance exceeds ``max_uv_ratio`` times the median of its step is
    dropped: its two pixels lie on different parts of the surface (an
    occluding contour or a UV seam).
    """
    h, w = mask.shape
    rank = np.full(mask.shape, -1, np.intp)
    rank[mask] = np.arange(int(mask.sum()))
    out_a, out_b = [], []
    for k in steps:
        for dy, dx in ((0, k), (k, 0)):
            m = mask[: h - dy, : w - dx] & mask[dy:, dx:]
            a = rank[: h - dy, : w - dx][m]
            b = rank[dy:, dx:][m]
            if uv is not None and a.size:
                uvm = np.asarray(uv)[mask].astype(np.float64)
                dist = np.linalg.norm(uvm[a] - uvm[b], axis=1)
                med = float(np.median(dist))
                keep = dist <= max_uv_ratio * max(med, 1e-12)
                a, b = a[keep], b[keep]
            out_a.append(a)
            out_b.append(b)
    return np.concatenate(out_a), np.concatenate(out_b)


def _usable(values: np.ndarray) -> np.ndarray:
    """Pixels bright enough to divide by and below the view's near-clipped top, per channel: ``(P, C)`` bool."""
    out = np.zeros(values.shape, bool)
    for c in range(values.shape[1]):
        x = values[:, c]
        pos = x[x > 0]
        if pos.size == 0:
            continue
        lo = 0.02 * float(np.median(pos))
        hi = 0.98 * float(pos.max())
        out[:, c] = (x > lo) & (x < hi)
    return out


def pair_lighting(rows_i, rows_j, Ii, Ij, weight, starts, iterations: int = 20, ridge: float = 1e-4):
    """The robust fit of ``log(I_j / I_i) = log(s_j / s_i)``, ``s = sigma . T``, ``sigma_3 = 1``, per group of pairs.

    Gauss-Newton on the log-ratio residual of every channel, reweighted at
    every iteration by Tukey's biweight of the pair's residuals over all
    channels together (each in units of its channel's median absolute
    residual), so that a pair on a colour edge drops out of every channel.
    It starts from the ambient lighting. In logs the photo's noise enters
    the residual only, not the equations' coefficients, so the fit is not
    pulled towards a dark shading as the linear form
    ``(I_j T_i - I_i T_j) . sigma = 0`` would be.

    Parameters
    ----------
    rows_i, rows_j : (R, K) arrays
        The transfer of each pair's two pixels.
    Ii, Ij : (R, C) arrays
        Their values; a pair counts in a channel where both are positive.
    weight : (R,) array
        Prior weight of each pair.
    starts : (G + 1,) int array
        The pairs of group g (one lighting each) are ``starts[g]:starts[g + 1]``.
    iterations : int
        Gauss-Newton steps.
    ridge : float
        Tikhonov weight on the non-constant coefficients, relative to the
        normal matrix's mean diagonal: keeps directions that the pairs do not
        see near the ambient lighting.

    Returns
    -------
    (G, C, K) array
        The lighting of each group and channel, constant term 1 (ambient
        for a group without pairs).
    """
    K, C = rows_i.shape[1], Ii.shape[1]
    G = len(starts) - 1
    sigma = np.zeros((G, C, K))
    sigma[:, :, 3] = 1.0
    valid = (Ii > 0) & (Ij > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        y = np.where(valid, np.log(np.where(valid, Ij, 1.0) / np.where(valid, Ii, 1.0)), 0.0)
    for g in range(G):
        lo, hi = starts[g], starts[g + 1]
        if hi - lo < K:
            continue
        sigma[g] = _fit_group(rows_i[lo:hi], rows_j[lo:hi], y[lo:hi], valid[lo:hi], weight[lo:hi], iterations, ridge)
    return sigma


def _fit_group(Ti, Tj, y, valid, w0, iterations, ridge):
    """One group's fit, all channels (see :func:`pair_lighting`): ``(C, K)``."""
    K, C = Ti.shape[1], y.shape[1]
    free = np.delete(np.arange(K), 3)
    sigma = np.zeros((C, K))
    sigma[:, 3] = 1.0

    def residual(sig, c):
        si, sj = Ti @ sig, Tj @ sig
        ok = (si > 1e-6) & (sj > 1e-6)
        e = y[:, c] - np.log(np.where(ok, sj, 1.0) / np.where(ok, si, 1.0))
        return e, si, sj, ok

    def cost(e, ok, sig, w, r):
        return float(np.sum(w * np.where(ok, e * e, 1e30))) + r * float(sig[free] @ sig[free])

    state = [residual(sigma[c], c) for c in range(C)]
    for _ in range(iterations):
        # Tukey's biweight of the pair's residual over its channels, each in robust standard deviations.
        u2 = np.zeros(y.shape[0])
        n = np.zeros(y.shape[0])
        for c, (e, _, _, ok) in enumerate(state):
            good = ok & valid[:, c]
            mad = 1.4826 * float(np.median(np.abs(e[good]))) if good.any() else 1.0
            u2 += np.where(good, (e / (_TUKEY * max(mad, 1e-6))) ** 2, 0.0)
            n += good
        u2 = np.where(n > 0, u2 / np.maximum(n, 1), 1.0)
        w_rob = w0 * np.where(u2 < 1, (1 - u2) ** 2, 0.0)
        moved = False
        for c in range(C):
            e, si, sj, ok = state[c]
            w = w_rob * (ok & valid[:, c])
            if not np.any(w > 0):
                continue
            # d e / d sigma = T_i / s_i - T_j / s_j; e(sigma + d) ~ e + J d.
            J = (Ti / np.where(ok, si, 1.0)[:, None] - Tj / np.where(ok, sj, 1.0)[:, None])[:, free]
            M = (J * w[:, None]).T @ J
            r = ridge * max(float(np.trace(M)) / free.size, 1e-30)
            # Minimise |e + J d|_w^2 + r |sigma_free + d|^2: the ridge pulls towards the ambient lighting.
            step = np.linalg.solve(M + r * np.eye(free.size), -(J.T @ (w * e)) - r * sigma[c, free])
            before = cost(e, ok, sigma[c], w, r)
            t = 1.0
            while t > 1e-3:
                trial = sigma[c].copy()
                trial[free] += t * step
                new = residual(trial, c)
                if cost(new[0], new[3], trial, w, r) <= before:
                    sigma[c], state[c] = trial, new
                    moved = moved or t * np.linalg.norm(step) > 1e-6 * np.linalg.norm(trial)
                    break
                t *= 0.5
        if not moved:
            break
    return sigma


def view_gains(values, transfer, sigma, pixel_texel, rounds: int = 200):
    """Per view and channel, the gain that brings its photo to the albedo the photos agree on: ``(m, C)``.

    Each pixel's ``log(I / s)`` is ``log rho_cell + log g_view`` up to noise:
    a two-way fit over the (cell, view) means, by alternating exact
    minimisations, refitted once without the (cell, view) means that
    disagree by more than 3 robust standard deviations (highlights,
    misregistration). View 0's gain is 1.

    Parameters
    ----------
    values : list of (P_v, C) arrays
    transfer : list of (P_v, K) arrays
    sigma : (m, C, K) array
        The lighting of each view before its gain.
    pixel_texel : list of (P_v,) int arrays
        A surface cell per pixel (-1: none); pixels of one cell see about one albedo.
    rounds : int
        Alternations of each fit.
    """
    m, C = len(values), values[0].shape[1]
    g = np.ones((m, C))
    cells = np.concatenate(pixel_texel)
    view = np.concatenate([np.full(len(t), v) for v, t in enumerate(pixel_texel)])
    for c in range(C):
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.concatenate(
                [np.asarray(x[:, c], np.float64) / (t @ sigma[v, c]) for v, (x, t) in enumerate(zip(values, transfer))]
            )
        ok = (cells >= 0) & np.isfinite(ratio) & (ratio > 0)
        if not ok.any():
            continue
        key, inv = np.unique(cells[ok] * m + view[ok], return_inverse=True)
        w = np.bincount(inv).astype(np.float64)
        y = np.bincount(inv, weights=np.log(ratio[ok])) / w
        cell, vw = np.unique(key // m, return_inverse=True)[1], key % m
        # Only cells that two views see or more tell the gains apart.
        keep = np.bincount(cell)[cell] >= 2
        offset = np.zeros(m)
        for _ in range(2):
            offset, res = _two_way(y, cell, vw, np.where(keep, w, 0.0), m, rounds)
            mad = 1.4826 * float(np.median(np.abs(res[keep]))) if keep.any() else 0.0
            keep &= np.abs(res) <= 3 * max(mad, 1e-9)
        g[:, c] = np.exp(offset - offset[0])
    return g


def _two_way(y, cell, view, w, m, rounds):
    """Least squares of ``y = a_cell + o_view`` with weights w, by alternation: ``(o, residual)``."""
    wc = np.bincount(cell, weights=w)
    wv = np.bincount(view, weights=w, minlength=m)
    o = np.zeros(m)
    a = np.zeros(wc.size)
    for _ in range(rounds):
        a = np.bincount(cell, weights=w * (y - o[view])) / np.maximum(wc, 1e-30)
        o_new = np.bincount(view, weights=w * (y - a[cell]), minlength=m) / np.maximum(wv, 1e-30)
        done = np.max(np.abs(o_new - o)) < 1e-7
        o = o_new
        if done:
            break
    return o, y - a[cell] - o[view]


def estimate_lighting(
    problem,
    model: str = "shared",
    steps=(2, 4, 8, 16, 32),
    iterations: int = 20,
    max_pairs: int = 500_000,
    cell_size: int = 128,
    seed: int = 0,
):
    """The lighting of each view and channel from neighbouring pixels' brightness ratios: ``(m, C, K)``.

    Parameters
    ----------
    problem : core.solve.problem.Problem
        Its transfer (or the paper's ``nu`` of the normals) is the shading model.
    model : {"shared", "per_view"}
        One world lighting per channel times a gain per view and channel, or
        a lighting per view and channel.
    steps : tuple of int
        Pixel distances of the pairs, along rows and columns.
    iterations : int
        Gauss-Newton steps of :func:`pair_lighting`.
    max_pairs : int
        Pairs kept at most (a fixed random subset beyond).
    cell_size : int
        UV cells of the gains' albedo (:func:`view_gains`).
    seed : int
        Of the subset.

    Returns
    -------
    (m, C, K) array
        Scaled so that view 0's constant term is 1 in every channel.
    """
    if model not in ("shared", "per_view"):
        raise ValueError(f"estimate_lighting: model must be 'shared' or 'per_view', got {model!r}")
    from ..geometry.texels import texel_index

    m, C = problem.n_views, problem.channels
    transfer = _pixel_transfer(problem)
    K = transfer[0].shape[1]
    values = [np.asarray(problem.images[v][problem.masks[v]], np.float64) for v in range(m)]
    usable = [_usable(x) for x in values]
    pa, pb, pv, pw = [], [], [], []
    offset = 0
    for v in range(m):
        uv = problem.uv[v] if problem.uv is not None else None
        a, b = neighbour_pairs(problem.masks[v], uv, steps)
        w = np.ones(a.size)
        if problem.view_weight is not None:
            vw = problem.view_weight[v][problem.masks[v]].astype(np.float64)
            w = np.sqrt(vw[a] * vw[b])
        pa.append(a + offset)
        pb.append(b + offset)
        pv.append(np.full(a.size, v))
        pw.append(w)
        offset += values[v].shape[0]
    pa, pb, pv, pw = (np.concatenate(x) for x in (pa, pb, pv, pw))
    T = np.concatenate(transfer)
    X = np.concatenate(values)
    U = np.concatenate(usable)
    ok = U[pa].any(axis=1) & U[pb].any(axis=1) & (pw > 0)
    idx = np.flatnonzero(ok)
    if idx.size > max_pairs:
        idx = np.sort(np.random.default_rng(seed).choice(idx, max_pairs, replace=False))
    a, b = pa[idx], pb[idx]
    use = U[a] & U[b]
    # Pairs are in view order already: a group per view is a slice.
    starts = np.array([0, idx.size]) if model == "shared" else np.searchsorted(pv[idx], np.arange(m + 1))
    fit = pair_lighting(T[a], T[b], np.where(use, X[a], 0.0), np.where(use, X[b], 0.0), pw[idx], starts, iterations)
    sigma = np.broadcast_to(fit, (m, C, K)).copy() if model == "shared" else fit
    cells = []
    for v in range(m):
        cells.append(
            texel_index(problem.uv[v][problem.masks[v]], cell_size)
            if problem.uv is not None
            else np.full(values[v].shape[0], -1)
        )
    g = view_gains(values, transfer, sigma, cells)
    return sigma * g[:, :, None]


def edge_weights(d, rho: np.ndarray, eps: float) -> np.ndarray:
    """Per row of ``d.B``, ``e / (|B rho| + e)``: near 1 inside flat regions, small across albedo edges.

    ``|B rho|`` is the colour difference across the row (the norm over the
    channels) and ``e = eps`` times the median colour norm of rho, so the
    weight does not depend on the albedo's scale.
    """
    diff = d.B @ np.asarray(rho, np.float32)
    g = np.sqrt(np.sum(np.asarray(diff, np.float64) ** 2, axis=1))
    e = eps * float(np.median(np.linalg.norm(rho, axis=1)))
    return e / (g + max(e, 1e-30))


def reweighted_lighting(problem, first, params, progress=None, cancel=None):
    """The lighting stage again, with each TV row weighted by :func:`edge_weights` of its first albedo.

    TV is an L1 penalty: it charges an albedo edge by its height, so a
    lighting that lowers the edges between flat regions lowers the energy,
    and the MM settles on such a lighting. Weighting each row by
    ``e / (|B rho| + e)`` at the first result's albedo (one step of
    reweighted L1) frees the edges found there, so the lighting is left to
    explain the variation inside the regions. The MM restarts from
    ``first`` (albedo and lighting) with the same model and TV weight.

    Parameters
    ----------
    problem : core.solve.problem.Problem
        The lighting stage's (texture domain).
    first : core.solve.solver.Result
        The lighting stage's result on ``problem``.
    params : core.solve.solver.SolverParams
        ``light_edges`` is ``eps`` of :func:`edge_weights`; ``lam``,
        ``lighting`` and the iteration bounds apply as in the first stage.

    Returns
    -------
    core.solve.solver.Result
        As :func:`core.solve.solver.solve` gives it, with ``info["edges"]``
        (iterations and last energy of this run).
    """
    import time

    from ..progress import check_cancel
    from .discretization import texture_domain
    from .solver import Result, _Channel, _iterate, _outputs, _rescaled

    d = texture_domain(problem, data_model=params.data_model)
    C = problem.channels
    rho = first.texture.reshape(-1, C)[d.texel_index]
    rho = np.where(np.isfinite(rho), rho, d.rho0)
    d.base = (d.base * edge_weights(d, rho, params.light_edges)).astype(np.float32)
    channels = [_Channel(d, c, params, rho[:, c], first.sigma[:, c]) for c in range(C)]

    def report(it, e):
        if progress is not None:
            progress(it / params.max_iter, f"iteration {it}, energy {e:.6g}")

    history, _ = _iterate(channels, params, report, lambda: check_cancel(cancel), time.perf_counter())
    rho, sigma = _rescaled(d, channels)
    views, texture, seen = _outputs(problem, d, rho)
    info = dict(first.info, edges={"iterations": len(history) - 1, "energy": history[-1:]})
    return Result(
        sigma=sigma,
        views=views,
        energy=first.energy,
        iterations=first.iterations,
        texture=texture,
        seen=seen,
        info=info,
    )
