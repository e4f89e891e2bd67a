"""Clipped highlights: the clipped pixels of 8-bit photos that the other views show to be a highlight.

A clipped pixel (:func:`core.io.photos.clipped_pixels`) holds less than the light that reached the camera. Where
the albedo is bright, it clips in every view that sees it; a specular highlight clips in the one or two views that
see it mirrored, and there the clipped value, divided by the diffuse shading, gives an albedo several times too
bright. So each connected region of clipped pixels in a photo is judged by the other views of its texels: its
observations whose texel another view sees unclipped vote for a highlight, those whose texel another view sees
clipped vote for an albedo (each by its weight). A region is an albedo when it has albedo votes and at least as
many as highlight votes; otherwise, and when no other view sees its texels, it is a highlight, and the albedo
stage leaves its observations out, with those of its rim (the unclipped pixels next to it, :data:`RIM`: a
highlight fades out over them, still far brighter than the albedo): its texels take their neighbours' albedo
through the TV term. The detail stage gives the same pixels its least agreement
(:func:`core.texture.detail.agreement`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import scipy.ndimage as ndi

__all__ = ["RIM", "clipped_regions", "highlight_observations", "highlights", "without_highlights"]

#: Pixels around a clipped region that go with it when it is a highlight. Measured on 40 scenes: 1 against none
#: gave the 27 unseen 0.0790 -> 0.0783 and the 13 fixtures 0.0660 either way; 2 did better on two of the scenes
#: and worse on one of four (docs/measurements.md).
RIM = 1
_CROSS = ndi.generate_binary_structure(2, 1)


def clipped_regions(clipped, masks) -> np.ndarray | None:
    """The connected regions of clipped pixels in each photo, and their rims, over the masked pixels.

    Parameters
    ----------
    clipped, masks : lists of (H, W) bool arrays
        Per view, the clipped pixels (None: none, a float photo) and the pixels that see the surface.

    Returns
    -------
    (P,) int32 array or None
        Per masked pixel (view by view, row-major, as :mod:`core.solve.discretization` orders them): its
        region's number r > 0, unique over all views, where it is clipped; -r where it is not but lies within
        :data:`RIM` pixels of region r (of the highest-numbered, if of several); 0 elsewhere. None when no pixel
        is clipped.
    """
    labels, count = [], 0
    for c, m in zip(clipped, masks):
        if c is None:
            labels.append(np.zeros(np.count_nonzero(m), np.int32))
            continue
        # 8-connected: a highlight's one-pixel diagonal steps are one region.
        lab, k = ndi.label(c & m, structure=np.ones((3, 3), bool))
        lab = np.where(lab > 0, lab + count, 0).astype(np.int32)
        # The rim: RIM steps to the 4 neighbours.
        near = ndi.grey_dilation(lab, footprint=ndi.iterate_structure(_CROSS, RIM)) if RIM else lab
        labels.append(np.where(lab > 0, lab, -near)[m])
        count += k
    return np.concatenate(labels) if count else None


def highlight_observations(d) -> np.ndarray:
    """Which observations of ``d`` lie in a clipped region that the other views show to be a highlight.

    Parameters
    ----------
    d : core.solve.discretization.Discretization
        In the texture domain (where views share unknowns), with ``clipped_region`` (None: no observation is)
        and one unknown per observation (``obs_unknown``); otherwise none is.

    Returns
    -------
    (O,) bool array
        The observations of the highlights and of their rims.
    """
    out = np.zeros(d.obs_pixel.size, bool)
    if d.clipped_region is None or d.obs_unknown is None or d.domain != "texture":
        return out
    # Only the observations on the unknowns of clipped ones (those included) and the rims take part: no array
    # over all of them but of bools.
    touched = np.zeros(d.n_unknowns, bool)
    touched[d.obs_unknown[d.from_pixels(d.clipped_region > 0)]] = True
    sel = np.flatnonzero(touched[d.obs_unknown] | d.from_pixels(d.clipped_region < 0))
    pixel = d.obs_pixel[sel]
    out[sel] = highlights(
        d.clipped_region[pixel], d.obs_unknown[sel], d.pixel_view[pixel], d.obs_weight[sel], d.n_views
    )
    return out


def highlights(region, texel, view, weight, n_views) -> np.ndarray:
    """The vote of the module docstring over observations: which lie in a region that is a highlight.

    Parameters
    ----------
    region : (O,) int array
        Each observation's clipped region, or minus that of the rim it is in (:func:`clipped_regions`), or 0.
    texel, view : (O,) int arrays
        The texel (any numbering) and the view of each observation.
    weight : (O,) array
        Its vote's weight.
    n_views : int

    Returns
    -------
    (O,) bool array
        The observations of the highlights and of their rims.
    """
    region = np.asarray(region)
    clipped = region > 0
    idx = np.flatnonzero(clipped)
    if not idx.size:
        return np.zeros(region.size, bool)
    texel, view = np.asarray(texel, np.int64), np.asarray(view, np.intp)
    # The texels some clipped observation has, numbered 0..k-1; then which views see each of them clipped, and
    # which unclipped (rims included: they are not clipped), as (k, n_views) marks.
    touched = np.zeros(int(texel.max()) + 1, bool)
    touched[texel[idx]] = True
    number = np.cumsum(touched, dtype=np.int32) - 1
    others = np.flatnonzero(~clipped & touched[texel])
    seen_clipped = np.zeros((int(number[-1]) + 1, int(n_views)), bool)
    seen_unclipped = np.zeros_like(seen_clipped)
    t, v = number[texel[idx]], view[idx]
    seen_clipped[t, v] = True
    seen_unclipped[number[texel[others]], view[others]] = True
    other_unclipped = seen_unclipped.sum(axis=1)[t] - seen_unclipped[t, v] > 0
    other_clipped = seen_clipped.sum(axis=1)[t] > 1
    w = np.asarray(weight, np.float64)[idx]
    n_regions = int(np.abs(region).max()) + 1
    highlight = np.bincount(region[idx], weights=w * other_unclipped, minlength=n_regions)
    albedo = np.bincount(region[idx], weights=w * other_clipped, minlength=n_regions)
    is_highlight = ~((albedo > 0) & (albedo >= highlight))
    is_highlight[0] = False
    return is_highlight[np.abs(region)]


def without_highlights(d):
    """``d`` with the weight of its :func:`highlight_observations` set to 0 (``d`` itself if there are none).

    The unknowns stay: one that only highlights see is left to the TV term.
    """
    drop = highlight_observations(d)
    if not drop.any():
        return d
    return replace(d, obs_weight=np.where(drop, 0.0, d.obs_weight).astype(np.float32))
