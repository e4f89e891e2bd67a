"""The solve: the paper's joint estimate in one stage, or the lighting and then the albedo in two.

:func:`solve` is the entry point. Without ``SolverParams.albedo_lam`` it is the paper's alternating MM of the
albedo and the lighting together (:func:`core.solve.solver.solve_joint`). With it (the add-on's default), two
stages (:func:`solve_two_stage`):

1. :func:`lighting_stage`: the joint MM with a strong TV weight, on a texture of at most 128² (the lighting has
   a few coefficients per view; it needs no fine texels). The strong weight keeps shading out of the albedo,
   and flattens its detail.
2. :func:`solve_albedo`: the albedo again, under that lighting held fixed, with a weak TV weight chosen from
   the photos' colour texture (:func:`core.solve.albedo_weight.adapted_albedo_lam`): a convex problem in rho
   alone, started from the photos divided by the shading (:func:`core.solve.lighting.division_start`), or from
   its own solve at half the size; at a strong weight, solved once more with the changes of its result freed
   (:func:`debiases`).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np

from ..geometry.texels import texel_totals
from ..memory import release_free_memory
from ..parallel import blas_on_one_thread, joined, start
from ..progress import check_cancel, shares, sub_progress
from .albedo_weight import adapted_albedo_lam, colour_measures
from .ambiguity import tilt_search
from .discretization import data_model_for, image_domain, pixels_per_texel, texture_domain
from .edges import reweighted_lighting, with_edges_freed
from .highlights import without_highlights
from .lighting import division_start, floored_where_dark
from .params import Result, SolverParams
from .pyramid import coarsen, supported_size, upsample_bilinear, with_texture_size
from .solver import Channel, channel_threads, iterate, iteration_report, rescaled, result_maps, solve_joint

__all__ = [
    "LIGHTING_SHARE",
    "albedo_stage",
    "debiases",
    "lighting_stage",
    "solve",
    "solve_albedo",
    "solve_two_stage",
    "thinned_for_lighting",
]


@blas_on_one_thread()
def solve(
    problem,
    params: SolverParams | None = None,
    progress=None,
    cancel=None,
    views: bool = True,
    scale_up: bool = True,
    albedo_problem=None,
) -> Result:
    """Estimate the albedo and the lighting: in two stages when ``params.albedo_lam`` is set, else jointly.

    The parameters are :func:`core.solve.solver.solve_joint`'s, and ``albedo_problem``
    :func:`solve_two_stage`'s; returns :func:`solve_two_stage`'s result, or :func:`core.solve.solver.solve_joint`'s.
    """
    params = params or SolverParams()
    params.check()
    params = params.resolved()
    if params.albedo_lam is None:
        return solve_joint(problem, params, progress, cancel, views, scale_up)
    return solve_two_stage(problem, params, progress, cancel, views, scale_up, albedo_problem)


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


def thinned_for_lighting(problem, most: float):
    """``problem`` at every other pixel of every other row, again, while it has more than ``most`` pixels per texel.

    The lighting has a few coefficients per view: thinned to 17-25 pixels per texel it was as accurate as on all
    of them, in less than half the time; at 10-16 some fixtures got worse (docs/measurements.md).
    """
    while pixels_per_texel(problem) > most:
        thin = coarsen(problem, texture=False)
        if thin is None:
            break
        problem = thin.on_layout(problem.texture)
    return problem


#: :func:`balanced_for_lighting` changes no pixel's weight by more than this factor either way: a texel seen
#: by one glancing pixel would otherwise weigh as much as one every photo sees head-on.
LIGHT_BALANCE_CAP = 4.0


def balanced_for_lighting(problem, power: float, cap: float = LIGHT_BALANCE_CAP):
    """``problem`` with each pixel's view weight times ``(m / W) ** power``, held within ``[1 / cap, cap]``.

    W is the view weight of all the pixels whose nearest texel is the pixel's, m the median of W over the
    texels; the weights are then scaled to the sum they had, so that the TV weight means what it did. The
    lighting's few coefficients per view are fitted to all of the surface at once, and the surface the photos
    see only at a glancing angle, mostly facing down or away from the cameras, has few pixels of low weight:
    without this its shading is what the rest of the surface extrapolates to, and its error goes into its
    albedo (docs/measurements.md).
    """
    if power <= 0:
        return problem
    nearest, weights, total = texel_totals(problem.uv, problem.masks, problem.view_weight, problem.texture.inside)
    seen = total > 0
    if not seen.any():
        return problem
    factor = np.clip((np.median(total[seen]) / np.where(seen, total, 1.0)) ** power, 1.0 / cap, cap)
    balanced = [w * factor[t] for t, w in zip(nearest, weights)]
    scale = sum(w.sum() for w in weights) / max(sum(b.sum() for b in balanced), 1e-300)
    view_weight = []
    for mask, b in zip(problem.masks, balanced):
        out = np.zeros(mask.shape, np.float32)
        out[mask] = b * scale
        view_weight.append(out)
    return replace(problem, view_weight=view_weight)


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


#: The share of :func:`solve_albedo`'s bar that its pass with the changes of its result freed takes (measured:
#: 35 iterations after 32, 13 after 19).
DEBIAS_SHARE = 0.45


def debiases(params) -> bool:
    """Whether :func:`solve_albedo` with ``params`` solves again with the changes of its result freed: at a TV
    weight of at least ``params.albedo_debias`` (0: never), with an edge scale ``albedo_edges`` to free them by."""
    return params.albedo_debias > 0 and params.albedo_edges > 0 and params.lam >= params.albedo_debias


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
    scale_up=True,
):
    """The albedo under a fixed lighting: the MM's rho-steps alone (a convex problem).

    Parameters
    ----------
    problem : core.solve.problem.Problem
    sigma : (m, C, 9) array
        The lighting of each view (as :class:`core.solve.params.Result` gives it).
    params : core.solve.params.SolverParams
        ``lam`` is the TV weight, lowered across the changes of colour of the
        start by ``albedo_edges`` (texture domain), and at ``albedo_debias`` or more solved once more with
        the changes of its result freed (in at most ``max_iter`` iterations of its own; started from a
        half-size solve, which made that pass, the changes of the start are freed instead); ``max_iter``,
        ``min_iter``, ``tol``, ``delta``, ``cg_iter``, ``threads``, ``extrapolate`` and
        ``max_texels_per_pixel`` apply as in :func:`core.solve.solver.solve`.
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
    scale_up : bool
        As :func:`core.solve.solver.solve_joint`'s.

    Returns
    -------
    core.solve.params.Result
        With ``sigma`` as given, rescaled with rho so that the mean shading is 1. The iterations and energies
        are those of the solve; the pass's, under its own weights, are in ``info["debias"]`` where it made one
        (``iterations``, and the last ``energy``), as the lighting stage reports its passes.
    """
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
        r.solved = (r.texture, r.seen)
        r.texture, r.seen = upsample_bilinear(r.texture, r.seen, problem.texture) if scale_up else (None, None)
        r.info["solved_size"] = size
        return r
    half = coarse = None
    domain = params.domain if d is None else d.domain
    if rho0 is None and domain == "texture" and _starts_from_half(problem):
        # Solved before this size's problem is built, so that the two are not held at once.
        # The bar's share of the half-size start, as measured: about 2/3 of the time before a refinement of a
        # few iterations, 1/5 before a solve to convergence.
        share = 0.65 if refine_iter is not None else 0.2
        half, coarse = _half_size_start(
            problem, sigma, params, sub_progress(progress, 0.0, share, "half size"), cancel, builds
        )
        progress = sub_progress(progress, share, 1.0)
        if refine_iter is not None:
            params = replace(
                params, max_iter=min(params.max_iter, refine_iter), min_iter=min(params.min_iter, refine_iter)
            )
    t_build0 = time.perf_counter()
    if d is None:
        d = (
            texture_domain(
                problem,
                data_model="merged" if merged else data_model_for(problem, params.data_model),
                threads=params.threads,
            )
            if params.domain == "texture"
            else image_domain(problem, normalise_correspondences=params.normalise_correspondences)
        )
    t_build = time.perf_counter() - t_build0
    d = without_highlights(d)
    if rho0 is None:
        rho0 = _start(d, sigma, half)
        half = None
    plain = d
    # The pass runs where the solve starts from the photos; a texture refined from its half-size solve, which made
    # the pass, frees the changes of that start instead, of brightness too.
    frees = debiases(params) and d.domain == "texture"
    debias, inherited = frees and coarse is None, frees and coarse is not None
    if params.albedo_edges > 0 and d.domain == "texture":
        d = with_edges_freed(d, rho0, params.albedo_edges, chromaticity=not inherited)
    debiased = None

    def channel(d, c, rho):
        ch = Channel(d, c, params, rho, sigma[:, c])
        shade = floored_where_dark(ch.shade.astype(np.float64), ch.values).astype(ch.ft)
        ch._set_sigma(ch.sigma, shade)
        ch.e = ch.energy()
        return ch

    it = 0
    deltas = ([] if warm_delta is None else [warm_delta]) + [params.delta]
    # The bar's share of the run with the smoother Huber, as measured: about 2/3 of the iterations.
    spans = [(0.0, 0.65), (0.65, 1.0)] if len(deltas) == 2 else [(0.0, 1.0)]
    if debias:
        spans = [(a * (1 - DEBIAS_SHARE), b * (1 - DEBIAS_SHARE)) for a, b in spans]
    with ThreadPoolExecutor(max_workers=channel_threads(params, problem.channels, d.obs_pixel.size)) as pool:
        channels = list(pool.map(lambda c: channel(d, c, rho0[:, c]), range(problem.channels)))
        rho0 = None  # each channel has its own copy
        release_free_memory()  # the build's temporaries
        for delta, span in zip(deltas, spans):
            report = iteration_report(sub_progress(progress, *span))
            if delta != channels[0].delta:
                for ch in channels:
                    ch.delta = delta
                    ch.e = ch.energy()
            least = params.min_iter if delta == params.delta else min(params.min_iter, WARM_MIN_ITER)
            history, _ = iterate(channels, params, report, lambda: check_cancel(cancel), t0, it, least, pool)
            it += len(history) - 1
        if debias:
            # Once more from the result, every change it kept freed (of colour or of brightness): TV lowers the
            # height of each change it keeps, and a region so freed takes its level from the photos.
            rho = np.stack([ch.rho for ch in channels], axis=1)
            d = with_edges_freed(plain, rho, params.albedo_edges, chromaticity=False)
            channels = list(pool.map(lambda c: channel(d, c, rho[:, c]), range(problem.channels)))
            rho = None
            report = iteration_report(sub_progress(progress, 1 - DEBIAS_SHARE, 1.0))
            # A run of its own, as the lighting stage's passes are: as many iterations at most as the stage's
            # (params are the caller's here: only a refinement from the half size, which has no pass, cuts them).
            pass_params = replace(params, max_iter=it + params.max_iter)
            freed, _ = iterate(channels, pass_params, report, lambda: check_cancel(cancel), t0, it, None, pool)
            debiased = {"iterations": len(freed) - 1, "energy": freed[-1:]}
    rho, sigma = rescaled(d, channels)
    views, texture, seen = result_maps(problem, d, rho, views=views and not merged)
    info = {
        "build_seconds": t_build,
        "solve_seconds": time.perf_counter() - t0 - t_build,
        "n_unknowns": d.n_unknowns,
        "domain": d.domain,
        "solved_size": problem.texture.size if d.domain == "texture" else None,
        "coarse_start": coarse,
        "data_model": d.data_model,
        "debias": debiased,
    }
    return Result(sigma=sigma, views=views, energy=history, iterations=it, texture=texture, seen=seen, info=info)


#: A pass of the lighting stage's edges that stops within this many iterations has found the edges it was
#: given settled: the passes end there (:func:`lighting_stage`).
EDGE_PASS_SETTLED = 10


def lighting_stage(problem, params, progress=None, cancel=None):
    """Stage 1 of the two-stage solve: the lighting, with the strong TV weight ``params.lam``.

    Solved on a texture of at most ``params.light_size`` (the lighting has 9
    coefficients per view and channel; it needs no fine texels), coarsened from ``problem.light_texture``
    where it has one, with the data
    model ``params.light_data_model`` and extrapolation ``params.light_extrapolate``, started from rho = I, and, when
    ``params.light_edges > 0`` (texture domain), solved again with the albedo
    edges it found freed (:func:`core.solve.edges.reweighted_lighting`), in passes: at most
    ``params.light_edge_passes``, until one stops within :data:`EDGE_PASS_SETTLED` iterations.

    Returns
    -------
    (core.solve.problem.Problem, core.solve.params.Result)
        The problem it was solved on, and its result (``albedo_lam`` unused).
    """
    light_problem = problem
    if params.domain == "texture" and problem.light_texture is not None:
        light_problem = problem.on_layout(problem.light_texture)
    if (
        params.domain == "texture"
        and params.light_size
        and light_problem.texture is not None
        and light_problem.texture.size > params.light_size
    ):
        light_problem = with_texture_size(light_problem, params.light_size)
    if params.domain == "texture" and params.light_pixels > 0:
        light_problem = thinned_for_lighting(light_problem, params.light_pixels)
    if params.domain == "texture" and params.light_balance > 0:
        light_problem = balanced_for_lighting(light_problem, params.light_balance)
    light_params = replace(params.resolved(), albedo_lam=None, extrapolate=params.light_extrapolate)
    if params.domain == "texture":
        light_params = replace(light_params, data_model=data_model_for(light_problem, params.light_data_model))
    edges = params.light_edges > 0 and params.domain == "texture"
    tilts = params.light_tilts > 0 and params.domain == "texture"
    # The bar's shares of the first run, the search (shorter without its rounds, where the light moves) and each
    # pass of the edges, as their times were measured (docs/measurements.md).
    tilt_share = 0.25 if params.lighting == "per_view" else 0.52
    edge_share = 0.1 * min(params.light_edge_passes, 3)
    parts = shares(
        {"first": 0.27, **({"tilts": tilt_share} if tilts else {}), **({"edges": edge_share} if edges else {})}
    )
    first = solve_joint(light_problem, light_params, sub_progress(progress, *parts["first"]), cancel)
    # One texture domain for the search and every pass: each weights its own copy's TV rows.
    domain = None
    if tilts or edges:
        domain = texture_domain(light_problem, data_model=light_params.data_model, threads=light_params.threads)
    if tilts:
        tilts_progress = sub_progress(progress, *parts["tilts"])
        tilts_progress(0.0, "searching along the albedo-lighting ambiguity")
        first = tilt_search(light_problem, first, light_params, cancel, tilts_progress, domain)
    if edges:
        # Reweighted L1 in passes: each frees the changes of colour of the albedo the one before found, until
        # one settles within EDGE_PASS_SETTLED iterations. Each pass takes half of what is left of the bar's share.
        lo, hi = parts["edges"]
        passes = []
        for k in range(params.light_edge_passes):
            last = k == params.light_edge_passes - 1
            mid = hi if last else lo + (hi - lo) / 2
            first = reweighted_lighting(
                light_problem, first, light_params, sub_progress(progress, lo, mid, "edges"), cancel, domain
            )
            passes.append(first.info["edges"]["iterations"])
            lo = mid
            if passes[-1] <= EDGE_PASS_SETTLED:
                break
        first.info["edges"]["passes"] = passes  # the iterations of each pass; the dict is the last pass's
    first.info["data_model"] = light_params.data_model
    return light_problem, first


#: The share of :func:`solve_two_stage`'s progress bar that its lighting stage takes (the albedo stage the rest).
LIGHTING_SHARE = 0.6


def solve_two_stage(problem, params, progress=None, cancel=None, views=True, scale_up=True, albedo_problem=None):
    """Lighting with a strong TV weight, then the albedo under that lighting with a weak one.

    Stage 1 is :func:`core.solve.solver.solve` with ``params`` (TV weight
    ``lam``, lighting model ``params.lighting``), on a texture of at most
    ``params.light_size`` (the lighting has 9 coefficients; it needs no fine
    texels). Stage 2 is :func:`solve_albedo` with ``params.albedo_lam`` on the
    full problem, or on ``albedo_problem(texture)`` where that callable gives another (``texture``: the photos'
    :func:`colour_texture` under stage 1's lighting, NaN outside the texture domain; None: the same problem).

    Returns
    -------
    core.solve.params.Result
        Stage 2's, with stage 1's summary in ``info["lighting_stage"]``.
    """

    t0 = time.perf_counter()
    albedo_params = replace(params, lam=params.albedo_lam)
    # The albedo stage's starts are built while the lighting stage runs (its coarse levels leave a core idle).
    with joined(start(_start_builds, problem, albedo_params, threads=params.threads)) as builds:
        lighting_progress = sub_progress(progress, 0.0, LIGHTING_SHARE, "lighting")
        light_problem, first = lighting_stage(problem, params, lighting_progress, cancel)
        builds = builds.result()
    # Measured once, where the hook or the albedo stage's weight uses it.
    wanted = params.domain == "texture" and (albedo_problem is not None or params.albedo_adapt)
    measures = colour_measures(light_problem, first.sigma) if wanted else (float("nan"), float("nan"))
    other = albedo_problem(measures[0]) if albedo_problem is not None else None
    if other is not None and other is not problem:
        problem, builds = other, None  # the starts were built for the other problem
    albedo_progress = sub_progress(progress, LIGHTING_SHARE, 1.0, "albedo")
    return albedo_stage(
        problem, light_problem, first, params, albedo_progress, cancel, views, builds, scale_up, t0, measures
    )


def albedo_stage(
    problem,
    light_problem,
    first,
    params,
    progress=None,
    cancel=None,
    views=True,
    builds=None,
    scale_up=True,
    started=None,
    measures=None,
):
    """Stage 2 of the two-stage solve: :func:`solve_albedo` on ``problem`` with ``params.albedo_lam`` (adapted
    to the photos' :func:`core.solve.albedo_weight.colour_measures` with ``params.albedo_adapt``), under
    :func:`lighting_stage`'s lighting ``first.sigma``; ``light_problem`` is the problem that stage was solved on.

    ``started``: when the lighting stage began (:func:`time.perf_counter`), for its seconds in the summary;
    ``measures``: :func:`core.solve.albedo_weight.colour_measures` of ``light_problem``, if the caller measured
    them already.

    Returns
    -------
    core.solve.params.Result
        With the lighting stage's summary in ``info["lighting_stage"]``.
    """
    t1 = time.perf_counter()
    t0 = t1 if started is None else started
    first.views = None  # not needed: free them before the larger stage
    albedo_params = replace(params, lam=params.albedo_lam)
    texture = sparsity = None
    if params.albedo_adapt and params.domain == "texture":
        texture, sparsity = colour_measures(light_problem, first.sigma) if measures is None else measures
        albedo_params = replace(albedo_params, lam=adapted_albedo_lam(params.albedo_lam, texture, sparsity))
    light_pixels = sum(int(m.sum()) for m in light_problem.masks)
    light_problem = None  # its thinned photos too
    if texture is not None and progress is not None:
        progress(
            0.0,
            f"lambda {albedo_params.lam:.3g} (from the photos' colour texture {texture:.3f}, its sparsity "
            f"{sparsity:.2f})",
        )
    second = solve_albedo(
        problem,
        first.sigma,
        albedo_params,
        progress=progress,
        cancel=cancel,
        views=views,
        builds=builds,
        scale_up=scale_up,
    )
    second.info["lighting_stage"] = {
        "iterations": first.iterations,
        "energy": first.energy[-1:],
        "solved_size": first.info.get("solved_size"),
        "lam": params.lam,
        "lighting": params.lighting,
        "edges": first.info.get("edges"),
        "tilt": first.info.get("tilt"),
        "data_model": first.info.get("data_model"),
        "pixels": light_pixels,
        "seconds": t1 - t0,
    }
    second.info["albedo_lam"] = albedo_params.lam
    second.info["colour_texture"] = texture
    second.info["colour_sparsity"] = sparsity
    second.info["elapsed"] = [time.perf_counter() - t0]
    return second
