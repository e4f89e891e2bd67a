"""Tests for core.texture.fuse: multi-view fusion into a texture, and hole filling."""

import numpy as np
import pytest
import scipy.ndimage as ndi

import core.texture.fill as fill
import core.texture.fuse as fusion
from core.texture import fill_unseen, fuse_views, outline_pixels

# ---------------------------------------------------------------- helpers


def albedo(uv):
    """A smooth RGB texture as a function of UV."""
    u, v = uv[..., 0], uv[..., 1]
    f = 0.3 + 0.4 * u + 0.2 * v
    return np.stack([f, f * f, 1 - 0.5 * f], axis=-1)


def flat_view(size, angle, scale, shift):
    """A view of the flat UV square: pixel (x, y) -> uv by a similarity map.

    Returns uv (H, W, 2) and the mask of pixels that land in [0, 1]^2.
    """
    ys, xs = np.mgrid[0:size, 0:size].astype(float)
    ca, sa = np.cos(angle), np.sin(angle)
    px = np.stack([xs - size / 2, ys - size / 2], -1) / size
    uv = scale * (px @ np.array([[ca, -sa], [sa, ca]]).T) + shift
    mask = np.all((uv >= 0) & (uv <= 1), axis=-1)
    return uv, mask


def three_views(size=120):
    return [flat_view(size, a, 1.5, (0.5, 0.5)) for a in (0.1, 0.9, 2.3)]


def centres_uv(n):
    r, c = np.divmod(np.arange(n * n), n)
    return np.stack([(c + 0.5) / n, 1 - (r + 0.5) / n], -1).reshape(n, n, 2)


# ---------------------------------------------------------------- fuse_views


def test_fusion_recovers_a_known_texture():
    n = 32
    views = three_views()
    maps = [albedo(uv) for uv, _ in views]
    out = fuse_views(maps, [m for _, m in views], [uv for uv, _ in views], n)
    assert out.shape == (n, n, 4) and out.dtype == np.float32
    assert np.all(out[..., 3] == 1)  # 9 pixels per texel: all seen
    # Each texel is a mean of pixels within half a texel of its centre.
    np.testing.assert_allclose(out[..., :3], albedo(centres_uv(n)), atol=0.4 / n)


def test_alpha_is_one_exactly_on_seen_texels():
    n = 64  # fewer pixels than texels: holes
    uv, mask = flat_view(50, 0.3, 0.7, (0.45, 0.5))
    out = fuse_views([albedo(uv)], [mask], [uv], n, inside=np.ones((n, n), bool))
    seen = np.zeros((n, n), bool)
    u, v = uv[mask].T
    seen[np.floor((1 - v) * n).astype(int), np.floor(u * n).astype(int)] = True
    assert 0 < seen.sum() < n * n
    np.testing.assert_array_equal(out[..., 3], seen.astype(np.float32))
    # Holes are filled from their neighbours; inside everything gets a value.
    assert np.all(out[..., 0] > 0)


def test_per_view_weighted_mean_within_a_texel():
    n = 4
    # 2x2 pixels, all in texel (0, 0): u in [0, 1/4], v in [3/4, 1].
    uv = np.array([[[0.05, 0.95], [0.2, 0.95]], [[0.05, 0.8], [0.2, 0.8]]])
    vals = np.array([[1.0, 2.0], [3.0, 4.0]])
    w = np.array([[1.0, 1.0], [1.0, 5.0]])
    out = fuse_views([vals], [np.ones((2, 2), bool)], [uv], n, view_weight=[w], inside=np.ones((n, n), bool))
    expect = (1 + 2 + 3 + 20) / 8
    assert out[0, 0, 1] == 1 and out[..., 1].sum() == 1
    # The single seen texel fills the whole (one-island) texture.
    np.testing.assert_allclose(out[..., 0], expect, rtol=1e-6)


def constant_views(values, n=8, size=40):
    uv, mask = flat_view(size, 0.0, 1.0, (0.5, 0.5))
    maps = [np.full(mask.shape + (1,), v) for v in values]
    return maps, [mask] * len(values), [uv] * len(values)


def test_weighted_median_across_views():
    n = 8
    maps, masks, uvs = constant_views([1.0, 2.0, 10.0])
    out = fuse_views(maps, masks, uvs, n)
    np.testing.assert_allclose(out[..., 0], 2.0)  # median, not the mean 4.33
    # Two equal views: the median is their mean.
    out = fuse_views(maps[:2], masks[:2], uvs[:2], n)
    np.testing.assert_allclose(out[..., 0], 1.5)
    # A view holding more than half the weight wins.
    wts = [np.full(masks[0].shape, w) for w in (0.1, 0.1, 1.0)]
    out = fuse_views(maps, masks, uvs, n, view_weight=wts)
    np.testing.assert_allclose(out[..., 0], 10.0)
    # Zero-weight views do not vote, unless no view has weight.
    wts = [np.full(masks[0].shape, w) for w in (0.0, 1.0, 1.0)]
    np.testing.assert_allclose(fuse_views(maps, masks, uvs, n, view_weight=wts)[..., 0], 6.0)
    wts = [np.zeros(masks[0].shape)] * 3
    np.testing.assert_allclose(fuse_views(maps, masks, uvs, n, view_weight=wts)[..., 0], 2.0)


def test_highlight_in_one_view_is_rejected():
    n = 32
    views = three_views()
    maps = []
    for i, (uv, _) in enumerate(views):
        m = albedo(uv)
        if i == 1:  # a white specular blob
            m += 2.0 * (np.sum((uv - 0.5) ** 2, axis=-1) < 0.2**2)[..., None]
        maps.append(m)
    out = fuse_views(maps, [m for _, m in views], [uv for uv, _ in views], n)
    np.testing.assert_allclose(out[..., :3], albedo(centres_uv(n)), atol=0.4 / n)


def test_grazing_views_count_less():
    n = 16
    views = three_views(80)
    maps = [albedo(uv) + (0.5 if i else 0.0) for i, (uv, _) in enumerate(views)]
    # Views 1 and 2 are wrong but grazing (weight 0.2 each against 1).
    wts = [np.full(uv.shape[:2], 1.0 if i == 0 else 0.2) for i, (uv, _) in enumerate(views)]
    out = fuse_views(maps, [m for _, m in views], [uv for uv, _ in views], n, view_weight=wts)
    np.testing.assert_allclose(out[..., :3], albedo(centres_uv(n)), atol=0.4 / n * 2)


def test_nan_pixels_are_ignored_and_inside_restricts():
    n = 8
    maps, masks, uvs = constant_views([1.0, 2.0, 10.0])
    maps[2] = np.full_like(maps[2], np.nan)
    out = fuse_views(maps, masks, uvs, n)
    np.testing.assert_allclose(out[..., 0], 1.5)
    inside = np.zeros((n, n), bool)
    inside[2:5, 2:5] = True
    out = fuse_views(maps, masks, uvs, n, inside=inside, margin=1)
    np.testing.assert_array_equal(out[..., 1], inside)
    assert np.all(out[1:6, 1:6, 0] == 1.5) and out[..., 0].sum() == 1.5 * 25


def test_fuse_views_bad_input():
    maps, masks, uvs = constant_views([1.0, 2.0])
    with pytest.raises(ValueError, match="masks"):
        fuse_views(maps, masks[:1], uvs, 8)
    bad = uvs[1].copy()
    bad[20, 20] = np.nan
    with pytest.raises(ValueError, match="view 1"):
        fuse_views(maps, masks, [uvs[0], bad], 8)
    with pytest.raises(ValueError, match="view_weight of view 0"):
        fuse_views(maps, masks, uvs, 8, view_weight=[-np.ones(masks[0].shape)] * 2)
    with pytest.raises(ValueError, match="no masked pixel"):
        fuse_views(maps, masks, [u + 5 for u in uvs], 8)
    with pytest.raises(ValueError, match="inside"):
        fuse_views(maps, masks, uvs, 8, inside=np.ones((4, 4), bool))


# ---------------------------------------------------------------- fill_unseen


def ramp_case(n=48):
    r, c = np.mgrid[0:n, 0:n].astype(float)
    tex = np.stack([0.02 * r + 0.01 * c + 0.1, 1 - 0.015 * c], -1)
    inside = (r >= 4) & (r < n - 4) & (c >= 6) & (c < n - 6)
    hole = ((r - n / 2) ** 2 + (c - n / 2) ** 2 < (n / 5) ** 2) | ((r == 10) & (c > 10) & (c < 30))
    return tex, inside & ~hole, inside, hole


@pytest.mark.parametrize("direct_max", [10**9, 20])
def test_fill_recovers_linear_ramp_in_hole(monkeypatch, direct_max):
    # direct_max=20 forces the coarse-to-fine (multigrid + CG) path.
    monkeypatch.setattr(fill, "_DIRECT_MAX", direct_max)
    tex, seen, inside, hole = ramp_case()
    given = np.where(seen[..., None], tex, np.nan)
    out = fill_unseen(given, seen, inside, margin=0)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out[seen], tex[seen].astype(np.float32))
    np.testing.assert_allclose(out[hole], tex[hole], atol=1e-4)
    assert np.all(out[~inside] == 0)


def test_fill_stays_within_neighbour_range_and_islands_do_not_leak(monkeypatch):
    monkeypatch.setattr(fill, "_DIRECT_MAX", 30)
    n = 64
    rng = np.random.default_rng(3)
    r, c = np.mgrid[0:n, 0:n]
    left = (c >= 2) & (c < 30) & (r >= 2) & (r < n - 2)
    right = (c >= 32) & (c < n - 2) & (r >= 2) & (r < n - 2)  # 2-texel gutter
    tex = np.where(left, 1.0 + 0.2 * rng.random((n, n)), 5.0 + 0.2 * rng.random((n, n)))
    seen = (left | right) & (rng.random((n, n)) > 0.4)
    seen[10:40, 5:25] = False  # big hole on the left
    out = fill_unseen(tex, seen, left | right, margin=0)
    for isl in (left, right):
        lo, hi = tex[isl & seen].min(), tex[isl & seen].max()
        assert np.all((out[isl] >= lo - 1e-5) & (out[isl] <= hi + 1e-5))
    np.testing.assert_array_equal(out[seen], tex[seen].astype(np.float32))


def test_fill_margin_and_unseen_islands():
    n = 32
    r, c = np.mgrid[0:n, 0:n]
    a = (r >= 10) & (r < 20) & (c >= 10) & (c < 20)
    b = (r >= 2) & (r < 5) & (c >= 26) & (c < 30)  # never seen
    tex = np.full((n, n, 3), np.nan)
    tex[a] = [2.0, 4.0, 6.0]
    seen = a & ~((r == 15) & (c == 15))
    out = fill_unseen(tex, seen, a | b, margin=3)
    np.testing.assert_allclose(out[15, 15], [2, 4, 6])
    np.testing.assert_allclose(out[b], np.broadcast_to([2, 4, 6], (b.sum(), 3)))
    # Chebyshev distance to the islands: within the margin filled, beyond it 0.
    from scipy.ndimage import distance_transform_cdt

    dist = distance_transform_cdt(~(a | b), metric="chessboard")
    ring = (dist > 0) & (dist <= 3)
    np.testing.assert_allclose(out[ring], np.broadcast_to([2, 4, 6], (ring.sum(), 3)), rtol=1e-6)
    assert np.all(out[dist > 3] == 0)


def test_fill_unseen_2d_and_bad_input():
    tex, seen, inside, _ = ramp_case(16)
    out = fill_unseen(tex[..., 0], seen, inside)
    assert out.shape == (16, 16)
    rows, cols = seen.nonzero()
    for value in (np.nan, np.inf):
        bad = tex.copy()
        bad[rows[2], cols[2], 1] = value
        bad[rows[4], cols[4], 0] = value
        with pytest.raises(ValueError, match=rf"\(row {rows[2]}, col {cols[2]}\) is NaN or infinite"):
            fill_unseen(bad, seen, inside)
    with pytest.raises(ValueError, match="inside"):
        fill_unseen(tex, seen, inside[:8])
    with pytest.raises(ValueError, match="no texel is seen"):
        fill_unseen(tex, np.zeros_like(seen), inside)
    with pytest.raises(ValueError, match="margin"):
        fill_unseen(tex, seen, inside, margin=-1)


@pytest.mark.parametrize("k", [2, 3, 5, 9])
def test_weighted_median_paths_match_reference(monkeypatch, k):
    # Groups of k records with ties and zero weights; both the sort-free and
    # the sorting path must give the textbook weighted median.
    rng = np.random.default_rng(k)
    g = 300
    vals = rng.integers(0, 4, (2, g * k)).astype(float)  # many ties
    w = rng.integers(0, 3, g * k).astype(float)  # zero weights too
    count = np.full(g, k)
    start = np.arange(g) * k

    def reference(v, wt):
        if wt.sum() == 0:
            wt = np.ones_like(wt)
        o = np.argsort(v, kind="stable")
        v, cw = v[o], np.cumsum(wt[o])
        half = cw[-1] / 2
        return 0.5 * (v[np.argmax(cw >= half)] + v[np.argmax(cw > half)])

    expect = np.array([[reference(vals[ch, s : s + k], w[s : s + k]) for ch in range(2)] for s in start])
    for pairwise_max in (0, 100):
        monkeypatch.setattr(fusion, "_PAIRWISE_MAX_K", pairwise_max)
        np.testing.assert_array_equal(fusion._weighted_median(count, start, vals, w), expect)


def _pixel_per_texel_view(n, mask):
    """A view whose pixel (r, c) lands on texel (r, c) of an n x n texture."""
    rows, cols = np.mgrid[0:n, 0:n]
    uv = np.stack([(cols + 0.5) / n, 1.0 - (rows + 0.5) / n], axis=-1).astype(np.float32)
    return uv, mask


def test_outline_pixels_have_a_neighbour_off_the_mask_within_the_photo():
    rng = np.random.default_rng(2)
    for shape in ((23, 31), (1, 9), (7, 1), (1, 1)):
        mask = rng.random(shape) > 0.3
        h, w = shape
        expect = np.zeros(shape, bool)
        for r, c in zip(*np.nonzero(mask)):
            near = [(r + dr, c + dc) for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1))]
            expect[r, c] = any(0 <= i < h and 0 <= j < w and not mask[i, j] for i, j in near)
        assert np.array_equal(outline_pixels(mask), expect)
        assert not outline_pixels(np.ones(shape, bool)).any()  # the photo's border is no outline


def test_outline_only_finds_the_texels_seen_only_at_the_outline():
    from core.texture.fill import outline_only

    n = 10
    mask = np.zeros((n, n), bool)
    mask[2:8, 0:7] = True  # touches the photo's left border, where it is cut off, not outlined
    uv, _ = _pixel_per_texel_view(n, mask)
    found = outline_only([uv], [mask], None, mask)
    ring = mask & ~ndi.binary_erosion(mask, border_value=1)
    np.testing.assert_array_equal(found, ring)
    assert not found[4, 0] and found[2, 0] and found[4, 6]
    # A second photo that sees the top rows' texels off its outline gives them a clean view.
    other = np.zeros((n, n), bool)
    other[1:4, 0:n] = True
    found = outline_only([uv, uv], [mask, other], None, mask | other)
    clean = ndi.binary_erosion(mask, border_value=1) | ndi.binary_erosion(other, border_value=1)
    np.testing.assert_array_equal(found, (mask | other) & ~clean)
    assert not found[2, 3] and found[7, 3] and found[1, 3]
    # Pixels the solve left out (clipped) count for nothing.
    used = mask.copy()
    used[4, 3] = False
    assert outline_only([uv], [mask], None, mask, used=[used])[4, 3]
    assert not outline_only([uv], [mask], None, mask & ~used, used=[used]).any()
    assert not outline_only([uv], [mask], None, mask, evidence=0).any()
    # A little clean weight, against the median texel's, is not enough.
    weight = np.ones((n, n), np.float32)
    weight[4, 3] = 0.01
    assert outline_only([uv], [mask], [weight], mask, evidence=0.02)[4, 3]
    assert not outline_only([uv], [mask], [weight], mask, evidence=0.005)[4, 3]


def test_a_texture_solved_smaller_is_filled_at_its_size_then_scaled_up():
    from core.geometry.texels import parent_texels
    from core.solve.pyramid import upsample_onto
    from core.texture.fill import fill_scaled_up

    # A ramp solved at 48 (a round hole unseen), for a texture of 4 x 48: the hole takes the ramp at 48 and
    # the texture is its bilinear scaling; a tiny island no solved texel saw takes the mean of the seen ones.
    tex, seen, inside, hole = ramp_case(48)
    big = 4 * 48
    parent = parent_texels(big, 48)
    fine_inside = inside[parent][:, parent]
    island = np.zeros((big, big), bool)
    island[1, 1] = True  # no texel at 48 holds it
    out = fill_scaled_up(tex, seen, fine_inside | island, 4)
    assert out.shape == (big, big, 2) and out.dtype == np.float32
    filled = fill_unseen(tex, seen, inside, 3)
    at_inside, _ = upsample_onto(filled, np.ones((48, 48), bool), fine_inside)
    np.testing.assert_allclose(out[fine_inside], at_inside[fine_inside], atol=1e-6)
    # The ramp is linear, and so is its bilinear scaling: the hole's texels hold it at 192 too.
    y, x = (np.mgrid[0:big, 0:big] + 0.5) / 4 - 0.5  # the texels' centres in the solved texels' rows, columns
    ramp = np.stack([0.02 * y + 0.01 * x + 0.1, 1 - 0.015 * x], -1)
    core_ = fine_inside & ndi.binary_erosion(fine_inside, iterations=8)
    np.testing.assert_allclose(out[core_], ramp[core_], atol=1e-3)
    assert np.isfinite(out).all() and np.all(out[island] == out[island][0])  # the orphan island: the mean
    np.testing.assert_allclose(out[island][0], tex[seen].mean(axis=0), rtol=1e-5)
    # A margin past the islands, then 0.
    dist = ndi.distance_transform_cdt(~(fine_inside | island), metric="chessboard")
    assert np.all(out[(dist > 0) & (dist <= 4) & ~(island | ndi.binary_dilation(island, iterations=40))] != 0)
    assert np.all(out[dist > 12] == 0)
    # At the same size it is fill_unseen.
    np.testing.assert_array_equal(fill_scaled_up(tex, seen, inside, 4), fill_unseen(tex, seen, inside, 4))
