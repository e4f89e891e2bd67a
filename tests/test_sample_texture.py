"""core.texture.sample: the texture seen by each view's pixels."""

import numpy as np
import pytest

from core.texture import sample_texture


def test_sample_texture_reads_texel_centres_and_interpolates():
    n = 8
    tex = np.zeros((n, n, 1), np.float32)
    tex[..., 0] = np.arange(n)[None, :] + 10 * np.arange(n)[:, None]  # value = col + 10 row
    r, c = np.array([0, 3, 7]), np.array([0, 5, 2])
    uv = np.stack([(c + 0.5) / n, 1 - (r + 0.5) / n], axis=1).reshape(1, 3, 2)
    got = sample_texture(tex, uv, np.ones((1, 3), bool))
    np.testing.assert_allclose(got[0, :, 0], c + 10 * r, atol=1e-5)
    mid = np.array([[[(2 + 1.0) / n, 1 - (1 + 0.5) / n]]])  # halfway between cols 2 and 3 of row 1
    assert sample_texture(tex, mid, np.ones((1, 1), bool))[0, 0, 0] == pytest.approx(12.5)
    assert np.isnan(sample_texture(tex, uv, np.zeros((1, 3), bool))).all()
