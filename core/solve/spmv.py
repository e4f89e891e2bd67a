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

try:  # scipy's kernels behind ``A @ x`` for CSR and CSC matrices; they add A x into y, outside the GIL.
    from scipy.sparse._sparsetools import csc_matvec as _csc_matvec
    from scipy.sparse._sparsetools import csr_matvec as _csr_matvec
except ImportError:  # pragma: no cover - a scipy without them gets the allocating product and np.bincount
    _csr_matvec = _csc_matvec = None

__all__ = ["matvec_into", "scatter_add", "PairNormal"]

_TAKE_BLOCK = 1 << 20
_SCATTER_BLOCK = 1 << 18  # its constants are kept: 3 MB
_scatter_consts = {}  # (dtype, block): ones, or for an index dtype 0..block, for scatter_add's one-entry columns


def _scatter_const(dtype, make):
    key = (np.dtype(dtype), _SCATTER_BLOCK)
    if key not in _scatter_consts:  # two threads may both make it: the same values either way
        _scatter_consts[key] = make(key[0])
    return _scatter_consts[key]


def scatter_add(index: np.ndarray, x: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out[index[k]] += x[k]`` for every k, in the order of k; returns ``out``.

    A product with the matrix whose column k holds a single 1 in row ``index[k]``, taken in blocks of columns:
    no matrix is stored, and each entry of ``out`` sums its terms in the order of k, as a CSR product over the
    same entries does (the same float32 sums). x and out share a float dtype; both contiguous.
    """
    if _csc_matvec is None:  # pragma: no cover
        out += np.bincount(index, weights=x, minlength=out.size).astype(out.dtype, copy=False)
        return out
    ones = _scatter_const(x.dtype, lambda t: np.ones(_SCATTER_BLOCK, t))
    ptr = _scatter_const(index.dtype, lambda t: np.arange(_SCATTER_BLOCK + 1, dtype=t))
    for a in range(0, index.size, _SCATTER_BLOCK):
        k = min(_SCATTER_BLOCK, index.size - a)
        _csc_matvec(out.size, k, ptr[: k + 1], index[a : a + k], ones, x[a : a + k], out)
    return out


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


class PairNormal:
    """``B^T diag(s) B`` off its diagonal, for a CSR ``B`` whose every row has two entries, with values that follow s.

    Row i of the product holds, for each row e of B that touches unknown i, the other unknown of e with the value
    ``c_1(e) c_2(e) s_e`` (the row's two coefficients): the pattern of ``B^T`` with other columns. Two rows of B
    between the same unknowns give two entries, which the product sums. Building it needs no sort, new weights
    cost one gather, and a product with it reads half the memory that ``B^T (s * (B x))`` does. The diagonal,
    ``(B^2)^T s``, is the caller's.
    """

    def __init__(self, B, BT):
        self.n = BT.shape[0]
        self.indptr = BT.indptr
        self.edge = BT.indices  # the row of B behind each entry
        self.coef = B.data[0::2] * B.data[1::2]
        # The other unknown of each entry's row: the sum of the row's two columns minus this one.
        ends = B.indices[0::2].astype(np.int64) + B.indices[1::2]
        other = np.take(ends, self.edge)
        other -= np.repeat(np.arange(self.n, dtype=np.int64), np.diff(BT.indptr))
        self.indices = other.astype(BT.indices.dtype)

    @classmethod
    def of(cls, B, BT):
        """The operator, or None when some row of B has not exactly two entries (or B has no rows)."""
        if not B.shape[0] or B.format != "csr" or not np.all(np.diff(B.indptr) == 2) or _csr_matvec is None:
            return None
        return cls(B, BT)

    def values(self, s: np.ndarray, out: np.ndarray) -> np.ndarray:
        """The entries for row weights ``s`` (B's dtype), into ``out`` (one per entry of ``B^T``)."""
        weighted = self.coef * s
        # In blocks: np.take casts int32 indices to a new intp array, which over all entries is twice out's size.
        for a in range(0, self.edge.size, _TAKE_BLOCK):
            np.take(weighted, self.edge[a : a + _TAKE_BLOCK], out=out[a : a + _TAKE_BLOCK])
        return out

    def matvec_into(self, values: np.ndarray, x: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``out[:] = L x`` with the entries ``values`` (x, out and values of one dtype, contiguous)."""
        out.fill(0)
        _csr_matvec(self.n, self.n, self.indptr, self.indices, values, x, out)
        return out
