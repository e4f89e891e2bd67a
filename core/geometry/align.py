"""Photos registered to the mesh: each camera's sub-pixel image shift, measured against the other photos.

Photogrammetry cameras are often about a pixel off the ones that took the photos. The bake then gives each pixel
the surface point next to the one it shows, which blurs the texture and misplaces the albedo's edges against the
shading. For each photo we measure the image shift ``t`` that best lines up its fine detail at ``x + t`` with the
other photos' texture seen through the bake at ``x``, and move the camera's principal point by ``t``: then the
camera projects the surface where the photo shows it.

The fine detail is the grey photo minus its Gaussian blur (masked to the mesh), so that the shading, which
differs between the photos when the light moves, drops out; a gain per photo absorbs exposure. The shift is
found by Gauss-Newton from zero, over a few rounds in which the others' texture is made again from their
shifted photos. A shift is applied only where every half of the photo agrees with it (:data:`MAX_SPREAD_PX`):
where the mesh is not the surface the photos show (a coarse proxy), the misregistration changes across the
photo, no one shift lines it up, and moving the camera would trade one misregistration for another. As a
camera's error is its own photo's and the mesh's shows in every photo, no camera is moved unless the halves
agree on most photos (:data:`MIN_AGREEING`). The others' texture must also explain some of the photo's detail
(:data:`MAX_MISFIT`), and the shift be at least a quarter pixel (:data:`MIN_SHIFT_PX`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage

from ..masks import masked
from ..parallel import thread_map
from ..progress import check_cancel
from .bilinear import clamped_corners, interpolate
from .texels import MATCHED_SIZE_MAX, pixel_matched_size, texel_index, texels_reached

__all__ = [
    "Alignment",
    "align_views",
    "photo_shifts",
    "shifted_camera",
    "BLUR_PX",
    "MAX_MISFIT",
    "MIN_AGREEING",
    "MAX_SPREAD_PX",
    "MIN_SHIFT_PX",
    "MAX_SHIFT_PX",
    "PIXELS_PER_TEXEL",
]

#: The Gaussian (in pixels) whose blur is taken off the photos: what is finer is the detail that is lined up.
BLUR_PX = 2.0
#: A shift is applied where each half of the photo (left, right, top, bottom) measures one within this many pixels.
MAX_SPREAD_PX = 0.35
#: No camera is moved unless the halves agree on at least this fraction of the photos measured. Measured: the
#: captures with cameras a pixel off 0.83-1.0, the scenes with a coarse proxy mesh 0.15 and 0.62 (and moving
#: the cameras of the second made its albedo worse).
MIN_AGREEING = 0.75
#: A shift is applied where the others' texture explains some of the photo's detail (leaves at most this fraction
#: unexplained): where the photos' detail is noise (few render samples on a flat albedo), it explains none of it,
#: and a shift found there lines up nothing.
MAX_MISFIT = 0.95
#: Shifts smaller than this (pixels) are left out: on photos whose cameras are right, the shifts measured reach
#: 0.2 px, and moving the cameras by them made the albedo worse.
MIN_SHIFT_PX = 0.25
#: Shifts larger than this (pixels) are not applied: the search from zero on detail of a few pixels does not
#: reach much further, and a larger shift found is a wrong match (measured: 2.05 px on a photo whose camera was
#: right, where the cameras a pixel off measured 0.3-1.5 px).
MAX_SHIFT_PX = 1.5
#: The others' texture is made at the largest size (at most :data:`core.geometry.texels.MATCHED_SIZE_MAX`) at which
#: the median photo has this many pixels per texel it reaches, whatever the texture asked for: finer, a texel holds
#: one pixel of one photo and the others' texture is their noise. On 8 captures with cameras 0.9 px off (photos of
#: 256 x 192 to 1024 x 768), the cameras were left 0.30 px off with 1.5 and 0.29 px with 2, and 0.47 px on the
#: 1024^2 texture of the default size (docs/measurements.md).
PIXELS_PER_TEXEL = 1.5
#: Most pixels of a photo its shift is measured on (every k-th pixel of the mesh beyond).
MAX_PIXELS = 30_000
# Pixels kept around the mesh's box when a photo is cropped: more than the blur and the largest shift reach.
_MARGIN = 12
#: Fewest pixels on the mesh (away from its outline) a photo needs for its shift to be measured.
MIN_PIXELS = 500


@dataclass
class Alignment:
    """What :func:`photo_shifts` measured, per photo.

    Attributes
    ----------
    measured : (m, 2) float64
        ``(dx, dy)`` in pixels: the photo shows at ``x + measured`` what the bake puts at ``x``; applied or not.
    misfit : (m,) float64
        The detail left unexplained after the shift, as a fraction of the detail (NaN: not measured).
    spread : (m,) float64
        How far (pixels) the shift measured on a half of the photo lies from the whole photo's, at most (inf:
        not measured).
    applied : (m,) bool
    mesh_fits : bool
        False when the halves of too many photos disagree (:data:`MIN_AGREEING`): the mesh is not the surface
        they show, and no camera is moved.
    texture_size : int
        The size of the others' texture the shifts were measured on (:data:`PIXELS_PER_TEXEL`).
    """

    measured: np.ndarray
    misfit: np.ndarray
    spread: np.ndarray
    applied: np.ndarray
    mesh_fits: bool = True
    texture_size: int = 0

    @property
    def shift(self) -> np.ndarray:
        """``(m, 2)``: the shift applied to each photo's camera, zero where not ``applied``."""
        return np.where(self.applied[:, None], self.measured, 0.0)


def shifted_camera(camera, shift, scale: float = 1.0):
    """``camera`` with its principal point moved by ``shift * scale`` pixels (``scale``: its pixels per the
    shift's, for a photo at another resolution)."""
    K = np.array(camera.K, np.float64)
    K[0, 2] += float(shift[0]) * scale
    K[1, 2] += float(shift[1]) * scale
    return replace(camera, K=K)


def _blur(img, mask, sigma):
    """Gaussian blur of ``img`` over ``mask`` only (normalised convolution)."""
    num = ndimage.gaussian_filter(np.where(mask, img, 0.0), sigma)
    den = ndimage.gaussian_filter(mask.astype(np.float64), sigma)
    return num / np.maximum(den, 1e-6)


class _View:
    """One photo's detail, its pixels' texels, and the pixels its shift is measured on."""

    def __init__(self, photo, mask, uv, weight, size):
        # Cropped to the mesh's box and a margin: a shift is the same in any crop, and the blurs cost less.
        box = np.s_[:, :]
        if mask.any():
            rs, cs = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
            box = np.s_[max(rs[0] - _MARGIN, 0) : rs[-1] + _MARGIN + 1, max(cs[0] - _MARGIN, 0) : cs[-1] + _MARGIN + 1]
        photo, mask, uv = photo[box], mask[box], uv[box]
        weight = None if weight is None else weight[box]
        self.grey = np.asarray(photo, np.float64).mean(axis=-1)
        # A pixel that is not a number (a researcher's array; the add-on refuses such photos) is off the mesh here.
        bad = ~np.isfinite(self.grey)
        if bad.any():
            mask = mask & ~bad
            self.grey[bad] = 0.0
        self.detail = self.grey - _blur(self.grey, ndimage.binary_erosion(mask), BLUR_PX)
        self.gy, self.gx = np.gradient(self.detail)
        self.mask_rows, self.mask_cols = np.nonzero(mask)
        t = texel_index(masked(uv, mask), size)
        ok = t >= 0
        self.mask_rows, self.mask_cols, t = self.mask_rows[ok], self.mask_cols[ok], t[ok]
        # Each texel the photo reaches once, and which of them each pixel is in.
        self.texels, self.texel_of_pixel = texels_reached(t)
        self.weight = np.ones(t.size) if weight is None else np.asarray(weight, np.float64)[mask][ok]
        self.weight_sum = np.bincount(self.texel_of_pixel, weights=self.weight, minlength=self.texels.size)
        # The others' texture is drawn on every pixel inside the outline, the shift measured on at most
        # MAX_PIXELS of them: it needs far fewer than a large photo has.
        self.inner = ndimage.binary_erosion(mask, iterations=3)
        self.inner_rows, self.inner_cols = np.nonzero(self.inner)
        self.inner_texels = texel_index(uv[self.inner], size)
        # Where each inner pixel's texel is among this photo's own (to take its own share out of the sums).
        pos = np.minimum(np.searchsorted(self.texels, self.inner_texels), max(self.texels.size - 1, 0))
        self.inner_own = np.flatnonzero(self.texels[pos] == self.inner_texels) if self.texels.size else pos[:0]
        self.inner_own_texel = pos[self.inner_own]
        step = max(-(-self.inner_rows.size // MAX_PIXELS), 1)
        self.rows, self.cols = self.inner_rows[::step], self.inner_cols[::step]

    def texel_sums(self, shift):
        """The weighted sum of the grey photo at ``x + shift`` per texel of :attr:`texels` (bilinear)."""
        vals = ndimage.map_coordinates(
            self.grey, [self.mask_rows + shift[1], self.mask_cols + shift[0]], order=1, mode="nearest"
        )
        return np.bincount(self.texel_of_pixel, weights=self.weight * vals, minlength=self.texels.size)


def _others(view, own_sums, total_s, total_w):
    """The other photos' mean at each inner pixel's texel (NaN where none of them reaches it)."""
    t = view.inner_texels
    s = np.where(t >= 0, total_s[np.maximum(t, 0)], 0.0)
    w = np.where(t >= 0, total_w[np.maximum(t, 0)], 0.0)
    s[view.inner_own] -= own_sums[view.inner_own_texel]
    w[view.inner_own] -= view.weight_sum[view.inner_own_texel]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(w > 1e-9, s / w, np.nan)


def _target_detail(view, others):
    """The others' texture seen through this view's bake, as detail, and where it is known."""
    img = np.zeros(view.inner.shape)
    valid = np.zeros(view.inner.shape, bool)
    good = np.isfinite(others)
    img[view.inner_rows[good], view.inner_cols[good]] = others[good]
    valid[view.inner_rows[good], view.inner_cols[good]] = True
    return img - _blur(img, valid, BLUR_PX), valid


def _dot(a, b) -> float:
    """``a . b`` of two vectors without BLAS, whose threads cost more than the product at this size."""
    return float(np.einsum("i,i->", a, b))


def _gauss_newton(view, target, rows, cols, start, iters=8):
    """The shift from ``start`` over the given pixels, and the detail left unexplained after it (a fraction)."""
    ref = target[rows, cols]
    ref2 = max(_dot(ref, ref), 1e-30)
    t = np.array(start, np.float64)
    h, w = view.detail.shape
    images = (view.detail.ravel(), view.gx.ravel(), view.gy.ravel())

    def corners():
        # Clamped like map_coordinates' "nearest"; the corners found once for the three images sampled there.
        return clamped_corners(np.clip(cols + t[0], 0, w - 1), np.clip(rows + t[1], 0, h - 1), w, h)

    def at(k):
        return interpolate(images[k], idx, wts)

    def residual():
        p = at(0)
        return p - (_dot(p, ref) / ref2) * ref, p

    for _ in range(iters):
        idx, wts = corners()
        r, _ = residual()
        gx, gy = at(1), at(2)
        jtj = np.array([[_dot(gx, gx), _dot(gx, gy)], [_dot(gx, gy), _dot(gy, gy)]])
        step = np.linalg.lstsq(jtj, -np.array([_dot(gx, r), _dot(gy, r)]), rcond=None)[0]
        t += np.clip(step, -1.0, 1.0)
        if np.abs(step).max() < 1e-3 or np.abs(t).max() > 2 * MAX_SHIFT_PX:
            break
    idx, wts = corners()
    r, p = residual()
    return t, _dot(r, r) / max(_dot(p, p), 1e-30)


def _measure(view, target, valid, start, halves=False):
    """``(shift, misfit, spread)``, or None if the photo has too few pixels where the others reach.

    ``misfit`` is the detail left unexplained at the shift. With ``halves`` the shift is also measured again on
    each half of the pixels (left and right, top and bottom): ``spread`` is the largest distance of those four
    from the whole photo's (0 without).
    """
    keep = valid[view.rows, view.cols]
    if np.count_nonzero(keep) < MIN_PIXELS:
        return None
    rows, cols = view.rows[keep], view.cols[keep]
    t, misfit = _gauss_newton(view, target, rows, cols, start)
    spread = 0.0
    if halves:
        for coord in (rows, cols):
            below = coord < np.median(coord)
            for half in (below, ~below):
                if np.count_nonzero(half) < MIN_PIXELS:
                    return t, misfit, np.inf
                th, _ = _gauss_newton(view, target, rows[half], cols[half], t, iters=4)
                spread = max(spread, float(np.hypot(*(th - t))))
    return t, misfit, spread


def _round(views, shift, size, threads, halves):
    """Every photo measured against the others' texture, each photo at its shift so far."""
    sums = thread_map(lambda i: views[i].texel_sums(shift[i]), range(len(views)), threads)
    total_s, total_w = np.zeros(size * size), np.zeros(size * size)
    for v, s in zip(views, sums):
        total_s[v.texels] += s
        total_w[v.texels] += v.weight_sum

    def measure(i):
        target, valid = _target_detail(views[i], _others(views[i], sums[i], total_s, total_w))
        return _measure(views[i], target, valid, shift[i], halves)

    return thread_map(measure, range(len(views)), threads)


def photo_shifts(
    photos, masks, uvs, weights=None, texture_size: int = MATCHED_SIZE_MAX, rounds: int = 3, threads=None, cancel=None
):
    """Each photo's image shift against the others' texture (see the module docstring).

    Parameters
    ----------
    photos : list of (H, W, C) arrays
        Linear photos at the working resolution.
    masks, uvs : lists of (H, W) bool and (H, W, 2) arrays
        The bake's.
    weights : list of (H, W) arrays, optional
        The bake's view weights, for the others' texture.
    texture_size : int
        The largest texture the others' texture is made at; it is halved until the median photo has
        :data:`PIXELS_PER_TEXEL` pixels per texel it reaches.
    rounds : int
        Rounds of measuring every photo against the others as they were shifted in the round before.
    threads : int or None
        Photos measured at once (None: every core).
    cancel : callable() -> bool, optional
        Checked before each round; when it returns True, :class:`core.errors.Cancelled` is raised.

    Returns
    -------
    Alignment
    """
    m = len(photos)
    size = pixel_matched_size(masks, uvs, texture_size, PIXELS_PER_TEXEL)
    views = thread_map(
        lambda i: _View(photos[i], masks[i], uvs[i], None if weights is None else weights[i], size), range(m), threads
    )
    shift = np.zeros((m, 2))
    misfit = np.full(m, np.nan)
    spread = np.full(m, np.inf)
    for k in range(rounds):
        check_cancel(cancel)
        found = _round(views, shift, size, threads, halves=k == rounds - 1)
        for i, f in enumerate(found):
            if f is not None:
                shift[i], misfit[i], spread[i] = f
    size_px = np.hypot(shift[:, 0], shift[:, 1])
    explains = misfit <= MAX_MISFIT  # NaN (not measured) compares False
    agree = spread <= MAX_SPREAD_PX
    # A camera's error is its photo's alone; a mesh that is not the surface misregisters every photo. So where
    # the halves disagree on more than a few photos, the misregistration is the mesh's, and no camera is moved.
    mesh_fits = np.count_nonzero(agree) >= MIN_AGREEING * np.count_nonzero(np.isfinite(misfit))
    applied = mesh_fits & explains & agree & (size_px >= MIN_SHIFT_PX) & (size_px <= MAX_SHIFT_PX)
    return Alignment(
        measured=shift,
        misfit=misfit,
        spread=spread,
        applied=applied,
        mesh_fits=bool(mesh_fits),
        texture_size=int(size),
    )


def align_views(inputs, bakes, texture_size: int = MATCHED_SIZE_MAX, threads=None, cancel=None):
    """The views with each camera moved by its photo's shift (:func:`photo_shifts`), and those views baked again.

    Parameters
    ----------
    inputs : core.scene.SceneInputs
    bakes : list of core.geometry.bake.ViewBake
    texture_size, threads, cancel
        As :func:`photo_shifts`; ``cancel`` is also checked before the views are baked again.

    Returns
    -------
    (SceneInputs, list, Alignment)
        New inputs and bakes (the given ones are not changed; a view without a shift keeps its own), and the
        shifts.
    """
    from .bake import bake_views

    found = photo_shifts(
        [v.photo for v in inputs.views],
        [b.mask for b in bakes],
        [b.uv for b in bakes],
        [b.view_weight for b in bakes],
        texture_size,
        threads=threads,
        cancel=cancel,
    )
    moved = np.flatnonzero(found.applied)
    if moved.size == 0:
        return inputs, list(bakes), found
    views, bakes, shift = list(inputs.views), list(bakes), found.shift
    for i in moved:
        v = views[i]
        full = v.full
        if full is not None:
            full = replace(full, camera=shifted_camera(full.camera, shift[i], full.camera.width / v.camera.width))
        views[i] = replace(v, camera=shifted_camera(v.camera, shift[i]), full=full)
    again = bake_views(None, replace(inputs, views=[views[i] for i in moved]), cancel=cancel, threads=threads)
    for i, b in zip(moved, again):
        bakes[i] = b
    return replace(inputs, views=views), bakes, found
