"""Clipped highlights (core.solve.highlights): which clipped regions the other views show to be a highlight."""

from dataclasses import replace

import numpy as np
import scipy.ndimage as ndi

from core.evaluate.synthetic import sphere_scene
from core.solve.discretization import texture_domain
from core.solve.highlights import clipped_regions, highlight_observations
from core.solve.params import SolverParams
from core.solve.stages import solve_albedo


def test_regions_are_numbered_over_all_views_in_the_masked_pixels_order_with_their_rims():
    mask = np.ones((6, 7), bool)
    mask[0, 0] = False
    a = np.zeros((6, 7), bool)
    a[2:4, 1] = True  # one region
    a[4, 4] = a[3, 5] = True  # one more: diagonal neighbours are connected
    b = np.zeros((6, 7), bool)
    b[0, 0] = True  # outside the mask: not a region
    b[0, 6] = True
    regions = clipped_regions([a, b], [mask, mask])
    n = int(mask.sum())
    first, second = (np.zeros((6, 7), int), np.zeros((6, 7), int))
    first[mask], second[mask] = regions[:n], regions[n:]
    assert regions.size == 2 * n
    assert set(np.unique(first[a])) == {1, 2} and np.all(first[~a] <= 0)
    assert set(np.unique(second[b & mask])) == {3} and np.all(second[~b] <= 0)
    # The rim: the unclipped pixels next to a region, marked with minus its number.
    assert first[1, 1] == first[3, 2] == first[2, 0] == -1 and first[5, 4] == first[2, 5] == first[3, 6] == -2
    assert first[1, 0] == 0 and first[5, 5] == 0 and first[2, 3] == 0  # diagonal: not the rim
    assert second[1, 6] == second[0, 5] == -3 and second[1, 5] == 0
    assert clipped_regions([np.zeros((6, 7), bool)] * 2, [mask, mask]) is None


def _texel(uv, n):
    """(row, column) of the texel holding each UV (row 0 at v = 1, as the layout has it)."""
    col = np.clip(np.floor(uv[..., 0] * n).astype(int), 0, n - 1)
    row = np.clip(np.floor((1.0 - uv[..., 1]) * n).astype(int), 0, n - 1)
    return row, col


def _scene_with_a_highlight(only_one_view=False):
    """A textured sphere whose photos clip at a level its brightest albedo passes in every view, and one photo with
    a highlight: a disc of pixels that clips there alone. With ``only_one_view``, no other photo sees the texels
    under the disc (and one texel around)."""
    scene = sphere_scene(n_views=6, height=60, width=80, texture_size=32, seed=3, textured=True)
    p = scene.problem
    level = np.quantile(np.concatenate([im[m].max(axis=1) for im, m in zip(p.images, p.masks)]), 0.9)
    rows, cols = np.mgrid[0:60, 0:80]
    # At the darkest albedo away from the silhouette, so that the albedo's own clipping does not touch it.
    inner = ndi.binary_erosion(p.masks[0], iterations=6)
    r0, c0 = np.unravel_index(np.argmax(np.where(inner, -scene.albedo_views[0].sum(axis=2), -np.inf)), inner.shape)
    disc = ((rows - r0) ** 2 + (cols - c0) ** 2 <= 16) & p.masks[0]
    masks = list(p.masks)
    if only_one_view:
        n = p.texture.size
        under = np.zeros((n, n), bool)
        under[_texel(p.uv[0][disc], n)] = True
        under = ndi.binary_dilation(under, iterations=2)
        for v in range(1, len(masks)):
            masks[v] = masks[v] & ~under[_texel(p.uv[v], n)]
    images, clipped = [], []
    for v, (im, m) in enumerate(zip(p.images, masks)):
        im = im.copy()
        if v == 0:
            im[disc] += 4.0 * level
        over = (im.max(axis=2) >= level) & m
        im[over] = np.minimum(im[over], level)
        images.append(im)
        clipped.append(over)
    return scene, replace(p, images=images, masks=masks, clipped=clipped), disc


def _in_view_0(pixels, masks):
    """``pixels`` of view 0 over all views' masked pixels."""
    return np.concatenate([pixels[masks[0]]] + [np.zeros(np.count_nonzero(m), bool) for m in masks[1:]])


def test_a_highlight_one_photo_shows_is_left_out_and_an_albedo_every_photo_clips_is_kept():
    scene, problem, disc = _scene_with_a_highlight()
    d = texture_domain(problem)
    drop = highlight_observations(d)
    pixel_of = d.obs_pixel
    in_disc = _in_view_0(disc, problem.masks)
    clipped = d.clipped_region[pixel_of] > 0
    assert drop[in_disc[pixel_of]].all()
    # The albedo's own clipping (outside the disc) is mostly kept: the other views clip it too.
    others = clipped & ~in_disc[pixel_of]
    assert others.sum() > 50
    assert drop[others].mean() < 0.35, drop[others].mean()
    # Unclipped observations go only as a highlight's rim: next to it in its own photo.
    rim = d.clipped_region[pixel_of] < 0
    assert not drop[~clipped & ~rim].any()
    ring = _in_view_0(ndi.binary_dilation(disc) & ~disc & problem.masks[0], problem.masks)[pixel_of]
    assert ring.any() and drop[ring].all()


def test_the_albedo_under_a_highlight_comes_from_the_other_views():
    scene, problem, disc = _scene_with_a_highlight(only_one_view=True)
    masks = problem.masks
    gt = np.concatenate([g[m] for g, m in zip(scene.albedo_views, masks)])
    in_disc = _in_view_0(disc, masks)

    def error(p):
        r = solve_albedo(p, scene.sigma, SolverParams(lam=0.05))
        est = np.concatenate([a[m] for a, m in zip(r.views, masks)])
        scale = np.sum(est * gt, axis=0) / np.sum(est * est, axis=0)  # the best scale over all pixels
        return np.sqrt(np.mean((scale * est[in_disc] - gt[in_disc]) ** 2, axis=0))

    kept, left_out = error(replace(problem, clipped=None)), error(problem)
    assert np.all(left_out < 0.3 * kept), (left_out, kept)
