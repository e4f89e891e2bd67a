"""TV weighted down across changes of colour (:func:`edge_weights`), in both stages of the two-stage solve.

The MM of the lighting stage minimises data + TV; TV charges an albedo edge by
its height, so the lighting it settles on lowers the edges between flat
regions (a lower energy, a worse lighting). Run again with each TV row weighted
down where the first run found a change of colour (:func:`reweighted_lighting`),
the lighting is left to explain the variation inside the regions.

The albedo stage (:func:`core.solve.stages.solve_albedo`) weights its rows
the same way, from its start: a strong TV weight then smooths the shading left
inside regions of one colour (a shadow changes brightness, not colour) while
the changes of colour keep their height. At a strong weight it is then solved
once more with every change its result kept freed, of colour or of brightness
(``chromaticity=False``): TV lowers the height of each change it keeps, and a
region so freed takes its level from the photos.
"""

from __future__ import annotations

import time

import numpy as np

from ..progress import check_cancel
from .discretization import texture_domain
from .solver import Channel, continued_result, iterate, iteration_report

__all__ = ["edge_weights", "with_edges_freed", "reweighted_lighting"]


def edge_weights(d, rho: np.ndarray, eps: float, chromaticity: bool = True) -> np.ndarray:
    """Per row of ``d.B``, ``e / (|B c| + e)``: near 1 inside flat regions, small across albedo edges.

    ``c`` is the albedo's chromaticity (``C * rho / sum(rho)`` over the C
    channels; rho itself with one channel), so that an edge counts where the
    colour changes: a cast shadow or shading left in the lighting stage's
    albedo changes its brightness much more than its colour, and stays held
    by TV. ``|B c|`` is the norm over the channels of the difference across
    the row, and ``e = eps`` times the median norm of ``c``. ``chromaticity=False``: ``c`` is rho itself, so
    that changes of brightness count too.
    """
    x = np.asarray(rho, np.float64)
    if chromaticity and x.shape[1] > 1:
        x = x.shape[1] * x / np.maximum(x.sum(axis=1, keepdims=True), 1e-12)
    diff = d.B @ x.astype(np.float32)
    g = np.sqrt(np.sum(np.asarray(diff, np.float64) ** 2, axis=1))
    e = eps * float(np.median(np.linalg.norm(x, axis=1)))
    return e / (g + max(e, 1e-30))


def with_edges_freed(d, rho: np.ndarray, eps: float, chromaticity: bool = True):
    """A shallow copy of ``d`` whose TV rows are weighted by :func:`edge_weights` of ``rho``; ``d`` keeps its own."""
    return d.with_base((d.base * edge_weights(d, rho, eps, chromaticity)).astype(np.float32))


def reweighted_lighting(problem, first, params, progress=None, cancel=None, domain=None):
    """The lighting stage again, with each TV row weighted by :func:`edge_weights` of its first albedo.

    TV is an L1 penalty: it charges an albedo edge by its height, so a
    lighting that lowers the edges between flat regions lowers the energy,
    and the MM settles on such a lighting. Weighting each row by
    :func:`edge_weights` of the first result's albedo (one step of
    reweighted L1) frees the changes of colour found there, so the lighting
    is left to explain the variation inside the regions. The MM restarts from
    ``first`` (albedo and lighting) with the same model and TV weight.

    Parameters
    ----------
    problem : core.solve.problem.Problem
        The lighting stage's (texture domain).
    first : core.solve.params.Result
        The lighting stage's result on ``problem``.
    params : core.solve.params.SolverParams
        ``light_edges`` is ``eps`` of :func:`edge_weights`; ``lam``,
        ``lighting`` and the iteration bounds apply as in the first stage.
    domain : core.solve.discretization.Discretization, optional
        :func:`core.solve.discretization.texture_domain` of ``problem`` with ``params``' data model, where the
        caller has made it (the passes of :func:`core.solve.stages.lighting_stage` share one); made here if None.

    Returns
    -------
    core.solve.params.Result
        As :func:`core.solve.solver.solve_joint` gives it, with ``info["edges"]``
        (iterations and last energy of this run).
    """
    d = texture_domain(problem, data_model=params.data_model, threads=params.threads) if domain is None else domain
    C = problem.channels
    rho = first.texture.reshape(-1, C)[d.texel_index]
    rho = np.where(np.isfinite(rho), rho, d.rho0)
    d = with_edges_freed(d, rho, params.light_edges)
    channels = [Channel(d, c, params, rho[:, c], first.sigma[:, c]) for c in range(C)]

    report = iteration_report(progress)
    history, _ = iterate(channels, params, report, lambda: check_cancel(cancel), time.perf_counter())
    return continued_result(problem, d, channels, first, edges={"iterations": len(history) - 1, "energy": history[-1:]})
