"""core.io.envmap: the world lighting as an equirectangular image in Blender's convention, at the right scale."""

from __future__ import annotations

import numpy as np
import pytest

from core.geometry.sh import DIFFUSE, sh_basis
from core.io.envmap import (
    add_sun,
    envmap_image,
    equirect_directions,
    equirect_uv,
    project_envmap,
    radiance_sh,
    world_lighting,
)

# A soft sky brighter towards +Z, -Y and +X, with some band 2: positive everywhere, so nothing is clamped.
SIGMA = np.array(
    [
        [0.25, -0.2, 0.3, 1.0, 0.05, -0.08, 0.04, 0.06, 0.03],
        [0.2, -0.25, 0.25, 0.9, -0.04, 0.05, 0.02, -0.03, 0.05],
        [0.15, -0.1, 0.35, 0.8, 0.02, 0.03, -0.05, 0.04, -0.02],
    ]
)


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def test_pixel_directions_follow_blenders_mapping_and_cover_the_sphere():
    dirs, omega = equirect_directions(64, 32)
    assert dirs.shape == (32, 64, 3) and omega.shape == (32, 64)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=-1), 1.0)
    assert abs(omega.sum() - 4 * np.pi) < 1e-12
    u, v = equirect_uv(dirs)
    np.testing.assert_allclose(u, np.broadcast_to((np.arange(64) + 0.5) / 64, (32, 64)), atol=1e-12)
    np.testing.assert_allclose(v, np.broadcast_to(1 - (np.arange(32)[:, None] + 0.5) / 32, (32, 64)), atol=1e-12)
    # Cycles' direction_to_equirectangular: u = (atan2(y, x) - pi) / -2pi, v = (acos(z) - pi) / -pi.
    for d, uv in (((1, 0, 0), (0.5, 0.5)), ((0, 1, 0), (0.25, 0.5)), ((0, -1, 0), (0.75, 0.5)), ((0, 0, 1), (0.5, 1))):
        np.testing.assert_allclose(equirect_uv(np.array(d, float)), uv, atol=1e-12)


def test_the_image_projects_back_onto_its_coefficients():
    c = radiance_sh(SIGMA)
    img = envmap_image(c)
    assert img.shape == (128, 256, 3) and img.dtype == np.float32 and img.min() > 0
    # Midpoint quadrature in latitude: exact to about 1e-4 at this size.
    np.testing.assert_allclose(project_envmap(img), c, atol=5e-4)
    np.testing.assert_allclose(project_envmap(envmap_image(c, size=(512, 256))), c, atol=1.5e-4)


@pytest.mark.parametrize("d", [(1, 0, 0), (0, 1, 0), (0.3, 0.4, 0.8), (0.6, -0.7, -0.35), (-0.9, 0.2, 0.1)])
def test_a_light_from_one_direction_peaks_where_blender_reads_that_direction(d):
    d = unit(d)
    # The 9-coefficient part of a point light in direction d: its projection basis(d) / |basis|^2.
    delta = sh_basis(d, np.float64) / np.array([1 / 3, 1 / 3, 1 / 3, 1, 1 / 15, 1 / 15, 1 / 15, 4 / 15, 4 / 5])
    img = envmap_image(np.stack([delta, 0.5 * delta, 0.25 * delta]) / (4 * np.pi), size=(256, 128))
    row, col = np.unravel_index(np.argmax(img[..., 0]), img.shape[:2])
    # Blender's pixel for d, from Cycles' formula written out (not from the module).
    u = 0.5 - np.arctan2(d[1], d[0]) / (2 * np.pi)
    v = 1 - np.arccos(d[2]) / np.pi
    want_row, want_col = int((1 - v) * 128), int(u * 256) % 256
    assert abs(row - want_row) <= 1
    assert min(abs(col - want_col), 256 - abs(col - want_col)) <= 1 + int(1 / max(np.sin(np.arccos(d[2])), 0.1))
    assert np.allclose(img[..., 1], 0.5 * img[..., 0], atol=1e-6)


def test_a_lambertian_albedo_lit_by_the_image_gets_the_shading():
    """Irradiance / pi by quadrature over the image, against sigma . nu(n): the pi / A_l factors."""
    img = envmap_image(radiance_sh(SIGMA)).astype(np.float64)
    dirs, omega = equirect_directions(256, 128)
    normals = np.array([unit(n) for n in [(0, 0, 1), (1, 0, 0), (0, -1, 0), (0.5, 0.5, -0.7), (-0.2, 0.9, 0.3)]])
    cos = np.maximum(np.einsum("hwk,nk->nhw", dirs, normals), 0.0)
    irradiance = np.einsum("nhw,hw,hwc->nc", cos, omega, img)
    np.testing.assert_allclose(irradiance / np.pi, sh_basis(normals, np.float64) @ SIGMA.T, rtol=2e-3)
    # The ambient-only lighting is a sky of radiance 1: a white diffuse surface renders 1.
    np.testing.assert_allclose(envmap_image(radiance_sh(DIFFUSE[None])), 1.0)


def test_negative_radiance_is_clamped_in_the_image_only():
    c = radiance_sh(np.array([[0.0, 0.0, 1.0, 0.5, 0, 0, 0, 0, 0]]))  # below the horizon: 0.5 - 1.5 < 0
    img = envmap_image(c)
    assert img.min() == 0.0 and (img[-1] == 0).all() and img[0].min() > 1.9
    with pytest.raises(ValueError, match="expected"):
        envmap_image(np.zeros((2, 9)))


def test_world_lighting_is_the_views_mean():
    gains = np.array([1.0, 0.5, 1.5])[:, None, None]
    views = gains * SIGMA[None]
    np.testing.assert_allclose(world_lighting(views), SIGMA)  # mean gain 1


def test_a_sun_disc_lights_a_lambertian_albedo_to_its_strength():
    """A surface facing the sun gets the sky's shading plus the sun's strength, by quadrature over the image."""
    sun, strength = unit((0.3, -0.5, 0.8)), np.array([2.0, 1.5, 1.0])
    sky = envmap_image(radiance_sh(SIGMA)).astype(np.float64)
    img = add_sun(sky, sun, strength).astype(np.float64)
    dirs, omega = equirect_directions(256, 128)
    irradiance = np.einsum("hw,hw,hwc->c", np.maximum(dirs @ sun, 0.0), omega, img - sky)
    # Within the disc's 2.5 degrees the cosine is at least 0.999.
    np.testing.assert_allclose(irradiance / np.pi, strength, rtol=2e-3)
    # Nothing else changes, and a negative strength adds nothing.
    assert np.count_nonzero((img != sky).any(axis=2)) < 40
    np.testing.assert_array_equal(add_sun(sky, sun, -strength), sky.astype(np.float32))
