"""core.evaluate.pictures: the pixel arrays of the add-on's previews and the demo's figures."""

from __future__ import annotations

import numpy as np
import pytest

from core.evaluate.pictures import BACKGROUND, grid, lighting_spheres, shade_sphere, sphere_normals, to_srgb8
from core.geometry.sh import DIFFUSE
from core.io.photos import linear_to_srgb, srgb_to_linear


def test_srgb_curve_round_trips_every_8_bit_code():
    codes = np.arange(256)
    back = np.round(linear_to_srgb(srgb_to_linear(codes / 255.0)) * 255)
    np.testing.assert_array_equal(back, codes)
    np.testing.assert_allclose(linear_to_srgb([2.0, 1.0, -1.0, 0.0]), [1, 1, 0, 0], atol=1e-12)  # clipped


def test_srgb_tone_map_matches_the_standard_curve():
    out = to_srgb8(np.array([[[0.0, 0.0031308, 0.5], [1.0, 2.0, np.nan]]]))
    np.testing.assert_array_equal(out[0, 0], [0, 10, 188])  # 0.5 linear -> 0.7354 sRGB -> 188
    np.testing.assert_array_equal(out[0, 1], BACKGROUND)  # NaN -> background
    np.testing.assert_array_equal(to_srgb8(np.full((1, 1), 1.0), white=2.0), [[[188, 188, 188]]])  # grey, exposed


def test_sphere_shading_follows_the_sh_basis():
    n, inside = sphere_normals(32)
    assert np.allclose(np.linalg.norm(n[inside], axis=1), 1)
    assert n[0, 16, 2] > 0.8 and n[16, 0, 0] < -0.8 and n[16, 16, 1] < -0.99  # top +Z, left -X, centre faces -Y
    np.testing.assert_allclose(shade_sphere(DIFFUSE, 32)[inside], 1.0)
    top_light = np.zeros(9)
    top_light[2], top_light[3] = 0.5, 1.0  # brighter towards +Z
    s = shade_sphere(top_light, 32)[..., 0]
    assert s[4, 16] > s[16, 16] > s[28, 16]
    assert np.isnan(s[0, 0]) and np.isnan(s[31, 31])  # corners are outside the disc


def test_lighting_spheres_share_one_exposure():
    dim, bright = np.tile(DIFFUSE, (3, 1)), 3 * np.tile(DIFFUSE, (3, 1))
    pics = lighting_spheres(np.stack([dim, bright]), size=20)
    assert pics.shape == (2, 20, 20, 3) and pics.dtype == np.uint8
    _, inside = sphere_normals(20)
    assert np.all(pics[0][inside] < pics[1][inside])  # the brighter light stays brighter
    np.testing.assert_array_equal(pics[:, ~inside], np.broadcast_to(BACKGROUND, (2, (~inside).sum(), 3)))
    # A light from the right (+X) lights the right of the sphere.
    side = np.zeros((1, 1, 9))
    side[0, 0, 3], side[0, 0, 0] = 1.0, 0.8  # constant + x (the basis of core.geometry.sh)
    p = lighting_spheres(side, size=20)[0, 10, :, 0]
    assert p[17] > p[10] > p[2]


def test_grid_places_pictures_in_rows():
    a = np.full((4, 5, 3), 100, np.uint8)
    b = np.full((6, 3, 3), 200, np.uint8)
    g = grid([a, b, a], columns=2, gap=1)
    # Cells: column widths 5 and 3, row heights 6 and 4, one pixel apart and around.
    assert g.shape == (1 + 6 + 1 + 4 + 1, 1 + 5 + 1 + 3 + 1, 3)
    assert (g[1:5, 1:6] == 100).all() and (g[1:7, 7:10] == 200).all() and (g[8:12, 1:6] == 100).all()
    assert (g[5:7, 1:6] == BACKGROUND).all() and (g[8:12, 7:10] == BACKGROUND).all()
    with pytest.raises(ValueError):
        grid([])


def test_a_sphere_under_a_sun_is_brighter_towards_it():

    sh = np.zeros((1, 10))
    sh[0, 3], sh[0, 9] = 0.5, 2.0  # an even sky and a sun
    sun = np.array([0.0, -1.0, 0.0])  # towards the viewer: the disc's centre
    out = shade_sphere(sh, 33, sun)
    n, inside = sphere_normals(33)
    np.testing.assert_allclose(out[inside, 0], 0.5 + 2.0 * np.maximum(n[inside] @ sun, 0.0), rtol=1e-6)
    assert abs(out[16, 16, 0] - 2.5) < 0.01
