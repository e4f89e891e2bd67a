"""Second-order spherical harmonics of the normal, as in the paper (eq. m).

``nu(n) = [n1, n2, n3, 1, n1 n2, n1 n3, n2 n3, n1^2 - n2^2, 3 n3^2 - 1]``.
The shading of a point under lighting ``sigma`` (9-vector) is ``sigma . nu(n)``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["sh_basis", "sh_products", "unpack_products", "sh_degree", "diffuse", "DIFFUSE", "SH_BASIS_NAMES"]

#: What each of the 9 coefficients multiplies, for files that record lighting (n: unit world normal).
SH_BASIS_NAMES = ("n1", "n2", "n3", "1", "n1*n2", "n1*n3", "n2*n3", "n1^2-n2^2", "3*n3^2-1")

#: The lighting of the trivial solution: ambient only (eq. sigma_naive).
DIFFUSE = np.array([0, 0, 0, 1, 0, 0, 0, 0, 0], dtype=np.float64)

# Upper-triangle index pairs of the 9x9 products, in row-major order (45 of them).
_IU = np.triu_indices(9)


def sh_basis(normals: np.ndarray, dtype=np.float32, order: int = 2) -> np.ndarray:
    """Return ``nu(n)`` with shape ``(..., (order + 1)^2)`` for unit normals ``(..., 3)``.

    Order 2 is the paper's 9 functions, in its order. Orders 3 and 4 append
    the real spherical harmonics of those degrees as polynomials of n
    (without normalising constants), used by the occlusion-aware transfer
    (:mod:`core.geometry.transfer`), where sharp lights and cast shadows
    need more than 9.
    """
    if order not in (2, 3, 4):
        raise ValueError(f"sh_basis: order must be 2, 3 or 4, got {order}")
    n = np.asarray(normals, dtype=np.float64)
    x, y, z = n[..., 0], n[..., 1], n[..., 2]
    cols = [x, y, z, np.ones_like(x), x * y, x * z, y * z, x * x - y * y, 3 * z * z - 1]
    if order >= 3:
        zz = z * z
        cols += [
            y * (3 * x * x - y * y),
            x * y * z,
            y * (5 * zz - 1),
            z * (5 * zz - 3),
            x * (5 * zz - 1),
            z * (x * x - y * y),
            x * (x * x - 3 * y * y),
        ]
    if order >= 4:
        cols += [
            x * y * (x * x - y * y),
            y * z * (3 * x * x - y * y),
            x * y * (7 * zz - 1),
            y * z * (7 * zz - 3),
            35 * zz * zz - 30 * zz + 3,
            x * z * (7 * zz - 3),
            (x * x - y * y) * (7 * zz - 1),
            x * z * (x * x - 3 * y * y),
            x * x * (x * x - 3 * y * y) - y * y * (3 * x * x - y * y),
        ]
    return np.stack(cols, axis=-1).astype(dtype, copy=False)


def sh_degree(k: int) -> np.ndarray:
    """The SH degree (band) of each of the first k functions of :func:`sh_basis`."""
    bands = np.array([1, 1, 1, 0, 2, 2, 2, 2, 2] + [3] * 7 + [4] * 9)
    return bands[:k]


def diffuse(k: int = 9) -> np.ndarray:
    """:data:`DIFFUSE` with ``k`` coefficients (ambient only)."""
    out = np.zeros(k)
    out[3] = 1.0
    return out


def sh_products(nu: np.ndarray) -> np.ndarray:
    """The ``K (K + 1) / 2`` distinct products ``nu_a nu_b`` (a <= b) per row; 45 for the paper's K = 9.

    Precomputed once so that the sigma-step's KxK normal matrix is one
    matrix-vector product per view: ``M = unpack(w @ products)``.
    """
    # Column by column from contiguous rows of nu^T: fancy indexing along axis 1 is far slower.
    cols = np.ascontiguousarray(np.asarray(nu).T)
    iu = np.triu_indices(cols.shape[0])
    out = np.empty((cols.shape[1], iu[0].size), dtype=cols.dtype)
    for k, (a, b) in enumerate(zip(*iu)):
        np.multiply(cols[a], cols[b], out=out[:, k])
    return out


def unpack_products(packed: np.ndarray) -> np.ndarray:
    """Symmetric ``(..., K, K)`` matrices from their ``K (K + 1) / 2`` upper-triangle entries."""
    k = int(round((np.sqrt(8 * packed.shape[-1] + 1) - 1) / 2))
    iu = _IU if k == 9 else np.triu_indices(k)
    out = np.zeros(packed.shape[:-1] + (k, k), dtype=packed.dtype)
    out[..., iu[0], iu[1]] = packed
    out[..., iu[1], iu[0]] = packed
    return out
