"""core.masks.masked: the pixels under a mask, as boolean indexing gives them."""

import numpy as np
import pytest

from core.masks import masked


@pytest.mark.parametrize("shape", [(7, 9), (7, 9, 2), (7, 9, 3), (7, 9, 2, 2)])
def test_masked_pixels_are_boolean_indexings_in_the_same_order(shape):
    rng = np.random.default_rng(5)
    a = rng.random(shape).astype(np.float32)
    mask = rng.random(shape[:2]) > 0.4
    got = masked(a, mask)
    np.testing.assert_array_equal(got, a[mask])
    assert got.dtype == a.dtype and got.flags.c_contiguous
    np.testing.assert_array_equal(masked(a[:, ::-1], mask), a[:, ::-1][mask])  # a view that is not contiguous
    assert masked(a, np.zeros(shape[:2], bool)).shape == (0, *shape[2:])
