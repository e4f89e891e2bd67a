from dataclasses import replace

import numpy as np
import pytest

from core.errors import Cancelled
from core.evaluate.metrics import scaled_rmse
from core.evaluate.synthetic import sphere_scene
from core.geometry.correspondences import find_correspondences
from core.solve import pyramid
from core.solve.discretization import texture_domain
from core.solve.params import SolverParams
from core.solve.problem import Correspondences, Problem
from core.solve.solver import energy
from core.solve.stages import solve


def _view_rmse(result, scene):
    masks = scene.problem.masks
    est = np.concatenate([v[m] for v, m in zip(result.views, masks)])
    gt = np.concatenate([g[m] for g, m in zip(scene.albedo_views, masks)])
    return scaled_rmse(est, gt)


def _image_rmse(scene):
    p = scene.problem
    return _view_rmse(type("R", (), {"views": p.images})(), scene)


@pytest.fixture(scope="module")
def varying():
    return sphere_scene(varying_light=True, n_views=6, height=60, width=80, texture_size=48, seed=3)


@pytest.fixture(scope="module")
def fixed():
    return sphere_scene(varying_light=False, n_views=6, height=60, width=80, texture_size=48, seed=4, noise=0.005)


@pytest.fixture(scope="module")
def textured():
    # The albedo is an image texture the renderer samples bilinearly, as in Blender.
    return sphere_scene(varying_light=True, n_views=6, height=60, width=80, texture_size=48, seed=3, textured=True)


@pytest.mark.parametrize(
    "domain,data_model,gauss_newton,extrapolate",
    [
        ("texture", "interpolate", False, 1.0),
        ("texture", "splat", False, 1.0),
        ("texture", "nearest", False, 1.0),
        ("image", "interpolate", False, 1.0),
        ("texture", "interpolate", True, 1.0),
        ("image", "interpolate", True, 1.0),
        ("texture", "splat", False, 0.0),
        ("image", "interpolate", False, 0.0),
    ],
)
def test_energy_never_increases(varying, domain, data_model, gauss_newton, extrapolate):
    r = solve(
        varying.problem,
        SolverParams(
            domain=domain,
            lam=0.5,
            max_iter=12,
            min_iter=12,
            levels=1,
            data_model=data_model,
            gauss_newton=gauss_newton,
            extrapolate=extrapolate,
        ),
    )
    e = np.asarray(r.energy)
    assert len(e) == 13
    assert np.all(np.diff(e) <= 0), np.diff(e)
    assert e[-1] < e[0]


def test_well_posed_recovery(textured):
    # Lighting varies across views (section 3, case 2): small lambda, noiseless, and the
    # texture-domain data model is the renderer's own, so the truth is an exact zero of
    # the data term. Measured, paper protocol (pixels of the views): 0.0012/0.0003/0.0014.
    # Over all seen texels 0.003/0.011/0.018: texels touched only by the corner of a
    # pixel's interpolation (data weight < 0.05) are set by TV alone.
    r = solve(
        textured.problem,
        SolverParams(
            lam=0.01, delta=1e-4, gauss_newton=True, data_model="interpolate", levels=1, max_iter=150, tol=1e-6
        ),
    )
    views = _view_rmse(r, textured)
    assert np.all(views < 0.01), views
    assert np.all(scaled_rmse(r.texture, textured.albedo_texture, r.seen) < 0.03)
    assert np.all(views < 0.05 * _image_rmse(textured)), views


def test_interpolated_data_term_is_zero_at_the_truth(textured):
    # A pixel sees the bilinear interpolation of the texture; only that model has the truth as a zero.
    sc = textured
    data = {}
    for model in ("interpolate", "splat"):
        d = texture_domain(sc.problem, data_model=model)
        rho = sc.albedo_texture.reshape(-1, sc.problem.channels)[d.texel_index]
        data[model] = energy(d, rho, sc.sigma, lam=0.0, mu=0.0, delta=1e-4)
    assert data["interpolate"] < 1e-3 * data["splat"], data


def test_observations_run_in_pixel_order_for_every_data_model(textured):
    # The merged data model takes each view's observations as one run, and the interpolated one each pixel's.
    for model in ("interpolate", "splat", "nearest", "merged"):
        d = texture_domain(textured.problem, data_model=model)
        assert np.all(np.diff(d.obs_pixel) >= 0), model


def test_the_data_term_in_chunks_is_the_data_term(fixed, monkeypatch):
    # With one unknown per observation the rho-step and the energy take the observations in chunks (7: many, the
    # last one short), with no array over all of them: the same solve as in one chunk, to float32 round-off.
    from core.solve import solver

    params = SolverParams(lam=0.5, max_iter=6, min_iter=6, levels=1, data_model="splat")
    whole = solve(fixed.problem, params)
    monkeypatch.setattr(solver, "_CHUNK", 7)
    chunked = solve(fixed.problem, params)
    np.testing.assert_allclose(chunked.energy, whole.energy, rtol=1e-5)
    np.testing.assert_allclose(chunked.texture[chunked.seen], whole.texture[whole.seen], rtol=1e-4, atol=1e-5)


def test_the_texture_domain_start_is_the_mean_of_the_observations_made_when_asked(textured):
    # The albedo stage starts elsewhere: the weighted mean of each texel's observations is made on first use only.
    d = texture_domain(textured.problem, data_model="splat")
    assert d.rho_start is None
    w = d.obs_weight.astype(np.float64)
    for c in range(3):
        num = np.bincount(d.obs_unknown, weights=w * d.values[d.obs_pixel, c], minlength=d.n_unknowns)
        mean = num / np.bincount(d.obs_unknown, weights=w, minlength=d.n_unknowns)
        np.testing.assert_allclose(d.rho0[:, c], mean, rtol=1e-6)
    assert d.rho0 is d.rho_start


def test_nearest_gives_each_pixel_one_observation_of_its_nearest_texel(textured):
    splat = texture_domain(textured.problem, data_model="splat")
    near = texture_domain(textured.problem, data_model="nearest")
    n_pixels = splat.nu.shape[0]
    assert np.array_equal(near.obs_pixel, np.arange(n_pixels))  # one each, in pixel order
    # Each pixel's whole weight (both normalised to their own number of texels, so up to one factor).
    ratio = near.obs_weight / splat.pixel_sum(splat.obs_weight.astype(np.float64))
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-4)
    # On the texel its splats weigh most.
    best = np.zeros(n_pixels)
    np.maximum.at(best, splat.obs_pixel, splat.obs_weight)
    texel = near.texel_index[near.obs_unknown]
    same = splat.texel_index[splat.obs_unknown] == texel[splat.obs_pixel]
    chosen = np.zeros(n_pixels)
    chosen[splat.obs_pixel[same]] = splat.obs_weight[same]
    np.testing.assert_allclose(chosen, best, rtol=1e-6)


def test_merged_gives_one_observation_per_texel_and_view_and_keeps_a_constant_albedo_exact():
    sc = sphere_scene(n_views=4, height=60, width=80, texture_size=16, n_cells=1, seed=2)
    splat = texture_domain(sc.problem, data_model="splat")
    merged = texture_domain(sc.problem, data_model="merged")
    # One observation for each (view, texel) pair of the splats, carrying their weight.
    view = np.searchsorted(splat.pixel_offsets, splat.obs_pixel, side="right") - 1
    pairs = np.unique(view * splat.n_unknowns + splat.obs_unknown)
    assert merged.obs_pixel.size == pairs.size < splat.obs_pixel.size / 3
    assert merged.n_views == splat.n_views and np.array_equal(merged.texel_index, splat.texel_index)
    np.testing.assert_allclose(
        merged.scatter(merged.obs_weight.astype(np.float64)),
        splat.scatter(splat.obs_weight.astype(np.float64)),
        rtol=1e-5,
    )
    # The shading is linear in the transfer, so a constant albedo fits the merged pixels as it fits the pixels.
    rho = sc.albedo_texture.reshape(-1, 3)[merged.texel_index]
    at_truth = energy(merged, rho, sc.sigma, lam=0.0, mu=0.0, delta=1e-4)
    assert at_truth < 1e-4 * energy(merged, 1.1 * rho, sc.sigma, lam=0.0, mu=0.0, delta=1e-4)
    with pytest.raises(ValueError, match="data_model"):
        texture_domain(sc.problem, data_model="mean")


def test_plain_alternation_stalls_where_gauss_newton_does_not(textured):
    # Why the joint step exists: from rho = I, alternating MM barely moves on this problem.
    p = SolverParams(lam=0.01, delta=1e-4, levels=1, max_iter=40, min_iter=40)
    plain = _view_rmse(solve(textured.problem, p), textured)
    joint = _view_rmse(solve(textured.problem, replace(p, gauss_newton=True)), textured)
    assert np.all(joint < 0.5 * plain), (joint, plain)


@pytest.mark.parametrize("domain", ["texture", "image"])
def test_energy_never_increases_after_a_coarse_start(varying, domain, monkeypatch):
    # The fixture is too small to coarsen by default; let it have one coarse level.
    monkeypatch.setattr(pyramid, "MIN_PIXELS", 1000)
    monkeypatch.setattr(pyramid, "MIN_SIZE", 16)
    p = varying.problem
    corr = find_correspondences(varying.cameras, varying.positions, p.masks, p.normals, neighbours=3)
    problem = Problem(
        p.images, p.masks, p.normals, correspondences=corr, uv=p.uv, texture=p.texture, view_weight=p.view_weight
    )
    params = SolverParams(domain=domain, lam=0.5, levels=2, coarse_iter=8, max_iter=12, min_iter=12)
    r = solve(problem, params)
    coarse = r.info["coarse"]
    assert coarse is not None and coarse["iterations"] == 8 and coarse["info"]["coarse"] is None
    if domain == "image":
        assert coarse["info"]["n_correspondence_rows"] > 0
    e = np.asarray(r.energy)
    assert len(e) == 13
    assert np.all(np.diff(e) <= 0), np.diff(e)
    # The history starts from the warm start, not from rho = I.
    cold = solve(problem, replace(params, levels=1, max_iter=1, min_iter=1))
    assert e[0] < cold.energy[0]


def test_fixed_lighting_beats_the_images(fixed):
    # Fixed lighting is the ill-posed case: TV must carry it. Measured 0.067/0.055/0.051
    # against 0.24/0.22/0.25 for rho = I; without the joint step 0.22/0.20/0.23.
    r = solve(fixed.problem, SolverParams(lam=1, delta=1e-4, gauss_newton=True, levels=1, max_iter=40))
    ours = _view_rmse(r, fixed)
    baseline = _image_rmse(fixed)
    assert np.all(ours < 0.6 * baseline), (ours, baseline)


def test_nothing_written_outside_the_masks(varying):
    for domain in ("texture", "image"):
        r = solve(varying.problem, SolverParams(domain=domain, max_iter=2, min_iter=1))
        for v, m in zip(r.views, varying.problem.masks):
            assert np.all(np.isnan(v[~m]))
            assert np.all(np.isfinite(v[m]))
        assert r.sigma.shape == (6, 3, 9)


def test_output_scale_convention(varying):
    # Mean shading over the observations is 1, so the albedo is in image units.
    r = solve(varying.problem, SolverParams(domain="texture", lam=0.1, max_iter=10))
    p = varying.problem
    from core.geometry.sh import sh_basis

    shade = np.concatenate(
        [sh_basis(n[m], np.float64) @ r.sigma[v].T for v, (n, m) in enumerate(zip(p.normals, p.masks))]
    )
    assert np.all(np.abs(shade.mean(axis=0) - 1) < 0.1)


def _two_view_problem(corr=None, lam=0.0):
    # Two views of the same flat patch under different constant lighting.
    h, w = 8, 10
    mask = np.ones((h, w), bool)
    normals = np.zeros((h, w, 3), np.float32)
    normals[..., 2] = 1
    rng = np.random.default_rng(0)
    albedo = rng.uniform(0.2, 0.8, (h, w, 1)).astype(np.float32)
    images = [albedo * 1.0, albedo * 1.0]
    return Problem(images, [mask, mask], [normals, normals], correspondences=corr), albedo


def test_correspondences_make_the_views_agree():
    h, w = 8, 10
    rng = np.random.default_rng(5)
    alb = rng.uniform(0.2, 0.8, (h, w, 1)).astype(np.float32)
    normals = np.zeros((h, w, 3), np.float32)
    normals[..., 2] = 1
    mask = np.ones((h, w), bool)
    # View 1 sees the same patch, with noise: the consistency term must pull the two maps together.
    img1 = alb + 0.05 * rng.standard_normal(alb.shape).astype(np.float32)
    ys, xs = np.mgrid[0:h, 0:w]
    pix = (ys * w + xs).ravel()
    corr = Correspondences(np.zeros(pix.size), pix, np.ones(pix.size), np.stack([xs.ravel(), ys.ravel()], 1))
    gaps = []
    for c in (None, corr):
        p = Problem([alb, img1], [mask, mask], [normals, normals], correspondences=c)
        r = solve(p, SolverParams(domain="image", lam=0.01, mu=10.0, delta=1e-3, max_iter=20))
        gaps.append(float(np.abs(r.views[0] - r.views[1]).mean()))
    assert gaps[1] < 0.2 * gaps[0], gaps


def test_cancel_and_progress(varying):
    calls = []
    with pytest.raises(Cancelled):
        solve(
            varying.problem,
            SolverParams(max_iter=20),
            progress=lambda f, m: calls.append(f),
            cancel=lambda: len(calls) >= 3,
        )
    assert calls and all(0 <= f <= 1 for f in calls)


@pytest.mark.parametrize(
    "bad",
    [
        dict(lam=-1),
        dict(mu=-0.5),
        dict(domain="surface"),
        dict(delta=0),
        dict(extrapolate=-1),
        dict(extrapolate=float("nan")),
        dict(light_extrapolate=-1),
        dict(data_model="bilinear"),
        dict(light_data_model="splats"),
        dict(max_texels_per_pixel=-1),
        dict(preconditioner="ilu"),
        dict(cg_iter=0),
    ],
)
def test_bad_params(varying, bad):
    with pytest.raises(ValueError):
        solve(varying.problem, SolverParams(**bad))


def test_progress_moves_forward_through_the_levels():
    scene = sphere_scene(n_views=4, height=240, width=320, texture_size=128, seed=7)
    seen = []
    solve(
        scene.problem,
        SolverParams(levels=3, coarse_iter=3, max_iter=3, min_iter=3),
        progress=lambda f, m: seen.append((f, m)),
    )
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions), seen
    assert any("coarse level" in m for _, m in seen) and fractions[-1] == 1.0


def test_a_texture_finer_than_the_photos_is_solved_coarser_and_sampled_up():
    sc = sphere_scene(n_views=6, height=60, width=80, texture_size=256, seed=2)
    capped = solve(sc.problem, SolverParams(max_iter=10))
    full = solve(sc.problem, SolverParams(max_iter=10, max_texels_per_pixel=0))
    assert capped.texture.shape == full.texture.shape == (256, 256, 3)
    assert capped.info["solved_size"] < 256 and full.info["solved_size"] == 256
    both = capped.seen & full.seen
    assert both.sum() > 0.9 * full.seen.sum()
    # Measured 0.226/0.228/0.258 against 0.241/0.237/0.276 at full size, in half the time.
    assert np.all(
        scaled_rmse(capped.texture, sc.albedo_texture, both) < scaled_rmse(full.texture, sc.albedo_texture, both) + 0.02
    )


@pytest.mark.parametrize("albedo_lam", [None, 1.0])
def test_the_same_result_on_any_number_of_threads(fixed, albedo_lam, monkeypatch):
    monkeypatch.setattr("core.solve.solver.SERIAL_OBSERVATIONS", 0)  # this problem is small: threads all the same
    params = SolverParams(lam=2.0, max_iter=8, coarse_iter=5, albedo_lam=albedo_lam, light_size=32, lighting="coupled")
    one = solve(fixed.problem, replace(params, threads=1))
    three = solve(fixed.problem, replace(params, threads=3))
    assert np.array_equal(one.texture, three.texture, equal_nan=True)
    assert np.array_equal(one.sigma, three.sigma) and one.energy == three.energy


def test_small_problems_run_their_channels_in_one_thread():
    from core.solve.solver import SERIAL_OBSERVATIONS, channel_threads

    assert channel_threads(SolverParams(), 3, SERIAL_OBSERVATIONS - 1) == 1
    assert channel_threads(SolverParams(), 3, SERIAL_OBSERVATIONS) == 3
    assert channel_threads(SolverParams(threads=2), 3, 10 * SERIAL_OBSERVATIONS) == 2


@pytest.mark.parametrize("same", [False, True])
def test_pair_rows_are_the_difference_rows_as_assembled(same):
    # The TV rows of the texture domain are built directly; they must be the general path's matrices, to the bit
    # (with a row from an unknown to itself, which sums to nothing, it takes the general path).
    from core.solve.discretization import _assemble, _difference_rows, _pair_rows

    rng = np.random.default_rng(4)
    a = rng.integers(0, 300, 1000)
    b = (a + rng.integers(1, 300, 1000)) % 300
    if same:
        b[7] = a[7]
    for made, assembled in zip(_pair_rows(a, b, 300), _assemble([_difference_rows(a, b)], 300)):
        assert made.shape == assembled.shape and made.indices.dtype == assembled.indices.dtype
        for part in ("indptr", "indices", "data"):
            np.testing.assert_array_equal(getattr(made, part), getattr(assembled, part))


def test_a_tv_edge_is_weighted_by_the_texel_side_it_crosses():
    from core.solve.discretization import _edge_lengths, _grid_edges

    rng = np.random.default_rng(0)
    size = 9
    pos = np.cumsum(rng.uniform(0.5, 1.5, (size, size, 3)), axis=0) + np.cumsum(
        rng.uniform(0.5, 1.5, (size, size, 3)), axis=1
    )
    pos[rng.random((size, size)) < 0.2] = np.nan  # texels outside the islands
    keep = np.isfinite(pos[..., 0])
    keep[4, 4] = True  # a kept texel without a position: its edges' lengths are unknown
    a, b, horizontal = _grid_edges(keep)
    length, got = _edge_lengths(pos.astype(np.float32), a, horizontal)
    p = pos.astype(np.float32).astype(np.float64)
    assert length.shape == got.shape == a.shape
    for t, u, h, n, g in zip(a, b, horizontal, length, got):
        r, c = divmod(int(t), size)
        np.testing.assert_equal(n, np.linalg.norm(p[r, c] - p[divmod(int(u), size)]))
        dr, dc = (1, 0) if h else (0, 1)  # across a horizontal edge the side runs along the rows
        near = [
            np.linalg.norm(p[r, c] - p[r + s * dr, c + s * dc])
            for s in (-1, 1)
            if 0 <= r + s * dr < size and 0 <= c + s * dc < size
        ]
        near = [x for x in near if np.isfinite(x)]
        assert (np.isnan(g) and not near) or g == pytest.approx(np.mean(near), rel=1e-12)
