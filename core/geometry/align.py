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
photo, no one shift lines it up, and moving the camera would trade one misregistration for another.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage

from ..parallel import thread_map
from .texels import pixel_matched_size, texel_index

__all__ = [
    "Alignment",
    "align_views",
    "photo_shifts",
    "shifted_camera",
    "BLUR_PX",
    "MAX_SPREAD_PX",
    "MIN_SHIFT_PX",
    "MAX_SHIFT_PX",
]

#: The Gaussian (in pixels) whose blur is taken off the photos: what is finer is the detail that is lined up.
BLUR_PX = 2.0
#: A shift is applied where each half of the photo (left, right, top, bottom) measures one within this many pixels.
MAX_SPREAD_PX = 0.35
#: Shifts smaller than this (pixels) are left out: on photos whose cameras are right, the shifts measured reach
#: 0.2 px, and moving the cameras by them made the albedo worse.
MIN_SHIFT_PX = 0.25
#: Shifts larger than this (pixels) are not a camera about a pixel off: not applied.
MAX_SHIFT_PX = 3.0
#: Fewest pixels on the mesh (away from its outline) a photo needs for its shift to be measured.
MIN_PIXELS = 500


@dataclass
class Alignment:
    """What :func:`photo_shifts` measured, per photo.

    Attributes
    ----------
    shift : (m, 2) float64
        ``(dx, dy)`` in pixels: the photo shows at ``x + shift`` what the bake puts at ``x``. Zero where not
        ``applied``.
    measured : (m, 2) float64
        The shift found, applied or not.
    misfit : (m,) float64
        The detail left unexplained after the shift, as a fraction of the detail (NaN: not measured).
    spread : (m,) float64
        How far (pixels) the shift measured on a half of the photo lies from the whole photo's, at most (inf:
        not measured).
    applied : (m,) bool
    """

    shift: np.ndarray
    measured: np.ndarray
    misfit: np.ndarray
    spread: np.ndarray
    applied: np.ndarray


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
    """One photo's detail and the pixels its shift is measured on."""

    def __init__(self, photo, mask, uv, weight, size):
        grey = np.asarray(photo, np.float64).mean(axis=-1)
        self.detail = grey - _blur(grey, ndimage.binary_erosion(mask), BLUR_PX)
        self.gy, self.gx = np.gradient(self.detail)
        inner = ndimage.binary_erosion(mask, iterations=3)
        self.rows, self.cols = np.nonzero(inner)
        self.grey = grey
        self.mask = mask
        t = texel_index(uv[mask], size)
        self.texel_of_mask = t
        self.weight = np.asarray(weight, np.float64)[mask] if weight is not None else np.ones(t.size)
        self.texel_of_inner = texel_index(uv[self.rows, self.cols], size)

    def values(self, shift):
        """The grey photo at ``x + shift`` for the pixels of the mask (bilinear)."""
        r, c = np.nonzero(self.mask)
        return ndimage.map_coordinates(self.grey, [r + shift[1], c + shift[0]], order=1, mode="nearest")


def _sums(view, shift, n_texels):
    ok = view.texel_of_mask >= 0
    w = view.weight[ok]
    s = np.bincount(view.texel_of_mask[ok], weights=w * view.values(shift)[ok], minlength=n_texels)
    return s, np.bincount(view.texel_of_mask[ok], weights=w, minlength=n_texels)


def _target_detail(view, others, size):
    """The others' texture seen through this view's bake, as detail; NaN where they do not reach."""
    t = view.texel_of_inner
    img = np.zeros(view.mask.shape)
    valid = np.zeros(view.mask.shape, bool)
    ok = t >= 0
    vals = np.full(t.size, np.nan)
    vals[ok] = others[t[ok]]
    good = np.isfinite(vals)
    img[view.rows[good], view.cols[good]] = vals[good]
    valid[view.rows[good], view.cols[good]] = True
    return img - _blur(img, valid, BLUR_PX), valid


def _gauss_newton(view, target, rows, cols, start, iters=8):
    """The shift from ``start`` over the given pixels, and the detail left unexplained after it (a fraction)."""
    ref = target[rows, cols]
    ref2 = max(float(np.dot(ref, ref)), 1e-30)
    t = np.array(start, np.float64)

    def at(img):
        return ndimage.map_coordinates(img, [rows + t[1], cols + t[0]], order=1, mode="nearest")

    def residual():
        p = at(view.detail)
        return p - (np.dot(p, ref) / ref2) * ref, p

    for _ in range(iters):
        r, _ = residual()
        step = np.linalg.lstsq(np.stack([at(view.gx), at(view.gy)], axis=1), -r, rcond=None)[0]
        t += np.clip(step, -1.0, 1.0)
        if np.abs(step).max() < 1e-3 or np.abs(t).max() > 2 * MAX_SHIFT_PX:
            break
    r, p = residual()
    return t, float(np.dot(r, r) / max(np.dot(p, p), 1e-30))


def _measure(view, target, valid, start, halves=False):
    """``(shift, misfit, spread)``, or None if the photo has too few pixels where the others reach.

    With ``halves`` the shift is measured again on each half of the pixels (left and right, top and bottom):
    ``spread`` is the largest distance of those four from the whole photo's (0 without).
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
                th, _ = _gauss_newton(view, target, rows[half], cols[half], t)
                spread = max(spread, float(np.hypot(*(th - t))))
    return t, misfit, spread


def _round(views, shift, size, threads, halves):
    """Every photo measured against the others' texture, each photo at its shift so far."""
    sums = [_sums(v, s, size * size) for v, s in zip(views, shift)]
    total_s = np.sum([s for s, _ in sums], axis=0)
    total_w = np.sum([w for _, w in sums], axis=0)

    def measure(i):
        w = total_w - sums[i][1]
        with np.errstate(invalid="ignore", divide="ignore"):
            others = np.where(w > 1e-9, (total_s - sums[i][0]) / w, np.nan)
        target, valid = _target_detail(views[i], others, size)
        return _measure(views[i], target, valid, shift[i], halves)

    return thread_map(measure, range(len(views)), threads)


def photo_shifts(photos, masks, uvs, weights=None, texture_size: int = 1024, rounds: int = 3, threads=None):
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
        The largest texture the others' texture is made at; it is halved until a texel gets about a pixel of the
        median photo.
    rounds : int
        Rounds of measuring every photo against the others as they were shifted in the round before.
    threads : int or None
        Photos measured at once (None: every core).

    Returns
    -------
    Alignment
    """
    m = len(photos)
    size = pixel_matched_size(masks, uvs, texture_size, 1.0)
    views = thread_map(
        lambda i: _View(photos[i], masks[i], uvs[i], None if weights is None else weights[i], size), range(m), threads
    )
    shift = np.zeros((m, 2))
    misfit = np.full(m, np.nan)
    spread = np.full(m, np.inf)
    for k in range(rounds):
        found = _round(views, shift, size, threads, halves=k == rounds - 1)
        for i, f in enumerate(found):
            if f is not None:
                shift[i], misfit[i], spread[i] = f
    size_px = np.hypot(shift[:, 0], shift[:, 1])
    applied = (spread <= MAX_SPREAD_PX) & (size_px >= MIN_SHIFT_PX) & (size_px <= MAX_SHIFT_PX)
    return Alignment(
        shift=np.where(applied[:, None], shift, 0.0), measured=shift, misfit=misfit, spread=spread, applied=applied
    )


def align_views(inputs, bakes, texture_size: int = 1024, threads=None):
    """The views with each camera moved by its photo's shift (:func:`photo_shifts`), and those views baked again.

    Parameters
    ----------
    inputs : core.scene.SceneInputs
    bakes : list of core.geometry.bake.ViewBake
    texture_size, threads
        As :func:`photo_shifts`.

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
    )
    moved = np.flatnonzero(found.applied)
    if moved.size == 0:
        return inputs, list(bakes), found
    views, bakes = list(inputs.views), list(bakes)
    for i in moved:
        v = views[i]
        full = v.full
        if full is not None:
            full = replace(full, camera=shifted_camera(full.camera, found.shift[i], full.camera.width / v.camera.width))
        views[i] = replace(v, camera=shifted_camera(v.camera, found.shift[i]), full=full)
    again = bake_views(None, replace(inputs, views=[views[i] for i in moved]), threads=threads)
    for i, b in zip(moved, again):
        bakes[i] = b
    return replace(inputs, views=views), bakes, found
