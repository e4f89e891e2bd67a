"""Tests for core.geometry.texels: texel convention, UV rasterisation, seam pairs."""

import numpy as np
import pytest

from core.geometry.texels import (
    bilinear_texels,
    texel_index,
    texel_of_uv,
    texels_reached,
    texture_layout,
    uv_of_texel,
)

# ---------------------------------------------------------------- meshes


def quad(uv_rect=(0.0, 0.0, 1.0, 1.0), pos_of_uv=None):
    """Two triangles over a UV rectangle (u0, v0, u1, v1), sharing an edge."""
    u0, v0, u1, v1 = uv_rect
    corners = np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]])
    pos = np.c_[corners, np.zeros(4)] if pos_of_uv is None else pos_of_uv(corners)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    return corners[tris], pos[tris], tris


def cube(gap=0.02):
    """Unit cube, each face its own UV island in a 3x2 grid: every edge is a seam."""
    verts = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    tri_uv, tri_pos, tri_vert = [], [], []
    cell = 1.0 / 3.0
    for k, f in enumerate(faces):
        cx, cy = (k % 3) * cell, (k // 3) * cell
        rect = np.array(
            [
                [cx + gap, cy + gap],
                [cx + cell - gap, cy + gap],
                [cx + cell - gap, cy + cell - gap],
                [cx + gap, cy + cell - gap],
            ]
        )
        for t in ([0, 1, 2], [0, 2, 3]):
            tri_uv.append(rect[t])
            tri_pos.append(verts[np.array(f)[t]])
            tri_vert.append(np.array(f)[t])
    return np.array(tri_uv), np.array(tri_pos), np.array(tri_vert)


def uv_sphere(nu, nv, pad=0.01):
    """Latitude-longitude sphere of radius 1 with one UV seam at u = 0 / 1."""
    th = np.linspace(0, np.pi, nv + 1)
    ph = np.linspace(0, 2 * np.pi, nu + 1)
    tt, pp = np.meshgrid(th, ph, indexing="ij")
    pos = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], -1)
    uv = np.stack([pp / (2 * np.pi), 1 - tt / np.pi], -1) * (1 - 2 * pad) + pad
    vid = np.arange((nv + 1) * (nu + 1)).reshape(nv + 1, nu + 1)
    vid[:, -1] = vid[:, 0]  # the seam column is the same vertices
    i, j = [a.ravel() for a in np.meshgrid(np.arange(nv), np.arange(nu), indexing="ij")]
    corners = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)]
    idx = []
    for t in ([0, 1, 2], [0, 2, 3]):
        idx.append(np.stack([np.stack(corners[k], -1) for k in t], 1))
    idx = np.concatenate(idx)  # (T, 3, 2) grid indices
    r, c = idx[..., 0], idx[..., 1]
    return uv[r, c], pos[r, c], vid[r, c]


def seam_distances(layout):
    p = layout.texel_pos.reshape(-1, 3)
    a, b = layout.seam_pairs.T
    return np.linalg.norm(p[a] - p[b], axis=1)


# ---------------------------------------------------------------- convention


def test_texel_convention_and_inverse():
    n = 8
    row, col = texel_of_uv([[0.5 / n, 1 - 0.5 / n], [(3 + 0.5) / n, 1 - (5 + 0.5) / n]], n)
    np.testing.assert_allclose(row, [0, 5], atol=1e-12)
    np.testing.assert_allclose(col, [0, 3], atol=1e-12)
    rng = np.random.default_rng(0)
    uv = rng.random((50, 2))
    np.testing.assert_allclose(uv_of_texel(*texel_of_uv(uv, n), n), uv, atol=1e-12)


def test_texel_index_contains_point():
    n = 8
    # Texel (r=1, c=2) spans u in [2/8, 3/8], v in [6/8, 7/8].
    idx = texel_index(
        [[2.01 / n, 6.99 / n], [2.99 / n, 6.01 / n], [0.0, 0.0], [1.0, 1.0], [-0.01, 0.5], [0.5, 1.01], [np.nan, 0.5]],
        n,
    )
    assert idx.tolist() == [1 * n + 2, 1 * n + 2, (n - 1) * n, n - 1, -1, -1, -1]


def test_bilinear_texels_interpolate_linear_function():
    n = 16
    rng = np.random.default_rng(1)
    uv = rng.uniform(1.0 / n, 1 - 1.0 / n, (100, 2))  # away from the border
    idx, w = bilinear_texels(uv, np.ones((n, n), bool))
    r, c = np.divmod(np.arange(n * n), n)
    centre_uv = uv_of_texel(r, c, n)
    f = 3 * centre_uv[:, 0] - 2 * centre_uv[:, 1]
    np.testing.assert_allclose(w.sum(axis=1), 1, atol=1e-6)
    np.testing.assert_allclose((f[idx] * w).sum(axis=1), 3 * uv[:, 0] - 2 * uv[:, 1], atol=1e-5)
    # At the border, neighbours outside the texture get weight 0 and the rest are renormalised.
    idx, w = bilinear_texels([[0.1 / n, 0.5 + 0.25 / n]], np.ones((n, n), bool))  # col -0.4
    assert np.sum(w[0] == 0) == 2 and np.all(idx[0] >= 0)
    np.testing.assert_allclose(w[0].sum(), 1, atol=1e-6)
    # Texels that are not valid get weight 0 too; none valid gives all zeros.
    valid = np.ones((n, n), bool)
    valid[:, 0] = False
    idx, w = bilinear_texels([[1.0 / n, 0.5 + 0.25 / n]], valid)  # between columns 0 and 1
    assert np.all(w[0][idx[0] % n == 0] == 0) and np.isclose(w[0].sum(), 1)
    assert np.all(bilinear_texels([[0.5, 0.5]], np.zeros((n, n), bool))[1] == 0)


def test_bad_size_raises():
    with pytest.raises(ValueError, match="texture size"):
        texel_of_uv([0.5, 0.5], 0)


# ---------------------------------------------------------------- rasterisation


def test_unit_quad_covers_every_texel_with_correct_positions():
    n = 16
    # An affine UV -> world map, so interpolation must be exact.
    m = np.array([[2.0, 0.5, -1.0], [0.0, 1.5, 0.3]])
    tri_uv, tri_pos, tri_vert = quad(pos_of_uv=lambda uv: uv @ m + [1.0, 2.0, 3.0])
    layout = texture_layout(tri_uv, tri_pos, tri_vert, n)
    assert layout.inside.all()
    r, c = np.divmod(np.arange(n * n), n)
    expect = uv_of_texel(r, c, n) @ m + [1.0, 2.0, 3.0]
    np.testing.assert_allclose(layout.texel_pos.reshape(-1, 3), expect, atol=1e-5)
    assert layout.seam_pairs.shape == (0, 2)


def test_conservative_border_texels_are_inside_and_on_the_surface():
    n = 10
    # u in [0.27, 0.73]: centres of columns 3..6 are covered; columns 2 and 7
    # are needed by bilinear lookups in the quad; columns 0, 1, 8, 9 are not.
    tri_uv, tri_pos, tri_vert = quad((0.27, 0.27, 0.73, 0.73))
    layout = texture_layout(tri_uv, tri_pos, tri_vert, n)
    cols = np.flatnonzero(layout.inside.any(axis=0))
    rows = np.flatnonzero(layout.inside.any(axis=1))
    assert cols.tolist() == list(range(2, 8)) and rows.tolist() == list(range(2, 8))
    p = layout.texel_pos
    # Border texels are clamped onto the quad (world == uv here).
    np.testing.assert_allclose(p[5, 2, 0], 0.27, atol=1e-6)
    np.testing.assert_allclose(p[5, 7, 0], 0.73, atol=1e-6)
    np.testing.assert_allclose(p[5, 2, 1], 1 - 5.5 / n, atol=1e-6)
    assert np.all((p[layout.inside][:, :2] >= 0.27 - 1e-6) & (p[layout.inside][:, :2] <= 0.73 + 1e-6))


def test_margin_grows_islands():
    n = 20
    # Texel centres 7.5 .. 11.5 (exactly between centres): the bilinear
    # footprint gives columns 7..12, a margin of 2 texels 5..14.
    tri_uv, tri_pos, tri_vert = quad((0.4, 0.4, 0.6, 0.6))
    a = texture_layout(tri_uv, tri_pos, tri_vert, n).inside
    b = texture_layout(tri_uv, tri_pos, tri_vert, n, margin=2).inside
    assert a.sum() == 6 * 6 and a[7:13, 7:13].all()
    assert b.sum() == 10 * 10 and b[5:15, 5:15].all()


def test_bilinear_lookups_inside_triangles_have_data():
    n = 64
    tri_uv, tri_pos, tri_vert = cube()
    layout = texture_layout(tri_uv, tri_pos, tri_vert, n)
    rng = np.random.default_rng(2)
    bary = rng.dirichlet([1, 1, 1], size=(tri_uv.shape[0], 200))
    pts = np.einsum("tkj,tji->tki", bary, tri_uv).reshape(-1, 2)
    idx, w = bilinear_texels(pts, np.ones((n, n), bool))
    used = idx[w > 1e-6]
    assert np.all(used >= 0) and layout.inside.ravel()[used].all()
    # ...and the islands stay apart: the gutter between faces is not filled.
    assert not layout.inside.all()


def test_uv_outside_unit_square_is_clipped():
    n = 8
    tri_uv, tri_pos, tri_vert = quad((0.5, 0.5, 1.5, 1.5))
    layout = texture_layout(tri_uv, tri_pos, tri_vert, n)
    # Texel centres 3.5 .. 11.5 in x: columns 3..7 (rows 0..4), clipped at 8.
    assert layout.inside[:5, 3:].all() and layout.inside.sum() == 25
    with pytest.raises(ValueError, match="no triangle covers"):
        texture_layout(*quad((2.0, 2.0, 3.0, 3.0)), n)


def test_bad_input_raises():
    tri_uv, tri_pos, tri_vert = quad()
    with pytest.raises(ValueError, match="tri_pos"):
        texture_layout(tri_uv, tri_pos[:1], tri_vert, 8)
    bad = tri_uv.copy()
    bad[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match="triangle 1"):
        texture_layout(bad, tri_pos, tri_vert, 8)
    with pytest.raises(ValueError, match="integer"):
        texture_layout(tri_uv, tri_pos, tri_vert.astype(float), 8)
    with pytest.raises(ValueError, match="margin"):
        texture_layout(tri_uv, tri_pos, tri_vert, 8, margin=-1)


# ---------------------------------------------------------------- seams


def test_cube_seam_pairs_link_nearby_texels():
    n = 96
    gap = 0.02
    tri_uv, tri_pos, tri_vert = cube(gap)
    layout = texture_layout(tri_uv, tri_pos, tri_vert, n)
    texel_world = 1.0 / ((1 / 3 - 2 * gap) * n)  # face side / its size in texels
    pairs = layout.seam_pairs
    # 12 edges, each about 26 texels long: roughly one pair per texel.
    assert 12 * 20 <= len(pairs) <= 12 * 40
    assert np.all(pairs[:, 0] < pairs[:, 1])
    assert len(np.unique(pairs, axis=0)) == len(pairs)
    assert layout.inside.ravel()[pairs].all()
    d = seam_distances(layout)
    assert d.max() < 2 * texel_world
    # Each pair joins two different faces (islands lie in different cells).
    cell = np.floor(np.stack(np.divmod(pairs, n), -1) * 3 / n).astype(int)
    assert np.all(np.any(cell[:, 0] != cell[:, 1], axis=1))


def test_no_seam_pairs_without_seams():
    # A 4x4-quad grid plane, UVs continuous across all shared edges.
    k = 4
    g = np.stack(np.meshgrid(np.linspace(0, 1, k + 1), np.linspace(0, 1, k + 1), indexing="ij"), -1)
    vid = np.arange((k + 1) ** 2).reshape(k + 1, k + 1)
    tris = []
    for i in range(k):
        for j in range(k):
            a, b, c, d = vid[i, j], vid[i + 1, j], vid[i + 1, j + 1], vid[i, j + 1]
            tris += [[a, b, c], [a, c, d]]
    tris = np.array(tris)
    uv = g.reshape(-1, 2)[tris] * 0.8 + 0.1
    pos = np.c_[g.reshape(-1, 2), np.zeros((k + 1) ** 2)][tris]
    layout = texture_layout(uv, pos, tris, 32)
    assert layout.seam_pairs.shape == (0, 2)


def test_sphere_2048_is_sane():
    # Speed is a benchmark's business, not a test's (measured 1.1-1.9 s for this mesh on 2 cores).
    tri_uv, tri_pos, tri_vert = uv_sphere(128, 80)  # 20480 triangles
    assert tri_uv.shape[0] == 20480
    n = 2048
    layout = texture_layout(tri_uv, tri_pos, tri_vert, n)
    inside = layout.inside
    # The island spans [0.01, 0.99]^2 (plus half a texel of conservative border).
    lo, hi = int(np.floor(0.01 * n - 0.5)), int(np.ceil(0.99 * n - 0.5))
    assert inside[lo + 1 : hi, lo + 1 : hi].all() and not inside[:lo].any() and not inside[:, hi + 1 :].any()
    r = np.linalg.norm(layout.texel_pos[inside], axis=1)
    assert np.all((r > 0.999) & (r < 1.0 + 1e-5))  # on or just inside the unit sphere
    # The u seam: pairs join the left and right columns of the island.
    cols = np.sort(layout.seam_pairs % n, axis=1)
    assert len(cols) > 1500
    assert np.all((cols[:, 0] < lo + 3) & (cols[:, 1] > hi - 3))
    texel_world = 2 * np.pi / (0.98 * n)
    assert seam_distances(layout).max() < 2 * texel_world


def test_a_stretched_triangle_across_islands_does_not_move_their_texels():
    # Two islands side by side in UV; an n-gon whose corners lie in both becomes a triangle spanning the gap
    # (and part of the right island). It may fill texels no other face covers, never take theirs.
    from core.geometry.texels import uv_stretched

    n = 32
    left_uv = np.array([[[0.05, 0.05], [0.45, 0.05], [0.45, 0.95]], [[0.05, 0.05], [0.45, 0.95], [0.05, 0.95]]])
    right_uv = left_uv + [0.5, 0.0]
    pos = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]]], float)
    tri_uv = np.concatenate([left_uv, right_uv])
    tri_pos = np.concatenate([pos, pos + [0, 0, 5.0]])
    tri_vert = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    base = texture_layout(tri_uv, tri_pos, tri_vert, n)
    span_uv = np.array([[[0.45, 0.5], [0.95, 0.3], [0.95, 0.7]]])  # reaches into the right island
    span_pos = np.array([[[1, 0.5, 0], [1.01, 0.5, 0.0], [1.0, 0.51, 0]]])
    layout = texture_layout(
        np.concatenate([tri_uv, span_uv]),
        np.concatenate([tri_pos, span_pos]),
        np.concatenate([tri_vert, [[1, 8, 9]]]),
        n,
    )
    assert uv_stretched(np.concatenate([tri_uv, span_uv]), np.concatenate([tri_pos, span_pos])).tolist() == [
        False
    ] * 4 + [True]
    both = base.inside
    np.testing.assert_array_equal(layout.texel_pos[both], base.texel_pos[both])
    assert (layout.inside & ~base.inside).any()  # the gap texels it alone covers
    np.testing.assert_array_equal(layout.seam_pairs, base.seam_pairs)


def test_a_sliver_across_islands_counts_as_stretched_by_its_long_edge():
    # An n-gon's triangle can be a sliver in UV: its area per surface area looks normal, but one edge runs
    # from one island to the other. It gets the low priority and makes no seam pairs all the same.
    from core.geometry.texels import STRETCH_FACTOR, triangle_areas, uv_stretched

    left_uv = np.array([[[0.05, 0.05], [0.45, 0.05], [0.45, 0.95]], [[0.05, 0.05], [0.45, 0.95], [0.05, 0.95]]])
    pos = np.array([[[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 0, 0], [1, 1, 0], [0, 1, 0]]], float)
    tri_uv = np.concatenate([left_uv, left_uv + [0.5, 0.0]])
    tri_pos = np.concatenate([pos, pos + [0, 0, 5.0]])
    tri_vert = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    sliver_uv = np.array([[[0.45, 0.5], [0.95, 0.505], [0.95, 0.5]]])  # 0.5 long, 0.005 wide in UV
    sliver_pos = np.array([[[1, 0.5, 0], [1.04, 0.5, 0], [1.02, 0.5346, 0]]])  # 0.04 a side on the surface
    all_uv, all_pos = np.concatenate([tri_uv, sliver_uv]), np.concatenate([tri_pos, sliver_pos])
    uv_area, area = triangle_areas(all_uv, all_pos)
    ratio = uv_area / area
    assert ratio[4] < STRETCH_FACTOR * np.median(ratio)  # the area alone would not tell
    assert uv_stretched(all_uv, all_pos).tolist() == [False] * 4 + [True]
    for n in (32, 128):
        base = texture_layout(tri_uv, tri_pos, tri_vert, n)
        layout = texture_layout(all_uv, all_pos, np.concatenate([tri_vert, [[1, 8, 9]]]), n)
        np.testing.assert_array_equal(layout.texel_pos[base.inside], base.texel_pos[base.inside])
        np.testing.assert_array_equal(layout.seam_pairs, base.seam_pairs)


def test_row_spans_keep_every_texel_of_the_whole_box(monkeypatch):
    """The rasteriser's runs per row drop no texel that testing each triangle's whole box would keep."""
    from core.geometry import texels

    rng = np.random.default_rng(3)
    # Random triangles, some with axis-aligned edges (a zero coefficient) and some slivers.
    tri_uv = rng.uniform(-0.05, 1.05, (60, 3, 2))
    tri_uv[:10, 1, 1] = tri_uv[:10, 0, 1]  # a horizontal edge
    tri_uv[10:20, 2, 0] = tri_uv[10:20, 0, 0]  # a vertical edge
    tri_uv[20:25, 2] = tri_uv[20:25, 0] + 1e-3 * (tri_uv[20:25, 1] - tri_uv[20:25, 0])  # slivers
    tri_pos = np.concatenate([tri_uv, rng.uniform(0, 1, (60, 3, 1))], axis=2)
    tri_vert = np.arange(180).reshape(60, 3)

    def whole_box(a, b, c, slack, lo, hi, ok):
        w = np.where(ok, np.maximum(hi[:, 0] - lo[:, 0] + 1, 0), 0)
        h = np.where(ok & (w > 0), np.maximum(hi[:, 1] - lo[:, 1] + 1, 0), 0)
        tri = np.repeat(np.arange(len(h)), h)
        row = np.repeat(lo[:, 1], h) + (np.arange(tri.size) - np.repeat(np.cumsum(h) - h, h))
        return tri, row, lo[tri, 0], w[tri]

    for size in (17, 64):
        spans = texture_layout(tri_uv, tri_pos, tri_vert, size)
        monkeypatch.setattr(texels, "_row_spans", whole_box)
        boxes = texture_layout(tri_uv, tri_pos, tri_vert, size)
        monkeypatch.undo()
        assert spans.inside.sum() > 0.3 * size * size
        assert np.array_equal(spans.texel_pos, boxes.texel_pos, equal_nan=True)
        assert np.array_equal(spans.seam_pairs, boxes.seam_pairs)


def test_texels_reached_is_np_unique_with_its_inverse():
    # A photo's pixels in row order reach a texture's texels in runs; random indices, one, none.
    rng = np.random.default_rng(8)
    rows, cols = np.divmod(np.arange(300 * 200), 200)
    runs = ((40 + 0.7 * rows + 0.2 * cols).astype(np.int64) * 512 + (90 + 0.6 * cols).astype(np.int64))[::-1]
    for texel in (runs, rng.integers(0, 2**40, 5000), np.array([7]), np.zeros(0, np.int64)):
        texels, at = texels_reached(texel)
        expect, expect_at = np.unique(texel, return_inverse=True)
        assert np.array_equal(texels, expect) and np.array_equal(at, expect_at)
        assert np.array_equal(texels[at], texel)
