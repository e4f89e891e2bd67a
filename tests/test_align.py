"""The photos' alignment (core.geometry.align) on synthetic views of a textured plane with known image shifts."""

import numpy as np
import pytest
from scipy import ndimage

from core.geometry.align import MIN_SHIFT_PX, photo_shifts, shifted_camera
from core.geometry.camera import Camera
from core.geometry.texels import pixel_matched_size
from core.texture.sample import sample_texture

H, W, N = 120, 160, 256


def _texture(seed=0):
    """A fine random albedo (features of a few texels), RGB."""
    rng = np.random.default_rng(seed)
    t = ndimage.gaussian_filter(rng.random((N, N, 3)), (1.2, 1.2, 0))
    return (0.2 + 3.0 * (t - t.mean())).clip(0.02, 1).astype(np.float32)


def _uv(x, y, offset):
    """A plane seen head on: pixel (x, y) shows UV ((x + ox) / 200, 1 - (y + oy) / 200)."""
    return np.stack([(x + offset[0]) / 200.0, 1.0 - (y + offset[1]) / 200.0], axis=-1).astype(np.float32)


def _views(shifts, split=None, seed=0):
    """Photos, masks and UVs of views of one texture; view i's photo shows at ``x + shifts[i]`` what its UV says
    is at ``x``, under a smooth shading and a gain of its own. ``split``: {view: the shift of its right half}."""
    tex = _texture(seed)
    rng = np.random.default_rng(seed + 1)
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    photos, masks, uvs = [], [], []
    for i, s in enumerate(shifts):
        offset = rng.uniform(0, 30, 2)
        sx = np.full_like(x, s[0])
        sy = np.full_like(y, s[1])
        if split and i in split:
            right = x >= W / 2
            sx[right], sy[right] = split[i]
        shown = _uv(x - sx, y - sy, offset)
        full = np.ones((H, W), bool)
        shading = (0.6 + 0.4 * np.cos(0.02 * x + i) * np.sin(0.015 * y + 2 * i))[..., None]
        photos.append((rng.uniform(0.7, 1.3) * shading * sample_texture(tex, shown, full)).astype(np.float32))
        masks.append(full)
        uvs.append(_uv(x, y, offset))
    return photos, masks, uvs


def test_shifts_of_photos_whose_cameras_are_off_are_found():
    true = np.array([[0.0, 0.0], [0.8, -0.5], [0.0, 0.0], [-0.6, 0.9], [0.0, 0.0], [1.1, 0.3], [0.0, 0.0]])
    found = photo_shifts(*_views(true), texture_size=N)
    moved = np.hypot(*true.T) > 0
    # The others' texture is made from photos that are themselves off: the shifts are found up to their mean.
    err = (found.measured - found.measured[~moved].mean(axis=0)) - true
    assert np.abs(err).max() < 0.15, err
    assert found.applied[moved].all()
    assert not found.applied[~moved].any()
    assert np.array_equal(found.shift[~moved], np.zeros((int((~moved).sum()), 2)))


def test_the_shifts_do_not_depend_on_the_texture_size_asked_for():
    # The others' texture is made at the photos' own density: on a texture finer than the photos (pixels 10
    # texels apart at 2048^2) a texel would hold one pixel of one photo, and nothing would line up.
    true = np.array([[0.0, 0.0], [0.8, -0.5], [0.0, 0.0], [-0.6, 0.9], [0.0, 0.0], [1.1, 0.3], [0.0, 0.0]])
    views = _views(true)
    found = photo_shifts(*views)
    at_1024 = photo_shifts(*views, texture_size=1024)
    assert np.array_equal(at_1024.measured, found.measured)
    assert at_1024.texture_size == found.texture_size < N
    moved = np.hypot(*true.T) > 0
    err = (found.measured - found.measured[~moved].mean(axis=0)) - true
    assert np.abs(err).max() < 0.15, err
    assert np.array_equal(found.applied, moved)


def test_a_ratio_that_every_size_has_is_refused():
    # A photo has at least one pixel per texel it reaches at any size: a ratio of 1 would never halve.
    photos, masks, uvs = _views(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="above 1"):
        pixel_matched_size(masks, uvs, 1024, 1.0)
    assert pixel_matched_size(masks, uvs, 1024, 1.5) < 1024


def test_photos_that_line_up_stay():
    found = photo_shifts(*_views(np.zeros((6, 2)), seed=3), texture_size=N)
    assert np.hypot(*found.measured.T).max() < MIN_SHIFT_PX
    assert not found.applied.any()
    assert np.all(found.shift == 0)


def test_no_shift_where_the_halves_of_a_photo_disagree():
    """A photo whose misregistration changes across it (a mesh that is not the surface) keeps its camera."""
    shifts = np.zeros((6, 2))
    shifts[2] = [1.2, 0.0]
    found = photo_shifts(*_views(shifts, split={2: (-1.2, 0.0)}, seed=5), texture_size=N)
    assert found.spread[2] > 0.5
    assert not found.applied[2]


@pytest.mark.parametrize("scale", [1.0, 2.5])
def test_shifted_camera_moves_the_projection_by_the_shift(scale):
    cam = Camera(
        K=np.array([[300.0, 0, 80], [0, 300.0, 60], [0, 0, 1]]),
        R=np.eye(3),
        t=np.array([0, 0, 4.0]),
        width=160,
        height=120,
    )
    pts = np.random.default_rng(0).uniform(-1, 1, (20, 3))
    xy, _ = cam.project(pts)
    moved, _ = shifted_camera(cam, (0.7, -0.4), scale).project(pts)
    assert np.allclose(moved - xy, np.array([0.7, -0.4]) * scale)
    assert np.array_equal(cam.K[:2, 2], [80, 60])  # the given camera is not changed


def test_a_photo_that_misses_the_mesh_is_left_alone():
    photos, masks, uvs = _views(np.array([[0.0, 0.0], [0.7, 0.0], [0.0, 0.0], [0.0, 0.0]]), seed=7)
    masks[2] = np.zeros_like(masks[2])
    found = photo_shifts(photos, masks, uvs, texture_size=N)
    assert not found.applied[2] and np.all(found.shift[2] == 0) and np.isinf(found.spread[2])
    assert found.applied[1]


def test_no_camera_moves_where_most_photos_disagree_with_themselves():
    """Four photos of six misregistered differently on their two halves: the mesh is not the surface they show,
    so even the photo that one shift would line up keeps its camera."""
    shifts = np.array([[1.0, 0.0], [-0.8, 0.6], [0.0, -1.0], [0.7, 0.7], [0.9, -0.3], [0.0, 0.0]])
    right = {0: (-0.8, 0.2), 1: (0.9, -0.6), 2: (0.2, 1.0), 3: (-0.9, -0.5)}
    found = photo_shifts(*_views(shifts, split=right, seed=9), texture_size=N)
    assert not found.mesh_fits
    assert not found.applied.any() and np.all(found.shift == 0)
    # The same photos whole: the mesh fits and the cameras that are off move.
    found = photo_shifts(*_views(shifts, seed=9), texture_size=N)
    assert found.mesh_fits and found.applied[:5].all()


def test_pixels_that_are_not_numbers_are_left_out():
    true = np.array([[0.0, 0.0], [0.8, -0.5], [0.0, 0.0], [-0.6, 0.9], [0.0, 0.0], [1.1, 0.3], [0.0, 0.0]])
    photos, masks, uvs = _views(true)
    photos[3][40:50, 60:70] = np.nan
    photos[5][0, 0] = np.inf
    found = photo_shifts(photos, masks, uvs, texture_size=N)
    moved = np.hypot(*true.T) > 0
    err = (found.measured - found.measured[~moved].mean(axis=0)) - true
    assert np.abs(err).max() < 0.15, err
    assert np.array_equal(found.applied, moved)
