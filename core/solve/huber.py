"""The Huber loss phi_delta (eq. def_phi_delta) and its quadratic majorant psi_delta (eq. psi_delta)."""

from __future__ import annotations

import numpy as np

__all__ = ["huber", "huber_inplace", "majorant", "mm_weight"]


def huber(x, delta):
    """phi_delta(x): x^2 / (2 delta) where |x| <= delta, |x| - delta / 2 elsewhere."""
    a = np.abs(x)
    return np.where(a <= delta, a * a / (2 * delta), a - delta / 2)


def huber_inplace(x, delta):
    """phi_delta(x) into a new array of x's dtype, with few temporaries (the solver's hot path).

    Uses ``phi(x) = |x| - delta/2 + max(delta - |x|, 0)^2 / (2 delta)``.
    """
    a = np.abs(x)
    t = delta - a
    np.maximum(t, 0, out=t)
    t *= t
    t *= 1.0 / (2 * delta)
    a -= delta / 2
    a += t
    return a


def mm_weight(x0, delta, out=None):
    """Curvature 1 / max(|x0|, delta) of psi_delta(.; x0), so psi = w x^2 / 2 + const.

    With ``out`` (which may be x0 itself) it is computed there, with no temporaries.
    """
    if out is None:
        return 1.0 / np.maximum(np.abs(x0), delta)
    np.abs(x0, out=out)
    np.maximum(out, delta, out=out)
    return np.divide(1.0, out, out=out)


def majorant(x, x0, delta):
    """psi_delta(x; x0): a quadratic in x that majorises phi_delta and touches it at x0."""
    a0 = np.abs(x0)
    return np.where(a0 <= delta, x * x / (2 * delta), x * x / (2 * np.maximum(a0, delta)) + a0 / 2 - delta / 2)
