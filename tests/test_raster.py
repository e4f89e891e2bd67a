"""core.geometry.raycast.raycast against analytic ray casting (the Cycles check is in tests/bpy)."""

import importlib

import numpy as np

from core.geometry.camera import Camera
from core.geometry.raycast import Triangles, raycast

# The module itself: the package's `raycast` is the function.
raycast_module = importlib.import_module("core.geometry.raycast")


def camera(R=None, eye=(0.0, 0.0, 0.0), w=40, h=30, f=25.0, skew=0.0):
    R = np.eye(3) if R is None else np.asarray(R, float)
    return Camera(
        K=[[f, skew, (w - 1) / 2 + 0.3], [0, f * 1.1, (h - 1) / 2 - 0.2], [0, 0, 1]],
        R=R,
        t=-R @ np.asarray(eye, float),
        width=w,
        height=h,
    )


def grid_quads(n, size, z):
    """An n x n grid of quads (2 triangles each) on the plane z, centred at the origin."""
    xs = np.linspace(-size, size, n + 1)
    tris = []
    for i in range(n):
        for j in range(n):
            a, b = (xs[i], xs[j], z), (xs[i + 1], xs[j], z)
            c, d = (xs[i + 1], xs[j + 1], z), (xs[i], xs[j + 1], z)
            tris += [(a, b, c), (a, c, d)]
    return np.array(tris)


def test_ground_plane_reaching_behind_the_camera():
    # Camera 1 m above a large ground grid, tilted 15 degrees below the horizon: triangles
    # cross the camera plane, so their projections must be clipped, not wrapped.
    t = np.radians(75.0)  # angle from straight down
    fwd = np.array([0.0, np.sin(t), -np.cos(t)])
    right = np.array([1.0, 0.0, 0.0])
    down = np.cross(fwd, right)
    R = np.stack([right, down, fwd])
    eye = np.array([0.0, 0.0, 1.0])
    cam = camera(R, eye)
    # Shifted so that the cell under the camera, which crosses the camera
    # plane, is also the one seen at the bottom of the frame.
    tris = grid_quads(6, 50.0, 0.0) + np.array([0.0, 5.0, 0.0])
    hits = raycast(cam, tris)
    d = cam.ray_directions()
    t_plane = -eye[2] / d[:, :, 2]
    with np.errstate(invalid="ignore"):
        ground = eye[:2] + d[:, :, :2] * t_plane[:, :, None] - [0.0, 5.0]
        on_grid = np.all(np.abs(ground) <= 50.0, axis=2)
    expect = (t_plane > 0) & on_grid
    np.testing.assert_array_equal(hits.mask, expect)
    # The horizon is in the frame: sky rows above, ground rows below.
    assert (t_plane <= 0).all(axis=1).any() and (t_plane > 0).all(axis=1).any()
    p = hits.interpolate(tris)
    np.testing.assert_allclose(p[expect], (eye + d * t_plane[:, :, None])[expect], atol=1e-7)
    depth = (p[expect] - eye) @ fwd
    np.testing.assert_allclose(hits.depth[expect], depth, rtol=1e-9)
    np.testing.assert_allclose(hits.bary[expect].sum(axis=1), 1.0)


def test_nearest_hit_wins_and_shared_edges_leave_no_holes():
    cam = camera(skew=0.7)
    near = grid_quads(7, 1.0, 4.0)  # a fine grid (many shared edges), nearer
    far = grid_quads(2, 10.0, 6.0)  # a plane behind it, filling the frame
    tris = np.concatenate([far, near])
    hits = raycast(cam, tris, batch=500)  # tiny batches: the depth test across batches
    d = cam.ray_directions()
    p_near = d * (4.0 / d[:, :, 2:3])
    in_near = np.all(np.abs(p_near[:, :, :2]) <= 1.0, axis=2)
    strictly = np.all(np.abs(p_near[:, :, :2]) < 1.0 - 1e-9, axis=2)
    assert strictly.sum() > 100 and (~in_near).sum() > 100
    assert np.all(hits.tri[strictly] >= len(far))  # the near grid, no holes on its edges
    assert np.all((hits.tri[~in_near] >= 0) & (hits.tri[~in_near] < len(far)))
    np.testing.assert_allclose(hits.depth[strictly], 4.0, rtol=1e-12)
    assert np.isinf(hits.depth[~hits.mask]).all() and (hits.tri[~hits.mask] == -1).all()


def test_back_faces_are_hit_and_behind_is_not():
    cam = camera()
    tri = np.array([[[-1.0, -1.0, 3.0], [-1.0, 1.0, 3.0], [1.0, 0.0, 3.0]]])  # either winding
    behind = tri * np.array([1.0, 1.0, -1.0])
    for t in (tri, tri[:, ::-1], np.concatenate([behind, tri])):
        hits = raycast(cam, t)
        assert hits.mask.sum() > 50
        assert set(np.unique(hits.tri[hits.mask])) == {len(t) - 1}
    assert not raycast(cam, behind).mask.any()


def brute_force(cam, tris):
    """The nearest hit of each pixel's ray, triangle by triangle (Moller-Trumbore): triangle index and depth."""
    d = cam.ray_directions().reshape(-1, 3)
    o = -cam.R.T @ cam.t
    fwd = cam.R[2]
    best, depth = np.full(len(d), -1), np.full(len(d), np.inf)
    for k, (a, b, c) in enumerate(tris):
        e1, e2 = b - a, c - a
        p = np.cross(d, e2)
        det = p @ e1
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (p @ (o - a)) / det
            q = np.cross(o - a, e1)
            v = (d @ q) / det
            t = (q @ e2) / det
        z = t * (d @ fwd)
        hit = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (z < depth)
        best[hit], depth[hit] = k, z[hit]
    return best.reshape(cam.height, cam.width), depth.reshape(cam.height, cam.width)


def test_a_mesh_finer_than_the_pixels_is_hit_where_rays_meet_it():
    # A bumpy sheet of about 20 triangles per pixel: most triangles hold no pixel centre and are passed over
    # before the exact test; the indices of those hit must still be the mesh's own.
    n = 110
    xs = np.linspace(-2.4, 2.4, n + 1)
    x, y = np.meshgrid(xs, xs)
    z = 4.0 + 0.15 * np.sin(7 * x) * np.cos(5 * y)
    p = np.stack([x, y, z], axis=-1)
    a, b, c, d = p[:-1, :-1], p[:-1, 1:], p[1:, 1:], p[1:, :-1]
    tris = np.concatenate([np.stack([a, b, c], -2).reshape(-1, 3, 3), np.stack([a, c, d], -2).reshape(-1, 3, 3)])
    rng = np.random.default_rng(3)
    tris = tris[rng.permutation(len(tris))]
    cam = camera(skew=0.4)
    hits = raycast(cam, tris, batch=700)
    best, depth = brute_force(cam, tris)
    assert len(tris) > 15 * (best >= 0).sum() and (best >= 0).mean() > 0.5
    edge = hits.tri != best  # a ray through a shared edge or corner may take either triangle
    assert edge.mean() < 0.01
    np.testing.assert_allclose(hits.depth[best >= 0], depth[best >= 0], rtol=1e-9)
    assert np.array_equal(hits.mask, best >= 0)


def test_triangles_as_shared_vertices_give_the_same_hits():
    # The same bumpy sheet with its corners shared: each vertex projected once, and the same hits to the bit.
    n = 60
    xs = np.linspace(-2.4, 2.4, n + 1)
    x, y = np.meshgrid(xs, xs)
    p = np.stack([x, y, 4.0 + 0.15 * np.sin(7 * x) * np.cos(5 * y)], axis=-1).reshape(-1, 3)
    i = np.arange(p.shape[0]).reshape(n + 1, n + 1)
    a, b, c, d = i[:-1, :-1], i[:-1, 1:], i[1:, 1:], i[1:, :-1]
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    faces = faces[np.random.default_rng(4).permutation(len(faces))]
    tris = p[faces]
    shared = Triangles.of(tris, faces + 7)  # any vertex numbers: only which corners are one vertex counts
    assert len(shared.vertices) == len(p) and np.array_equal(shared.tri_pos, tris)
    tilted = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # looking along the sheet
    # Every corner in front (each vertex's pixels worked out once), skewed, and part of the sheet behind.
    for cam in (camera(), camera(skew=0.4), camera(tilted, eye=(0.0, -1.0, 4.1))):
        ours, soup = raycast(cam, shared, batch=700), raycast(cam, tris, batch=700)
        assert ours.mask.mean() > 0.2
        for got, expect in zip((ours.tri, ours.depth, ours.bary), (soup.tri, soup.depth, soup.bary)):
            assert np.array_equal(got, expect)
    # Vertex numbers that do not match the corners: nothing shared, the same triangles.
    wrong = Triangles.of(tris, np.zeros_like(faces))
    assert len(wrong.vertices) == 3 * len(tris) and np.array_equal(wrong.tri_pos, tris)


def test_boxes_from_the_vertices_are_the_triangles_own():
    # Corners on pixel centres, within the margin of one and between two: a box from its corners' own first and
    # last pixels is the box of the triangle's projected bounds, to the pixel.
    cam = camera(w=23, h=17)
    rng = np.random.default_rng(5)
    n = 3000  # triangles of about a pixel, each corner its own vertex
    near = [0.0, 1e-3, -1e-3, 0.999e-3, -0.999e-3, 1.001e-3, 0.5, 1e-12, -1e-12]
    col = (rng.integers(-3, 26, n)[:, None] + rng.integers(0, 2, (n, 3)) + rng.choice(near, (n, 3))).ravel()
    row = (rng.integers(-3, 20, n)[:, None] + rng.integers(0, 2, (n, 3)) + rng.choice(near, (n, 3))).ravel()
    z = rng.uniform(2.0, 6.0, 3 * n)
    fx, _, cx, fy, cy = raycast_module._intrinsics(cam)
    vv = np.stack([(col - cx) / fx * z, (row - cy) / fy * z, z], axis=1)
    faces = np.arange(3 * n).reshape(n, 3)
    ours = raycast_module._vertex_boxes(cam, vv, Triangles(vv, faces).corners)
    theirs = raycast_module._pixel_boxes(cam, raycast_module._bounds(vv[faces], 1e-9))
    assert 0.2 < np.mean(theirs[3] > 0) < 0.95
    for a, b in zip(ours, theirs):
        assert np.array_equal(a, b)


def test_a_few_pixels_are_hit_as_in_the_whole_cast_and_the_rest_miss():
    # A fine sheet (triangles of a fraction of a pixel) and a ball of large triangles before a wall: the rays
    # through a scattered few pixels, and through a block of them, hit what the whole cast hits, to the bit.
    n = 90
    xs = np.linspace(-2.4, 2.4, n + 1)
    x, y = np.meshgrid(xs, xs)
    grid = np.stack([x, y, 6.0 + 0.15 * np.sin(7 * x) * np.cos(5 * y)], axis=-1)
    a, b, c, d = grid[:-1, :-1], grid[:-1, 1:], grid[1:, 1:], grid[1:, :-1]
    sheet = np.concatenate([np.stack([a, b, c], -2).reshape(-1, 3, 3), np.stack([a, c, d], -2).reshape(-1, 3, 3)])
    p, faces = bumpy_ball(centre=(0.0, 0.0, 4.0))
    cam = camera(w=80, h=60, f=55.0)
    rng = np.random.default_rng(6)
    for tris in (sheet, np.concatenate([p[faces], grid_quads(3, 6.0, 7.5)]), Triangles.of(p[faces], faces)):
        whole = raycast(cam, tris, batch=900)
        block = np.zeros((60, 80), bool)
        block[20:31, 33:52] = True
        for pixels in (rng.random(60 * 80) < 0.03, block.ravel()):
            few = raycast(cam, tris, batch=900, pixels=pixels)
            at = pixels.reshape(60, 80)
            assert whole.mask[at].sum() > 20
            for got, expect in zip((few.tri, few.depth, few.bary), (whole.tri, whole.depth, whole.bary)):
                assert np.array_equal(got[at], expect[at])
            assert not few.mask[~at].any() and np.all(few.depth[~at] == np.inf) and not few.bary[~at].any()


def bumpy_ball(n=24, centre=(0.0, 0.0, 5.0)):
    """A closed ball with dents (so that some of its front hides more of its front), as shared vertices."""
    th, ph = np.meshgrid(np.linspace(0, np.pi, n + 1)[1:-1], np.linspace(0, 2 * np.pi, 2 * n, endpoint=False))
    r = 1.0 + 0.25 * np.sin(3 * th) * np.cos(4 * ph)
    ring = np.stack([r * np.sin(th) * np.cos(ph), r * np.sin(th) * np.sin(ph), r * np.cos(th)], -1)
    p = np.concatenate([ring.transpose(1, 0, 2).reshape(-1, 3), [[0, 0, 1.0], [0, 0, -1.0]]]) + centre
    i = np.arange(ring.shape[0] * ring.shape[1]).reshape(ring.shape[1], ring.shape[0])  # (latitude, longitude)
    j = np.roll(i, -1, axis=1)
    faces = [np.stack([i[:-1], i[1:], j[1:]], -1), np.stack([i[:-1], j[1:], j[:-1]], -1)]
    top, bottom = len(p) - 2, len(p) - 1
    faces += [np.stack([np.full(i.shape[1], top), i[0], j[0]], -1)[None]]
    faces += [np.stack([np.full(i.shape[1], bottom), j[-1], i[-1]], -1)[None]]
    return p, np.concatenate([f.reshape(-1, 3) for f in faces])


def passes_of(cam, tris):
    """The ray caster's passes over ``tris`` (all in front of ``cam``), and its signed volumes, nearest corners and
    boxes of pixels."""
    vc = cam.to_camera(tris)
    boxes = raycast_module._pixel_boxes(cam, raycast_module._bounds(vc, 1e-9))
    vol, z_lo = raycast_module._edge_planes(vc)[1], vc[..., 2].min(axis=1)
    return raycast_module._passes(vol, z_lo, boxes), vol, z_lo, boxes


def test_what_the_nearer_triangles_hide_is_left_out_and_the_hits_stay():
    # Triangles of many pixels each are cast nearest side first, and those behind every hit in their box are
    # left out: a closed dented ball before a wall, with its winding consistent and then flipped at random.
    p, faces = bumpy_ball()
    wall = grid_quads(3, 6.0, 7.5)
    cam = camera(skew=0.3, w=80, h=60, f=55.0)
    rng = np.random.default_rng(5)
    for flip in (np.zeros(len(faces), bool), rng.random(len(faces)) < 0.5):
        ball = p[np.where(flip[:, None], faces[:, ::-1], faces)]
        tris = np.concatenate([ball, wall])
        hits, (best, depth) = raycast(cam, tris, batch=900), brute_force(cam, tris)
        assert hits.mask.mean() > 0.5 and (best >= len(ball)).mean() > 0.2  # the ball and the wall around it
        assert np.array_equal(hits.mask, best >= 0)
        assert (hits.tri != best).mean() < 0.01  # a ray through a shared edge may take either triangle
        np.testing.assert_allclose(hits.depth[best >= 0], depth[best >= 0], rtol=1e-9)
        if not flip.any():
            # What the passes before hide of the last (the ball's far side, and the wall): about the ball's far
            # half, none of it hit by any ray. (With the winding at random, the first passes leave holes.)
            (*before, last), vol, z_lo, boxes = passes_of(cam, tris)
            seen = raycast(cam, tris[np.concatenate(before)]).depth
            hidden = last[raycast_module._hidden(seen, z_lo[last], [b[last] for b in boxes])]
            assert hidden.size > 0.3 * len(ball)
            assert not np.isin(hidden, best).any()


def test_a_triangle_is_left_out_only_behind_every_hit_in_its_box():
    depth = np.full((50, 70), 5.0)
    depth[40:, 60:] = np.inf  # pixels no triangle hit yet
    depth[20, 25] = 6.0  # the farthest hit
    # Boxes (first column, last column, first row, row count) and nearest corners: behind every hit of its box;
    # level with them; just behind; its box reaches pixels not hit; in front of the farthest hit; behind it.
    c0, c1 = np.array([0, 40, 40, 50, 0, 0]), np.array([9, 50, 50, 65, 29, 29])
    r0, nr = np.array([0, 20, 20, 30, 0, 0]), np.array([10, 5, 5, 15, 32, 32])
    z_lo = np.array([5.1, 5.0, 5.0 * (1 + 1e-6), 9.0, 5.5, 6.5])
    hidden = raycast_module._hidden(depth, z_lo, [c0, c1, r0, nr])
    assert hidden.tolist() == [True, False, True, False, False, True]


def test_a_mesh_seen_from_one_side_is_cast_near_half_first_whichever_its_winding():
    # A relief seen from the front (every triangle's face towards the camera): its near half, then its far half,
    # with the winding either way round.
    n = 20
    xs = np.linspace(-2.0, 2.0, n + 1)
    x, y = np.meshgrid(xs, xs)
    p = np.stack([x, y, 6.0 + 0.5 * y + 0.2 * np.sin(3 * x)], axis=-1)
    a, b, c, d = p[:-1, :-1], p[:-1, 1:], p[1:, 1:], p[1:, :-1]
    sheet = np.concatenate([np.stack([a, b, c], -2).reshape(-1, 3, 3), np.stack([a, c, d], -2).reshape(-1, 3, 3)])
    cam = camera(w=80, h=60, f=60.0)
    orders = []
    for tris in (sheet, sheet[:, ::-1]):
        passes, vol, z_lo, _ = passes_of(cam, tris)
        assert (vol < 0).all() or (vol > 0).all()
        assert len(passes) == 2 and z_lo[passes[0]].max() <= z_lo[passes[1]].min()
        orders.append(passes)
    assert all(np.array_equal(one, other) for one, other in zip(*orders))


def test_runs_give_what_repeat_gives():
    from core.geometry.runs import runs

    counts = np.array([3, 0, 1, 5, 0, 2])
    run, place = runs(counts)
    np.testing.assert_array_equal(run, np.repeat(np.arange(counts.size), counts))
    np.testing.assert_array_equal(place, [0, 1, 2, 0, 0, 1, 2, 3, 4, 0, 1])
    values = np.array([0.1, 7.0, -2.5, 1e-300, np.inf, 3.0])
    np.testing.assert_array_equal(np.take(values, run), np.repeat(values, counts))
    empty = runs(np.zeros(0, np.intp))
    assert empty[0].size == 0 and empty[1].size == 0


def test_barycentric_weights_are_contiguous_planes():
    cam = camera()
    hits = raycast(cam, grid_quads(4, 0.5, 2.0))
    assert hits.bary.shape == (cam.height, cam.width, 3)
    for c in range(3):
        assert hits.bary[..., c].flags.c_contiguous  # bake_pixels reads them without a copy
