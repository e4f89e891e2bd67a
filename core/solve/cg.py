"""Preconditioned conjugate gradients, the one CG loop of the solver and of the texture fill."""

from __future__ import annotations

import numpy as np

__all__ = ["pcg"]


def pcg(matvec, b, x, precondition, max_iter, rtol=1e-7):
    """Solve ``A x = b`` for a symmetric positive definite A by preconditioned CG, warm-started at x.

    Parameters
    ----------
    matvec : callable
        ``v -> A v``.
    b, x : 1-D arrays
        Right-hand side and start; x is updated in place and returned.
    precondition : array or callable
        The inverse diagonal, or ``r -> M^-1 r`` (symmetric positive definite).
    max_iter : int
    rtol : float
        Stop once ``|b - A x| <= rtol |b|``.

    Returns
    -------
    x : array
        Every iteration lowers ``x^T A x / 2 - b^T x``.
    """
    apply = precondition if callable(precondition) else precondition.__mul__
    r = b - matvec(x)
    z = apply(r)
    p = z.copy()
    rz = float(np.dot(r, z))
    stop = (rtol * max(float(np.linalg.norm(b)), 1e-30)) ** 2
    for _ in range(max_iter):
        if rz <= 0 or float(np.dot(r, r)) <= stop:
            break
        ap = matvec(p)
        pap = float(np.dot(p, ap))
        if pap <= 0:
            break
        alpha = rz / pap
        x += alpha * p
        r -= alpha * ap
        z = apply(r)
        rz_new = float(np.dot(r, z))
        p *= rz_new / rz
        p += z
        rz = rz_new
    return x
