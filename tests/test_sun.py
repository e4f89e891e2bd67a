"""The sun search (core.geometry.sun) on a synthetic scene: a box on a ground plane, checker albedo."""

import numpy as np
import pytest

from core.geometry.camera import Camera
from core.geometry.raycast import raycast
from core.geometry.sun import _pairs, find_sun
from core.geometry.transfer import visibility

SUN = np.array([0.5, -0.4, 0.77]) / np.linalg.norm([0.5, -0.4, 0.77])


def _quad(p0, p1, p2, p3):
    return [[p0, p1, p2], [p0, p2, p3]]


def _scene():
    """A 4 x 4 ground at z = 0 and a 0.8 x 0.8 x 1 box on it, as triangles (T, 3, 3)."""
    g = 2.0
    tris = _quad((-g, -g, 0), (g, -g, 0), (g, g, 0), (-g, g, 0))
    a, h = 0.4, 1.0
    c = [(-a, -a), (a, -a), (a, a), (-a, a)]
    for i in range(4):
        (x0, y0), (x1, y1) = c[i], c[(i + 1) % 4]
        tris += _quad((x0, y0, 0), (x1, y1, 0), (x1, y1, h), (x0, y0, h))
    tris += _quad(*[(x, y, h) for x, y in c])
    return np.array(tris, np.float64)


def _look_at(eye, width=160, height=120, focal=150.0):
    eye = np.asarray(eye, np.float64)
    f = -eye / np.linalg.norm(eye)
    r = np.cross(f, (0, 0, 1.0))
    r /= np.linalg.norm(r)
    R = np.stack([r, np.cross(f, r), f])
    K = [[focal, 0, (width - 1) / 2], [0, focal, (height - 1) / 2], [0, 0, 1]]
    return Camera(K, R, -R @ eye, width, height)


def _views(tris, sun_strength):
    """Photos of the scene under a sky brighter at the zenith plus a sun along SUN, with a checker albedo."""
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    face_n = np.cross(e1, e2)
    face_n /= np.linalg.norm(face_n, axis=1, keepdims=True)
    photos, masks, positions, normals = [], [], [], []
    for az in np.radians([20, 110, 200, 290]):
        cam = _look_at(6.0 * np.array([np.cos(az), np.sin(az), 0.7]))
        hits = raycast(cam, tris)
        m = hits.mask
        pos = hits.interpolate(tris)
        nrm = np.zeros(m.shape + (3,))
        nrm[m] = face_n[hits.tri[m]]
        # Face the camera (the box's quads are not all wound outwards).
        flip = np.einsum("ij,ij->i", nrm[m], pos[m] - cam.center) > 0
        nrm[np.nonzero(m)[0][flip], np.nonzero(m)[1][flip]] *= -1
        p, n = pos[m], nrm[m]
        lit = visibility(p, n, tris, SUN[None], resolution=512)[:, 0] * np.maximum(n @ SUN, 0.0)
        cells = np.floor(p[:, 0] / 0.25) + np.floor(p[:, 1] / 0.25) + np.floor(p[:, 2] / 0.25)
        albedo = np.where(cells % 2 == 0, 0.3, 0.8)
        photo = np.zeros(m.shape + (3,))
        sky = 0.25 + 0.15 * n[:, 2]
        photo[m] = (albedo * (sky + sun_strength * lit))[:, None]
        photos.append(photo)
        masks.append(m)
        positions.append(pos)
        normals.append(nrm)
    return photos, masks, positions, normals


@pytest.fixture(scope="module")
def scene():
    return _scene()


def test_finds_the_sun_from_its_shadows(scene):
    found = find_sun(*_views(scene, 1.5), scene, n_directions=200)
    angle = np.degrees(np.arccos(np.clip(found.direction @ SUN, -1, 1)))
    # The coarse candidates are 14 degrees apart; three rounds of refinement get within a few.
    assert angle < 6.0, angle
    assert found.directions.shape == (290, 3) and found.scores.shape == (290,)


def test_a_quarter_of_the_pairs_still_finds_it(scene):
    # 3768 pairs here; every 4th keeps 942 of them, each still with both of its own ends.
    found = find_sun(*_views(scene, 1.5), scene, n_directions=200, max_pairs=1000)
    assert np.degrees(np.arccos(np.clip(found.direction @ SUN, -1, 1))) < 6.0


def test_at_most_max_pairs_are_every_kth_of_all_pairs_in_order():
    rng = np.random.default_rng(5)
    shapes = [(37, 52), (61, 44), (50, 50)]
    masks = [rng.random(s) < 0.7 for s in shapes]
    photos, positions, normals = ([rng.random((*s, 3)).astype(np.float32) for s in shapes] for _ in range(3))
    points, nrm, dlog = _pairs(photos, masks, positions, normals, 3)
    n = dlog.size
    for most in (50, 97, n - 1):
        keep = np.arange(0, n, -(-n // most))
        got = _pairs(photos, masks, positions, normals, 3, most)
        assert got[2].size <= most
        np.testing.assert_array_equal(got[0], np.concatenate([points[keep], points[n + keep]]))
        np.testing.assert_array_equal(got[1], np.concatenate([nrm[keep], nrm[n + keep]]))
        np.testing.assert_array_equal(got[2], dlog[keep])
    assert all(
        np.array_equal(a, b) for a, b in zip(_pairs(photos, masks, positions, normals, 3, n), (points, nrm, dlog))
    )


def test_no_pairs_is_a_clear_error(scene):
    photos, masks, positions, normals = _views(scene, 1.0)
    empty = [np.zeros_like(m) for m in masks]
    with pytest.raises(ValueError, match="no two neighbouring pixels"):
        find_sun(photos, empty, positions, normals, scene, n_directions=20)


def test_the_pipeline_goes_on_without_a_sun_it_cannot_search_for(scene):
    # A scene whose photos have no two neighbouring pixels on the mesh (a tiny mesh far away): no sun term,
    # a reason in the report and in the progress.
    from types import SimpleNamespace

    from core.pipeline import _find_sun

    photos, masks, positions, normals = _views(scene, 1.0)
    rows, cols = np.indices(masks[0].shape)
    apart = [m & ((rows + cols) % 2 == 0) for m in masks]  # a checkerboard: no neighbour right or below
    said = []
    sun, info = _find_sun(
        photos,
        apart,
        scene,
        [SimpleNamespace(position=p, normal=n) for p, n in zip(positions, normals)],
        "coupled",
        SimpleNamespace(threads=1),
        lambda frac, msg: said.append(msg),
    )
    assert sun is None
    assert info == {"used": False, "reason": "sun search: no two neighbouring pixels on the mesh in any photo"}
    assert said[-1] == "sun shadows: off, sun search: no two neighbouring pixels on the mesh in any photo"


def test_the_transfer_rows_are_nu_then_the_sun_column_with_shadows(scene):
    from core.geometry.sh import sh_basis
    from core.geometry.sun import SunLight
    from core.geometry.transfer import transfer_rows
    from core.solve.problem import row_blocks

    _, masks, positions, normals = _views(scene, 1.0)
    m = masks[0]
    n, p = normals[0][m].astype(np.float32), positions[0][m]
    sun = SunLight(SUN, scene)
    rows = transfer_rows(n, None, None, sun, p)
    assert rows.shape == (n.shape[0], 10) and rows.dtype == np.float32
    assert np.array_equal(rows[:, :9], sh_basis(n))
    lit = np.maximum(n @ SUN, 0) > 0.2
    # The sun's column: the cosine where the sun is seen, 0 in the box's shadow and on faces turned away.
    seen = visibility(p, n, scene, SUN[None], resolution=512)[:, 0] > 0.5
    # (the sun's shadow map and the visibility rays disagree on a few pixels at the shadow's edges)
    assert np.mean(np.abs(rows[lit & seen, 9] - n[lit & seen] @ SUN) < 1e-4) > 0.97
    assert np.mean(rows[lit & ~seen, 9] < 0.05) > 0.9 and (lit & ~seen).sum() > 50
    # Into a block of the problem's transfer, in place.
    block = row_blocks([n.shape[0]], 10)[0]
    assert transfer_rows(n, None, None, sun, p, out=block) is block and np.array_equal(block, rows)
    assert transfer_rows(n).shape == (n.shape[0], 9)


def test_the_shading_rows_are_the_transfer_rows_times_the_lighting(scene):
    # The detail stage's shading puts the lighting into the occlusion grid's cells before interpolating: the
    # same shading as the solve's transfer rows times the lighting, with and without occlusion and the sun.
    from core.geometry.sun import SunLight
    from core.geometry.transfer import occlusion_grid, shading_rows, transfer_rows

    _, masks, positions, normals = _views(scene, 1.0)
    m = masks[0]
    n, p = normals[0][m].astype(np.float32), positions[0][m]
    uv = (p[:, :2] / 4.0 + 0.5).astype(np.float32)  # the ground's and the box's points, laid out from above
    uvs = [np.where(mk[..., None], pos[..., :2] / 4.0 + 0.5, 0).astype(np.float32) for mk, pos in zip(masks, positions)]
    cells = occlusion_grid(scene, uvs, masks, normals, positions, grid=16, n_directions=32, resolution=64)
    assert cells.valid.sum() > 50 and np.abs(cells.occ).max() > 0.05  # the box occludes the ground around it
    sun = SunLight(SUN, scene)
    sigma = np.random.default_rng(1).uniform(-0.5, 1.0, (3, 10)).astype(np.float32)
    far = uv * 3 - 1  # two thirds of the points off the texture, some beyond the grid's border cells
    for grid, light, at in ((None, None, uv), (cells, None, uv), (None, sun, uv), (cells, sun, uv), (cells, sun, far)):
        k = 9 + (light is not None)
        expected = transfer_rows(n, at, grid, light, p) @ sigma[:, :k].T
        got = shading_rows(sigma[:, :k], n, at, grid, light, p)
        assert got.shape == (n.shape[0], 3) and got.dtype == np.float32
        np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-5 * np.abs(expected).max())


@pytest.mark.parametrize("facing", [1.0, 0.5])
def test_the_sun_term_is_the_shadow_maps_openness_times_the_cosine(scene, facing, monkeypatch):
    # Points that face away from the sun are left out of its shadow map's lookup when they are many: the same
    # numbers as looking every point up.
    from core.geometry import sun as sun_module
    from core.geometry.sun import SunLight

    _, masks, positions, normals = _views(scene, 1.0)
    n, p = normals[1][masks[1]].astype(np.float32), positions[1][masks[1]].astype(np.float32)
    light = SunLight(SUN, scene)
    away = np.random.default_rng(0).random(n.shape[0]) > facing
    n[away & (n @ SUN > 0)] *= -1  # turned away: their cosine is 0 or less
    term = light.term(p, n)
    cosine = np.maximum(n.astype(np.float64) @ light.direction, 0.0)
    expect = (light.shadow.open(p, n.astype(np.float64)) * cosine).astype(np.float32)
    np.testing.assert_array_equal(term, expect)
    assert term.dtype == np.float32 and (term[away] == 0).all() and (term > 0.3).mean() > 0.2
    monkeypatch.setattr(sun_module, "_LOOKUP_ALL", 2.0)  # never all: only those facing the sun
    np.testing.assert_array_equal(light.term(p, n), expect)
