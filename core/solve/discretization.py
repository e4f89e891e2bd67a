"""Discretisations of the energy: data observations and rows of differences.

Both parameterisations of the reflectance share one form, so that the energy,
the MM loop and the sigma-step are written once (:mod:`core.solve.solver`):

* a data term over *observations* ``o``: ``beta_o * phi(rho[u_o] * a_o - I_o)``
  where ``u_o`` is an unknown, ``a_o = sigma . nu`` the shading of the pixel
  ``p_o`` that made the observation, and ``I_o`` its value;
* a regulariser over the rows ``e`` of a sparse difference matrix ``B``:
  ``s_e * phi((B rho)_e)``, with ``s_e = lambda * base_e`` for TV rows and
  ``mu * base_e`` for correspondence rows.

Image domain (the paper): one unknown per masked pixel of every view, one
observation per pixel, TV rows between 4-neighbours inside each mask
(Neumann boundary), and one row per correspondence.

Texture domain (the paper's future work): one unknown per texel that some
pixel lands in; TV rows between texel neighbours inside the islands and
across seams, weighted by surface length. There is no mu-term: pixels that
land on the same texel *are* the correspondences. Four data models:

* ``"interpolate"``: one observation per pixel, whose reflectance
  is the bilinear interpolation of the 4 texels around its UV, as a renderer
  samples the texture: ``beta_p * phi((A rho)_p * a_p - I_p)`` with a sparse
  ``A``. A texture-mapped albedo is an exact zero of the data term.
* ``"splat"``: each pixel splats its observation onto
  the 4 texels with bilinear weights, one observation per (pixel, texel). The
  data term is diagonal in rho, so an iteration costs about half as much,
  but a texel then averages pixels up to a texel away, which biases albedo
  edges and gradients at the scale of a texel. On the rendered fixtures the
  two give the same RMSE (docs/measurements.md); on a synthetic textured
  sphere only ``"interpolate"`` reaches the truth.
* ``"nearest"`` (the solver's default, with :data:`NEAREST_MIN_PIXELS_PER_TEXEL`
  pixels per texel or more; the splat with fewer, :func:`data_model_for`): one
  observation per pixel, of the texel of largest bilinear weight, with the
  pixel's whole weight: a quarter of the splats' work, and a texel then
  averages pixels up to half a texel away, not a whole one, so the albedo's
  edges blur less. Both stages of the two-stage solve use it
  (``light_data_model``, ``data_model``; docs/measurements.md).
* ``"merged"``: the splats of one view on one texel as one observation, of
  their weighted mean value and transfer (a virtual pixel) and their summed
  weight. Exact where the albedo is constant over them, since the shading is
  linear in the transfer; what differs between the pixels is below the
  texel's scale. The albedo stage's half-size starts use it, at sizes
  coarser than the photos, where it cuts the observations 3-9 times. It
  has no per-pixel maps (:func:`core.solve.solver.result_maps` gives none).

In all, ``u_o`` generalises to a row of ``A`` (a selection row for the image
domain and the splat).
"""

from __future__ import annotations

import copy
import threading
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..geometry.bilinear import masked_corners
from ..geometry.sh import sh_basis
from ..geometry.texels import bilinear_texels, nearest_texel
from ..masks import masked
from ..parallel import start, thread_map
from .highlights import clipped_regions
from .problem import Problem, stacked_rows
from .spmv import PairNormal, scatter_add

__all__ = [
    "Discretization",
    "NEAREST_MIN_PIXELS_PER_TEXEL",
    "data_model_for",
    "image_domain",
    "pixels_per_texel",
    "texture_domain",
]

#: The least photo pixels per texel (inside the islands) for the "nearest" data model; with fewer, texels are
#: left without a pixel of their own, and :func:`data_model_for` takes the 4-texel splat. Between 2.8 (a working
#: resolution of 0.01 MP, where "nearest" failed in the lighting stage) and 13.6 (the fewest of the 13 fixtures,
#: where it did as well as the splat there); in the albedo stage it was lower on 12 of the 13 scenes with more
#: (docs/measurements.md).
NEAREST_MIN_PIXELS_PER_TEXEL = 8


def pixels_per_texel(problem: Problem) -> float:
    """Photo pixels on the mesh per texel inside the UV islands of ``problem.texture``."""
    pixels = sum(int(np.count_nonzero(m)) for m in problem.masks)
    return pixels / max(int(np.count_nonzero(problem.texture.inside)), 1)


def data_model_for(problem: Problem, model: str) -> str:
    """``model`` for :func:`texture_domain` on ``problem``: itself, except "nearest" on fewer than
    :data:`NEAREST_MIN_PIXELS_PER_TEXEL` pixels per texel (then "splat")."""
    if model != "nearest" or problem.texture is None:
        return model
    return model if pixels_per_texel(problem) >= NEAREST_MIN_PIXELS_PER_TEXEL else "splat"


@dataclass
class Discretization:
    """Everything the solver needs, as flat arrays (see the module docstring).

    Pixels are the masked pixels of all views concatenated, view by view, in
    row-major order; ``pixel_offsets[i]:pixel_offsets[i+1]`` are view i's.
    """

    domain: str
    n_unknowns: int
    pixel_offsets: np.ndarray  # (m+1,)
    values: np.ndarray  # (P, C) float32 pixel values I
    nu: np.ndarray  # (P, 9) float32 SH basis of the pixel normals
    obs_unknown: np.ndarray | None  # (O,) intp; None when obs_matrix mixes unknowns
    obs_pixel: np.ndarray  # (O,) intp, sorted
    obs_weight: np.ndarray  # (O,) float32 beta
    B: sp.csr_matrix  # (E, n) float32
    BT: sp.csr_matrix  # (n, E) float32
    B2T: sp.csr_matrix  # (n, E) float32, squares of B's entries, transposed
    n_tv: int  # rows [0, n_tv) are TV, the rest correspondences
    base: np.ndarray  # (E,) float32 base row weights
    rho_start: np.ndarray | None  # (n, C) float32 starting reflectance; None: made on first use (rho0)
    texel_index: np.ndarray | None = None  # texture domain: flat texel of each unknown
    obs_matrix: sp.csr_matrix | None = None  # (O, n) float32 A, when observations mix unknowns
    # Texture domain: (P,) int32, the pixel's region of clipped pixels, minus that of its rim, or 0
    # (core.solve.highlights.clipped_regions); None if none clipped
    clipped_region: np.ndarray | None = None
    data_model: str | None = None  # texture domain: the data model it was built with

    @property
    def n_views(self) -> int:
        return len(self.pixel_offsets) - 1

    @property
    def pixel_view(self) -> np.ndarray:
        """(P,) intp: the view of each pixel (made on each use)."""
        return np.repeat(np.arange(self.n_views), np.diff(self.pixel_offsets))

    @property
    def obs_view(self) -> np.ndarray:
        """(O,) intp: the view of each observation (made on each use; only the Gauss-Newton step needs it)."""
        return self.pixel_view[self.obs_pixel]

    def __post_init__(self):
        self._matrices = None
        self._pair = None
        self._nu_t = None
        self._row_weights = {}  # (lam, mu, dtype): row_scale, shared by the channels
        self._kept = {}  # kept(): what a solver makes of the observations alone, shared by the solves that follow
        self._lock = threading.Lock()  # the channels' threads ask for what is made on first use at once

    @property
    def rho0(self) -> np.ndarray:
        """(n, C) float32 starting reflectance: ``rho_start``, or the weighted mean of each unknown's observations
        (made on first use: the albedo stage starts elsewhere and never asks)."""
        with self._lock:
            if self.rho_start is None:
                w = self.obs_weight.astype(np.float64)
                wsum = self.scatter(w)
                means = [
                    self.scatter(w * self.from_pixels(self.values[:, c]).astype(np.float64)) / wsum
                    for c in range(self.values.shape[1])
                ]
                self.rho_start = np.stack(means, axis=1).astype(np.float32)
        return self.rho_start

    @property
    def diagonal_data(self) -> bool:
        """True when each observation sees one unknown (``obs_unknown``): the data term is diagonal in rho."""
        return self.obs_unknown is not None

    def gather(self, rho: np.ndarray) -> np.ndarray:
        """Reflectance at each observation, ``A @ rho``."""
        return np.take(rho, self.obs_unknown, axis=0) if self.diagonal_data else self.obs_matrix @ rho

    def from_pixels(self, x: np.ndarray) -> np.ndarray:
        """Per-pixel values ``(P, ...)`` at each observation (``np.take``: several times faster than ``x[idx]``)."""
        return np.take(x, self.obs_pixel, axis=0)

    def scatter(self, x: np.ndarray, squared: bool = False) -> np.ndarray:
        """``A^T x``, or with ``squared`` the same with A's entries squared: observations summed onto unknowns.

        float32 in, float32 out (outside the GIL); other dtypes are summed in float64.
        """
        if self.diagonal_data:
            if x.dtype == np.float32:
                return scatter_add(self.obs_unknown, x, np.zeros(self.n_unknowns, np.float32))
            return np.bincount(self.obs_unknown, weights=x, minlength=self.n_unknowns)
        _, AT, A2T = self.observation_matrices()
        return (A2T if squared else AT) @ x

    def pixel_sum(self, x: np.ndarray) -> np.ndarray:
        """Observations summed onto their pixels, ``(P,)``; float32 as :meth:`scatter`, others in float64."""
        if x.dtype == np.float32:
            return scatter_add(self.obs_pixel, x, np.zeros(self.nu.shape[0], np.float32))
        return np.bincount(self.obs_pixel, weights=x, minlength=self.nu.shape[0])

    def kept(self, key, make):
        """``make()``, made on first use for ``key`` and then shared, read-only, by every solve on these
        observations (the channels' threads, the restarts of the search over tilts, copies by :meth:`with_base`)."""
        with self._lock:
            if key in self._kept:
                return self._kept[key]
        value = make()  # outside the lock: other channels make their own at the same time
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
        with self._lock:
            return self._kept.setdefault(key, value)

    def nu_by_coefficient(self) -> np.ndarray:
        """``nu.T`` with contiguous rows, ``(K, P)`` (kept): the sigma-step's normal matrices weight it faster."""
        with self._lock:
            if self._nu_t is None:
                self._nu_t = np.ascontiguousarray(self.nu.T)
        return self._nu_t

    def pair_normal(self):
        """:class:`core.solve.spmv.PairNormal` of B (kept), or None when B's rows are not all pairs."""
        with self._lock:
            if self._pair is None:
                self._pair = PairNormal.of(self.B, self.BT) or False
        return self._pair or None

    def observation_matrices(self):
        """``A``, ``A^T`` and ``(A^2)^T`` as CSR matrices (A built from ``obs_unknown`` when it is a selection)."""
        if self._matrices is None:
            A = self.obs_matrix
            if A is None:
                o = self.obs_unknown.size
                A = sp.csr_matrix(
                    (np.ones(o, np.float32), self.obs_unknown, np.arange(o + 1)), shape=(o, self.n_unknowns)
                )
            self._matrices = (A, A.T.tocsr(), A.multiply(A).T.tocsr())
        return self._matrices

    def row_scale(self, lam: float, mu: float) -> np.ndarray:
        s = self.base.copy()
        s[: self.n_tv] *= lam
        s[self.n_tv :] *= mu
        return s

    def with_base(self, base: np.ndarray) -> Discretization:
        """A shallow copy with other row weights ``base``: it shares the observations and the kept matrices, and
        makes its own :meth:`row_weights`."""
        out = copy.copy(self)
        out.base = base
        out._row_weights = {}
        return out

    def row_weights(self, lam: float, mu: float, dtype) -> np.ndarray:
        """:meth:`row_scale` in ``dtype``, made once and shared, read-only, by the channels' threads."""
        key = (float(lam), float(mu), np.dtype(dtype).str)
        with self._lock:
            if key not in self._row_weights:
                s = self.row_scale(lam, mu).astype(dtype)
                s.flags.writeable = False
                self._row_weights[key] = s
            return self._row_weights[key]


def _masked_pixels(problem: Problem):
    offsets = np.zeros(problem.n_views + 1, dtype=np.intp)
    values, nus = [], []
    for i in range(problem.n_views):
        mask = problem.masks[i]
        values.append(masked(problem.images[i], mask))
        nus.append(sh_basis(masked(problem.normals[i], mask)) if problem.transfer is None else problem.transfer[i])
        offsets[i + 1] = offsets[i] + int(mask.sum())
    # The pipeline's transfer is one array in blocks per view (row_blocks): no copy of it.
    return offsets, np.concatenate(values).astype(np.float32), stacked_rows(nus)


def _clipped_regions(problem: Problem):
    """(P,) int32 regions of clipped pixels over the masked pixels, or None (:func:`clipped_regions`)."""
    return None if problem.clipped is None else clipped_regions(problem.clipped, problem.masks)


def _difference_rows(a, b, coef_b=None):
    """Rows ``x[a] - sum_k coef_b[:, k] x[b[:, k]]`` as (columns, values), each of shape (rows, k + 1)."""
    a = np.asarray(a, dtype=np.intp)
    b = np.asarray(b, dtype=np.intp).reshape(a.size, -1)
    if coef_b is None:
        coef_b = np.ones(b.shape, dtype=np.float32)
    cols = np.concatenate([a[:, None], b], axis=1)
    vals = np.concatenate([np.ones((a.size, 1), np.float32), -coef_b.astype(np.float32)], axis=1)
    return cols, vals


def _assemble(groups, n_unknowns):
    """B from groups of difference rows (in order), as CSR built directly, and its transposes."""
    widths = np.concatenate([np.full(c.shape[0], c.shape[1], np.int64) for c, _ in groups])
    indptr = np.concatenate([[0], np.cumsum(widths)])
    B = sp.csr_matrix(
        (np.concatenate([v.ravel() for _, v in groups]), np.concatenate([c.ravel() for c, _ in groups]), indptr),
        shape=(widths.size, n_unknowns),
        dtype=np.float32,
    )
    B.sum_duplicates()
    B.eliminate_zeros()
    return _with_transposes(B)


def _with_transposes(B):
    """``B``, ``B^T`` and ``(B^2)^T`` as CSR matrices."""
    BT = B.T.tocsr()
    # Same pattern as BT: share its index arrays.
    B2T = sp.csr_matrix((BT.data * BT.data, BT.indices, BT.indptr), shape=BT.shape, copy=False)
    return B, BT, B2T


def _grid_edges(keep: np.ndarray):
    """Horizontal and vertical neighbour pairs (flat indices) where both ends are kept."""
    h, w = keep.shape
    idx = np.arange(h * w).reshape(h, w)
    hx = keep[:, :-1] & keep[:, 1:]
    vy = keep[:-1, :] & keep[1:, :]
    a = np.concatenate([idx[:, :-1][hx], idx[:-1, :][vy]])
    b = np.concatenate([idx[:, 1:][hx], idx[1:, :][vy]])
    horizontal = np.concatenate([np.ones(int(hx.sum()), bool), np.zeros(int(vy.sum()), bool)])
    return a, b, horizontal


def image_domain(problem: Problem, normalise_correspondences: bool = True) -> Discretization:
    """The paper's parameterisation: one unknown per masked pixel of each view.

    Correspondence rows link pixel ``(view_a, pixel_a)`` with the bilinear
    interpolation of view ``view_b`` at ``xy_b`` over its masked pixels; a pair
    whose 4 corners are not all masked straddles a silhouette and is dropped.
    With ``normalise_correspondences``, each pair's weight is divided by the
    mean number of pairs at its two ends, so that every pixel's consistency
    weight sums to about 1 whatever the number of views that see it.
    """
    offsets, values, nu = _masked_pixels(problem)
    n = int(offsets[-1])
    # Map (view, flat pixel) -> unknown.
    lut = []
    for i in range(problem.n_views):
        m = problem.masks[i].ravel()
        t = np.full(m.size, -1, dtype=np.intp)
        t[m] = np.arange(offsets[i], offsets[i + 1])
        lut.append(t)
    row_groups = []
    n_tv = 0
    for i in range(problem.n_views):
        a, b, _ = _grid_edges(problem.masks[i])
        row_groups.append(_difference_rows(lut[i][a], lut[i][b]))
        n_tv += a.size
    base = [np.ones(n_tv, dtype=np.float32)]
    corr = problem.correspondences
    if corr is not None and len(corr):
        rows, w = _correspondence_rows(problem, lut, n, normalise_correspondences)
        row_groups.append(rows)
        base.append(w)
    B, BT, B2T = _assemble(row_groups, n)
    obs = np.arange(n, dtype=np.intp)
    return Discretization(
        domain="image",
        n_unknowns=n,
        pixel_offsets=offsets,
        values=values,
        nu=nu,
        obs_unknown=obs,
        obs_pixel=obs,
        obs_weight=np.ones(n, dtype=np.float32),
        B=B,
        BT=BT,
        B2T=B2T,
        n_tv=n_tv,
        base=np.concatenate(base),
        rho_start=values.copy(),
    )


def _correspondence_rows(problem: Problem, lut: list, n: int, normalise: bool):
    """The image domain's correspondence rows (see :func:`_difference_rows`) and their float32 base weights.

    ``lut[i]`` maps view i's flat pixels to unknowns (-1 off the mask).
    """
    corr = problem.correspondences
    ua = np.empty(len(corr), dtype=np.intp)
    ub = np.empty((len(corr), 4), dtype=np.intp)
    wb = np.empty((len(corr), 4), dtype=np.float32)
    keep = np.zeros(len(corr), dtype=bool)
    for j in np.unique(corr.view_b):
        sel = np.flatnonzero(corr.view_b == j)
        flat, wts = masked_corners(corr.xy_b[sel, 0], corr.xy_b[sel, 1], problem.masks[j])
        full = (flat >= 0).all(axis=1) & problem.masks[j].ravel()[flat].all(axis=1)
        ub[sel] = lut[j][flat]
        wb[sel] = wts
        keep[sel] = full
    for i in np.unique(corr.view_a):
        sel = corr.view_a == i
        ua[sel] = lut[i][corr.pixel_a[sel]]
    keep &= (ua >= 0) & (corr.view_a != corr.view_b) & (corr.weight > 0)
    ua, ub, wb = ua[keep], ub[keep], wb[keep]
    w = corr.weight[keep].astype(np.float64)
    if normalise and ua.size:
        main_b = ub[np.arange(ub.shape[0]), np.argmax(wb, axis=1)]
        count = np.bincount(np.concatenate([ua, main_b]), minlength=n)
        w = w * 2.0 / (count[ua] + count[main_b])
    return _difference_rows(ua, ub, wb), w.astype(np.float32)


def texture_domain(
    problem: Problem, max_edge_ratio: float = 4.0, data_model: str = "splat", threads: int | None = None
) -> Discretization:
    """Reflectance on the texels of the mesh's UV map.

    Each masked pixel sees the 4 texels around its UV with bilinear weights:
    as one observation of their interpolation (``data_model="interpolate"``),
    as 4 splatted observations (``"splat"``), or as one observation of the
    texel of largest weight (``"nearest"``); see the module docstring.
    Pixel weights are the ``view_weight``, normalised so that an unknown
    carries a total data weight of 1 on average, as a pixel does in the image
    domain, so that lambda means the same in both domains. TV edges are
    weighted by the surface length of the texel side they cross (relative to
    the median), and edges longer than ``max_edge_ratio`` times the median are
    dropped: such texels touch in UV but not on the surface. ``threads`` (None: every core) build the views'
    observations and the TV rows side by side.
    """
    if problem.texture is None or problem.uv is None:
        raise ValueError("texture domain: the problem needs uv and a texture layout")
    if data_model not in ("interpolate", "splat", "nearest", "merged"):
        raise ValueError(
            f"texture domain: data_model must be 'interpolate', 'splat', 'nearest' or 'merged', got {data_model!r}"
        )
    size = problem.texture.size
    offsets, values, nu = _masked_pixels(problem)
    region = _clipped_regions(problem)
    tex_obs, pix_obs, w_obs = _splats(problem, offsets, nearest=data_model == "nearest", threads=threads)
    if data_model == "merged":
        offsets, values, nu, tex_obs, pix_obs, w_obs, region = _merged_per_view(
            offsets, values, nu, tex_obs, pix_obs, w_obs, size, region
        )
    seen_count = np.bincount(tex_obs, weights=w_obs, minlength=size * size)
    texels = np.flatnonzero(seen_count > 0)
    lut = np.full(size * size, -1, dtype=np.intp)
    lut[texels] = np.arange(texels.size)
    n = texels.size
    w_obs *= n / w_obs.sum()
    rows = start(_texel_rows, problem.texture, texels, lut, max_edge_ratio, threads=threads)
    obs_unknown = lut[tex_obs]  # the observations are in pixel order already (_splats, _merged_per_view)
    B, BT, B2T, base = rows.result()
    obs_matrix = None
    if data_model == "interpolate":
        obs_matrix, pix_obs, w_obs = _interpolation_rows(obs_unknown, pix_obs, w_obs, n)
        obs_unknown = None
    w_obs = w_obs.astype(np.float32)
    d = Discretization(
        domain="texture",
        n_unknowns=n,
        pixel_offsets=offsets,
        values=values,
        nu=nu,
        obs_unknown=obs_unknown,
        obs_pixel=pix_obs,
        obs_weight=w_obs,
        B=B,
        BT=BT,
        B2T=B2T,
        n_tv=B.shape[0],
        base=base,
        rho_start=None,
        texel_index=texels,
        obs_matrix=obs_matrix,
        clipped_region=region,
        data_model=data_model,
    )
    return d


def _splats(problem: Problem, offsets: np.ndarray, nearest: bool = False, threads: int | None = None):
    """Every (pixel, texel) pair with a bilinear weight > 0: flat texel, pixel, and weight times view_weight,
    in pixel order (the order the discretisation keeps).

    With ``nearest``, only the pixel's texel of largest bilinear weight, carrying the pixel's whole weight.
    The views on up to ``threads`` threads.
    """
    inside = problem.texture.inside

    def view(i):
        mask = problem.masks[i]
        if nearest:  # one column: the texel of largest weight, with the pixel's whole weight
            flat, wts = (a[:, None] for a in nearest_texel(masked(problem.uv[i], mask), inside))
        else:
            flat, wts = bilinear_texels(masked(problem.uv[i], mask), inside)
        if problem.view_weight is not None:
            wts = wts * problem.view_weight[i][mask][:, None]
        pix = np.repeat(np.arange(offsets[i], offsets[i + 1]), flat.shape[1])
        keep = wts.ravel() > 0
        return flat.ravel()[keep], pix[keep], wts.ravel()[keep]

    tex_obs, pix_obs, w_obs = zip(*thread_map(view, range(problem.n_views), threads))
    tex_obs = np.concatenate(tex_obs)
    if tex_obs.size == 0:
        raise ValueError("texture domain: no pixel lands inside the UV islands")
    return tex_obs, np.concatenate(pix_obs), np.concatenate(w_obs).astype(np.float64)


def _merged_per_view(offsets, values, nu, tex_obs, pix_obs, w_obs, size, region=None):
    """The splats of each view summed per texel into one virtual pixel: its weighted mean value and transfer.

    ``pix_obs`` runs view by view (as :func:`_splats` makes it); ``size`` is the texture's. Returns the
    virtual pixels' offsets per view, values and transfer, one observation of each (texel, pixel and summed
    weight), and their clipped regions if ``region`` (per pixel) is given: a virtual pixel with a clipped pixel
    in it is in that pixel's region (the highest-numbered, if several); rims are not carried.
    """
    new_offsets = np.zeros_like(offsets)
    vals, nus, texs, ws, regions = [], [], [], [], []
    bounds = np.searchsorted(pix_obs, offsets)
    group_of = np.zeros(size * size, np.intp)
    for v in range(len(offsets) - 1):
        lo, hi, a, b = bounds[v], bounds[v + 1], offsets[v], offsets[v + 1]
        present = np.zeros(size * size, bool)
        present[tex_obs[lo:hi]] = True
        texels = np.flatnonzero(present)
        group_of[texels] = np.arange(texels.size)
        group = group_of[tex_obs[lo:hi]]
        wsum = np.bincount(group, weights=w_obs[lo:hi], minlength=texels.size)
        # Rows of weights over the view's pixels: one sparse product sums their values and transfer.
        weights = (w_obs[lo:hi] / wsum[group]).astype(np.float32)
        merge = sp.csr_matrix((weights, (group, pix_obs[lo:hi] - a)), shape=(texels.size, b - a))
        vals.append(merge @ values[a:b])
        nus.append(merge @ nu[a:b])
        if region is not None:
            r = np.zeros(texels.size, np.int32)
            np.maximum.at(r, group, region[pix_obs[lo:hi]])
            regions.append(r)
        texs.append(texels)
        ws.append(wsum)
        new_offsets[v + 1] = new_offsets[v] + texels.size
    n = int(new_offsets[-1])
    return (
        new_offsets,
        np.concatenate(vals),
        np.concatenate(nus),
        np.concatenate(texs),
        np.arange(n),
        np.concatenate(ws),
        np.concatenate(regions) if region is not None else None,
    )


def _pair_rows(a: np.ndarray, b: np.ndarray, n_unknowns: int):
    """B with the rows ``x[a] - x[b]``, and its transposes, as :func:`_assemble` builds them from
    :func:`_difference_rows`, made directly: each row's two columns in order, so scipy has nothing to sort."""
    if np.any(a == b):  # such a row sums to nothing: the general path drops it
        return _assemble([_difference_rows(a, b)], n_unknowns)
    idx = np.int32 if max(2 * a.size, n_unknowns) < 2**31 else np.int64
    first = a < b
    cols = np.empty((a.size, 2), idx)
    cols[:, 0] = np.where(first, a, b)
    cols[:, 1] = np.where(first, b, a)
    vals = np.empty((a.size, 2), np.float32)
    vals[:, 0] = np.where(first, 1.0, -1.0)
    vals[:, 1] = -vals[:, 0]
    B = sp.csr_matrix(
        (vals.ravel(), cols.ravel(), np.arange(0, 2 * a.size + 1, 2, dtype=idx)), shape=(a.size, n_unknowns)
    )
    B.has_canonical_format = True  # sorted, no duplicates: sum_duplicates would do nothing
    return _with_transposes(B)


def _texel_rows(layout, texels: np.ndarray, lut: np.ndarray, max_edge_ratio: float):
    """The texture domain's TV rows: B, its transposes and the base weights.

    Edges join seen texels that are grid neighbours, weighted by the
    perpendicular texel side on the surface, or that face each other across a
    seam, with weight 1.
    """
    size = layout.size
    seen = np.zeros(size * size, dtype=bool)
    seen[texels] = True
    seen = seen.reshape(size, size)
    a, b, horizontal = _grid_edges(seen)
    length, perp = _edge_lengths(layout.texel_pos, a, horizontal)
    perp = np.where(np.isfinite(perp), perp, length)
    med = float(np.median(length)) if length.size else 1.0
    good = length <= max_edge_ratio * med
    a, b, perp = a[good], b[good], perp[good]
    seam = layout.seam_pairs
    seam = seam[(lut[seam[:, 0]] >= 0) & (lut[seam[:, 1]] >= 0) & (seam[:, 0] != seam[:, 1])]
    ea = np.concatenate([a, seam[:, 0]])
    eb = np.concatenate([b, seam[:, 1]])
    base = np.concatenate([perp / med, np.ones(seam.shape[0])]).astype(np.float32)
    return (*_pair_rows(lut[ea], lut[eb], texels.size), base)


def _interpolation_rows(obs_unknown, pix_obs, w_obs, n: int):
    """The splats, sorted by pixel, merged into one observation per pixel: ``(A, pixels, weights)``.

    A pixel's weight is the sum of its splats'; its row of A holds their
    weights normalised to sum 1.
    """
    pixels, start = np.unique(pix_obs, return_index=True)
    w_pix = np.add.reduceat(w_obs, start)
    rows = np.repeat(np.arange(pixels.size), np.diff(np.append(start, pix_obs.size)))
    obs_matrix = sp.csr_matrix(((w_obs / w_pix[rows]).astype(np.float32), (rows, obs_unknown)), shape=(pixels.size, n))
    return obs_matrix, pixels, w_pix


def _edge_lengths(pos: np.ndarray, a: np.ndarray, horizontal: np.ndarray):
    """Per grid edge from texel ``a`` (flat; to its right neighbour where ``horizontal``, else to the one
    below, as :func:`_grid_edges` gives them): its length on the surface, and the surface length of the side
    of texel ``a`` that it crosses (NaN where unknown).

    That side's length is the mean distance to the texel's two neighbours across the edge (one at the
    texture's border, or where a neighbour has no position): along the rows for a horizontal edge, along the
    columns for a vertical one. ``pos`` is the ``(N, N, 3)`` texel positions (NaN outside the islands); the
    distances between neighbours are taken on the whole grid at once, in float64.
    """
    n = pos.shape[0]
    right = np.zeros((n, n - 1))
    below = np.zeros((n - 1, n))
    p = np.empty((n, n))
    for k in range(3):
        np.copyto(p, pos[..., k])
        d = p[:, 1:] - p[:, :-1]
        d *= d
        right += d
        d = p[1:] - p[:-1]
        d *= d
        below += d
    del p, d
    right, below = np.sqrt(right, out=right).ravel(), np.sqrt(below, out=below).ravel()
    length, across = np.empty(a.size), np.empty(a.size)
    h, v = horizontal, ~horizontal
    r, c = np.divmod(a[h], n)
    length[h] = right[r * (n - 1) + c]
    across[h] = _mean_of_known(_at(below, (r - 1) * n + c, r > 0), _at(below, r * n + c, r < n - 1))
    r, c = np.divmod(a[v], n)
    length[v] = below[r * n + c]
    across[v] = _mean_of_known(_at(right, r * (n - 1) + c - 1, c > 0), _at(right, r * (n - 1) + c, c < n - 1))
    return length, across


def _at(values, index, valid):
    """``values[index]`` where ``valid``, NaN elsewhere."""
    return np.where(valid, np.take(values, np.where(valid, index, 0)), np.nan)


def _mean_of_known(x, y):
    """The mean of the finite ones of x and y, elementwise; NaN where neither is."""
    kx, ky = np.isfinite(x), np.isfinite(y)
    with np.errstate(invalid="ignore"):
        return (np.where(kx, x, 0.0) + np.where(ky, y, 0.0)) / (kx.astype(np.float64) + ky)
