import numpy as np
import pytest

from core.geometry.sh import sh_basis
from core.geometry.transfer import ShadowMap, occlusion_transfer, pixel_transfer, sphere_directions, visibility


def _quad(p0, p1, p2, p3):
    """Two triangles of the quad p0 p1 p2 p3 (counter-clockwise)."""
    return [[p0, p1, p2], [p0, p2, p3]]


def _icosphere(levels=2):
    t = (1 + 5**0.5) / 2
    v = [
        (-1, t, 0),
        (1, t, 0),
        (-1, -t, 0),
        (1, -t, 0),
        (0, -1, t),
        (0, 1, t),
        (0, -1, -t),
        (0, 1, -t),
        (t, 0, -1),
        (t, 0, 1),
        (-t, 0, -1),
        (-t, 0, 1),
    ]
    f = [
        (0, 11, 5),
        (0, 5, 1),
        (0, 1, 7),
        (0, 7, 10),
        (0, 10, 11),
        (1, 5, 9),
        (5, 11, 4),
        (11, 10, 2),
        (10, 7, 6),
        (7, 1, 8),
        (3, 9, 4),
        (3, 4, 2),
        (3, 2, 6),
        (3, 6, 8),
        (3, 8, 9),
        (4, 9, 5),
        (2, 4, 11),
        (6, 2, 10),
        (8, 6, 7),
        (9, 8, 1),
    ]
    tris = np.array([[v[i] for i in face] for face in f], float)
    tris /= np.linalg.norm(tris, axis=2, keepdims=True)
    for _ in range(levels):
        a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
        ab, bc, ca = [(x + y) / np.linalg.norm(x + y, axis=1, keepdims=True) for x, y in ((a, b), (b, c), (c, a))]
        tris = np.concatenate([np.stack(s, axis=1) for s in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return tris


def test_directions_cover_the_sphere_evenly():
    d = sphere_directions(256)
    assert np.allclose(np.linalg.norm(d, axis=1), 1)
    # Every SH function but the constant integrates to ~0 over the lattice.
    means = sh_basis(d, np.float64).mean(axis=0)
    assert abs(means[3] - 1) < 1e-12
    assert np.all(np.abs(np.delete(means, 3)) < 0.02), means


def test_a_convex_mesh_blocks_nothing():
    # On a convex object every direction above the horizon is open, so T = nu(n) exactly.
    tris = _icosphere(2)
    centre = tris.mean(axis=1)
    normal = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    occ = occlusion_transfer(centre, normal, tris, n_directions=96, resolution=256)
    assert np.abs(occ).max() == 0.0


def _floor_and_wall(gap=0.5, size=4.0):
    floor = _quad((-size, -size, 0), (size, -size, 0), (size, size, 0), (-size, size, 0))
    wall = _quad((gap, -size, 0), (gap, size, 0), (gap, size, size), (gap, -size, size))
    return np.array(floor + wall, float)


def _brute_force_transfer(p, n, gap=0.5, size=4.0, k=40000):
    """T(x) by exact ray-plane tests against the wall, over a dense lattice of directions."""
    d = sphere_directions(k)
    cos = np.maximum(d @ n, 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (gap - p[0]) / d[:, 0]
        y, z = p[1] + t * d[:, 1], p[2] + t * d[:, 2]
    blocked = (d[:, 0] > 0) & (np.abs(y) <= size) & (z >= 0) & (z <= size)
    nu = sh_basis(d, np.float64)
    # The clamped cosine's coefficients: pi (l = 0), 2 pi / 3 (l = 1), pi / 4 (l = 2).
    band_a = np.array([2 * np.pi / 3] * 3 + [np.pi] + [np.pi / 4] * 5)
    return ((cos * ~blocked) @ nu) * (4 * np.pi / k) / band_a


@pytest.mark.parametrize("x", [0.0, 0.25, -1.0])
def test_transfer_next_to_a_wall_matches_brute_force(x):
    tris = _floor_and_wall()
    p = np.array([[x, 0.3, 0.0]])
    n = np.array([[0.0, 0.0, 1.0]])
    T = sh_basis(n, np.float64)[0] + occlusion_transfer(p, n, tris, n_directions=256, resolution=256)[0]
    expected = _brute_force_transfer(p[0], n[0])
    assert np.abs(T - expected).max() < 0.03, (T, expected)
    # The wall blocks some of the sky: less ambient light than in the open, more the closer.
    assert T[3] < 0.95


def test_visibility_sees_the_wall_and_not_the_floor():
    tris = _floor_and_wall()
    p = np.array([[0.0, 0.0, 0.0]])
    dirs = np.array([[1.0, 0.0, 1.0], [-1.0, 0.0, 1.0], [0.0, 0.0, 1.0]]) / np.array([[2**0.5], [2**0.5], [1]])
    vis = visibility(p, np.array([[0.0, 0.0, 1.0]]), tris, dirs, resolution=256)
    assert vis.tolist() == [[False, True, True]]


def test_pixel_transfer_of_open_surface_is_nu():
    # One flat square seen from above: nothing occludes it, and every pixel gets nu(n).
    tris = np.array(_quad((-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)), float)
    h = w = 16
    ys, xs = np.mgrid[0:h, 0:w]
    pos = np.stack([(xs + 0.5) / w * 2 - 1, (ys + 0.5) / h * 2 - 1, np.zeros((h, w))], axis=-1)
    uv = np.stack([(xs + 0.5) / w, 1 - (ys + 0.5) / h], axis=-1).astype(np.float32)
    normal = np.zeros((h, w, 3), np.float32)
    normal[..., 2] = 1
    mask = np.ones((h, w), bool)
    mask[0, 0] = False
    out = pixel_transfer(tris, [uv], [mask], [normal], [pos], grid=8, n_directions=64, resolution=128)[0]
    assert out.shape == (h * w - 1, 9)  # a row per masked pixel
    assert np.allclose(out, sh_basis(normal[mask]), atol=1e-6)


def test_higher_orders_are_spherical_harmonics():
    # Orthogonal over the sphere (Fibonacci lattice quadrature), so each band is its own.
    from core.geometry.sh import sh_basis, sh_degree

    d = sphere_directions(20000)
    Y = sh_basis(d, np.float64, order=4)
    gram = Y.T @ Y / len(d)
    off = gram - np.diag(np.diag(gram))
    assert Y.shape == (20000, 25) and np.abs(off).max() < 2e-3 * np.diag(gram).max()
    assert sh_degree(25).tolist() == [1, 1, 1, 0, 2, 2, 2, 2, 2] + [3] * 7 + [4] * 9


def test_open_surface_transfer_at_order_4():
    # Funk-Hecke: an open point's transfer is nu(n) up to band 2, nothing in band 3 and -1/6 of band 4
    # (the clamped cosine's coefficients), checked against direct quadrature of max(0, n.w) Y(w).
    from core.geometry.transfer import open_factor

    n = np.array([0.3, -0.5, 0.81])
    n /= np.linalg.norm(n)
    d = sphere_directions(200000)
    Y = sh_basis(d, np.float64, order=4)
    direct = (np.maximum(d @ n, 0) @ Y) * 4 * np.pi / len(d)
    norm = np.array([2 * np.pi / 3] * 3 + [np.pi] + [np.pi / 4] * 21)
    expected = open_factor(25) * sh_basis(n, np.float64, order=4)
    assert np.abs(direct / norm - expected).max() < 2e-3


def test_visibility_is_the_same_on_any_number_of_threads():
    tris = _floor_and_wall()
    rng = np.random.default_rng(0)
    p = np.stack([rng.uniform(-1.5, 1.5, 40), rng.uniform(-1.5, 1.5, 40), np.zeros(40)], axis=1)
    n = np.tile([0.0, 0.0, 1.0], (40, 1))
    dirs = sphere_directions(16)
    one = visibility(p, n, tris, dirs, resolution=64, threads=1)
    assert np.array_equal(one, visibility(p, n, tris, dirs, resolution=64, threads=3))


def test_a_shadow_map_cast_for_a_few_points_tells_them_as_the_whole_map_does():
    tris = _floor_and_wall()
    rng = np.random.default_rng(1)
    p = np.stack([rng.uniform(-1.5, 1.5, 300), rng.uniform(-1.5, 1.5, 300), np.zeros(300)], axis=1)
    n = np.tile([0.0, 0.0, 1.0], (300, 1))
    for w in sphere_directions(12, 0.1):
        whole, few = ShadowMap(w, tris, 256), ShadowMap(w, tris, 256, only=(p, n))
        assert np.isinf(few.depth).mean() > 0.95 > np.isinf(whole.depth).mean()  # most of it is not cast
        assert np.array_equal(few.open(p, n), whole.open(p, n))
        assert np.array_equal(few.open_only(), whole.open(p, n))  # the lookup made for the cast, kept
    with pytest.raises(ValueError, match="without only"):
        whole.open_only()
    assert 0.1 < visibility(p, n, tris, sphere_directions(12, 0.1), resolution=256).mean() < 0.9
