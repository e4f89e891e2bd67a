import numpy as np

from core.io.photos import CLIP_CODE, clipped_pixels
from core.pipeline import _unclipped


def test_clipped_pixels_are_those_near_the_8bit_ceiling_in_any_channel():
    codes = np.array([[[255, 10, 10], [10, 10, CLIP_CODE]], [[CLIP_CODE - 1, 200, 0], [10, 10, 10]]])
    assert clipped_pixels(codes / 255.0).tolist() == [[True, True], [False, False]]


def test_a_view_keeps_its_mask_when_everything_clipped():
    mask = np.array([[True, True], [False, True]])
    clipped = np.array([[True, False], [True, False]])
    assert _unclipped(mask, clipped).tolist() == [[False, True], [False, True]]
    assert _unclipped(mask, np.ones((2, 2), bool)).tolist() == mask.tolist()
    assert _unclipped(mask, None) is mask
