"""Second-order spherical harmonics of the normal, as in the paper (eq. m).

``nu(n) = [n1, n2, n3, 1, n1 n2, n1 n3, n2 n3, n1^2 - n2^2, 3 n3^2 - 1]``.
The shading of a point under lighting ``sigma`` (9-vector) is ``sigma . nu(n)``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["sh_basis", "sh_products", "DIFFUSE", "SH_BASIS_NAMES"]

#: What each of the 9 coefficients multiplies, for files that record lighting (n: unit world normal).
SH_BASIS_NAMES = ("n1", "n2", "n3", "1", "n1*n2", "n1*n3", "n2*n3", "n1^2-n2^2", "3*n3^2-1")

#: The lighting of the trivial solution: ambient only (eq. sigma_naive).
DIFFUSE = np.array([0, 0, 0, 1, 0, 0, 0, 0, 0], dtype=np.float64)

# Upper-triangle index pairs of the 9x9 products, in row-major order (45 of them).
_IU = np.triu_indices(9)


def sh_basis(normals: np.ndarray, dtype=np.float32) -> np.ndarray:
    """Return ``nu(n)`` with shape ``(..., 9)`` for unit normals ``(..., 3)``."""
    n = np.asarray(normals, dtype=np.float64)
    n1, n2, n3 = n[..., 0], n[..., 1], n[..., 2]
    out = np.stack([n1, n2, n3, np.ones_like(n1), n1 * n2, n1 * n3, n2 * n3,
                    n1 * n1 - n2 * n2, 3 * n3 * n3 - 1], axis=-1)
    return out.astype(dtype, copy=False)


def sh_products(nu: np.ndarray) -> np.ndarray:
    """The 45 distinct products ``nu_a nu_b`` (a <= b) per row, shape ``(P, 45)``.

    Precomputed once so that the sigma-step's 9x9 normal matrix is one
    matrix-vector product per view: ``M = unpack(w @ products)``.
    """
    # Column by column from contiguous rows of nu^T: fancy indexing along axis 1 is far slower.
    cols = np.ascontiguousarray(np.asarray(nu).T)
    out = np.empty((cols.shape[1], 45), dtype=cols.dtype)
    for k, (a, b) in enumerate(zip(*_IU)):
        np.multiply(cols[a], cols[b], out=out[:, k])
    return out


def unpack_products(packed: np.ndarray) -> np.ndarray:
    """Symmetric ``(..., 9, 9)`` matrices from their 45 upper-triangle entries."""
    out = np.zeros(packed.shape[:-1] + (9, 9), dtype=packed.dtype)
    out[..., _IU[0], _IU[1]] = packed
    out[..., _IU[1], _IU[0]] = packed
    return out
