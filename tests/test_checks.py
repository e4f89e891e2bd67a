"""core.checks: photos that cannot be images of light on the mesh are refused before the solve."""
import numpy as np
import pytest

from core.checks import NEGATIVE_MAX_SHARE, check_photos
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
    k = int(NEGATIVE_MAX_SHARE * masks[0].sum())   # at the limit: still accepted
    rows, cols = np.nonzero(masks[0])
    photos[0][rows[:k], cols[:k], 1] = -0.2
    photos[0][0, 0] = -1.0                          # off the mesh: not counted
    warnings = check_photos(names, photos, masks)
    assert warnings == [f"camera 'cam0': {k} negative pixels on the mesh were left out"]
    assert not masks[0][rows[:k], cols[:k]].any() and masks[0][rows[k:], cols[k:]].all()
    photos[1][rows[:k + 1], cols[:k + 1], 0] = -0.2   # one more than the limit
    with pytest.raises(DelightError, match="'cam1'"):
        check_photos(names, photos, masks)
