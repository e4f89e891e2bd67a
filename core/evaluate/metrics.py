"""Accuracy against ground truth, with the paper's protocol (section 5.1)."""

from __future__ import annotations

import numpy as np

__all__ = ["scaled_rmse"]


def scaled_rmse(estimate, truth, mask=None) -> np.ndarray:
    """Per-channel RMSE after scaling the estimate by the one factor per channel that fits best.

    Parameters
    ----------
    estimate, truth : (..., C) arrays
        Reflectance estimate and ground truth (in [0, 1]).
    mask : (...) bool array, optional
        Where to compare (for example the seen texels inside the UV islands).
        Non-finite estimates are always left out.

    Returns
    -------
    (C,) array of RMSE values.
    """
    e = np.asarray(estimate, dtype=np.float64)
    t = np.asarray(truth, dtype=np.float64)
    if e.shape != t.shape:
        raise ValueError(f"scaled_rmse: estimate {e.shape} and truth {t.shape} differ")
    e = e.reshape(-1, e.shape[-1]) if e.ndim > 1 else e[:, None]
    t = t.reshape(e.shape)
    keep = np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(t), axis=1)
    if mask is not None:
        keep &= np.asarray(mask, dtype=bool).ravel()
    if not keep.any():
        raise ValueError("scaled_rmse: nothing to compare")
    e, t = e[keep], t[keep]
    scale = np.sum(e * t, axis=0) / np.maximum(np.sum(e * e, axis=0), 1e-30)
    return np.sqrt(np.mean((scale * e - t) ** 2, axis=0))
