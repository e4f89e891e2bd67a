"""JSON output: plain values from NumPy ones, non-finite floats as null."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["json_value"]


def json_value(x):
    """``x`` with NumPy arrays and scalars turned into plain Python, NaN and infinities into None."""
    if isinstance(x, dict):
        return {str(k): json_value(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_value(v) for v in x]
    if isinstance(x, np.ndarray):
        return json_value(x.tolist())
    if isinstance(x, np.generic):
        return json_value(x.item())
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if x is None or isinstance(x, (bool, int, str)):
        return x
    return str(x)
