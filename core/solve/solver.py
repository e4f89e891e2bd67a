"""Alternating majorization-minimization (Melou et al. 2018, section 4).

The energy (eq. var) is, per colour channel,

``E(rho, sigma) = sum_o beta_o phi(rho[u_o] sigma_v(o) . nu_o - I_o)
+ lambda sum_TV w_e phi((B rho)_e) + mu sum_corr w_e phi((B rho)_e)``

(see :mod:`core.solve.discretization` for the two discretisations). Each outer
iteration majorises every Huber term by its quadratic psi_delta at the
current point, then

1. rho-step: minimises the quadratic majorant, a sparse weighted least
   squares, by CG warm-started from the current rho, preconditioned by
   aggregation multigrid in the image domain (:mod:`core.solve.multigrid`) and by
   Jacobi in the texture domain;
2. sigma-step: one 9x9 weighted least squares per view and channel.

Both steps can only lower the majorant, so the energy never increases; a
step that would raise it through float32 round-off is rejected. The channels
are independent problems and run in parallel threads (the sparse products and
NumPy kernels release the GIL).

Scale. The data term is invariant under ``(k rho, sigma / k)`` while the
regularisers shrink with k, so the scale drifts. During the iterations it is
pinned by keeping the constant SH coefficient of view 0 at its start value
(1); at the end, rho and sigma are rescaled so that the mean shading over the
observations is 1 in every channel. The output albedo is therefore in the
units of the images: the reflectance that the photos would show under a
shading of average brightness.

Defaults were chosen by albedo RMSE against the ground truth of the rendered
fixtures (docs/measurements.md, "What we measured about the solver"), not by energy:
delta = 1e-3 (1e-4 leaves rho = I nearly a fixed point), mu = 10 with
per-pixel normalised correspondences (mu = 1000 turns them into hard
constraints that flatten the albedo), 4 levels, the splat data model and no
Gauss-Newton step (both tie or lose on the renders; they are what recovers a
textured surface exactly in the well-posed synthetic case). lambda is the
caller's; the add-on and the command lines pick it with
:mod:`core.solve.lambda_choice`.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np

from ..geometry.sh import diffuse
from ..memory import release_free_memory
from ..parallel import resolve_threads
from ..progress import check_cancel
from .cg import pcg
from .discretization import Discretization, data_model_for, image_domain, texture_domain
from .gauss_newton import gauss_newton_step
from .huber import huber_inplace, mm_weight
from .lighting import Coupling, per_view_lighting_step, shading, shared_lighting_step, view_normal_equations
from .multigrid import Hierarchy, block_grid
from .params import Result, SolverParams
from .problem import SUN_COLUMNS, Problem, TextureLayout
from .pyramid import coarsen, supported_size, upsample_bilinear, upsample_pixels, with_texture_size
from .spmv import matvec_into, scatter_add

__all__ = [
    "solve_joint",
    "energy",
    "Channel",
    "iterate",
    "iteration_report",
    "rescaled",
    "result_maps",
    "continued_result",
    "channel_threads",
    "release_after_iteration",
]


#: Below this many observations the channels run in one thread: their steps are then short enough that the
#: interpreter's lock, not the arithmetic, sets the pace and threads only add waiting (docs/measurements.md).
SERIAL_OBSERVATIONS = 150_000


#: From this many observations the solver's loops give glibc's freed pages back after every iteration
#: (:func:`release_after_iteration`): a channel's temporaries are then tens of MB and the peak is at stake.
#: Below it the pages are kept through the level and given back at its end: trimmed every iteration, they were
#: only faulted in again the next (docs/measurements.md).
TRIM_OBSERVATIONS = 1_000_000


def release_after_iteration(d: Discretization) -> None:
    """After an iteration on ``d``: :func:`core.memory.release_free_memory` if ``d`` is large enough."""
    if d.obs_pixel.size >= TRIM_OBSERVATIONS:
        release_free_memory()


def channel_threads(params: SolverParams, channels: int, observations: int | None = None) -> int:
    """Threads for the channels' pool: one per channel, or ``params.threads`` if that is fewer.

    With None (every core) each channel gets its own thread even on fewer cores: the system shares them out,
    where a pool of two threads for three channels would leave one core idle while the last channel runs.
    One thread for a problem of fewer than :data:`SERIAL_OBSERVATIONS` observations.
    """
    if observations is not None and observations < SERIAL_OBSERVATIONS:
        return 1
    if params.threads is None:
        return max(1, channels)
    return max(1, min(resolve_threads(params.threads), channels))


# Elementwise work over the difference rows goes in chunks of this many, so its temporaries stay small
# and are reused rather than faulted in afresh (see core.solve.spmv).
_CHUNK = 1 << 20


def _weighted_huber(x, w, delta):
    """``sum(w * phi_delta(x))``, computed in x's precision chunk by chunk and summed in float64."""
    total = 0.0
    for lo in range(0, x.size, _CHUNK):
        h = huber_inplace(x[lo : lo + _CHUNK], delta)
        h *= w[lo : lo + _CHUNK]
        total += float(np.add.reduce(h, dtype=np.float64))
    return total


def _gathered_chunks(d, rho, chunk):
    """``(lo, hi, rho at observations lo:hi)`` over all observations, :data:`_CHUNK` at a time, each gathered into
    the buffer ``chunk`` (a diagonal data term: one unknown per observation)."""
    for lo in range(0, d.obs_unknown.size, _CHUNK):
        hi = min(lo + _CHUNK, d.obs_unknown.size)
        yield lo, hi, np.take(rho, d.obs_unknown[lo:hi], out=chunk[: hi - lo], mode="clip")  # "clip": unbuffered


def _channel_energy(d, rho, obs_shade, obs_values, s, delta, rows=None, chunk=None):
    """One channel's energy; ``rows``, if given, is a buffer for ``B @ rho`` in rho's dtype, ``chunk`` one of
    :data:`_CHUNK` for the residuals (with a diagonal data term)."""
    if d.diagonal_data:  # the residual chunk by chunk: no array over all observations
        chunk = np.empty(min(_CHUNK, d.obs_unknown.size), rho.dtype) if chunk is None else chunk
        data = 0.0
        for lo, hi, r in _gathered_chunks(d, rho, chunk):
            r *= obs_shade[lo:hi]
            r -= obs_values[lo:hi]
            data += _weighted_huber(r, d.obs_weight[lo:hi], delta)
    else:
        r = d.gather(rho)  # a new array: the residual is made in it
        r *= obs_shade
        r -= obs_values
        data = _weighted_huber(r, d.obs_weight, delta)
    if not d.B.shape[0]:
        return data
    Brho = d.B @ rho if rows is None else matvec_into(d.B, rho, rows)
    return data + _weighted_huber(Brho, s.astype(rho.dtype, copy=False), delta)


def energy(d: Discretization, rho: np.ndarray, sigma: np.ndarray, lam: float, mu: float, delta: float) -> float:
    """Energy of eq. (var) summed over channels; rho is (n, C), sigma (m, C, 9)."""
    s = d.row_scale(lam, mu).astype(np.float64)
    return sum(
        _channel_energy(d, rho[:, c], d.from_pixels(shading(d, sigma[:, c])), d.from_pixels(d.values[:, c]), s, delta)
        for c in range(rho.shape[1])
    )


class Channel:
    """The MM state of one colour channel."""

    def __init__(self, d: Discretization, c: int, params: SolverParams, rho0=None, sigma0=None, hierarchy=None):
        self.d = d
        self.hierarchy = hierarchy
        self.ft = np.dtype(params.precision).type
        self.values = np.ascontiguousarray(d.values[:, c])
        self.rho = np.ascontiguousarray(d.rho0[:, c] if rho0 is None else rho0).astype(self.ft)
        k = d.nu.shape[1]  # 9, or more with an order-3/4 transfer
        self.sigma = np.tile(diffuse(k), (d.n_views, 1)) if sigma0 is None else np.array(sigma0, dtype=np.float64)
        self.delta = params.delta
        self.cg_iter = params.cg_iter
        self.gauss_newton = params.gauss_newton
        self.extrapolate = params.extrapolate
        self.lighting = params.lighting
        self.coupling = None
        if params.lighting == "coupled":
            self.coupling = Coupling(d, c, params.coupling, self.sigma)
        self.s_ft = d.row_weights(params.lam, params.mu, self.ft)
        # Kept buffers over the difference rows: B x, and the rho-step's weights (see core.solve.spmv).
        self._Bx = np.empty(d.B.shape[0], self.ft)
        self._sw = np.empty(d.B.shape[0], self.ft)
        self._pair_values = None  # the rho-step's B^T diag(sw) B (core.solve.spmv.PairNormal), made on first use
        # With a diagonal data term the observations are worked on in chunks (kept): no array over all of them.
        self._chunk = self._chunk2 = None
        if d.diagonal_data:
            k = min(_CHUNK, d.obs_unknown.size)
            self._chunk, self._chunk2 = np.empty(k, self.ft), np.empty(k, self.ft)
        # Gathered once per change: the observations' values and shading.
        self.obs_values = d.from_pixels(self.values).astype(self.ft)
        self._set_sigma(self.sigma, shading(d, self.sigma, self.ft))
        self.e = self.energy()

    def _set_sigma(self, sigma, shade, obs_shade=None):
        self.sigma, self.shade = sigma, shade
        self.obs_shade = self.d.from_pixels(shade) if obs_shade is None else obs_shade

    def energy(self, rho=None, obs_shade=None, sigma=None, world=None):
        e = _channel_energy(
            self.d,
            self.rho if rho is None else rho,
            self.obs_shade if obs_shade is None else obs_shade,
            self.obs_values,
            self.s_ft,
            self.delta,
            rows=self._Bx,
            chunk=self._chunk,
        )
        if self.coupling is not None:  # the lighting prior is part of the energy
            e += self.coupling.penalty(self.sigma if sigma is None else sigma, world)
        return e

    def data_weights(self, rho_o, lo=0, hi=None, out=None):
        """beta * the majorant's curvature at the current residuals, over observations ``lo:hi`` (into ``out``,
        which may be ``rho_o``, or a new array)."""
        w = np.multiply(rho_o, self.obs_shade[lo:hi], out=out)
        w -= self.obs_values[lo:hi]
        mm_weight(w, self.delta, out=w)
        w *= self.d.obs_weight[lo:hi]
        return w

    def _data_normal(self):
        """The data term's right-hand side ``A^T (w a I)`` and diagonal ``A^T (w a^2)`` (diagonal data), chunk by
        chunk in the kept buffers."""
        d, a = self.d, self.obs_shade
        rhs, diag = np.zeros(d.n_unknowns, self.ft), np.zeros(d.n_unknowns, self.ft)
        for lo, hi, w in _gathered_chunks(d, self.rho, self._chunk):
            idx = d.obs_unknown[lo:hi]
            self.data_weights(w, lo, hi, out=w)
            w *= a[lo:hi]  # w a
            scatter_add(idx, np.multiply(w, self.obs_values[lo:hi], out=self._chunk2[: hi - lo]), rhs)
            w *= a[lo:hi]  # w a^2
            scatter_add(idx, w, diag)
        return rhs, diag

    def rho_step(self):
        d = self.d
        a = self.obs_shade
        if d.diagonal_data:
            rhs, jacobi = self._data_normal()
            diag = jacobi
            data = lambda x: diag * x  # noqa: E731
        else:
            rho_o = d.gather(self.rho)
            waa = self.data_weights(rho_o)
            waa *= a  # w a
            rhs = d.scatter(np.multiply(waa, self.obs_values, out=rho_o)).astype(self.ft, copy=False)
            waa *= a  # w a^2
            del rho_o
            jacobi = d.scatter(waa, squared=True).astype(self.ft, copy=False)
            data = lambda x: d.scatter(waa * d.gather(x))  # noqa: E731
        pair = d.pair_normal() if self.hierarchy is None else None
        if d.B.shape[0]:
            # sw = s * mm_weight(B rho), in the kept buffers.
            Bx = matvec_into(d.B, self.rho, self._Bx)
            sw = np.multiply(self.s_ft, mm_weight(Bx, self.delta, out=Bx), out=self._sw)
            B, BT = d.B, d.BT
        if pair is not None:
            # B^T diag(sw) B as one matrix: its off-diagonal part, and the diagonal with the data term's.
            if self._pair_values is None:
                self._pair_values = np.empty(pair.edge.size, self.ft)
                self._Lx, self._Dx = np.empty(d.n_unknowns, self.ft), np.empty(d.n_unknowns, self.ft)
            values = pair.values(sw, self._pair_values)
            tv_diag = (d.B2T @ sw).astype(self.ft, copy=False)
            full_diag = tv_diag + jacobi if d.diagonal_data else tv_diag
            Lx, Dx = self._Lx, self._Dx

            def matvec(x):
                out = pair.matvec_into(values, x, Lx)
                out += np.multiply(full_diag, x, out=Dx)
                if not d.diagonal_data:
                    out += data(x)
                return out

            jacobi = jacobi + tv_diag
        elif d.B.shape[0]:

            def matvec(x):
                y = matvec_into(B, x, Bx)
                y *= sw
                out = BT @ y
                out += data(x)
                return out
        else:
            matvec = data
        if self.hierarchy is not None:  # only built for a diagonal data term with rows in B
            precondition = self.hierarchy.preconditioner(matvec, jacobi, sw, self.ft)
        else:
            if d.B.shape[0] and pair is None:
                jacobi = jacobi + d.B2T @ sw
            precondition = np.where(jacobi > 0, 1.0 / np.maximum(jacobi, 1e-30), 0.0).astype(self.ft)
        rho = pcg(matvec, rhs, self.rho.copy(), precondition, self.cg_iter)
        e = self.energy(rho=rho)
        if e <= self.e:
            self.rho, self.e = rho, e

    def normal_equations(self):
        """Per view, the sigma-step's 9x9 matrix and right-hand side at the current majorant: ``(m, 9, 9), (m, 9)``."""
        d = self.d
        rho_o = d.gather(self.rho)
        w = self.data_weights(rho_o)
        wr = w * rho_o
        h = d.pixel_sum(wr) * self.values
        wr *= rho_o
        g = d.pixel_sum(wr)
        # float32 products (BLAS); the energy check in sigma_step guards the result.
        return view_normal_equations(d.nu, d.pixel_offsets, g, h, np.float32, d.nu_by_coefficient())

    def sigma_step(self):
        if self.lighting == "fixed":
            return
        d = self.d
        Ms, bs = self.normal_equations()
        world = None
        if self.lighting == "shared":
            sigma = shared_lighting_step(Ms, bs, self.sigma)
        elif self.lighting == "coupled":
            sigma, world = self.coupling.step(Ms, bs, self.sigma)
        else:
            sigma = per_view_lighting_step(Ms, bs, self.sigma)
        if sigma.shape[1] == SUN_COLUMNS:  # the last column is a sun term (Problem.transfer): no negative sun
            sigma = np.array(sigma)
            sigma[:, -1] = np.maximum(sigma[:, -1], 0.0)
        shade = shading(d, sigma, self.ft)
        obs_shade = d.from_pixels(shade)
        e = self.energy(obs_shade=obs_shade, sigma=sigma, world=world)
        if e <= self.e:
            self._set_sigma(sigma, shade, obs_shade)
            if world is not None:
                self.coupling.world = world
            self.e = e

    def step(self):
        before = self.rho
        self.rho_step()
        if self.gauss_newton:
            gauss_newton_step(self)
        self.sigma_step()
        if self.extrapolate > 0:
            further = self.rho + self.ft(self.extrapolate) * (self.rho - before)
            e = self.energy(rho=further)
            if e < self.e:
                self.rho, self.e = further, e
        return self.e


def solve_joint(
    problem, params: SolverParams | None = None, progress=None, cancel=None, views: bool = True, scale_up: bool = True
) -> Result:
    """Estimate reflectance and lighting together with alternating MM: the paper's algorithm.

    The levels of :func:`_ladder` are solved coarse to fine, each started
    from the one below. ``params.albedo_lam`` is not used here: the entry
    point :func:`core.solve.stages.solve` runs two stages when it is set.

    Parameters
    ----------
    problem : core.solve.problem.Problem
    params : SolverParams
    progress : callable(fraction, message), optional
    cancel : callable() -> bool, optional
        Polled between steps; when it returns True, :class:`core.errors.Cancelled` is raised.
    views : bool
        False: a texture-domain result without its per-view maps (``Result.views`` None), which cost a pass
        over every observation; the image domain always has them.
    scale_up : bool
        False: a texture solved smaller than the problem's (``max_texels_per_pixel``) is left as solved, in
        ``Result.solved``, with ``Result.texture`` and ``seen`` None; for a caller that fills it there first.

    Returns
    -------
    Result
        The finest level's; ``info["coarse"]`` holds the level below it, and so on down.
    """
    params = params or SolverParams()
    params.check()
    params = params.resolved()
    t0 = time.perf_counter()

    def poll():
        check_cancel(cancel)

    levels = _ladder(problem, params)
    result = None
    for i, level in enumerate(levels):
        last = i == len(levels) - 1
        report = _level_report(progress, levels, i)
        result = _solve_level(level, result, report, poll, t0, views or not last, scale_up or not last)
    return result


@dataclass
class _Level:
    """One rung of the coarse-to-fine ladder.

    Attributes
    ----------
    problem : Problem
        What is discretised and solved at this level.
    params : SolverParams
        With this level's iteration bounds.
    layout : TextureLayout or None
        The finer texture to sample the result up to, when the texel cap
        (``max_texels_per_pixel``) solved the level on a smaller one.
    label : str
        How the progress messages name the level.
    """

    problem: Problem
    params: SolverParams
    layout: TextureLayout | None = None
    label: str = ""


def _ladder(problem, params: SolverParams) -> list[_Level]:
    """The levels to solve, coarsest first: the problem, then up to ``levels - 1`` coarsenings of it.

    In the texture domain each level's texture is first capped at
    ``max_texels_per_pixel`` (see :func:`core.solve.pyramid.supported_size`);
    the levels below a capped one are coarsened from the capped problem and
    not capped again. The coarse levels stop after ``coarse_iter`` iterations.
    """
    texture = params.domain == "texture"
    cap = params.max_texels_per_pixel if texture else 0.0
    coarse_params = replace(params, max_iter=params.coarse_iter, min_iter=min(params.min_iter, params.coarse_iter))
    ladder, label = [], ""
    while True:
        layout = None
        if cap > 0 and problem.texture is not None:
            size = supported_size(problem, cap)
            if size < problem.texture.size:
                layout, problem, cap = problem.texture, with_texture_size(problem, size), 0.0
        ladder.append(_Level(problem, coarse_params if ladder else params, layout, label))
        smaller = coarsen(problem, texture=texture) if len(ladder) < params.levels else None
        if smaller is None:
            return ladder[::-1]
        problem = smaller
        label = (
            f"coarse level {problem.texture.size}"
            if texture
            else f"coarse level {problem.masks[0].shape[1]}x{problem.masks[0].shape[0]}"
        )


# Share of the progress bar that the levels below a level take.
_COARSE_SHARE = 0.3


def _level_report(progress, levels, i):
    """``report(fraction, message)`` for level ``i``: its fraction of its own work, placed on the whole bar."""
    if progress is None:
        return lambda frac, msg: None
    depth = len(levels) - 1 - i
    prefix = "".join(f"{levels[j].label}: " for j in range(len(levels) - 2, i - 1, -1))

    def report(frac, msg):
        frac = float(frac)
        for _ in range(depth):
            frac = _COARSE_SHARE * frac
        progress(frac, prefix + msg)

    return report


def _solve_level(
    level: _Level, below: Result | None, report, check_cancel, t0: float, views=True, scale_up=True
) -> Result:
    """Build one level's discretisation, start it from the level below, iterate, and rescale."""
    problem, params = level.problem, level.params
    base = 0.0 if below is None else _COARSE_SHARE  # of the progress bar, taken by the levels below
    report(base, f"building the {params.domain}-domain problem")
    if params.domain == "image":
        d = image_domain(problem, normalise_correspondences=params.normalise_correspondences)
    else:
        d = texture_domain(problem, data_model=data_model_for(problem, params.data_model), threads=params.threads)
    check_cancel()
    # Timings count from the start of the whole solve, levels below included.
    t_build = time.perf_counter() - t0
    rho0, sigma0 = (None, None) if below is None else _warm_start(problem, d, below)
    hierarchy = None
    if params.preconditioner == "multigrid" and d.B.shape[0] and d.diagonal_data:
        hierarchy = Hierarchy(block_grid(problem, d), d.B, d.BT)
    channels = [
        Channel(d, c, params, None if rho0 is None else rho0[:, c], None if sigma0 is None else sigma0[:, c], hierarchy)
        for c in range(problem.channels)
    ]
    history, elapsed = iterate(
        channels,
        params,
        iteration_report(lambda frac, msg: report(base + (1 - base) * frac, msg)),
        check_cancel,
        t0,
    )
    check_cancel()
    it = len(history) - 1
    rho, sigma = rescaled(d, channels)
    views, texture, seen = result_maps(problem, d, rho, views)
    report(1.0, f"done in {it} iterations")
    info = {
        "build_seconds": t_build,
        "solve_seconds": time.perf_counter() - t0 - t_build,
        "n_unknowns": d.n_unknowns,
        "n_observations": int(d.obs_pixel.size),
        "n_tv_rows": d.n_tv,
        "n_correspondence_rows": int(d.B.shape[0] - d.n_tv),
        "domain": d.domain,
        "elapsed": elapsed,
        "solved_size": problem.texture.size if d.domain == "texture" else None,
        "coarse": None
        if below is None
        else {
            "size": None if below.texture is None else int(below.texture.shape[0]),
            "shapes": None if below.views is None else [v.shape[:2] for v in below.views],
            "iterations": below.iterations,
            "energy": below.energy,
            "info": below.info,
        },
    }
    solved = None
    if level.layout is not None:
        solved = (texture, seen)
        texture, seen = upsample_bilinear(texture, seen, level.layout) if scale_up else (None, None)
    return Result(
        sigma=sigma, views=views, energy=history, iterations=it, texture=texture, seen=seen, info=info, solved=solved
    )


def _warm_start(problem, d: Discretization, below: Result):
    """rho and sigma of the level below, rho sampled bilinearly onto this level's unknowns."""
    # Both are taken after the lower level's rescaling, so their product is its own.
    if d.domain == "texture":
        up = upsample_bilinear(below.texture, below.seen, problem.texture)[0]
        up = up.reshape(-1, problem.channels)[d.texel_index]
    else:
        up = np.concatenate([upsample_pixels(v, m) for v, m in zip(below.views, problem.masks)])
    return np.where(np.isfinite(up), up, d.rho0), below.sigma


def iteration_report(progress):
    """``report(iteration, energy, fraction)`` for :func:`iterate`: ``progress`` (None: nothing) told the fraction
    done and the energy."""

    def report(it, e, fraction):
        if progress is not None:
            progress(fraction, f"iteration {it}, energy {e:.6g}")

    return report


#: :func:`iterate`'s bar goes no further than this on the energy's convergence alone: the stopping test ends it.
_CONVERGED_SHARE = 0.95


def converged_share(first: float, change: float, tol: float) -> float:
    """How far a loop whose relative energy change went from ``first`` (its first) to ``change`` is towards
    its stopping test (``tol``), on a log scale: 0 at the first, :data:`_CONVERGED_SHARE` at ``tol``.

    The MM's energy falls about geometrically, so its log change is about linear in the iterations: a loop that
    stops early moves the bar at the pace of its iterations rather than of ``max_iter``'s.
    """
    if not (first > tol and change > 0):
        return 0.0
    return _CONVERGED_SHARE * min(max(np.log(first / change) / np.log(first / tol), 0.0), 1.0)


def stalled(prev: float, cur: float, tol: float) -> bool:
    """The outer loop's stopping test: the energy changed by no more than ``tol`` of itself."""
    return abs(prev - cur) <= tol * max(abs(prev), 1e-30)


def iterate(channels, params: SolverParams, report, check_cancel, t0: float, done: int = 0, least=None, pool=None):
    """The outer MM loop over all channels; returns the energy history and its times since ``t0``.

    Iterations are numbered on from ``done`` up to ``params.max_iter``, and
    ``report(iteration, energy, fraction)`` is called after each, the fraction the larger of the iteration's
    share of ``max_iter`` and the energy's convergence (:func:`converged_share`). The stopping test on
    the relative energy change is skipped before ``least`` iterations of this
    call (default ``params.min_iter``), so that a warm start cannot stop the
    loop at once. ``pool``: the channels' threads, if the caller has them.
    """
    own = pool is None
    if own:
        pool = ThreadPoolExecutor(max_workers=channel_threads(params, len(channels), channels[0].d.obs_pixel.size))
    least = params.min_iter if least is None else least
    history, elapsed = [sum(ch.e for ch in channels)], [time.perf_counter() - t0]
    first, reached = None, 0.0  # the first relative change, and the furthest share of the way to the stop
    try:
        for it in range(done + 1, params.max_iter + 1):
            check_cancel()
            history.append(sum(pool.map(lambda ch: ch.step(), channels)))
            release_after_iteration(channels[0].d)
            elapsed.append(time.perf_counter() - t0)
            prev, cur = history[-2], history[-1]
            change = abs(prev - cur) / max(abs(prev), 1e-30)
            first = change if first is None else first
            reached = max(reached, converged_share(first, change, params.tol))
            start = done / params.max_iter
            report(it, cur, max(it / params.max_iter, start + (1 - start) * reached))
            if it - done >= least and stalled(prev, cur, params.tol):
                break
    finally:
        if own:
            pool.shutdown(wait=True)
        release_free_memory()
    return history, elapsed


def rescaled(d: Discretization, channels):
    """rho (n, C) and sigma (m, C, 9), scaled so that the mean shading over the observations is 1 per channel."""
    rho = np.stack([ch.rho for ch in channels], axis=1)
    sigma = np.stack([ch.sigma for ch in channels], axis=1)
    for c, ch in enumerate(channels):
        kappa = float(np.dot(d.obs_weight, d.from_pixels(ch.shade)) / d.obs_weight.sum())
        if np.isfinite(kappa) and kappa > 0:
            rho[:, c] *= kappa
            sigma[:, c] /= kappa
    return rho, sigma


def continued_result(problem, d: Discretization, channels, first: Result, views: bool = True, **info) -> Result:
    """The result of ``channels`` that took ``first`` further: rescaled (:func:`rescaled`), with ``first``'s
    energy history and iterations, and its info with ``info`` added."""
    rho, sigma = rescaled(d, channels)
    maps, texture, seen = result_maps(problem, d, rho, views)
    return Result(
        sigma=sigma,
        views=maps,
        energy=first.energy,
        iterations=first.iterations,
        texture=texture,
        seen=seen,
        info=dict(first.info, **info),
    )


def result_maps(problem, d: Discretization, rho: np.ndarray, views: bool = True):
    """Per-view reflectance maps (None without ``views``, texture domain only), and the texture in the texture
    domain."""
    maps = _view_maps(problem, d, rho) if views or d.domain == "image" else None
    texture = seen = None
    if d.domain == "texture":
        size = problem.texture.size
        texture = np.full((size * size, rho.shape[1]), np.nan, dtype=np.float32)
        texture[d.texel_index] = rho
        texture = texture.reshape(size, size, rho.shape[1])
        seen = np.zeros(size * size, dtype=bool)
        seen[d.texel_index] = True
        seen = seen.reshape(size, size)
    return maps, texture, seen


def _view_maps(problem, d: Discretization, rho: np.ndarray) -> list:
    """Per view, the reflectance at each masked pixel (the mean over its observations), NaN elsewhere."""
    C = rho.shape[1]
    if d.domain == "image":
        pix_rho = rho
    else:
        # A pixel whose observations all weigh 0 (a left-out highlight, a grazing view) takes their plain mean.
        unweighted = np.bincount(d.obs_pixel, weights=d.obs_weight, minlength=d.nu.shape[0]) == 0
        w = np.where(unweighted[d.obs_pixel], 1.0, d.obs_weight)
        wsum = np.bincount(d.obs_pixel, weights=w, minlength=d.nu.shape[0])
        rho_o = d.gather(rho)
        pix_rho = np.stack(
            [np.bincount(d.obs_pixel, weights=w * rho_o[:, c], minlength=d.nu.shape[0]) for c in range(C)],
            axis=1,
        )
        with np.errstate(invalid="ignore", divide="ignore"):
            pix_rho = pix_rho / wsum[:, None]
    maps = []
    for v in range(d.n_views):
        mask = problem.masks[v]
        out = np.full(mask.shape + (C,), np.nan, dtype=np.float32)
        out[mask] = pix_rho[d.pixel_offsets[v] : d.pixel_offsets[v + 1]]
        maps.append(out)
    return maps
