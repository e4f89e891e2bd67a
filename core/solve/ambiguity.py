"""A search along the albedo-lighting ambiguity, between the lighting stage's two runs.

A shading ``s`` and an albedo ``rho`` explain the photos about as well as ``s g(n)`` and ``rho / g(n)`` for a
smooth function g of the normal: only the prior on the albedo tells them apart. Where the light moves between
photos each view has its own shading ``s_v``, but g is the surface's, so ``s_v g(n)`` for all views at once is
the same valley. The lighting stage's MM starts from rho = I, all of the photos' variation taken as albedo, and
creeps along that valley, so it stops on the albedo's side of it. :func:`tilt_search` restarts each channel
from its shading tilted by ``exp(a . n)`` for a set of vectors a (:func:`tilt_vectors`), each view's lighting
refitted to the tilted shading by least squares and the albedo the photos divided by it, and iterates each start
a few times. The energy is the one the lighting stage's second run minimises, with the albedo's changes of colour
freed (:mod:`core.solve.edges`): under plain TV the lowest energy is often a lighting that lowers the albedo's
edges, and the search would find it. Where the energy has several valleys of about the same depth, which one has
the lowest is chaotic, so the few ends of lowest energy are averaged (:func:`averaged_ends`: each scaled to a
mean shading of 1, the lightings averaged and the albedos by their geometric mean) and the average iterated
twice more; with one end kept, the untilted start is among them and the energy can only fall.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..geometry.transfer import sphere_directions
from ..progress import check_cancel
from .discretization import texture_domain
from .edges import with_edges_freed
from .lighting import division_start, shading
from .problem import SUN_COLUMNS
from .sh import view_normal_equations
from .solver import Channel, Result, channel_threads, continued_result

__all__ = ["TILT_LENGTHS", "tilt_vectors", "tilted_lighting", "averaged_ends", "tilt_search"]

#: Lengths of the tilt vectors: ``exp(a . n)`` changes the shading by a factor ``exp(2 |a|)`` between opposite
#: normals.
TILT_LENGTHS = (0.4, 0.8)


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


#: MM iterations of the average of the search's ends (:func:`averaged_ends`).
AVERAGE_ITER = 2


def averaged_ends(d, c: int, params, ends) -> Channel:
    """One channel started from the average of the :class:`Channel` ``ends``, iterated :data:`AVERAGE_ITER` times.

    Each end is scaled to a mean shading of 1 over the observations (the scale is free between albedo and
    lighting); the lightings are averaged, the albedos by their geometric mean.
    """
    w = d.obs_weight.astype(np.float64)
    logs, sigmas = [], []
    for ch in ends:
        scale = float(np.dot(w, d.from_pixels(ch.shade)) / w.sum())
        logs.append(np.log(np.maximum(ch.rho.astype(np.float64) * scale, 1e-6)))
        sigmas.append(np.asarray(ch.sigma, np.float64) / scale)
    out = Channel(d, c, params, np.exp(np.mean(logs, axis=0)).astype(np.float32), np.mean(sigmas, axis=0))
    for _ in range(AVERAGE_ITER):
        out.step()
    return out


def tilt_search(problem, first: Result, params, cancel=None) -> Result:
    """The lighting stage's result, each channel moved along the ambiguity (module docstring).

    Parameters
    ----------
    problem : core.solve.problem.Problem
        The lighting stage's (texture domain).
    first : core.solve.solver.Result
        The lighting stage's first run on ``problem``.
    params : core.solve.solver.SolverParams
        ``light_tilts`` directions (:func:`tilt_vectors`), each start iterated ``light_tilt_iter`` times, the
        ``light_tilt_average`` ends of lowest energy averaged (:func:`averaged_ends`), with
        the lighting stage's model and TV weight, its TV rows weighted down across the changes of colour of
        ``first``'s albedo when ``light_edges > 0`` (:func:`core.solve.edges.with_edges_freed`): measured by
        plain TV, a lower energy is often a lighting that lowers the albedo's edges.
    cancel : callable() -> bool, optional

    Returns
    -------
    core.solve.solver.Result
        With ``info["tilt"]``: per channel the tilt of lowest energy and the energies before and after, and the
        seconds.
    """
    t0 = time.perf_counter()
    d = texture_domain(problem, data_model=params.data_model, threads=params.threads)
    C = problem.channels
    rho = first.texture.reshape(-1, C)[d.texel_index]
    rho = np.where(np.isfinite(rho), rho, d.rho0)
    if params.light_edges > 0:
        d = with_edges_freed(d, rho, params.light_edges)
    normals = np.concatenate([n[m] for n, m in zip(problem.normals, problem.masks)]).astype(np.float64)
    gram, _ = view_normal_equations(d.nu, d.pixel_offsets, np.ones(d.nu.shape[0]))
    tilts = tilt_vectors(params.light_tilts)
    has_data = d.scatter(d.obs_weight.astype(np.float64)) > 0

    def channel(c):
        sigma = np.asarray(first.sigma[:, c], np.float64)
        ends, before = [], None
        for i, a in enumerate(tilts):
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
            for _ in range(params.light_tilt_iter):
                ch.step()
            # Only the ends that may be averaged are held (each holds arrays over the observations).
            ends = sorted([*ends, (ch.e, i, ch, a)], key=lambda end: end[:2])
            del ends[max(params.light_tilt_average, 1) :]
        lowest, tilt = ends[0][2], ends[0][3]
        kept = lowest if len(ends) == 1 else averaged_ends(d, c, params, [end[2] for end in ends])
        return kept, {"tilt": tilt.tolist(), "energy_before": before, "energy_after": kept.e}

    with ThreadPoolExecutor(max_workers=channel_threads(params, C, d.obs_pixel.size)) as pool:
        found = list(pool.map(channel, range(C)))
    tilt = {"channels": [i for _, i in found], "seconds": time.perf_counter() - t0}
    return continued_result(problem, d, [ch for ch, _ in found], first, views=False, tilt=tilt)
