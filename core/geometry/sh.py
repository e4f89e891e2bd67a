"""Second-order spherical harmonics of the normal, as in the paper (eq. m).

``nu(n) = [n1, n2, n3, 1, n1 n2, n1 n3, n2 n3, n1^2 - n2^2, 3 n3^2 - 1]``.
The shading of a point under lighting ``sigma`` (9-vector) is ``sigma . nu(n)``. Integrals over the sphere
(the occlusion's transfer, the search over tilts) are sums over :func:`sphere_directions`.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "sh_basis",
    "sh_degree",
    "diffuse",
    "sphere_directions",
    "DIFFUSE",
    "SH_BASIS_NAMES",
]

#: What each of the 9 coefficients multiplies, for files that record lighting (n: unit world normal).
SH_BASIS_NAMES = ("n1", "n2", "n3", "1", "n1*n2", "n1*n3", "n2*n3", "n1^2-n2^2", "3*n3^2-1")

#: The lighting of the trivial solution: ambient only (eq. sigma_naive).
DIFFUSE = np.array([0, 0, 0, 1, 0, 0, 0, 0, 0], dtype=np.float64)


def sh_basis(normals: np.ndarray, dtype=np.float32, order: int = 2, planes: bool = False) -> np.ndarray:
    """Return ``nu(n)`` with shape ``(..., (order + 1)^2)`` for unit normals ``(..., 3)``.

    Order 2 is the paper's 9 functions, in its order. Orders 3 and 4 append
    the real spherical harmonics of those degrees as polynomials of n
    (without normalising constants), used by the occlusion-aware transfer
    (:mod:`core.geometry.transfer`), where sharp lights and cast shadows
    need more than 9.

    ``planes``: the same numbers as the transposed view of a ``((order + 1)^2, ...)`` array, each function's
    values contiguous: faster to make, and to multiply by a lighting.
    """
    if order not in (2, 3, 4):
        raise ValueError(f"sh_basis: order must be 2, 3 or 4, got {order}")
    normals = np.asarray(normals)
    # Each coordinate as a float64 array of its own: the products below read whole arrays.
    x, y, z = (normals[..., k].astype(np.float64) for k in range(3))
    zz = z * z
    cols = [
        lambda: x,
        lambda: y,
        lambda: z,
        lambda: 1.0,
        lambda: x * y,
        lambda: x * z,
        lambda: y * z,
        lambda: x * x - y * y,
        lambda: 3 * z * z - 1,
    ]
    if order >= 3:
        cols += [
            lambda: y * (3 * x * x - y * y),
            lambda: x * y * z,
            lambda: y * (5 * zz - 1),
            lambda: z * (5 * zz - 3),
            lambda: x * (5 * zz - 1),
            lambda: z * (x * x - y * y),
            lambda: x * (x * x - 3 * y * y),
        ]
    if order >= 4:
        cols += [
            lambda: x * y * (x * x - y * y),
            lambda: y * z * (3 * x * x - y * y),
            lambda: x * y * (7 * zz - 1),
            lambda: y * z * (7 * zz - 3),
            lambda: 35 * zz * zz - 30 * zz + 3,
            lambda: x * z * (7 * zz - 3),
            lambda: (x * x - y * y) * (7 * zz - 1),
            lambda: x * z * (x * x - 3 * y * y),
            lambda: x * x * (x * x - 3 * y * y) - y * y * (3 * x * x - y * y),
        ]
    # Each column computed in float64 and written into the result, one at a time: no (..., K) float64 stack.
    if planes:
        out = np.empty((len(cols), *normals.shape[:-1]), dtype)
        for k, col in enumerate(cols):
            out[k] = col()
        return np.moveaxis(out, 0, -1)
    out = np.empty((*normals.shape[:-1], len(cols)), dtype)
    for k, col in enumerate(cols):
        out[..., k] = col()
    return out


def sh_degree(k: int) -> np.ndarray:
    """The SH degree (band) of each of the first k functions of :func:`sh_basis`."""
    bands = np.array([1, 1, 1, 0, 2, 2, 2, 2, 2] + [3] * 7 + [4] * 9)
    return bands[:k]


def diffuse(k: int = 9) -> np.ndarray:
    """:data:`DIFFUSE` with ``k`` coefficients (ambient only)."""
    out = np.zeros(k)
    out[3] = 1.0
    return out


def sphere_directions(k: int, min_z: float = -1.0) -> np.ndarray:
    """``k`` unit directions spread evenly over the sphere (a Fibonacci lattice), ``(k, 3)``.

    Each stands for 4 pi / k sr; with ``min_z`` > -1 they cover the cap ``z >= min_z`` around +Z instead,
    2 pi (1 - min_z) / k sr each.
    """
    i = np.arange(k) + 0.5
    z = 1.0 - (1.0 - min_z) * i / k
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
