"""Aggregation multigrid preconditioner for the rho-step.

The rho-step solves ``(diag(D) + B^T diag(w) B) x = b``. Where rho is flat,
the majorant makes the TV and correspondence weights ``w`` (up to
``mu / delta``) thousands of times the data weights ``D``, so Jacobi-CG only
moves information a few pixels per iteration: on the benchmark sphere at
half the paper's size, 30 iterations leave 0.83 of the rho-step's error
(README, "What we measured about the solver", item 8).

Here the unknowns are grouped into 2x2 blocks of a grid, level after level,
and every level's matrix is the Galerkin product ``P^T A P`` of the one
above, rebuilt from the new weights at each rho-step (the patterns are fixed
and built once). In the image domain the grid is the texture's when the
pixels have UVs: a block then holds the pixels of *all* views that see one
surface patch, which is what the stiff correspondence rows tie together.
Blocks of each view's own pixel grid leave that coupling to the smoother
and help far less (measured on the benchmark sphere at scale 0.5: 40
iterations reduce the rho-step's error to 0.14 with view blocks, 0.010 with
surface blocks; 300 Jacobi iterations to 0.04). A symmetric V-cycle with
l1-Jacobi smoothing (always convergent) and a direct solve on the coarsest
level preconditions CG.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .uvlayout import texel_of_uv

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
    while size < 2 ** 14:
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
        return surface_grid(np.concatenate([uv[m] for uv, m in zip(problem.uv, problem.masks)]))
    return np.concatenate([np.column_stack([np.full(int(m.sum()), i), *np.nonzero(m)])
                           for i, m in enumerate(problem.masks)]).astype(np.intp)


def _blocks(grid):
    """Group the grid's 2x2 blocks: (unknown -> block, block grid)."""
    half = grid.astype(np.int64)
    half[:, 1:] //= 2
    extent = half.max(axis=0) + 1
    key = (half[:, 0] * extent[1] + half[:, 1]) * extent[2] + half[:, 2]
    _, first, agg = np.unique(key, return_index=True, return_inverse=True)
    return agg.ravel(), half[first]


class Hierarchy:
    """The fixed aggregation patterns of one discretisation (built once, shared by the channels).

    Parameters
    ----------
    grid : (n, 3) int array
        (sheet, row, column) of every unknown; 2x2 blocks of each sheet are aggregated.
    B, BT : sparse matrices
        The difference rows and their transpose.
    """

    def __init__(self, grid, B, BT):
        self.abs_BT = abs(BT)
        self.P = []
        grid = np.asarray(grid)
        n = grid.shape[0]
        while n > COARSEST:
            agg, grid = _blocks(grid)
            nc = grid.shape[0]
            if nc > 0.7 * n:  # blocks no longer shrink the problem
                break
            self.P.append(sp.csr_matrix((np.ones(n, np.float64), (np.arange(n), agg)), shape=(n, nc)))
            n = nc
        self.agg = [P.indices for P in self.P]
        if self.P:
            BP = (B @ self.P[0].astype(np.float32)).astype(np.float64).tocsr()
            BP.eliminate_zeros()  # rows inside one block
            self.rows = np.diff(BP.indptr) > 0
            self.BP = BP[self.rows]
            self.BPT = self.BP.T.tocsr()

    def preconditioner(self, matvec, D, w, dtype=np.float32):
        """``r -> z ~ A^-1 r`` for ``A = diag(D) + B^T diag(w) B``, given as ``matvec``: one symmetric V-cycle."""
        inv0 = (1.0 / np.maximum(D + 2 * (self.abs_BT @ w), 1e-30)).astype(dtype)
        if not self.P:
            return inv0.__mul__
        A = (self.BPT @ sp.diags(w[self.rows].astype(np.float64)) @ self.BP
             + sp.diags(self.P[0].T @ D.astype(np.float64))).tocsr()
        ops = [(matvec, inv0)]
        for P in self.P[1:]:
            ops.append((A.astype(dtype).__matmul__, (1.0 / abs(A).sum(axis=1).A1).astype(dtype)))
            A = (P.T @ A @ P).tocsr()
        coarsest = spla.splu((A + sp.diags(1e-9 * A.diagonal())).tocsc())  # guards a block with no data
        return _VCycle(ops, self.agg, [P.shape[1] for P in self.P], coarsest, dtype)


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
