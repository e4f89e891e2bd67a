import numpy as np
import pytest

from core.evaluate.synthetic import sphere_scene
from core.geometry.bilinear import masked_corners
from core.geometry.correspondences import find_correspondences
from core.geometry.texels import uv_of_texel
from core.solve import pyramid
from core.solve.discretization import texture_domain
from core.solve.problem import Problem
from core.solve.pyramid import coarsen, upsample_pixels


@pytest.fixture(scope="module")
def scene():
    sc = sphere_scene(n_views=6, height=120, width=160, texture_size=64, seed=2, distance=2.5)
    p = sc.problem
    corr = find_correspondences(sc.cameras, sc.positions, p.masks, p.normals, max_pairs=10**7, neighbours=4)
    # Each weight names its pair's source pixel, so the test can tell which pairs survived.
    corr.weight = (corr.view_a * 10**6 + corr.pixel_a + 1).astype(np.float64)
    problem = Problem(
        p.images,
        p.masks,
        p.normals,
        correspondences=corr,
        uv=p.uv,
        texture=p.texture,
        view_weight=p.view_weight,
        names=p.names,
    )
    return sc, problem


def _footprint(pos, mask):
    """Median distance between horizontally adjacent masked pixels: one pixel on the surface."""
    both = mask[:, 1:] & mask[:, :-1]
    return float(np.median(np.linalg.norm(pos[:, 1:] - pos[:, :-1], axis=2)[both]))


@pytest.mark.parametrize("texture", [True, False])
def test_coarse_correspondences_link_the_same_surface_points(scene, monkeypatch, texture):
    sc, problem = scene
    monkeypatch.setattr(pyramid, "MIN_PIXELS", 1000)  # this small scene would not be coarsened
    small = coarsen(problem, texture=texture)
    assert small is not None and (small.texture is None) != texture
    fine, corr = problem.correspondences, small.correspondences
    # Every other pixel in both directions keeps about a quarter of the pairs.
    assert 0.2 * len(fine) < len(corr) < 0.3 * len(fine), (len(corr), len(fine))
    pos = [p[::2, ::2] for p in sc.positions]
    foot = np.median([_footprint(p, m) for p, m in zip(pos, small.masks)])
    # Source pixel and its weight: coarse (r, c) is fine (2r, 2c) of the same view.
    w = np.array([m.shape[1] for m in small.masks])[corr.view_a]
    r, c = np.divmod(corr.pixel_a, w)
    fine_w = np.array([m.shape[1] for m in problem.masks])[corr.view_a]
    assert np.array_equal(corr.weight, corr.view_a * 10**6 + 2 * r * fine_w + 2 * c + 1)
    # The two ends see the same point, within a small part of a coarse pixel, for
    # the pairs the image domain uses (all 4 bilinear corners inside b's mask).
    err = np.full(len(corr), np.nan)
    for b in np.unique(corr.view_b):
        sel = np.flatnonzero(corr.view_b == b)
        flat, wts = masked_corners(corr.xy_b[sel, 0], corr.xy_b[sel, 1], small.masks[b])
        inside = small.masks[b].ravel()[flat].all(axis=1)
        sel, flat, wts = sel[inside], flat[inside], wts[inside]
        pb = np.einsum("kj,kjd->kd", wts, pos[b].reshape(-1, 3)[flat])
        pa = np.stack([pos[a][rr, cc] for a, rr, cc in zip(corr.view_a[sel], r[sel], c[sel])])
        err[sel] = np.linalg.norm(pa - pb, axis=1) / foot
    used = np.isfinite(err)
    assert used.mean() > 0.8, used.mean()
    err = err[used]
    # Measured: median 0.04, 90% 0.31, 99% 0.87 (the fine pairs, in fine pixels:
    # 0.03 / 0.32 / 1.04; the tail is grazing views); pixel corners at integers
    # instead of centres would give a median of 0.5.
    q = np.percentile(err, [50, 90, 99])
    assert q[0] < 0.15 and q[1] < 0.5 and q[2] < 1.2, q


def test_coarsen_without_a_texture(scene, monkeypatch):
    _, problem = scene
    bare = Problem(problem.images, problem.masks, problem.normals, correspondences=problem.correspondences)
    monkeypatch.setattr(pyramid, "MIN_SIZE", 10**6)  # no texture limits an image-domain problem
    monkeypatch.setattr(pyramid, "MIN_PIXELS", 1000)
    assert coarsen(problem) is None
    small = coarsen(bare)
    assert small is not None and small.texture is None and small.uv is None
    assert [m.shape for m in small.masks] == [(60, 80)] * 6
    monkeypatch.setattr(pyramid, "MIN_PIXELS", 10**6)
    assert coarsen(bare) is None


def test_coarsen_keeps_the_transfer_rows_of_the_pixels_it_keeps(scene, monkeypatch):
    # The transfer is held per masked pixel: each coarse pixel's row must be its fine pixel's.
    _, problem = scene
    monkeypatch.setattr(pyramid, "MIN_SIZE", 8)
    monkeypatch.setattr(pyramid, "MIN_PIXELS", 1000)
    rows, cols = zip(*(np.nonzero(m) for m in problem.masks))
    transfer = [np.stack([r, c] + [r * 0] * 7, axis=1).astype(np.float32) for r, c in zip(rows, cols)]
    small = coarsen(Problem(problem.images, problem.masks, problem.normals, transfer=transfer))
    for t, m in zip(small.transfer, small.masks):
        r, c = np.nonzero(m)
        np.testing.assert_array_equal(t[:, :2], np.stack([2 * r, 2 * c], axis=1))


def test_upsample_pixels_is_bilinear_inside_the_coarse_mask():
    h, w = 20, 30
    r, c = np.mgrid[0:h, 0:w]
    fine_truth = (1 + 0.1 * r - 0.05 * c).astype(np.float32)
    coarse = fine_truth[::2, ::2][..., None].copy()  # coarse (R, C) is fine (2R, 2C)
    coarse[:, :3] = np.nan  # outside the coarse mask
    mask = np.ones((h, w), bool)
    up = upsample_pixels(coarse, mask)[:, 0].reshape(h, w)
    inner = np.zeros((h, w), bool)
    inner[:-2, 6:-2] = True  # every corner inside the coarse mask
    np.testing.assert_allclose(up[inner], fine_truth[inner], atol=1e-5)
    assert np.all(np.isnan(up[:, :5]))  # on or between masked-out coarse pixels
    assert np.all(np.isfinite(up[:, 5:]))


def test_supported_size_halves_only_textures_finer_than_the_photos():
    sc = sphere_scene(n_views=6, height=60, width=80, texture_size=256, seed=2)
    pixels = sum(int(m.sum()) for m in sc.problem.masks)
    size = pyramid.supported_size(sc.problem, 2.0)
    assert size < 256
    # The chosen size has at most 2 seen texels per pixel, twice that size more than 2.
    for n, ok in ((size, True), (2 * size, False)):
        seen = texture_domain(pyramid.with_texture_size(sc.problem, n)).n_unknowns
        assert (seen <= 2 * pixels) == ok, (n, seen, pixels)
    small = sphere_scene(n_views=6, height=60, width=80, texture_size=32, seed=2)
    assert pyramid.supported_size(small.problem, 2.0) == 32


def test_upsample_bilinear_is_exact_for_a_linear_albedo():
    sc = sphere_scene(n_views=6, height=60, width=80, texture_size=64, seed=2)
    layout = sc.problem.texture
    coarse_layout = pyramid.with_texture_size(sc.problem, 32).texture

    def linear(n):
        r, c = np.mgrid[0:n, 0:n]
        uv = uv_of_texel(r, c, n)
        return (0.2 + 0.5 * uv[..., 0] + 0.3 * uv[..., 1])[..., None].astype(np.float32)

    seen = coarse_layout.inside.copy()
    seen[:, :4] = False  # a part no camera saw stays unseen
    coarse = np.where(seen[..., None], linear(32), np.nan)
    fine, fine_seen = pyramid.upsample_bilinear(coarse, seen, layout)
    assert fine.shape == (64, 64, 1) and not fine_seen[:, :8].any()
    # Away from the unseen part and the texture's border, bilinear sampling of a linear function is exact.
    inner = fine_seen.copy()
    inner[:, :10] = inner[:, -1:] = inner[:1] = inner[-1:] = False
    np.testing.assert_allclose(fine[inner, 0], linear(64)[inner, 0], atol=1e-5)
    assert np.all(np.isnan(fine[~fine_seen]))


@pytest.mark.parametrize("n,size", [(5, 10), (48, 96), (48, 192), (7, 224), (48, 100)])
def test_upsampling_on_the_grid_matches_a_bilinear_lookup_per_texel(n, size):
    from core.geometry.bilinear import interpolate
    from core.geometry.texels import bilinear_texels, parent_texels, uv_of_texel

    rng = np.random.default_rng(n + size)
    seen = rng.random((n, n)) < 0.7
    coarse = np.where(seen[..., None], rng.random((n, n, 3)), np.nan).astype(np.float32)
    inside = rng.random((size, size)) < 0.8
    fine, fine_seen = pyramid.upsample_onto(coarse, seen, inside)
    # Each texel of ``inside`` whose coarse texel was seen, looked up at its centre among the seen corners.
    parent = parent_texels(size, n)
    r, c = np.nonzero(inside & seen[parent][:, parent])
    idx, w = bilinear_texels(uv_of_texel(r, c, size), seen)
    ok = w.sum(axis=1) > 0
    expect = np.full((size, size, 3), np.nan, np.float32)
    expect[r[ok], c[ok]] = interpolate(coarse.reshape(-1, 3), idx[ok], w[ok], nan_as_zero=True)
    np.testing.assert_array_equal(fine_seen, np.isfinite(expect[..., 0]))
    assert fine_seen.any() and not fine_seen.all()
    np.testing.assert_allclose(fine[fine_seen], expect[fine_seen], atol=1e-6)
    assert np.all(np.isnan(fine[~fine_seen]))


def test_upsampling_onto_a_texture_in_blocks_of_rows_gives_the_same_numbers(monkeypatch):
    from core.solve import pyramid

    rng = np.random.default_rng(8)
    coarse = rng.random((13, 13, 3)).astype(np.float32)
    coarse[rng.random((13, 13)) > 0.9] = np.nan
    seen = rng.random((13, 13)) > 0.25
    target = rng.random((40, 40)) > 0.3
    whole = pyramid.upsample_onto(coarse, seen, target)  # one block: 40 rows < _UPSAMPLE_ROWS
    monkeypatch.setattr(pyramid, "_UPSAMPLE_ROWS", 3)
    blocks = pyramid.upsample_onto(coarse, seen, target)
    np.testing.assert_array_equal(blocks[0].view(np.uint32), whole[0].view(np.uint32))  # NaN where unseen, too
    np.testing.assert_array_equal(blocks[1], whole[1])
    assert np.isfinite(whole[0][whole[1]]).all() and np.isnan(whole[0][~whole[1]]).all()
