"""Sparse matrix-vector products into a buffer the caller keeps.

scipy's ``A @ x`` returns a new array each call. An array larger than
glibc's biggest reusable block (32 MB) comes fresh from the kernel every
time, and faulting its pages in is a large share of a product over the
difference rows, and threads doing fresh products run slower together than
one alone: the channels' threads only pay off with kept buffers
(docs/measurements.md).
"""

from __future__ import annotations

import numpy as np

try:  # scipy's kernel behind ``A @ x`` for CSR matrices; it adds A x into y.
    from scipy.sparse._sparsetools import csr_matvec as _csr_matvec
except ImportError:  # pragma: no cover - a scipy without it gets the allocating product
    _csr_matvec = None

__all__ = ["matvec_into"]


def matvec_into(A, x: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out[:] = A @ x`` for a CSR matrix ``A``; returns ``out``.

    Allocates nothing when A, x and out share one dtype and x and out are
    contiguous; otherwise it falls back to ``A @ x`` (same result).
    """
    if (
        _csr_matvec is not None
        and A.format == "csr"
        and A.dtype == x.dtype == out.dtype
        and x.ndim == 1
        and x.flags.c_contiguous
        and out.flags.c_contiguous
        and A.indptr.dtype == A.indices.dtype
    ):
        out.fill(0)
        _csr_matvec(A.shape[0], A.shape[1], A.indptr, A.indices, A.data, x, out)
    else:
        out[...] = A @ x
    return out
