"""Lighting as the scene has it: one world lighting shared by the photos, and a two-stage schedule.

The paper gives every view 9 free SH coefficients per channel. Under one fixed
light (the common capture) that is 9 m numbers where the scene has 9, and the
spare freedom lets each view's lighting absorb part of the albedo: alternating
from rho = I does not resolve the albedo-lighting ambiguity. Two remedies live
here, both used through :class:`core.solve.solver.SolverParams`:

* ``lighting="shared"``: the lighting of view v is ``g_v sigma``, one world
  lighting ``sigma`` per channel times a gain ``g_v`` per view and channel
  (exposure and white balance, 3 numbers per photo). :func:`shared_lighting_step`
  is its sigma-step: it alternates exact minimisations of the quadratic
  majorant in sigma and in the gains, so the MM keeps its descent.
* ``lighting="coupled"``: free per view, held to such a shared lighting by a
  quadratic prior that is part of the energy (:class:`Coupling`); between the
  two. :func:`choose_lighting` picks it, or ``per_view`` when the light moves.
* ``albedo_lam``: :func:`solve_two_stage` first estimates the lighting with a
  strong TV weight (which keeps shading out of the albedo but flattens its
  detail), then solves the albedo again with that lighting fixed and a weak TV
  weight (:func:`solve_albedo`, a convex problem in rho alone).

:func:`fit_lighting` fits the lighting to a known albedo (the true-lighting
ceiling of the benchmarks) and :func:`shading_error` compares two lightings by
the shading they give over the observations.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np

from ..memory import release_free_memory
from ..parallel import joined, start
from ..progress import check_cancel, sub_progress
from .discretization import image_domain, texture_domain
from .problem import SUN_COLUMNS
from .pyramid import coarsen, supported_size, upsample_bilinear, with_texture_size
from .sh import view_normal_equations
from .solver import _shading

#: TV weight of the albedo stage (with ``SolverParams.albedo_edges``), chosen by leave-one-scene-out over the
#: fixtures (docs/measurements.md); with ``SolverParams.albedo_adapt``, the weight at COLOUR_TEXTURE_REFERENCE.
ALBEDO_LAMBDA = 20.0
#: With ``albedo_adapt`` the albedo stage's weight is ``albedo_lam * (f / COLOUR_TEXTURE_REFERENCE) **
#: -COLOUR_TEXTURE_POWER`` within ``albedo_lam`` times COLOUR_TEXTURE_RANGE, f the photos' colour texture
#: (:func:`colour_texture`): an albedo with fine changes of colour everywhere wants a weak TV that keeps them,
#: flat patches a strong one that takes the shading left in them. Fitted by leave-one-scene-out over the 13
#: fixtures, where the best weight spans 0.05 to 80 (docs/measurements.md).
COLOUR_TEXTURE_REFERENCE = 0.044
COLOUR_TEXTURE_POWER = 6.0
COLOUR_TEXTURE_RANGE = (1 / 400, 4.0)

__all__ = [
    "ALBEDO_LAMBDA",
    "adapted_albedo_lam",
    "colour_texture",
    "choose_lighting",
    "Coupling",
    "per_view_lighting_step",
    "prior_metric",
    "shared_lighting_step",
    "split_gains",
    "solve_albedo",
    "lighting_stage",
    "lighting_data_model",
    "pixels_per_texel",
    "thinned_for_lighting",
    "solve_two_stage",
    "fit_lighting",
    "shading_error",
    "division_start",
    "shading_floor",
]


def _free(k):
    """Coefficients of sigma free in the sigma-step; the constant term (index 3) is pinned to fix the scale."""
    return np.delete(np.arange(k), 3)


# Shading below this fraction of the median shading is raised to it when the lighting is fixed: where the
# lighting says "dark", dividing by it blows the albedo up.
SHADING_FLOOR = 0.2


def choose_lighting(variation: float | None) -> str:
    """The lighting model for a measured :func:`core.solve.lambda_choice.lighting_variation`.

    One light for all photos (or too little overlap to tell): per-view
    lightings held to a shared one (``"coupled"``); a light that moves
    between the photos: free per view (``"per_view"``).
    """
    from .lambda_choice import VARYING_THRESHOLD

    return "per_view" if variation is not None and variation > VARYING_THRESHOLD else "coupled"


def split_gains(sigma_views: np.ndarray):
    """Write per-view lightings ``(m, 9)`` as ``g_v sigma`` with ``g_0 = 1``: returns ``(sigma, g)``.

    Exact when the views' lightings are proportional; otherwise the gains are
    the least-squares ratios to view 0's lighting.
    """
    sigma = np.array(sigma_views[0], dtype=np.float64)
    nn = float(sigma @ sigma)
    g = sigma_views @ sigma / nn if nn > 0 else np.ones(len(sigma_views))
    g[0] = 1.0
    return sigma, g


def per_view_lighting_step(Ms: np.ndarray, bs: np.ndarray, sigma_views: np.ndarray) -> np.ndarray:
    """Each view's lighting minimising ``s^T M_v s - 2 b_v^T s``, view 0's constant term held (it pins the scale)."""
    sigma = np.array(sigma_views, dtype=np.float64)
    free = _free(sigma.shape[1])
    for v, (M, b) in enumerate(zip(Ms, bs)):
        if v == 0:
            rhs = b[free] - M[free, 3] * sigma[0, 3]
            sigma[0, free] = np.linalg.lstsq(M[np.ix_(free, free)], rhs, rcond=1e-10)[0]
        else:
            sigma[v] = np.linalg.lstsq(M, b, rcond=1e-10)[0]
    return sigma


def shared_lighting_step(
    Ms: np.ndarray, bs: np.ndarray, sigma_views: np.ndarray, rounds: int = 4, pin_constant: bool = True
) -> np.ndarray:
    """The sigma-step of one channel for a lighting shared by the views, up to a gain per view.

    Minimises ``sum_v (g_v^2 s^T M_v s - 2 g_v s^T b_v)`` over the world
    lighting s (its constant term kept, which pins the scale) and the gains
    g_v (``g_0 = 1``), alternating exact minimisations, each of which can
    only lower it.

    Parameters
    ----------
    Ms, bs : (m, 9, 9), (m, 9) arrays
        Each view's normal equations at the current majorant
        (:meth:`core.solve.solver._Channel.normal_equations`).
    sigma_views : (m, 9) array
        The current lighting of each view, ``g_v s``.
    rounds : int
        Alternations.
    pin_constant : bool
        Keep the constant term of s. The MM needs it (with ``g_0 = 1``) to fix
        the scales that the albedo, the gains and s trade between them; a fit
        to a known albedo does not (``g_0 = 1`` is the only gauge there).

    Returns
    -------
    (m, 9) array
        The new ``g_v s``.
    """
    s, g = split_gains(np.asarray(sigma_views, dtype=np.float64))
    free = _free(s.size)
    for _ in range(rounds):
        A = np.einsum("v,vij->ij", g * g, Ms)
        r = np.einsum("v,vi->i", g, bs)
        if pin_constant:
            rhs = r[free] - A[free, 3] * s[3]
            s[free] = np.linalg.lstsq(A[np.ix_(free, free)], rhs, rcond=1e-10)[0]
        else:
            s = np.linalg.lstsq(A, r, rcond=1e-10)[0]
        q = np.einsum("i,vij,j->v", s, Ms, s)
        p = bs @ s
        ok = q > 1e-30
        g_new = np.where(ok, p / np.where(ok, q, 1.0), g)
        g_new[0] = 1.0
        g = g_new
    return g[:, None] * s[None, :]


#: The coupled prior's floor, relative to the mean eigenvalue of each view's metric (:func:`prior_metric`).
PRIOR_FLOOR = 1e-3


def prior_metric(G: np.ndarray, floor: float = PRIOR_FLOOR) -> np.ndarray:
    """Each view's metric ``G_v`` plus ``floor`` times its mean eigenvalue on the diagonal.

    A view that sees few normals (the flat faces of a building) leaves some of its lighting's coefficients
    undetermined by its pixels; measured by ``G_v`` alone the prior leaves them free too, and they drift
    far from any light, into the world lighting and, through the occlusion, into the albedo. The floor holds
    them to the world lighting.
    """
    k = G.shape[-1]
    return G + (floor * np.trace(G, axis1=-2, axis2=-1) / k)[:, None, None] * np.eye(k)


class Coupling:
    """A prior that holds per-view lightings near one shared lighting: ``lighting="coupled"``.

    The energy gains ``kappa / 2 * sum_v (sigma_v - g_v s)^T G_v (sigma_v - g_v s)``,
    where ``s`` is a world lighting and ``g_v`` a gain per view (``g_0 = 1``),
    both free, and ``G_v = Ibar^2 sum_p beta_p nu_p nu_p^T`` over the view's pixels
    (``Ibar`` the mean observed value): the squared difference of the two
    shadings over the view, in the units of the data, with a floor
    (:func:`prior_metric`) for what the view does not see. ``kappa = 0`` is the
    paper's free lighting per view, ``kappa -> inf`` the shared one.

    With a sun term (a transfer of :data:`core.solve.problem.SUN_COLUMNS`), the
    sun is not free per view: its coefficient is ``g_v t``, one strength t per
    channel times each view's gain, kept >= 0. Free per view, it trades with
    the albedo (docs/measurements.md).
    """

    def __init__(self, d, c, kappa, sigma0):
        self.kappa = float(kappa)
        w = d.obs_weight.astype(np.float64)
        values = d.from_pixels(d.values[:, c]).astype(np.float64)
        ibar2 = (np.sum(w * values) / max(np.sum(w), 1e-30)) ** 2
        beta = np.bincount(d.obs_pixel, weights=w, minlength=d.nu.shape[0])
        self.G = prior_metric(ibar2 * view_normal_equations(d.nu, d.pixel_offsets, beta)[0])
        self.world = self._fit_world(np.asarray(sigma0, np.float64), *split_gains(np.asarray(sigma0, np.float64)))

    def _fit_world(self, sigma, s, g, rounds=3):
        G = self.G
        for _ in range(rounds):
            s = np.linalg.lstsq(np.einsum("v,vij->ij", g * g, G), np.einsum("v,vij,vj->i", g, G, sigma), rcond=1e-10)[0]
            q = np.einsum("i,vij,j->v", s, G, s)
            p = np.einsum("i,vij,vj->v", s, G, sigma)
            ok = q > 1e-30
            g = np.where(ok, p / np.where(ok, q, 1.0), g)
            g[0] = 1.0
        return s, g

    def penalty(self, sigma, world=None):
        s, g = self.world if world is None else world
        diff = sigma - g[:, None] * s[None, :]
        return 0.5 * self.kappa * float(np.einsum("vi,vij,vj->", diff, self.G, diff))

    def step(self, Ms, bs, sigma_views, rounds=2):
        """The sigma-step: per-view lightings and the world lighting, alternately minimised exactly."""
        sigma = np.array(sigma_views, dtype=np.float64)
        s, g = self.world
        kG = self.kappa * self.G
        sun = sigma.shape[1] == SUN_COLUMNS
        free = _free(sigma.shape[1] - sun)
        for _ in range(rounds):
            # Each view's quadratic in its lighting: data majorant plus the prior towards g_v s.
            As = Ms + kG
            rs = [bs[v] + kG[v] @ (g[v] * s) for v in range(len(sigma))]
            sigma = self._with_sun(As, rs, sigma, g, free) if sun else per_view_lighting_step(As, rs, sigma)
            s, g = self._fit_world(sigma, s, g)
        return sigma, (s, g)

    @staticmethod
    def _with_sun(As, rs, sigma, g, free):
        """Every view's SH and the one sun strength t (coefficient ``g_v t``), minimised jointly, t >= 0.

        Each view's SH is eliminated (``x_v = X0_v - X1_v g_v t``), which leaves a 1-D quadratic in t: its
        minimum, clamped at 0, is exact. SH and the sun overlap (the sun's smooth part is SH), so minimising
        them in turn crawls along that valley and can end on either side of it.
        """
        sigma = np.array(sigma)
        k = sigma.shape[1]
        r = np.array(rs, dtype=np.float64)
        r[0] -= As[0][:, 3] * sigma[0, 3]  # view 0's constant term is held: it pins the scale
        # View 0 without its constant term; the others' SH all at once (the prior makes their matrices definite).
        X0 = np.linalg.lstsq(As[0][np.ix_(free, free)], np.stack([r[0, free], As[0][free, -1]], 1), rcond=1e-10)[0]
        sh = np.arange(k - 1)
        A, R = As[1:, : k - 1, : k - 1], np.stack([r[1:, : k - 1], As[1:, : k - 1, -1]], axis=-1)
        try:
            X = np.linalg.solve(A, R)
        except np.linalg.LinAlgError:
            X = None
        if X is None or not np.all(np.isfinite(X)):
            X = np.stack([np.linalg.lstsq(a, b, rcond=1e-10)[0] for a, b in zip(A, R)])
        idx = [free] + [sh] * (len(sigma) - 1)
        sols = [X0, *X]
        num = den = 0.0
        for v, (i, Xv) in enumerate(zip(idx, sols)):
            q = As[v][-1, -1] - As[v][-1, i] @ Xv[:, 1]
            p = r[v, -1] - As[v][-1, i] @ Xv[:, 0]
            num += g[v] * p
            den += g[v] * g[v] * q
        t = max(num / den, 0.0) if den > 0 else sigma[0, -1] / g[0]
        for v, (i, Xv) in enumerate(zip(idx, sols)):
            sigma[v, i] = Xv[:, 0] - Xv[:, 1] * g[v] * t
            sigma[v, -1] = g[v] * t
        return sigma


def shading_floor(shade: np.ndarray, floor: float = SHADING_FLOOR) -> float:
    """The least shading :func:`floored` keeps: ``floor`` times the median of the positive values."""
    pos = shade[shade > 0]
    return floor * (float(np.median(pos)) if pos.size else 1.0)


def floored(shade: np.ndarray, floor: float = SHADING_FLOOR) -> np.ndarray:
    """The shading raised to at least ``floor`` times its median over the positive values."""
    return np.maximum(shade, shading_floor(shade, floor))


def division_start(d, sigma: np.ndarray) -> np.ndarray:
    """Per unknown, the least-squares albedo of its observations under a fixed lighting: ``(n, C)``.

    ``rho_u = sum_o beta_o a_o I_o / sum_o beta_o a_o^2`` over the observations
    of unknown u, with the floored shading ``a`` (the minimiser of the data
    term alone when each observation sees one unknown).
    """
    C = d.values.shape[1]
    out = np.empty((d.n_unknowns, C), np.float32)
    w = d.obs_weight.astype(np.float64)
    for c in range(C):
        a = d.from_pixels(floored(_shading(d, sigma[:, c], np.float64)))
        num = d.scatter(w * a * d.from_pixels(d.values[:, c]))
        den = d.scatter(w * a * a)
        out[:, c] = np.where(den > 0, num / np.maximum(den, 1e-30), 0.0)
    return out


def _start(d, sigma, half=None) -> np.ndarray:
    """The albedo stage's start: the half-size solve where it has a value, else :func:`division_start`."""
    if half is None:
        return division_start(d, sigma)
    rho = half.reshape(-1, half.shape[-1])[d.texel_index].astype(np.float32)
    missing = ~np.isfinite(rho)
    if missing.any():
        rho[missing] = division_start(d, sigma)[missing]
    return rho


#: The albedo stage starts from its own solve at half the size (:func:`solve_albedo`) while its texture has
#: fewer photo pixels per texel than this: there each texel's division of the photos is mostly noise, which
#: the MM takes many iterations to smooth and the edge weights would take for changes of colour. Between
#: 2.03 (lambert_sky at 512², where it paid) and 3.56 (the sparsest fixture at 256², where it did not).
COARSE_START_PIXELS = 3.0
#: Iterations at most of that half-size solve, and the least size it is solved at.
COARSE_START_ITER = 30
COARSE_START_MIN_SIZE = 64
#: The half-size solve first runs with the Huber parameter this many times larger, to its stopping rule (at
#: least WARM_MIN_ITER iterations), then with the solver's own: an MM near L1 crawls, and one a little
#: smoother gets it near the minimum first. With its tolerance it reached a better start in fewer iterations
#: (docs/measurements.md).
COARSE_START_DELTA_FACTOR = 3.0
COARSE_START_TOL = 1e-3
WARM_MIN_ITER = 3
#: Iterations of the texture itself once started from its half-size solve: it is finer than the photos resolve
#: (fewer than COARSE_START_PIXELS pixels per texel), the half-size solve holds what they tell, and running to
#: the stopping rule there cost time without making the fixtures more accurate (docs/measurements.md).
REFINE_ITER = 2


def pixels_per_texel(problem) -> float:
    """Photo pixels on the mesh per texel inside the UV islands of ``problem.texture``."""
    pixels = sum(int(np.count_nonzero(m)) for m in problem.masks)
    return pixels / max(int(np.count_nonzero(problem.texture.inside)), 1)


def thinned_for_lighting(problem, most: float):
    """``problem`` at every other pixel of every other row, again, while it has more than ``most`` pixels per texel.

    The lighting has a few coefficients per view: 130 pixels per texel (the 2K case's 128² lighting texture)
    tell it no more than 32 do, at a quarter of the work. Down to 16-28 no fixture changed; at 10-16 some got worse
    (docs/measurements.md).
    """
    while pixels_per_texel(problem) > most:
        thin = coarsen(problem, texture=False)
        if thin is None:
            break
        problem = thin.on_layout(problem.texture)
    return problem


def _half_size_start(problem, sigma, params, progress, cancel, builds=None):
    """:func:`solve_albedo` at half the size, sampled bilinearly at the texel centres of ``problem.texture``.

    Returns that texture (NaN where unseen) and a summary of the solve (its size and iterations).
    """
    quick = replace(
        params,
        max_iter=COARSE_START_ITER,
        min_iter=min(params.min_iter, COARSE_START_ITER),
        tol=max(params.tol, COARSE_START_TOL),
    )
    size = problem.texture.size // 2
    half, d = builds.pop(size) if builds and size in builds else (with_texture_size(problem, size), None)
    warm = COARSE_START_DELTA_FACTOR * params.delta
    coarse = solve_albedo(
        half, sigma, quick, None, progress, cancel, d, refine_iter=None, warm_delta=warm, merged=True, builds=builds
    )
    fine, _ = upsample_bilinear(coarse.texture, coarse.seen, problem.texture)
    return fine, {"size": coarse.info["solved_size"], "iterations": coarse.iterations}


def _starts_from_half(problem) -> bool:
    """Whether :func:`solve_albedo` starts this texture-domain problem from its own solve at half the size."""
    size = problem.texture.size
    return size >= 2 * COARSE_START_MIN_SIZE and pixels_per_texel(problem) < COARSE_START_PIXELS


def _capped_size(problem, params):
    """The texture size that ``params.max_texels_per_pixel`` solves this problem at, if smaller; else None."""
    if params.domain != "texture" or params.max_texels_per_pixel <= 0 or problem.texture is None:
        return None
    size = supported_size(problem, params.max_texels_per_pixel)
    return size if size < problem.texture.size else None


def _start_builds(problem, params) -> dict:
    """The half-size starts :func:`solve_albedo` solves, built ahead: ``{size: (problem, discretisation)}``.

    They do not depend on the lighting, so :func:`solve_two_stage` builds them on a thread of their own while
    the lighting stage runs. The same levels as :func:`solve_albedo` makes, by the same steps.
    """
    params = replace(params, lighting="fixed", albedo_lam=None).resolved()
    if params.domain != "texture" or problem.texture is None:
        return {}
    capped = _capped_size(problem, params)
    if capped is not None:
        problem = with_texture_size(problem, capped)
    out = {}
    while _starts_from_half(problem):
        problem = with_texture_size(problem, problem.texture.size // 2)
        out[problem.texture.size] = (problem, texture_domain(problem, data_model="merged", threads=params.threads))
    return out


def solve_albedo(
    problem,
    sigma: np.ndarray,
    params,
    rho0=None,
    progress=None,
    cancel=None,
    d=None,
    refine_iter=REFINE_ITER,
    warm_delta=None,
    merged=False,
    views=True,
    builds=None,
):
    """The albedo under a fixed lighting: the MM's rho-steps alone (a convex problem).

    Parameters
    ----------
    problem : core.solve.problem.Problem
    sigma : (m, C, 9) array
        The lighting of each view (as :class:`core.solve.solver.Result` gives it).
    params : core.solve.solver.SolverParams
        ``lam`` is the TV weight, lowered across the changes of colour of the
        start by ``albedo_edges`` (texture domain); ``max_iter``, ``min_iter``, ``tol``, ``delta``,
        ``cg_iter``, ``threads``, ``extrapolate`` and ``max_texels_per_pixel``
        apply as in :func:`core.solve.solver.solve`.
    rho0 : (n, C) array, optional
        Start; default :func:`division_start`, or with fewer than
        :data:`COARSE_START_PIXELS` pixels per texel (texture domain) this
        function's result at half the size. ``albedo_edges`` takes its edges
        from the start.
    d : Discretization, optional
        The problem's, if already built.
    refine_iter : int or None
        Iterations at most after a start from the half-size solve (None: as ``params`` says); the half-size
        solves themselves run as ``params`` says.
    warm_delta : float, optional
        First run the MM with this Huber parameter to the stopping rule (at least :data:`WARM_MIN_ITER`
        iterations), then with ``params.delta``; ``max_iter`` bounds the two together, and the returned
        energies are the second run's.
    merged : bool
        Texture domain: the "merged" data model (one observation per texel and photo), with no per-view maps
        in the result; the half-size starts use it.
    views : bool
        False: no per-view maps in a texture-domain result (as :func:`core.solve.solver.solve`).
    builds : dict, optional
        :func:`_start_builds`' half-size starts, taken out as they are used.

    Returns
    -------
    core.solve.solver.Result
        With ``sigma`` as given, rescaled with rho so that the mean shading is 1.
    """
    from .solver import Result, _Channel, _iterate, _outputs, _rescaled, channel_threads

    params = replace(params, lighting="fixed", albedo_lam=None).resolved()
    t0 = time.perf_counter()
    sigma = np.asarray(sigma, dtype=np.float64)
    size = None if d is not None else _capped_size(problem, params)
    if size is not None:
        r = solve_albedo(
            with_texture_size(problem, size),
            sigma,
            replace(params, max_texels_per_pixel=0.0),
            None,
            progress,
            cancel,
            refine_iter=refine_iter,
            warm_delta=warm_delta,
            merged=merged,
            views=views,
            builds=builds,
        )
        r.texture, r.seen = upsample_bilinear(r.texture, r.seen, problem.texture)
        r.info["solved_size"] = size
        return r
    half = coarse = None
    domain = params.domain if d is None else d.domain
    if rho0 is None and domain == "texture" and _starts_from_half(problem):
        # Solved before this size's problem is built, so that the two are not held at once.
        half, coarse = _half_size_start(
            problem, sigma, params, sub_progress(progress, 0.0, 0.3, "half size"), cancel, builds
        )
        progress = sub_progress(progress, 0.3, 1.0)
        if refine_iter is not None:
            params = replace(
                params, max_iter=min(params.max_iter, refine_iter), min_iter=min(params.min_iter, refine_iter)
            )
    t_build0 = time.perf_counter()
    if d is None:
        d = (
            texture_domain(problem, data_model="merged" if merged else params.data_model, threads=params.threads)
            if params.domain == "texture"
            else image_domain(problem, normalise_correspondences=params.normalise_correspondences)
        )
    t_build = time.perf_counter() - t_build0
    if rho0 is None:
        rho0 = _start(d, sigma, half)
        half = None
    if params.albedo_edges > 0 and d.domain == "texture":
        from .edges import with_edges_freed

        d = with_edges_freed(d, rho0, params.albedo_edges)

    def channel(c):
        ch = _Channel(d, c, params, rho0[:, c], sigma[:, c])
        shade = floored(ch.shade.astype(np.float64)).astype(ch.ft)
        ch._set_sigma(ch.sigma, shade)
        ch.e = ch.energy()
        return ch

    def report(i, e):
        if progress is not None:
            progress(i / params.max_iter, f"iteration {i}, energy {e:.6g}")

    it = 0
    with ThreadPoolExecutor(max_workers=channel_threads(params, problem.channels, d.obs_pixel.size)) as pool:
        channels = list(pool.map(channel, range(problem.channels)))
        rho0 = None  # each channel has its own copy
        release_free_memory()  # the build's temporaries
        for delta in ([] if warm_delta is None else [warm_delta]) + [params.delta]:
            if delta != channels[0].delta:
                for ch in channels:
                    ch.delta = delta
                    ch.e = ch.energy()
            least = params.min_iter if delta == params.delta else min(params.min_iter, WARM_MIN_ITER)
            history, _ = _iterate(channels, params, report, lambda: check_cancel(cancel), t0, it, least, pool)
            it += len(history) - 1
    rho, sigma = _rescaled(d, channels)
    views, texture, seen = _outputs(problem, d, rho, views=views and not merged)
    info = {
        "build_seconds": t_build,
        "solve_seconds": time.perf_counter() - t0 - t_build,
        "n_unknowns": d.n_unknowns,
        "domain": d.domain,
        "solved_size": problem.texture.size if d.domain == "texture" else None,
        "coarse_start": coarse,
    }
    return Result(sigma=sigma, views=views, energy=history, iterations=it, texture=texture, seen=seen, info=info)


#: The least photo pixels per texel (inside the islands) of the lighting stage's texture for its "nearest"
#: data model; with fewer, texels are left without a pixel of their own, and the 4-texel splat is used.
#: Between 2.8 (a working resolution of 0.01 MP, where "nearest" failed) and 13.6 (the fewest of the 13
#: fixtures, where it did as well as the splat; docs/measurements.md).
NEAREST_MIN_PIXELS_PER_TEXEL = 8


def lighting_data_model(problem, model: str) -> str:
    """The lighting stage's data model: ``model``, except "nearest" on too few pixels (then "splat")."""
    if model != "nearest" or problem.texture is None:
        return model
    return model if pixels_per_texel(problem) >= NEAREST_MIN_PIXELS_PER_TEXEL else "splat"


def lighting_stage(problem, params, progress=None, cancel=None):
    """Stage 1 of the two-stage solve: the lighting, with the strong TV weight ``params.lam``.

    Solved on a texture of at most ``params.light_size`` (the lighting has 9
    coefficients per view and channel; it needs no fine texels) with the data
    model ``params.light_data_model`` and extrapolation ``params.light_extrapolate``, started from rho = I, and, when
    ``params.light_edges > 0`` (texture domain), solved again with the albedo
    edges it found freed (:func:`core.solve.edges.reweighted_lighting`).

    Returns
    -------
    (core.solve.problem.Problem, core.solve.solver.Result)
        The problem it was solved on, and its result (``albedo_lam`` unused).
    """
    from .solver import solve

    light_problem = problem
    if (
        params.domain == "texture"
        and params.light_size
        and problem.texture is not None
        and problem.texture.size > params.light_size
    ):
        light_problem = with_texture_size(problem, params.light_size)
    if params.domain == "texture" and params.light_pixels > 0:
        light_problem = thinned_for_lighting(light_problem, params.light_pixels)
    light_params = replace(params.resolved(), albedo_lam=None, extrapolate=params.light_extrapolate)
    if params.domain == "texture":
        light_params = replace(light_params, data_model=lighting_data_model(light_problem, params.light_data_model))
    edges = params.light_edges > 0 and params.domain == "texture"
    first = solve(light_problem, light_params, sub_progress(progress, 0.0, 0.6 if edges else 1.0), cancel)
    if edges:
        from .edges import reweighted_lighting

        edges_progress = sub_progress(progress, 0.6, 1.0, "edges")
        first = reweighted_lighting(light_problem, first, light_params, edges_progress, cancel)
    first.info["data_model"] = light_params.data_model
    return light_problem, first


def solve_two_stage(problem, params, progress=None, cancel=None, views=True):
    """Lighting with a strong TV weight, then the albedo under that lighting with a weak one.

    Stage 1 is :func:`core.solve.solver.solve` with ``params`` (TV weight
    ``lam``, lighting model ``params.lighting``), on a texture of at most
    ``params.light_size`` (the lighting has 9 coefficients; it needs no fine
    texels). Stage 2 is :func:`solve_albedo` with ``params.albedo_lam`` on the
    full problem.

    Returns
    -------
    core.solve.solver.Result
        Stage 2's, with stage 1's summary in ``info["lighting_stage"]``.
    """

    t0 = time.perf_counter()
    albedo_params = replace(params, lam=params.albedo_lam)
    # The albedo stage's starts are built while the lighting stage runs (its coarse levels leave a core idle).
    with joined(start(_start_builds, problem, albedo_params, threads=params.threads)) as builds:
        light_problem, first = lighting_stage(problem, params, sub_progress(progress, 0.0, 0.6, "lighting"), cancel)
        builds = builds.result()
    first.views = None  # not needed: free them before the larger stage
    texture = None
    if params.albedo_adapt and params.domain == "texture":
        texture = colour_texture(light_problem, first.sigma)
        albedo_params = replace(albedo_params, lam=adapted_albedo_lam(params.albedo_lam, texture))
    light_pixels = sum(int(m.sum()) for m in light_problem.masks)
    light_problem = None  # its thinned photos too
    t1 = time.perf_counter()
    albedo_progress = sub_progress(progress, 0.6, 1.0, "albedo")
    if texture is not None:
        albedo_progress(0.0, f"lambda {albedo_params.lam:.3g} (from the photos' colour texture {texture:.3f})")
    second = solve_albedo(
        problem, first.sigma, albedo_params, progress=albedo_progress, cancel=cancel, views=views, builds=builds
    )
    second.info["lighting_stage"] = {
        "iterations": first.iterations,
        "energy": first.energy[-1:],
        "solved_size": first.info.get("solved_size"),
        "lam": params.lam,
        "lighting": params.lighting,
        "edges": first.info.get("edges"),
        "data_model": first.info.get("data_model"),
        "pixels": light_pixels,
        "seconds": t1 - t0,
    }
    second.info["albedo_lam"] = albedo_params.lam
    second.info["colour_texture"] = texture
    second.info["elapsed"] = [time.perf_counter() - t0]
    return second


def colour_texture(problem, sigma: np.ndarray) -> float:
    """How much fine colour texture the photos show: the median change of chromaticity between neighbouring
    texels of the photos divided by their shading (:func:`division_start`, nearest texel), on the problem's
    texture (:func:`solve_two_stage` gives it the lighting stage's, at most 128², where the rule was fitted).

    Chromaticity (``3 rho / sum(rho)``) hardly changes with the shading, so where the lighting left shading in
    the division this measures the albedo's own changes of colour. NaN when no two neighbouring texels are seen.
    """
    if problem.channels != 3:  # grey photos: no colour to change
        return float("nan")
    size = problem.texture.size
    d = texture_domain(problem, data_model="nearest")
    img = np.full((size * size, 3), np.nan)
    img[d.texel_index] = division_start(d, sigma)
    img = img.reshape(size, size, 3)
    total = img.sum(axis=-1)
    seen = np.isfinite(total) & (total > 0)
    chroma = 3 * img / np.maximum(total, 1e-4)[..., None]
    steps = []
    for axis in (0, 1):
        step = np.diff(chroma, axis=axis)
        both = np.delete(seen, -1, axis) & np.delete(seen, 0, axis)
        steps.append(np.sqrt((step[both] ** 2).sum(axis=-1)))
    steps = np.concatenate(steps)
    return float(np.median(steps)) if steps.size else float("nan")


def adapted_albedo_lam(albedo_lam: float, texture: float) -> float:
    """The albedo stage's TV weight for the photos' :func:`colour_texture` (``albedo_lam`` where it is NaN)."""
    if not np.isfinite(texture):
        return albedo_lam
    lo, hi = COLOUR_TEXTURE_RANGE
    factor = (max(texture, 1e-12) / COLOUR_TEXTURE_REFERENCE) ** -COLOUR_TEXTURE_POWER
    return float(albedo_lam * np.clip(factor, lo, hi))


def _ls_equations(d, rho, c):
    """Per view, the least-squares normal equations of the lighting for a known albedo (one channel)."""
    rho_o = d.gather(rho[:, c].astype(np.float32)).astype(np.float64)
    w = d.obs_weight.astype(np.float64)
    npix = d.nu.shape[0]
    g = np.bincount(d.obs_pixel, weights=w * rho_o * rho_o, minlength=npix)
    h = np.bincount(d.obs_pixel, weights=w * rho_o, minlength=npix) * d.values[:, c]
    return view_normal_equations(d.nu, d.pixel_offsets, g, h)


def fit_lighting(d, rho: np.ndarray, lighting: str = "per_view", rounds: int = 50) -> np.ndarray:
    """The least-squares lighting of each view for a known albedo: ``(m, C, 9)``.

    Parameters
    ----------
    d : Discretization
    rho : (n, C) array
        The albedo at d's unknowns.
    lighting : {"per_view", "shared"}
        Free per view, or one lighting times a gain per view and channel.
    rounds : int
        Alternations of the shared fit.
    """
    C = rho.shape[1]
    out = np.empty((d.n_views, C, d.nu.shape[1]))
    for c in range(C):
        Ms, bs = _ls_equations(d, rho, c)
        per_view = np.stack([np.linalg.lstsq(M, b, rcond=1e-10)[0] for M, b in zip(Ms, bs)])
        if lighting == "shared":
            per_view = shared_lighting_step(Ms, bs, per_view, rounds=rounds, pin_constant=False)
        out[:, c] = per_view
    return out


def shading_error(d, sigma: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per channel, the relative RMS difference of two lightings' shading over the observations.

    The estimate is scaled by the one factor per channel that fits the
    reference best (the albedo's scale is free): ``|k s - s_ref| / |s_ref|``,
    weighted by the observations' weights.
    """
    C = sigma.shape[1]
    w = d.obs_weight.astype(np.float64)
    out = np.empty(C)
    for c in range(C):
        s = d.from_pixels(_shading(d, sigma[:, c], np.float64))
        r = d.from_pixels(_shading(d, reference[:, c], np.float64))
        k = np.sum(w * s * r) / max(np.sum(w * s * s), 1e-30)
        out[c] = np.sqrt(np.sum(w * (k * s - r) ** 2) / max(np.sum(w * r * r), 1e-30))
    return out
