import numpy as np
import pytest

from core.solve.discretization import image_domain
from core.solve.problem import Correspondences, Problem, row_blocks, stacked_rows


def _views(m=2, h=6, w=7):
    img = np.full((h, w, 3), 0.5, np.float32)
    mask = np.ones((h, w), bool)
    nrm = np.zeros((h, w, 3), np.float32)
    nrm[..., 2] = 1
    return [img.copy() for _ in range(m)], [mask.copy() for _ in range(m)], [nrm.copy() for _ in range(m)]


def test_valid_problem():
    p = Problem(*_views())
    assert p.n_views == 2 and p.channels == 3


def _expect(match, **changes):
    imgs, masks, nrms = _views()
    kw = dict(images=imgs, masks=masks, normals=nrms)
    for f in changes.values():
        f(kw)
    with pytest.raises(ValueError, match=match):
        Problem(**kw)


def test_nan_pixels():
    _expect("view 1.*NaN", images=lambda kw: kw["images"][1].__setitem__((2, 3, 0), np.nan))


def test_nan_outside_the_mask_is_ignored():
    imgs, masks, nrms = _views()
    imgs[0][0, 0] = np.nan
    masks[0][0, 0] = False
    Problem(imgs, masks, nrms)


def test_empty_mask():
    _expect("view 0.*empty", masks=lambda kw: kw["masks"][0].fill(False))


def test_zero_normals():
    _expect("view 1.*unit length", normals=lambda kw: kw["normals"][1].__setitem__((1, 1), 0))


def test_shape_mismatch():
    _expect("view 0.*mask shape", masks=lambda kw: kw["masks"].__setitem__(0, np.ones((5, 7), bool)))
    _expect("view 1.*normals shape", normals=lambda kw: kw["normals"].__setitem__(1, np.ones((6, 7, 2))))
    _expect("channels", images=lambda kw: kw["images"].__setitem__(1, np.ones((6, 7, 1))))


def test_clipped_pixels_must_match_their_photos():
    imgs, masks, nrms = _views()
    with pytest.raises(ValueError, match=r"view 1.*clipped shape \(6, 6\), expected \(6, 7\)"):
        Problem(imgs, masks, nrms, clipped=[None, np.zeros((6, 6), bool)])
    with pytest.raises(ValueError, match="1 clipped for 2 images"):
        Problem(imgs, masks, nrms, clipped=[np.zeros((6, 7), bool)])
    # A view without clipping (a float photo) has none; no view with any: no clipping at all.
    p = Problem(imgs, masks, nrms, clipped=[None, np.ones((6, 7), bool)])
    assert not p.clipped[0].any() and p.clipped[1].all()
    assert Problem(imgs, masks, nrms, clipped=[None, None]).clipped is None


def test_correspondence_indices_out_of_range():
    imgs, masks, nrms = _views()
    for corr, match in [
        (Correspondences([0], [42], [5], [[1.0, 1.0]]), "view_b index out of range"),
        (Correspondences([0], [420], [1], [[1.0, 1.0]]), "pixel_a 420 out of range"),
        (Correspondences([0], [4], [1], [[10.0, 1.0]]), "outside view 1"),
    ]:
        with pytest.raises(ValueError, match=match):
            Problem(imgs, masks, nrms, correspondences=corr)


def test_a_transfer_of_order_2_and_a_sun_column_is_accepted_and_other_widths_are_not():
    imgs, masks, nrms = _views()
    rows = [int(m.sum()) for m in masks]
    assert Problem(imgs, masks, nrms, transfer=[np.zeros((n, 10), np.float32) for n in rows]).n_views == 2
    with pytest.raises(ValueError, match="10, 16 or 25"):
        Problem(imgs, masks, nrms, transfer=[np.zeros((n, 11), np.float32) for n in rows])


def test_a_transfer_has_a_row_per_masked_pixel():
    # Held per masked pixel, not as (H, W, K) maps: at the 2K case's size that is a quarter of the memory.
    imgs, masks, nrms = _views()
    with pytest.raises(ValueError, match="one row per masked pixel"):
        Problem(imgs, masks, nrms, transfer=[np.zeros(m.shape + (9,), np.float32) for m in masks])
    short = [np.zeros((int(m.sum()) - 1, 9), np.float32) for m in masks]
    with pytest.raises(ValueError, match="one row per masked pixel"):
        Problem(imgs, masks, nrms, transfer=short)
    bad = [np.zeros((int(m.sum()), 9), np.float32) for m in masks]
    bad[1][0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        Problem(imgs, masks, nrms, transfer=bad)


def test_stacked_rows_gives_back_the_array_of_row_blocks_and_copies_anything_else():
    blocks = row_blocks([3, 0, 4], 10)
    assert [b.shape for b in blocks] == [(3, 10), (0, 10), (4, 10)]
    for i, b in enumerate(blocks):
        b[:] = i
    whole = stacked_rows(blocks)
    assert whole.shape == (7, 10) and whole is blocks[0].base  # no copy
    assert np.array_equal(whole[:, 0], [0, 0, 0, 2, 2, 2, 2])
    # Separate arrays, blocks out of order, or not all of the array: a new array, the same rows.
    for other in ([b.copy() for b in blocks], blocks[::-1], blocks[:1]):
        joined = stacked_rows(other)
        assert not np.shares_memory(joined, whole)
        assert np.array_equal(joined, np.concatenate(other))


def test_the_discretization_holds_a_transfer_of_row_blocks_without_a_copy():
    imgs, masks, nrms = _views()
    transfer = row_blocks([int(m.sum()) for m in masks], 10)
    for i, rows in enumerate(transfer):
        rows[:] = np.arange(10) + i
    d = image_domain(Problem(imgs, masks, nrms, transfer=transfer))
    assert d.nu is transfer[0].base
    copied = image_domain(Problem(imgs, masks, nrms, transfer=[t.copy() for t in transfer]))
    assert np.array_equal(copied.nu, d.nu) and not np.shares_memory(copied.nu, d.nu)
