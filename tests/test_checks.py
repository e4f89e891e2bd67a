"""core.checks: photos that cannot be images of light on the mesh are refused before the solve."""

import numpy as np
import pytest

from core.checks import NEGATIVE_MAX_SHARE, check_photos, check_uv_layout
from core.errors import DelightError


def views(n=3, shape=(20, 30)):
    rng = np.random.default_rng(0)
    photos = [rng.uniform(0.1, 0.9, shape + (3,)).astype(np.float32) for _ in range(n)]
    masks = [np.zeros(shape, bool) for _ in range(n)]
    for m in masks:
        m[5:15, 5:25] = True
    return [f"cam{i}" for i in range(n)], photos, masks


def test_good_photos_pass_untouched():
    names, photos, masks = views()
    before = [m.copy() for m in masks]
    assert check_photos(names, photos, masks) == []
    assert all(np.array_equal(a, b) for a, b in zip(masks, before))


def test_a_negated_photo_is_refused():
    names, photos, masks = views()
    photos[1] = -photos[1]
    with pytest.raises(DelightError, match="'cam1': 100 % of its photo's pixels on the mesh are negative"):
        check_photos(names, photos, masks)


def test_a_black_photo_is_refused():
    names, photos, masks = views()
    photos[2][:] = 0.0
    with pytest.raises(DelightError, match="'cam2': its photo is black"):
        check_photos(names, photos, masks)


def test_a_few_negative_pixels_are_left_out_with_a_warning():
    names, photos, masks = views()
    k = int(NEGATIVE_MAX_SHARE * masks[0].sum())  # at the limit: still accepted
    rows, cols = np.nonzero(masks[0])
    photos[0][rows[:k], cols[:k], 1] = -0.2
    photos[0][0, 0] = -1.0  # off the mesh: not counted
    warnings = check_photos(names, photos, masks)
    assert warnings == [f"camera 'cam0': {k} negative pixels on the mesh were left out"]
    assert not masks[0][rows[:k], cols[:k]].any() and masks[0][rows[k:], cols[k:]].all()
    photos[1][rows[: k + 1], cols[: k + 1], 0] = -0.2  # one more than the limit
    with pytest.raises(DelightError, match="'cam1'"):
        check_photos(names, photos, masks)


def grid_mesh(k=8):
    """A k x k grid of unit squares in the plane z = 0, two triangles each, UV = position / k."""
    tris = []
    for i in range(k):
        for j in range(k):
            a, b, c, d = (i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)
            tris += [(a, b, c), (a, c, d)]
    xy = np.array(tris, np.float64)
    pos = np.concatenate([xy, np.zeros(xy.shape[:2] + (1,))], axis=2)
    return (xy / k * 0.9 + 0.05).astype(np.float32), pos


def test_a_clean_uv_layout_gives_no_warning():
    uv, pos = grid_mesh()
    assert check_uv_layout(uv, pos, 64) == []


def test_overlapping_zero_area_and_stretched_faces_are_measured():
    uv, pos = grid_mesh()
    folded = uv.copy()
    folded[:32] = folded[32:64]  # a quarter of the faces on top of another quarter
    (w,) = check_uv_layout(folded, pos, 64)
    assert "overlapping UV islands" in w and float(w.split("UV layout: ")[1].split(" %")[0]) > 20
    flat = uv.copy()
    flat[:10] = flat[:10, :1]  # 10 faces collapsed to a point
    (w,) = check_uv_layout(flat, pos, 64)
    assert w.startswith("UV layout: 10 faces (7.8 % of the surface) have no area")
    stretched = uv.copy()
    stretched[5, 1:] = ((0.95, 0.05), (0.95, 0.95))  # one face spans the whole map
    warnings = check_uv_layout(stretched, pos, 64)
    assert any("1 faces (0.8 % of the surface) are stretched" in w for w in warnings)
