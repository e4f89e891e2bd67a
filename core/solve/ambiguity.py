"""A search along the albedo-lighting ambiguity, between the lighting stage's two runs.

A shading ``s`` and an albedo ``rho`` explain the photos about as well as ``s g(n)`` and ``rho / g(n)`` for a
smooth function g of the normal: only the prior on the albedo tells them apart. Where the light moves between
photos each view has its own shading ``s_v``, but g is the surface's, so ``s_v g(n)`` for all views at once is
the same valley. The lighting stage's MM starts from rho = I, all of the photos' variation taken as albedo, and
creeps along that valley, so it stops on the albedo's side of it. :func:`tilt_search` restarts each channel
from its shading tilted by ``exp(a . n)`` for a set of vectors a (:func:`tilt_vectors`), each view's lighting
refitted to the tilted shading by least squares and the albedo the photos divided by it, iterates each start a
few times, and keeps one of lowest energy; the untilted start is one of them, and no end above it is kept, so the
energy can only fall. The untilted start continues the lighting stage's converged run, and a tilted one after a
few iterations is still far above its own minimum, so under one light the ends of lowest energy are narrowed in
rounds, each iterated further before the next comparison (successive halving, ``light_tilt_rounds``); without
them the search rarely leaves the untilted start. The last round's ends are often within a per cent in energy,
which then says little: of those near the lowest (:data:`ENTROPY_WINDOW`), the one whose albedo has the fewest
distinct values (:func:`albedo_entropy`) is kept. Where the light moves, the rounds are skipped: on synthetic
spheres they helped under one light and not under a moving one (docs/measurements.md). The energy is the one
the lighting stage's second run minimises, with the albedo's changes of colour freed (:mod:`core.solve.edges`):
under plain TV the lowest energy is often a lighting that lowers the albedo's edges, and the search would find
it.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from scipy.ndimage import gaussian_filter1d

from ..geometry.sh import sphere_directions
from ..masks import masked
from ..progress import StepCounter, check_cancel
from .discretization import texture_domain
from .edges import with_edges_freed
from .lighting import division_start, shading, view_normal_equations
from .params import Result
from .problem import SUN_COLUMNS
from .solver import Channel, channel_threads, continued_result, stalled

__all__ = ["TILT_LENGTHS", "ENTROPY_WINDOW", "tilt_vectors", "tilted_lighting", "albedo_entropy", "tilt_search"]

#: Lengths of the tilt vectors: ``exp(a . n)`` changes the shading by a factor ``exp(2 |a|)`` between opposite
#: normals.
TILT_LENGTHS = (0.4, 0.8)


#: The albedo's entropy picks among the last round's ends within this fraction of the lowest energy
#: (``light_tilt_entropy``): on rendered scenes it picks better up to a few per cent apart, and on spheres of
#: flat cells, whose ends are up to 46 % apart, the energy picks better beyond that (docs/measurements.md).
ENTROPY_WINDOW = 0.05


def tilt_vectors(directions: int) -> np.ndarray:
    """``(1 + len(TILT_LENGTHS) * directions, 3)``: zero, then each length times each of ``directions``
    directions spread over the sphere."""
    dirs = sphere_directions(directions)
    return np.concatenate([np.zeros((1, 3)), *[length * dirs for length in TILT_LENGTHS]])


def tilted_lighting(d, sigma: np.ndarray, normals: np.ndarray, a: np.ndarray, gram: np.ndarray) -> np.ndarray:
    """Each view's lighting fitted by least squares to its shading ``sigma_v . T`` times ``exp(a . n)``.

    Parameters
    ----------
    d : Discretization
    sigma : (m, K) array
        One channel's lighting.
    normals : (P, 3) array
        The unit normal of each of d's pixels.
    a : (3,) array
    gram : (m, K, K) array
        Each view's ``T^T T`` over its pixels.

    Returns
    -------
    (m, K) array
        With a sun term (the last of :data:`core.solve.problem.SUN_COLUMNS` columns) kept >= 0.
    """
    target = shading(d, sigma, np.float64) * np.exp(normals @ a)
    _, rhs = view_normal_equations(d.nu, d.pixel_offsets, None, target)
    out = np.stack([np.linalg.lstsq(gram[v], rhs[v], rcond=1e-10)[0] for v in range(d.n_views)])
    if out.shape[1] == SUN_COLUMNS:
        out[:, -1] = np.maximum(out[:, -1], 0.0)
    return out


def albedo_entropy(rho: np.ndarray, width: float) -> float:
    """The entropy of ``log rho``'s distribution, its histogram smoothed by a Gaussian of ``width``.

    Tilting the shading by ``g(n)`` spreads each region of one albedo over a range of values, which raises it.
    Values below a thousandth of the median are taken as that; the logarithm makes it independent of the scale.
    """
    rho = np.asarray(rho, np.float64)
    floor = 1e-3 * max(float(np.median(rho)), 1e-12)
    logs = np.log(np.maximum(rho, floor))
    step = width / 5
    counts = np.bincount(((logs - logs.min()) / step).astype(np.int64)).astype(np.float64)
    density = gaussian_filter1d(np.pad(counts, 15), 5.0, truncate=3.0)
    p = density[density > 0] / density.sum()
    return float(-(p * np.log(p)).sum())


def tilt_search(problem, first: Result, params, cancel=None, progress=None, domain=None) -> Result:
    """The lighting stage's result, each channel moved along the ambiguity to the tilt kept (module docstring).

    Parameters
    ----------
    problem : core.solve.problem.Problem
        The lighting stage's (texture domain).
    first : core.solve.params.Result
        The lighting stage's first run on ``problem``.
    params : core.solve.params.SolverParams
        ``light_tilts`` directions (:func:`tilt_vectors`), each start iterated ``light_tilt_iter`` times, the
        lowest narrowed in ``light_tilt_rounds`` under one light, with the lighting stage's model and TV
        weight, its TV rows weighted down across the changes of colour of
        ``first``'s albedo when ``light_edges > 0`` (:func:`core.solve.edges.with_edges_freed`): measured by
        plain TV, a lower energy is often a lighting that lowers the albedo's edges. Of the last round's ends,
        the one of least :func:`albedo_entropy` (width ``light_tilt_entropy``; 0: the lowest energy).
    cancel : callable() -> bool, optional
    progress : callable(fraction, message), optional
        Told the share of the search's iterations done (all channels), at most one at a time.
    domain : core.solve.discretization.Discretization, optional
        :func:`core.solve.discretization.texture_domain` of ``problem`` with ``params``' data model, where the
        caller has made it; made here if None.

    Returns
    -------
    core.solve.params.Result
        With ``info["tilt"]``: per channel the tilt kept, the energies before and after and the albedo's
        ``entropy``, the other end of the last round (``next_tilt``, ``next_energy``, ``next_entropy``; None
        without rounds; the entropies None when they chose nothing), and the seconds.
    """
    t0 = time.perf_counter()
    d = texture_domain(problem, data_model=params.data_model, threads=params.threads) if domain is None else domain
    C = problem.channels
    rho = first.texture.reshape(-1, C)[d.texel_index]
    rho = np.where(np.isfinite(rho), rho, d.rho0)
    if params.light_edges > 0:
        d = with_edges_freed(d, rho, params.light_edges)
    normals = np.concatenate([masked(n, m) for n, m in zip(problem.normals, problem.masks)]).astype(np.float64)
    gram, _ = view_normal_equations(d.nu, d.pixel_offsets, np.ones(d.nu.shape[0]))
    tilts = tilt_vectors(params.light_tilts)
    has_data = d.scatter(d.obs_weight.astype(np.float64)) > 0

    # No end is iterated more than max_iter times in all, as no run of the solver is.
    start_iter = min(params.light_tilt_iter, params.max_iter)
    rounds, done = [], start_iter
    for keep, iterations in () if params.lighting == "per_view" else params.light_tilt_rounds:
        rounds.append((keep, min(iterations, params.max_iter - done)))
        done += rounds[-1][1]
    # Only the ends the first round iterates are held (each holds arrays over the observations).
    held = rounds[0][0] if rounds else 1
    steps = StepCounter(
        progress,
        C * (len(tilts) * start_iter + sum(k * i for k, i in rounds)),
        "searching along the albedo-lighting ambiguity",
    )

    def channel(c):
        sigma = np.asarray(first.sigma[:, c], np.float64)
        ends, before = [], None
        for a in tilts:
            check_cancel(cancel)
            if np.any(a):
                start = tilted_lighting(d, sigma, normals, a, gram)
                rho0 = division_start(d, start[:, None], channels=[c], floor=1e-3)[:, 0]
                rho0 = np.where(has_data, rho0, rho[:, c])
            else:
                start, rho0 = sigma, rho[:, c]
            ch = Channel(d, c, params, rho0.astype(np.float32), start)
            if before is None:
                before = ch.e
            for _ in range(start_iter):
                ch.step()
            steps.add(start_iter)
            ends = sorted([*ends, (ch, a)], key=lambda end: end[0].e)[:held]
        for keep, iterations in rounds:
            ends = ends[:keep]
            for ch, _ in ends:
                # An end whose energy has stopped falling (the solver's own test) is not iterated further.
                for _ in range(iterations):
                    check_cancel(cancel)
                    prev = ch.e
                    if stalled(prev, ch.step(), params.tol):
                        break
                steps.add(iterations)  # those a stall left out as well
            steps.add((keep - len(ends)) * iterations)
            ends.sort(key=lambda end: end[0].e)
        entropy = {}
        if rounds and params.light_tilt_entropy > 0:
            # The energy has narrowed the ends to a few, often within a per cent: the albedo's entropy picks.
            # Only ends near the lowest energy, and no higher than the search's start (ends is sorted by energy).
            entropy = {id(ch): albedo_entropy(ch.rho, params.light_tilt_entropy) for ch, _ in ends}
            top = min(before, (1 + ENTROPY_WINDOW) * ends[0][0].e)
            n = max(1, sum(ch.e <= top for ch, _ in ends))
            ends = sorted(ends[:n], key=lambda end: entropy[id(end[0])]) + ends[n:]
        best, a = ends[0]
        # The last round's other end: where its energy is within a few per cent, the choice is a near tie.
        runner_up = ends[1] if len(ends) > 1 else None
        return best, {
            "tilt": a.tolist(),
            "energy_before": before,
            "energy_after": best.e,
            "entropy": entropy.get(id(best)),
            "next_tilt": None if runner_up is None else runner_up[1].tolist(),
            "next_energy": None if runner_up is None else runner_up[0].e,
            "next_entropy": None if runner_up is None else entropy.get(id(runner_up[0])),
        }

    with ThreadPoolExecutor(max_workers=channel_threads(params, C, d.obs_pixel.size)) as pool:
        found = list(pool.map(channel, range(C)))
    tilt = {"channels": [i for _, i in found], "seconds": time.perf_counter() - t0}
    return continued_result(problem, d, [ch for ch, _ in found], first, views=False, tilt=tilt)
