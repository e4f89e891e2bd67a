"""The lighting models of the sigma-step, and fitting and comparing lightings.

The shading of pixel p of view v is ``sigma_v . nu_p`` (:func:`shading`), ``nu_p`` the 9 SH of its normal (or
its transfer with occlusion and a sun, :mod:`core.geometry.transfer`). The paper gives every view 9 free SH
coefficients per channel. Under one fixed light (the common capture) that is 9 m numbers where the scene has 9,
and the spare freedom lets each view's lighting absorb part of the albedo: alternating from rho = I does not
resolve the albedo-lighting ambiguity. So the sigma-step (:meth:`core.solve.solver.Channel.sigma_step`) has
three models, chosen by ``SolverParams.lighting``:

* ``"per_view"``: the paper's, 9 free coefficients per view (:func:`per_view_lighting_step`);
* ``"shared"``: the lighting of view v is ``g_v sigma``, one world lighting ``sigma`` per channel times a gain
  ``g_v`` per view and channel (exposure and white balance, 3 numbers per photo). :func:`shared_lighting_step`
  alternates exact minimisations of the quadratic majorant in sigma and in the gains, so the MM keeps its
  descent;
* ``"coupled"``: free per view, held to such a shared lighting by a quadratic prior that is part of the energy
  (:class:`Coupling`); between the two. :func:`choose_lighting` picks it, or ``per_view`` when the light moves.

:func:`fit_lighting` fits the lighting to a known albedo (the true-lighting ceiling of the benchmarks),
:func:`division_start` the albedo to a known lighting, and :func:`shading_error` compares two lightings by the
shading they give over the observations. :func:`weighted_gram` and :func:`view_normal_equations` make the
least-squares sums of those fits, view by view.
"""

from __future__ import annotations

import numpy as np

from .lambda_choice import VARYING_THRESHOLD
from .problem import SUN_COLUMNS

__all__ = [
    "choose_lighting",
    "Coupling",
    "dark_floor_bounds",
    "division_start",
    "fit_lighting",
    "floored_where_dark",
    "per_view_lighting_step",
    "prior_metric",
    "raised",
    "shading",
    "shading_error",
    "shading_floor",
    "shared_lighting_step",
    "split_gains",
    "view_normal_equations",
    "weighted_gram",
]


def shading(d, sigma: np.ndarray, dtype=np.float32) -> np.ndarray:
    """``sigma_v . nu_p`` for every pixel p of every view v of the discretisation d; sigma is (m, 9)."""
    out = np.empty(d.nu.shape[0], dtype=dtype)
    for v in range(d.n_views):
        a, b = d.pixel_offsets[v], d.pixel_offsets[v + 1]
        out[a:b] = np.dot(d.nu[a:b], sigma[v].astype(dtype))  # np.dot releases the GIL, @ does not
    return out


def weighted_gram(nu: np.ndarray, w: np.ndarray, nu_t: np.ndarray | None = None) -> np.ndarray:
    """``sum_p w_p nu_p nu_p^T``: the ``(K, K)`` normal matrix of a lighting fit over rows ``nu`` with weights ``w``.

    One matrix product in nu's precision (BLAS), which reads nu once: the sigma-step makes one per view and
    channel every iteration. ``np.dot``, not ``@``: NumPy's matmul holds the GIL, and the channels' threads
    then wait on each other (docs/measurements.md). ``nu_t``, if given, is ``nu.T`` with contiguous rows (the
    same values): weighting it row by row is faster than weighting nu's columns.
    """
    w = w.astype(nu.dtype, copy=False)
    left = (nu * w[:, None]).T if nu_t is None else nu_t * w
    return np.dot(left, nu)


def view_normal_equations(nu, offsets, g, h=None, dtype=np.float64, nu_t=None):
    """Per view v (rows ``offsets[v]:offsets[v + 1]``): ``sum_p g_p nu_p nu_p^T`` and ``sum_p h_p nu_p``.

    Computed in ``dtype`` (float32: the sigma-step's BLAS products); returned as float64 arrays ``(m, K, K)``
    and ``(m, K)``, the former unset when ``g`` is None and the latter when ``h`` is. ``nu_t``: as
    :func:`weighted_gram`, used when it is of ``dtype``.
    """
    m, k = len(offsets) - 1, nu.shape[1]
    Ms, bs = np.empty((m, k, k)), np.empty((m, k))
    if nu_t is not None and nu_t.dtype != dtype:
        nu_t = None
    for v in range(m):
        lo, hi = offsets[v], offsets[v + 1]
        rows = nu[lo:hi].astype(dtype, copy=False)
        if g is not None:
            Ms[v] = weighted_gram(rows, g[lo:hi], None if nu_t is None else nu_t[:, lo:hi])
        if h is not None:
            bs[v] = np.dot(h[lo:hi].astype(dtype, copy=False), rows)  # np.dot releases the GIL, @ does not
    return Ms, bs


def _free(k):
    """Coefficients of sigma free in the sigma-step; the constant term (index 3) is pinned to fix the scale."""
    return np.delete(np.arange(k), 3)


def choose_lighting(variation: float | None) -> str:
    """The lighting model for a measured :func:`core.solve.lambda_choice.lighting_variation`.

    One light for all photos (or too little overlap to tell): per-view
    lightings held to a shared one (``"coupled"``); a light that moves
    between the photos: free per view (``"per_view"``).
    """
    return "per_view" if variation is not None and variation > VARYING_THRESHOLD else "coupled"


def split_gains(sigma_views: np.ndarray):
    """Write per-view lightings ``(m, 9)`` as ``g_v sigma`` with ``g_0 = 1``: returns ``(sigma, g)``.

    Exact when the views' lightings are proportional; otherwise the gains are
    the least-squares ratios to view 0's lighting.
    """
    sigma = np.array(sigma_views[0], dtype=np.float64)
    nn = float(sigma @ sigma)
    g = sigma_views @ sigma / nn if nn > 0 else np.ones(len(sigma_views))
    g[0] = 1.0
    return sigma, g


def per_view_lighting_step(Ms: np.ndarray, bs: np.ndarray, sigma_views: np.ndarray) -> np.ndarray:
    """Each view's lighting minimising ``s^T M_v s - 2 b_v^T s``, view 0's constant term held (it pins the scale)."""
    sigma = np.array(sigma_views, dtype=np.float64)
    free = _free(sigma.shape[1])
    for v, (M, b) in enumerate(zip(Ms, bs)):
        if v == 0:
            rhs = b[free] - M[free, 3] * sigma[0, 3]
            sigma[0, free] = np.linalg.lstsq(M[np.ix_(free, free)], rhs, rcond=1e-10)[0]
        else:
            sigma[v] = np.linalg.lstsq(M, b, rcond=1e-10)[0]
    return sigma


def shared_lighting_step(
    Ms: np.ndarray, bs: np.ndarray, sigma_views: np.ndarray, rounds: int = 4, pin_constant: bool = True
) -> np.ndarray:
    """The sigma-step of one channel for a lighting shared by the views, up to a gain per view.

    Minimises ``sum_v (g_v^2 s^T M_v s - 2 g_v s^T b_v)`` over the world
    lighting s (its constant term kept, which pins the scale) and the gains
    g_v (``g_0 = 1``), alternating exact minimisations, each of which can
    only lower it.

    Parameters
    ----------
    Ms, bs : (m, 9, 9), (m, 9) arrays
        Each view's normal equations at the current majorant
        (:meth:`core.solve.solver.Channel.normal_equations`).
    sigma_views : (m, 9) array
        The current lighting of each view, ``g_v s``.
    rounds : int
        Alternations.
    pin_constant : bool
        Keep the constant term of s. The MM needs it (with ``g_0 = 1``) to fix
        the scales that the albedo, the gains and s trade between them; a fit
        to a known albedo does not (``g_0 = 1`` is the only gauge there).

    Returns
    -------
    (m, 9) array
        The new ``g_v s``.
    """
    s, g = split_gains(np.asarray(sigma_views, dtype=np.float64))
    free = _free(s.size)
    for _ in range(rounds):
        A = np.einsum("v,vij->ij", g * g, Ms)
        r = np.einsum("v,vi->i", g, bs)
        if pin_constant:
            rhs = r[free] - A[free, 3] * s[3]
            s[free] = np.linalg.lstsq(A[np.ix_(free, free)], rhs, rcond=1e-10)[0]
        else:
            s = np.linalg.lstsq(A, r, rcond=1e-10)[0]
        q = np.einsum("i,vij,j->v", s, Ms, s)
        p = bs @ s
        ok = q > 1e-30
        g_new = np.where(ok, p / np.where(ok, q, 1.0), g)
        g_new[0] = 1.0
        g = g_new
    return g[:, None] * s[None, :]


#: The coupled prior's floor, relative to the mean eigenvalue of each view's metric (:func:`prior_metric`).
PRIOR_FLOOR = 1e-3


def prior_metric(G: np.ndarray, floor: float = PRIOR_FLOOR) -> np.ndarray:
    """Each view's metric ``G_v`` plus ``floor`` times its mean eigenvalue on the diagonal.

    A view that sees few normals (the flat faces of a building) leaves some of its lighting's coefficients
    undetermined by its pixels; measured by ``G_v`` alone the prior leaves them free too, and they drift
    far from any light, into the world lighting and, through the occlusion, into the albedo. The floor holds
    them to the world lighting.
    """
    k = G.shape[-1]
    return G + (floor * np.trace(G, axis1=-2, axis2=-1) / k)[:, None, None] * np.eye(k)


class Coupling:
    """A prior that holds per-view lightings near one shared lighting: ``lighting="coupled"``.

    The energy gains ``kappa / 2 * sum_v (sigma_v - g_v s)^T G_v (sigma_v - g_v s)``,
    where ``s`` is a world lighting and ``g_v`` a gain per view (``g_0 = 1``),
    both free, and ``G_v = Ibar^2 sum_p beta_p nu_p nu_p^T`` over the view's pixels
    (``Ibar`` the mean observed value): the squared difference of the two
    shadings over the view, in the units of the data, with a floor
    (:func:`prior_metric`) for what the view does not see. ``kappa = 0`` is the
    paper's free lighting per view, ``kappa -> inf`` the shared one.

    With a sun term (a transfer of :data:`core.solve.problem.SUN_COLUMNS`), the
    sun is not free per view: its coefficient is ``g_v t``, one strength t per
    channel times each view's gain, kept >= 0. Free per view, it trades with
    the albedo (docs/measurements.md).
    """

    def __init__(self, d, c, kappa, sigma0):
        self.kappa = float(kappa)
        self.G = d.kept(("coupling metric", c), lambda: self._metric(d, c))
        self.world = self._fit_world(np.asarray(sigma0, np.float64), *split_gains(np.asarray(sigma0, np.float64)))

    @staticmethod
    def _metric(d, c):
        """``G_v`` of every view, ``(m, K, K)``: of the observations alone, so made once per channel."""
        w = d.obs_weight.astype(np.float64)
        values = d.from_pixels(d.values[:, c]).astype(np.float64)
        ibar2 = (np.sum(w * values) / max(np.sum(w), 1e-30)) ** 2
        beta = np.bincount(d.obs_pixel, weights=w, minlength=d.nu.shape[0])
        return prior_metric(ibar2 * view_normal_equations(d.nu, d.pixel_offsets, beta)[0])

    def _fit_world(self, sigma, s, g, rounds=3):
        G = self.G
        for _ in range(rounds):
            s = np.linalg.lstsq(np.einsum("v,vij->ij", g * g, G), np.einsum("v,vij,vj->i", g, G, sigma), rcond=1e-10)[0]
            q = np.einsum("i,vij,j->v", s, G, s)
            p = np.einsum("i,vij,vj->v", s, G, sigma)
            ok = q > 1e-30
            g = np.where(ok, p / np.where(ok, q, 1.0), g)
            g[0] = 1.0
        return s, g

    def penalty(self, sigma, world=None):
        s, g = self.world if world is None else world
        diff = sigma - g[:, None] * s[None, :]
        return 0.5 * self.kappa * float(np.einsum("vi,vij,vj->", diff, self.G, diff))

    def step(self, Ms, bs, sigma_views, rounds=2):
        """The sigma-step: per-view lightings and the world lighting, alternately minimised exactly."""
        sigma = np.array(sigma_views, dtype=np.float64)
        s, g = self.world
        kG = self.kappa * self.G
        sun = sigma.shape[1] == SUN_COLUMNS
        free = _free(sigma.shape[1] - sun)
        for _ in range(rounds):
            # Each view's quadratic in its lighting: data majorant plus the prior towards g_v s.
            As = Ms + kG
            rs = [bs[v] + kG[v] @ (g[v] * s) for v in range(len(sigma))]
            sigma = self._with_sun(As, rs, sigma, g, free) if sun else per_view_lighting_step(As, rs, sigma)
            s, g = self._fit_world(sigma, s, g)
        return sigma, (s, g)

    @staticmethod
    def _with_sun(As, rs, sigma, g, free):
        """Every view's SH and the one sun strength t (coefficient ``g_v t``), minimised jointly, t >= 0.

        Each view's SH is eliminated (``x_v = X0_v - X1_v g_v t``), which leaves a 1-D quadratic in t: its
        minimum, clamped at 0, is exact. SH and the sun overlap (the sun's smooth part is SH), so minimising
        them in turn crawls along that valley and can end on either side of it.
        """
        sigma = np.array(sigma)
        k = sigma.shape[1]
        r = np.array(rs, dtype=np.float64)
        r[0] -= As[0][:, 3] * sigma[0, 3]  # view 0's constant term is held: it pins the scale
        # View 0 without its constant term; the others' SH all at once (the prior makes their matrices definite).
        X0 = np.linalg.lstsq(As[0][np.ix_(free, free)], np.stack([r[0, free], As[0][free, -1]], 1), rcond=1e-10)[0]
        sh = np.arange(k - 1)
        A, R = As[1:, : k - 1, : k - 1], np.stack([r[1:, : k - 1], As[1:, : k - 1, -1]], axis=-1)
        try:
            X = np.linalg.solve(A, R)
        except np.linalg.LinAlgError:
            X = None
        if X is None or not np.all(np.isfinite(X)):
            X = np.stack([np.linalg.lstsq(a, b, rcond=1e-10)[0] for a, b in zip(A, R)])
        idx = [free] + [sh] * (len(sigma) - 1)
        sols = [X0, *X]
        num = den = 0.0
        for v, (i, Xv) in enumerate(zip(idx, sols)):
            q = As[v][-1, -1] - As[v][-1, i] @ Xv[:, 1]
            p = r[v, -1] - As[v][-1, i] @ Xv[:, 0]
            num += g[v] * p
            den += g[v] * g[v] * q
        t = max(num / den, 0.0) if den > 0 else sigma[0, -1] / g[0]
        for v, (i, Xv) in enumerate(zip(idx, sols)):
            sigma[v, i] = Xv[:, 0] - Xv[:, 1] * g[v] * t
            sigma[v, -1] = g[v] * t
        return sigma


def _ls_equations(d, rho, c):
    """Per view, the least-squares normal equations of the lighting for a known albedo (one channel)."""
    rho_o = d.gather(rho[:, c].astype(np.float32)).astype(np.float64)
    w = d.obs_weight.astype(np.float64)
    npix = d.nu.shape[0]
    g = np.bincount(d.obs_pixel, weights=w * rho_o * rho_o, minlength=npix)
    h = np.bincount(d.obs_pixel, weights=w * rho_o, minlength=npix) * d.values[:, c]
    return view_normal_equations(d.nu, d.pixel_offsets, g, h)


# Shading below this fraction of the median shading is raised to it when the lighting is fixed: where the
# lighting says "dark", dividing by it blows the albedo up.
SHADING_FLOOR = 0.2


def shading_floor(shade: np.ndarray, floor: float = SHADING_FLOOR) -> float:
    """The least shading :func:`floored` keeps: ``floor`` times the median of the positive values."""
    pos = shade[shade > 0]
    return floor * (float(np.median(pos)) if pos.size else 1.0)


def floored(shade: np.ndarray, floor: float = SHADING_FLOOR) -> np.ndarray:
    """The shading raised to at least ``floor`` times its median over the positive values."""
    return np.maximum(shade, shading_floor(shade, floor))


# Where the photo is dark too, the floor may fall to this fraction of the median (:func:`floored_where_dark`):
# a shadow the lighting draws and the photo shows is no mistake to guard against.
SHADOW_FLOOR = 0.1
# The brightest albedo a pixel may take under the lowered floor: this quantile of value / shading over the
# pixels shaded at least at the median, times SHADOW_MARGIN.
SHADOW_QUANTILE = 0.99
SHADOW_MARGIN = 1.2


def dark_floor_bounds(
    shade: np.ndarray,
    values: np.ndarray,
    floor: float = SHADING_FLOOR,
    least: float = SHADOW_FLOOR,
    quantile: float = SHADOW_QUANTILE,
    margin: float = SHADOW_MARGIN,
) -> tuple[float, float, float]:
    """``(low, high, brightest)`` for :func:`floored_where_dark`, from one channel's pixels.

    ``low`` and ``high`` are ``least`` and ``floor`` times the median shading; ``brightest`` is the brightest
    albedo of the well-lit pixels: ``quantile`` of value / shading where the shading is at least its median,
    times ``margin`` (0 if there is none).
    """
    median = shading_floor(shade, 1.0)
    lit = shade >= median
    ratio = np.maximum(values[lit], 0.0) / shade[lit]
    brightest = float(np.quantile(ratio, quantile)) * margin if ratio.size else 0.0
    return least * median, floor * median, brightest if brightest > 0 else 0.0


def raised(shade: np.ndarray, values: np.ndarray, bounds) -> np.ndarray:
    """The shading raised to each pixel's floor of :func:`floored_where_dark`.

    ``bounds`` is ``(low, high, brightest)`` as :func:`dark_floor_bounds` gives it; without a brightest albedo
    (a black photo) the floor is ``high`` everywhere.
    """
    low, high, brightest = bounds
    if not brightest > 0:
        return np.maximum(shade, high)
    return np.maximum(shade, np.clip(np.maximum(values, 0.0) / brightest, low, high))


def floored_where_dark(shade: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The shading raised as by :func:`floored`, but less where the photo is dark as well.

    The floor guards the division by the lighting against its dark mistakes: a pixel shaded far darker than its
    photo shows would take a blown-up albedo. A fixed floor also lifts the true shadows (a sun's, which the
    sun term draws) and darkens their albedo. Here each pixel's floor is the shading at which its own value
    gives the brightest albedo of the well-lit pixels, kept between :data:`SHADOW_FLOOR` and
    :data:`SHADING_FLOOR` times the median (:func:`dark_floor_bounds`): a dark mistake under a bright pixel is
    held as before, a shadow under a dark pixel keeps more of its shading.

    Parameters
    ----------
    shade, values : (P,) arrays
        The pixels' shading and their photo's value (one channel).
    """
    return raised(shade, values, dark_floor_bounds(shade, values))


def division_start(d, sigma: np.ndarray, channels=None, floor: float | None = None) -> np.ndarray:
    """Per unknown, the least-squares albedo of its observations under a fixed lighting: ``(n, C)``.

    ``rho_u = sum_o beta_o a_o I_o / sum_o beta_o a_o^2`` over the observations
    of unknown u, with the floored shading ``a`` (the minimiser of the data
    term alone when each observation sees one unknown); 0 where u has no weight.

    Parameters
    ----------
    d : Discretization
    sigma : (m, C, K) array
        The lighting of each of ``channels``.
    channels : sequence of int, optional
        Which of the photos' channels ``sigma`` lights; default all.
    floor : float, optional
        The least shading, absolute; default :func:`floored` (:data:`SHADING_FLOOR` of the median).
    """
    channels = range(d.values.shape[1]) if channels is None else channels
    out = np.empty((d.n_unknowns, len(channels)), np.float32)
    w = d.obs_weight.astype(np.float64)
    for k, c in enumerate(channels):
        shade = shading(d, sigma[:, k], np.float64)
        a = d.from_pixels(floored(shade) if floor is None else np.maximum(shade, floor))
        num = d.scatter(w * a * d.from_pixels(d.values[:, c]))
        den = d.scatter(w * a * a)
        out[:, k] = np.where(den > 0, num / np.maximum(den, 1e-30), 0.0)
    return out


def fit_lighting(d, rho: np.ndarray, lighting: str = "per_view", rounds: int = 50) -> np.ndarray:
    """The least-squares lighting of each view for a known albedo: ``(m, C, 9)``.

    Parameters
    ----------
    d : Discretization
    rho : (n, C) array
        The albedo at d's unknowns.
    lighting : {"per_view", "shared"}
        Free per view, or one lighting times a gain per view and channel.
    rounds : int
        Alternations of the shared fit.
    """
    C = rho.shape[1]
    out = np.empty((d.n_views, C, d.nu.shape[1]))
    for c in range(C):
        Ms, bs = _ls_equations(d, rho, c)
        per_view = np.stack([np.linalg.lstsq(M, b, rcond=1e-10)[0] for M, b in zip(Ms, bs)])
        if lighting == "shared":
            per_view = shared_lighting_step(Ms, bs, per_view, rounds=rounds, pin_constant=False)
        out[:, c] = per_view
    return out


def shading_error(d, sigma: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per channel, the relative RMS difference of two lightings' shading over the observations.

    The estimate is scaled by the one factor per channel that fits the
    reference best (the albedo's scale is free): ``|k s - s_ref| / |s_ref|``,
    weighted by the observations' weights.
    """
    C = sigma.shape[1]
    w = d.obs_weight.astype(np.float64)
    out = np.empty(C)
    for c in range(C):
        s = d.from_pixels(shading(d, sigma[:, c], np.float64))
        r = d.from_pixels(shading(d, reference[:, c], np.float64))
        k = np.sum(w * s * r) / max(np.sum(w * s * s), 1e-30)
        out[c] = np.sqrt(np.sum(w * (k * s - r) ** 2) / max(np.sum(w * r * r), 1e-30))
    return out
