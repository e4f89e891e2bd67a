"""Aggregation multigrid preconditioner for the rho-step.

The rho-step solves ``(diag(D) + B^T diag(w) B) x = b``. Where rho is flat,
the majorant makes the TV and correspondence weights ``w`` (up to
``mu / delta``) thousands of times the data weights ``D``, so Jacobi-CG only
moves information a few pixels per iteration (docs/measurements.md has the
error left after k iterations of each preconditioner).

Here the unknowns are grouped into 2x2 blocks of a grid, level after level,
and every level's matrix is the Galerkin product ``P^T A P`` of the one
above, rebuilt from the new weights at each rho-step (the patterns are fixed
and built once). In the image domain the grid is the texture's when the
pixels have UVs: a block then holds the pixels of *all* views that see one
surface patch, which is what the stiff correspondence rows tie together.
Blocks of each view's own pixel grid leave that coupling to the smoother
and help far less, so they are only the fallback for pixels without UVs.
A symmetric V-cycle with l1-Jacobi smoothing (always convergent) and a
direct solve on the coarsest level preconditions CG.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..geometry.texels import texel_of_uv
from ..masks import masked

__all__ = ["Hierarchy", "block_grid", "surface_grid"]

# Stop coarsening at this many unknowns; that level is factorised.
COARSEST = 3000


def surface_grid(uv: np.ndarray, per_block: float = 4.0) -> np.ndarray:
    """Grid cells ``(0, row, col)`` of UV points on a texel grid sized so that a 2x2 block holds ~per_block points.

    The size is the finest power of two whose 2x2 blocks number at most
    ``len(uv) / per_block``.
    """
    uv = np.asarray(uv, dtype=np.float64)
    n = uv.shape[0]

    def cells(size):
        r, c = texel_of_uv(uv, size)
        return tuple(np.clip(np.floor(x + 0.5), 0, size - 1).astype(np.intp) for x in (r, c))

    # Blocks of the grid of size 2s are the cells of size s; there are at most s^2 of them.
    size = 2 ** max(0, int(np.log2(max(n / per_block, 1.0)) // 2))
    while size < 2**14:
        r, c = cells(2 * size)
        if np.unique(r * (2 * size) + c).size > n / per_block:
            break
        size *= 2
    rows, cols = cells(2 * size)
    return np.column_stack([np.zeros(n, np.intp), rows, cols])


def block_grid(problem, d) -> np.ndarray:
    """``(sheet, row, col)`` of each unknown of the discretisation ``d`` of ``problem``, for :class:`Hierarchy`.

    Texture domain: the texel grid. Image domain: the texture grid at the
    pixels' UVs when they have them (surface patches), else each view's own
    pixel grid.
    """
    if d.domain == "texture":
        return np.column_stack([np.zeros(d.n_unknowns, np.intp), *np.divmod(d.texel_index, problem.texture.size)])
    if problem.uv is not None:
        return surface_grid(np.concatenate([masked(uv, m) for uv, m in zip(problem.uv, problem.masks)]))
    return np.concatenate(
        [np.column_stack([np.full(int(m.sum()), i), *np.nonzero(m)]) for i, m in enumerate(problem.masks)]
    ).astype(np.intp)


def _blocks(grid):
    """Group the grid's 2x2 blocks: (unknown -> block, block grid)."""
    half = grid.astype(np.int64)
    half[:, 1:] //= 2
    extent = half.max(axis=0) + 1
    key = (half[:, 0] * extent[1] + half[:, 1]) * extent[2] + half[:, 2]
    _, first, agg = np.unique(key, return_index=True, return_inverse=True)
    return agg.ravel(), half[first]


class _Pattern:
    """A fixed CSR pattern of a symmetric level matrix whose values are recomputed at each rho-step."""

    def __init__(self, n, keys):
        """``keys``: sorted unique ``row * n + col`` of the entries (every diagonal one included)."""
        self.n = n
        self.indices = (keys % n).astype(np.int32)
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(keys // n, minlength=n))]).astype(np.int32)

    def matrix(self, data):
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.n, self.n))


def _l1_inverse(A, dtype):
    """``1 / sum_j |A_ij|``, the l1-Jacobi smoother, for a level matrix (every row holds its diagonal)."""
    return (1.0 / np.add.reduceat(np.abs(A.data), A.indptr[:-1])).astype(dtype)


def _sort_keys(keys):
    """``order`` sorting the int64 ``keys`` >= 0, and ``first``: True where a new key starts in ``keys[order]``.

    Packs each key with its index into one int64 when they fit: sorting
    plain values is faster than an argsort.
    """
    bits = max(int(keys.size).bit_length(), 1)
    if keys.size and int(keys.max()) < 2 ** (63 - bits):
        packed = np.sort((keys << bits) | np.arange(keys.size))
        order, sorted_keys = packed & ((1 << bits) - 1), packed >> bits
    else:
        order = np.argsort(keys)
        sorted_keys = keys[order]
    first = np.ones(keys.size, dtype=bool)
    first[1:] = sorted_keys[1:] != sorted_keys[:-1]
    return order, first, sorted_keys


def _distinct(keys):
    """The sorted distinct ``keys``, and where each key is among them."""
    order, first, sorted_keys = _sort_keys(keys)
    where = np.empty(keys.size, dtype=np.intp)
    where[order] = np.cumsum(first) - 1
    return sorted_keys[first], where


def _gram_pattern(M):
    """The pattern of ``M^T diag(w) M + diag(e)`` and the fixed linear maps from (w, e) to its values.

    Returns (pattern, U, M2T, upper, lower, diag): the strictly upper values
    are ``U @ w``, stored at positions ``upper`` and mirrored at ``lower``;
    the diagonal is ``M2T @ w + e``, at ``diag``.
    """
    n = M.shape[1]
    lengths = np.diff(M.indptr)
    keys, row, coef = [np.zeros(0, np.int64)], [np.zeros(0, np.int32)], [np.zeros(0)]
    for L in np.unique(lengths[lengths >= 2]):
        rows = np.flatnonzero(lengths == L).astype(np.int32)
        at = M.indptr[rows][:, None] + np.arange(L)
        cols, vals = M.indices[at].astype(np.int64), M.data[at]
        for k in range(L):
            for m in range(k + 1, L):
                keys.append(np.minimum(cols[:, k], cols[:, m]) * n + np.maximum(cols[:, k], cols[:, m]))
                row.append(rows)
                coef.append(vals[:, k] * vals[:, m])
    # Row p of U sums the contributions of all difference rows to one pair (i < j).
    order, starts, keys = _sort_keys(np.concatenate(keys))
    U = sp.csr_matrix(
        (np.concatenate(coef)[order], np.concatenate(row)[order], np.append(np.flatnonzero(starts), order.size)),
        shape=(int(starts.sum()), M.shape[0]),
    )
    upper_keys = keys[starts]
    ui, uj = np.divmod(upper_keys, n)
    full, where = _distinct(np.concatenate([upper_keys, uj * n + ui, np.arange(n, dtype=np.int64) * (n + 1)]))
    nu = upper_keys.size
    # The diagonal is (M^2)^T w: the transpose of a CSR matrix is a CSC view, multiplied without converting.
    M2T = sp.csr_matrix((M.data**2, M.indices, M.indptr), shape=M.shape).T
    return _Pattern(n, full), U, M2T, where[:nu], where[nu : 2 * nu], where[2 * nu :]


def _galerkin_map(pattern: _Pattern, agg, nc):
    """The pattern of ``P^T A P`` for the aggregation ``agg`` (n -> nc), and where each entry of A goes in it."""
    rows = np.repeat(np.arange(pattern.n), np.diff(pattern.indptr))
    keys, where = _distinct(agg[rows].astype(np.int64) * nc + agg[pattern.indices])
    return _Pattern(nc, keys), where


class Hierarchy:
    """The fixed aggregation patterns of one discretisation (built once, shared by the channels).

    Every level's matrix has a fixed pattern, and its values are a fixed
    linear map of the rho-step's weights: the first coarse level's are
    ``U @ w`` for the (block-crossing) difference rows, each deeper level's a
    sum of the level above's entries. Rebuilding the levels at each rho-step
    is then a few sparse products and sums instead of sparse triple
    products, which cost far more than the rest of the step.

    Parameters
    ----------
    grid : (n, 3) int array
        (sheet, row, column) of every unknown; 2x2 blocks of each sheet are aggregated.
    B, BT : sparse matrices
        The difference rows and their transpose.
    """

    def __init__(self, grid, B, BT):
        self.abs_BT = sp.csr_matrix((np.abs(BT.data), BT.indices, BT.indptr), shape=BT.shape)
        self.agg = []
        grid = np.asarray(grid)
        n = grid.shape[0]
        self.sizes = []
        while n > COARSEST:
            agg, grid = _blocks(grid)
            nc = grid.shape[0]
            if nc > 0.7 * n:  # blocks no longer shrink the problem
                break
            self.agg.append(agg)
            self.sizes.append(nc)
            n = nc
        if not self.agg:
            return
        # B P: B's rows with columns renamed to blocks; entries in one block add up, rows inside one cancel.
        BP = sp.csr_matrix(
            (B.data.astype(np.float64), self.agg[0][B.indices], B.indptr.copy()), shape=(B.shape[0], self.sizes[0])
        )
        BP.sum_duplicates()
        BP.eliminate_zeros()
        self.rows = np.flatnonzero(np.diff(BP.indptr) > 0)
        first, self.U, self.BP2T, self.upper, self.lower, self.diag = _gram_pattern(BP[self.rows])
        self.levels = [first]
        self.maps = []
        for agg, nc in zip(self.agg[1:], self.sizes[1:]):
            coarse, where = _galerkin_map(self.levels[-1], agg, nc)
            self.levels.append(coarse)
            self.maps.append(where)

    def level_matrices(self, D, w):
        """The coarse levels' matrices ``P^T A P`` (float64 CSR, finest first) for ``A = diag(D) + B^T diag(w) B``."""
        w1 = w[self.rows].astype(np.float64)
        data = np.empty(self.levels[0].indices.size)
        data[self.upper] = data[self.lower] = self.U @ w1
        data[self.diag] = self.BP2T @ w1 + np.bincount(self.agg[0], weights=D, minlength=self.sizes[0])
        out = [self.levels[0].matrix(data)]
        for coarse, where in zip(self.levels[1:], self.maps):
            data = np.bincount(where, weights=data, minlength=coarse.indices.size)
            out.append(coarse.matrix(data))
        return out

    def preconditioner(self, matvec, D, w, dtype=np.float32):
        """``r -> z ~ A^-1 r`` for ``A = diag(D) + B^T diag(w) B``, given as ``matvec``: one symmetric V-cycle."""
        inv0 = (1.0 / np.maximum(D + 2 * (self.abs_BT @ w), 1e-30)).astype(dtype)
        if not self.agg:
            return inv0.__mul__
        *levels, A = self.level_matrices(D, w)
        ops = [(matvec, inv0)] + [(L.astype(dtype).__matmul__, _l1_inverse(L, dtype)) for L in levels]
        coarsest = spla.splu((A + sp.diags(1e-9 * A.diagonal())).tocsc())  # guards a block with no data
        return _VCycle(ops, self.agg, self.sizes, coarsest, dtype)


class _VCycle:
    """One symmetric V-cycle; a plain object, so that it is freed as soon as the rho-step drops it."""

    def __init__(self, ops, agg, sizes, coarsest, dtype):
        self.ops, self.agg, self.sizes, self.coarsest, self.dtype = ops, agg, sizes, coarsest, dtype

    def __call__(self, r):
        down = []
        for (A, inv), agg, size in zip(self.ops, self.agg, self.sizes):
            z = inv * r
            down.append((r, z))
            r = np.bincount(agg, weights=r - A(z), minlength=size).astype(self.dtype)
        e = self.coarsest.solve(r.astype(np.float64)).astype(self.dtype)
        for (A, inv), agg, (r, z) in zip(self.ops[::-1], self.agg[::-1], down[::-1]):
            z += e[agg]
            z += inv * (r - A(z))
            e = z
        return e
