"""Correspondences between views of analytic spheres (ray casting in NumPy)."""

import numpy as np
import pytest

from core.geometry.camera import Camera
from core.geometry.correspondences import find_correspondences, neighbour_views
from core.solve.problem import Problem

BIG = (np.zeros(3), 1.0)
EYE2 = np.array([2.0, -4.6, -0.5])
SMALL = (0.4 * EYE2, 0.3)  # between camera 2 and the big sphere


def look_at(eye, target=(0.0, 0.0, 0.0), w=96, h=80, f=150.0):
    eye = np.asarray(eye, float)
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)  # y down in the image
    R = np.stack([x, y, z])
    return Camera(K=[[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]], R=R, t=-R @ eye, width=w, height=h)


def ray_sphere(o, d, centre, radius):
    oc = o - centre
    b = d @ oc
    disc = b * b - (oc @ oc - radius**2)
    t = -b - np.sqrt(np.maximum(disc, 0))
    return np.where((disc > 0) & (t > 0), t, np.inf)


def render(cam, spheres):
    """Analytic bake: positions, mask, normals, and which sphere each pixel sees."""
    d = cam.ray_directions().reshape(-1, 3)
    ts = np.stack([ray_sphere(cam.center, d, c, r) for c, r in spheres])
    which = np.argmin(ts, axis=0)
    t = ts.min(axis=0)
    mask = np.isfinite(t)
    p = cam.center + d * np.where(mask, t, 0)[:, None]
    centres = np.array([c for c, _ in spheres])[which]
    n = p - centres
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    p[~mask] = np.nan
    n[~mask] = 0
    shape = (cam.height, cam.width)
    return p.reshape(shape + (3,)), mask.reshape(shape), n.reshape(shape + (3,)), which.reshape(shape)


@pytest.fixture(scope="module")
def scene():
    cams = [look_at((0.0, -5.0, 1.0)), look_at((3.5, -3.5, 0.5)), look_at(EYE2, w=88, h=88), look_at((0.0, 5.0, 0.5))]
    spheres = [BIG, SMALL]
    baked = [render(c, spheres) for c in cams]
    return cams, spheres, baked


def test_pairs_see_the_same_point_and_never_an_occluded_one(scene):
    cams, spheres, baked = scene
    pos, masks, nrm, which = (list(x) for x in zip(*baked))
    c = find_correspondences(cams, pos, masks, nrm, neighbours=3)
    assert len(c) > 3000
    problem = Problem(
        images=[np.ones(m.shape + (3,)) for m in masks], masks=masks, normals=nrm, correspondences=c
    )  # valid for the solver (indices, ranges, masks)
    assert problem.correspondences is c
    for a in range(4):
        for b in range(4):
            sel = (c.view_a == a) & (c.view_b == b)
            if a == b:
                assert not sel.any()
            if not sel.any():
                continue
            pa = pos[a].reshape(-1, 3)[c.pixel_a[sel]]
            # Cast the ray through xy_b analytically: it must hit the same point.
            xy = c.xy_b[sel]
            d = np.c_[xy, np.ones(len(xy))] @ np.linalg.inv(cams[b].K).T @ cams[b].R
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            ts = np.stack([ray_sphere(cams[b].center, d, cc, r) for cc, r in spheres])
            pb = cams[b].center + d * ts.min(axis=0)[:, None]
            pixel_size = np.linalg.norm(pa - cams[b].center, axis=1) / cams[b].K[0, 0]
            err = np.linalg.norm(pa - pb, axis=1) / pixel_size
            assert np.all(np.isfinite(err)) and err.max() < 0.05, (a, b, err.max())


def test_occluded_and_far_side_points_make_no_pairs(scene):
    cams, spheres, baked = scene
    pos, masks, nrm, which = (list(x) for x in zip(*baked))
    c = find_correspondences(cams, pos, masks, nrm, neighbours=3)
    # Camera 3 looks from the other side: nothing it sees is visible from camera 0.
    assert not ((c.view_a == 3) & (c.view_b == 0)).any()
    assert not ((c.view_a == 0) & (c.view_b == 3)).any()
    # Points of the big sphere that view 0 sees but the small sphere hides from view 2.
    p0 = pos[0].reshape(-1, 3)
    on_big = masks[0].ravel() & (which[0].ravel() == 0)
    d = p0 - cams[2].center
    dist = np.linalg.norm(d, axis=1)
    d /= dist[:, None]
    t_small = ray_sphere(cams[2].center, np.nan_to_num(d), *SMALL)
    hidden = on_big & (t_small < dist - 1e-6)
    assert hidden.sum() > 50  # the test really has occluded points
    sel = (c.view_a == 0) & (c.view_b == 2)
    assert sel.sum() > 500
    assert not hidden[c.pixel_a[sel]].any()
    # ... and most visible ones, away from silhouettes, do pair up (the test is not vacuous).
    xy, _ = cams[2].project(p0)
    interior = on_big & ~hidden & np.all((xy > 2) & (xy < [cams[2].width - 3, cams[2].height - 3]), axis=1)
    n0 = nrm[0].reshape(-1, 3)
    facing = np.einsum("ij,ij->i", n0, cams[2].center - p0) > 0.3 * np.linalg.norm(cams[2].center - p0, axis=1)
    want = interior & facing
    got = np.zeros_like(want)
    got[c.pixel_a[sel]] = True
    assert (got & want).sum() > 0.9 * want.sum()


def test_subsampling_and_neighbours(scene):
    cams, spheres, baked = scene
    pos, masks, nrm, _ = (list(x) for x in zip(*baked))
    full = find_correspondences(cams, pos, masks, nrm, neighbours=3)
    few = find_correspondences(cams, pos, masks, nrm, neighbours=3, max_pairs=500, seed=1)
    again = find_correspondences(cams, pos, masks, nrm, neighbours=3, max_pairs=500, seed=1)
    assert 300 < len(few) <= 500
    np.testing.assert_array_equal(few.pixel_a, again.pixel_a)  # seeded
    assert np.all(np.diff(few.view_a) >= 0)
    # Every subsampled pair is one of the full set's pairs.
    key = lambda c: set(zip(c.view_a.tolist(), c.pixel_a.tolist(), c.view_b.tolist()))  # noqa: E731
    assert key(few) <= key(full)
    one = find_correspondences(cams, pos, masks, nrm, neighbours=1)
    nb = neighbour_views(cams, pos, masks, 1)
    assert nb[0] == [2]  # camera 2 looks from closest to camera 0
    for a in range(4):
        assert set(one.view_b[one.view_a == a].tolist()) <= set(nb[a])
