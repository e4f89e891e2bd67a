"""Alternating majorization-minimization solver (Melou et al. 2018, section 4).

API contract (implementation in progress)::

    result = solve(problem, SolverParams(domain="texture"), progress=None, cancel=None)

``progress(fraction: float, message: str)`` is called now and then; ``cancel()``
returns True to stop, and then :class:`Cancelled` is raised.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["SolverParams", "Result", "Cancelled", "solve"]


class Cancelled(Exception):
    """Raised by :func:`solve` when ``cancel()`` returned True."""


@dataclass
class SolverParams:
    domain: str = "texture"          # "texture" or "image"
    lam: float = 5.0                 # lambda, TV weight
    mu: float = 1000.0               # mu, consistency weight (image domain)
    delta: float = 1e-4              # Huber delta
    max_iter: int = 50
    tol: float = 1e-3                # relative energy change to stop
    min_iter: int = 5
    cg_iter: int = 30


@dataclass
class Result:
    sigma: np.ndarray                # (m, C, 9) lighting per view and channel
    views: list                      # per-view reflectance (H, W, C) float32, NaN outside masks
    energy: list                     # energy after each outer iteration (index 0: start)
    iterations: int
    texture: np.ndarray | None = None   # (N, N, C) float32 texture domain only, NaN where unseen
    seen: np.ndarray | None = None      # (N, N) bool, texels with data
    info: dict = field(default_factory=dict)


def solve(problem, params=None, progress=None, cancel=None) -> Result:
    raise NotImplementedError
