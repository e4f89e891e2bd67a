import json
import os
import subprocess
import sys

import numpy as np
import pytest

from core.cli import SH_BASIS, main, write_outputs
from core.io.bundle import load_bundle, save_bundle
from core.io.envmap import envmap_image, radiance_sh
from core.io.exr import read_exr
from core.io.names import unique_names
from core.solve.params import Result, SolverParams
from core.solve.problem import Correspondences, Problem, TextureLayout

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


# ---------------------------------------------------------------- synthetic data


def _view_axes(k):
    """Orthographic camera k: right, down and forward unit vectors (CV convention)."""
    yaw = 2 * np.pi * k / 3 + 0.3
    forward = np.array([np.cos(yaw), np.sin(yaw), -0.3])
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    return right, np.cross(forward, right), forward


def _sphere_uv(p):
    u = 0.5 + np.arctan2(p[..., 1], p[..., 0]) / (2 * np.pi)
    v = 0.5 + np.arcsin(np.clip(p[..., 2], -1, 1)) / np.pi
    return np.stack([u, v], axis=-1)


def _sh(n):
    n1, n2, n3 = n[..., 0], n[..., 1], n[..., 2]
    return np.stack([n1, n2, n3, np.ones_like(n1), n1 * n2, n1 * n3, n2 * n3, n1**2 - n2**2, 3 * n3**2 - 1], axis=-1)


def make_problem(
    sizes=((24, 32),) * 3, channels=3, texture=True, corr=True, weights=True, names=None, tex_size=16, seed=0
):
    """Views of a unit sphere with a two-tone albedo under per-view SH lighting."""
    rng = np.random.default_rng(seed)
    images, masks, normals, uvs, vws, frames = [], [], [], [], [], []
    for k, (h, w) in enumerate(sizes):
        right, down, forward = _view_axes(k)
        scale = 0.45 * min(h, w)
        y, x = np.mgrid[0:h, 0:w].astype(np.float64)
        a, b = (x - (w - 1) / 2) / scale, (y - (h - 1) / 2) / scale
        mask = a**2 + b**2 < 0.9
        depth = np.sqrt(np.clip(1 - a**2 - b**2, 0, None))
        p = a[..., None] * right + b[..., None] * down - depth[..., None] * forward
        albedo = np.where(p[..., 2:3] > 0.2, [0.8, 0.5, 0.3][:channels], [0.3, 0.4, 0.6][:channels])
        sigma = np.zeros((channels, 9))
        sigma[:, 3] = 0.7 + 0.1 * k
        sigma[:, :3] = 0.3 * rng.standard_normal(3)
        shading = np.einsum("hwj,cj->hwc", _sh(p), sigma)
        img = np.where(mask[..., None], albedo * shading, np.nan)
        images.append(img.astype(np.float32))
        masks.append(mask)
        normals.append(np.where(mask[..., None], p, 0.0))
        uvs.append(_sphere_uv(p))
        vws.append(np.where(mask, depth, 0.0))
        frames.append((p, right, down, forward, scale, h, w))
    c = None
    if corr:
        va, pa, vb, xyb = [], [np.zeros(0, int)], [], [np.zeros((0, 2))]
        for i, (p, *_rest) in enumerate(frames):
            idx = np.flatnonzero(masks[i].ravel())[::2]
            pts = p.reshape(-1, 3)[idx]
            for j, (_, right, down, forward, scale, h, w) in enumerate(frames):
                if j == i:
                    continue
                x = pts @ right * scale + (w - 1) / 2
                y = pts @ down * scale + (h - 1) / 2
                ok = (pts @ forward < -0.2) & (x > 0) & (y > 0) & (x < w - 1) & (y < h - 1)
                va += [i] * int(ok.sum())
                vb += [j] * int(ok.sum())
                pa.append(idx[ok])
                xyb.append(np.stack([x[ok], y[ok]], 1))
        c = Correspondences(va, np.concatenate(pa), vb, np.concatenate(xyb), rng.uniform(0.5, 1.0, len(va)))
    layout = None
    if texture:
        n = tex_size
        r, col = np.mgrid[0:n, 0:n]
        u, v = (col + 0.5) / n, 1 - (r + 0.5) / n
        phi, theta = (u - 0.5) * 2 * np.pi, (v - 0.5) * np.pi
        pos = np.stack([np.cos(theta) * np.cos(phi), np.cos(theta) * np.sin(phi), np.sin(theta)], -1)
        pos[0, 0] = np.nan  # one texel outside the islands
        seams = np.stack([np.arange(n) * n, np.arange(n) * n + n - 1], 1)
        layout = TextureLayout(pos, seams)
    return Problem(
        images,
        masks,
        normals,
        correspondences=c,
        uv=uvs if texture else None,
        texture=layout,
        view_weight=vws if weights else None,
        names=names or [f"cam{k}" for k in range(len(sizes))],
    )


# ---------------------------------------------------------------- bundle


def _assert_same(p, q):
    assert q.names == p.names
    for field in ("images", "masks", "normals", "uv", "view_weight"):
        a, b = getattr(p, field), getattr(q, field)
        assert (a is None) == (b is None), field
        for x, y in zip(a or [], b or []):
            assert x.dtype == y.dtype and x.shape == y.shape, field
            np.testing.assert_array_equal(x, y, err_msg=field)
    assert (p.correspondences is None) == (q.correspondences is None)
    if p.correspondences is not None:
        for f in ("view_a", "pixel_a", "view_b", "xy_b", "weight"):
            np.testing.assert_array_equal(getattr(p.correspondences, f), getattr(q.correspondences, f))
    assert (p.texture is None) == (q.texture is None)
    if p.texture is not None:
        np.testing.assert_array_equal(p.texture.texel_pos, q.texture.texel_pos)
        np.testing.assert_array_equal(p.texture.seam_pairs, q.texture.seam_pairs)


def test_round_trip_with_everything_and_different_view_sizes(tmp_path):
    p = make_problem(sizes=((24, 32), (20, 26), (30, 18)), names=["left", "a/b", "ü"])
    path = tmp_path / "problem.npz"
    save_bundle(path, p)
    q = load_bundle(path)
    assert [im.shape for im in q.images] == [(24, 32, 3), (20, 26, 3), (30, 18, 3)]
    assert len(q.correspondences) > 100
    _assert_same(p, q)
    with np.load(path, allow_pickle=False) as z:  # the documented keys
        per_view = {f"{k}_{i}" for k in ("image", "mask", "normal", "uv", "view_weight") for i in range(3)}
        assert set(z.files) == per_view | {
            "format",
            "version",
            "n_views",
            "names",
            "corr_view_a",
            "corr_pixel_a",
            "corr_view_b",
            "corr_xy_b",
            "corr_weight",
            "texel_pos",
            "seam_pairs",
        }
        assert int(z["n_views"]) == 3 and z["mask_0"].dtype == bool


def test_round_trip_minimal_grey(tmp_path):
    p = make_problem(channels=1, texture=False, corr=False, weights=False, sizes=((8, 10),))
    path = tmp_path / "no-suffix.bundle"  # the name is kept as given
    save_bundle(path, p)
    assert os.listdir(tmp_path) == ["no-suffix.bundle"]
    q = load_bundle(path)
    assert q.uv is None and q.view_weight is None and q.correspondences is None and q.texture is None
    assert q.channels == 1
    _assert_same(p, q)


def test_bundle_written_without_this_package(tmp_path):
    # the docstring's minimal example, with plain Python lists and default dtypes
    n = np.zeros((2, 3, 3))
    n[..., 2] = 1
    path = tmp_path / "ext.npz"
    np.savez_compressed(
        path,
        format="delight-problem-bundle",
        version=1,
        n_views=1,
        names=["photo"],
        image_0=np.full((2, 3, 3), 0.5),
        mask_0=np.ones((2, 3), int),
        normal_0=n,
        corr_view_a=[0],
        corr_pixel_a=[1],
        corr_view_b=[0],
        corr_xy_b=[[0.0, 1.0]],
    )
    q = load_bundle(path)
    assert q.names == ["photo"] and q.images[0].dtype == np.float32 and q.masks[0].all()
    np.testing.assert_array_equal(q.correspondences.weight, [1.0])


def _rewrite(src, dst, drop=(), **replace):
    with np.load(src, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if k not in drop}
    arrays.update(replace)
    np.savez(dst, **arrays)


@pytest.mark.parametrize(
    "key", ["format", "n_views", "names", "mask_1", "normal_0", "image_2", "corr_pixel_a", "uv_1", "view_weight_0"]
)
def test_missing_key_is_named(tmp_path, key):
    src, dst = tmp_path / "full.npz", tmp_path / "broken.npz"
    save_bundle(src, make_problem())
    _rewrite(src, dst, drop=(key,))
    with pytest.raises(ValueError, match=rf"broken\.npz.*missing key '{key}'"):
        load_bundle(dst)


def test_bad_bundles_give_clear_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing.npz"):
        load_bundle(tmp_path / "nothing.npz")
    text = tmp_path / "notes.npz"
    text.write_text("hello")
    with pytest.raises(ValueError, match=r"notes\.npz: not an \.npz archive"):
        load_bundle(text)
    npy = tmp_path / "single.npy"
    np.save(npy, np.zeros(3))
    with pytest.raises(ValueError, match="not an .npz archive"):
        load_bundle(npy)
    src = tmp_path / "good.npz"
    save_bundle(src, make_problem(sizes=((8, 10),) * 2))
    cases = {
        "float_index.npz": ({"corr_view_a": np.zeros(3)}, "'corr_view_a' holds indices"),
        "object.npz": ({"image_0": np.array([None, 1], dtype=object)}, "'image_0' cannot be read"),
        "newer.npz": ({"version": np.array(2)}, "version 2 is newer"),
        "other.npz": ({"format": np.array("something else")}, "format is 'something else'"),
        # the Problem's own validation, with the file named
        "bad_normals.npz": ({"normal_1": np.ones((8, 10, 3), np.float32)}, "view 1 .*unit length"),
        "view_count.npz": ({"n_views": np.array(3), "names": np.array(["a", "b", "c"])}, "missing key 'image_2'"),
        "few_names.npz": ({"names": np.array(["a"])}, "'names' must be 2 strings"),
    }
    for name, (replace, message) in cases.items():
        dst = tmp_path / name
        _rewrite(src, dst, **replace)
        with pytest.raises(ValueError, match=rf"{name}.*{message}"):
            load_bundle(dst)


def test_save_rejects_non_problems_and_keeps_existing_file(tmp_path):
    path = tmp_path / "p.npz"
    save_bundle(path, make_problem(sizes=((8, 10),)))
    before = path.read_bytes()
    with pytest.raises(TypeError, match="Problem"):
        save_bundle(path, {"images": []})
    with pytest.raises(FileNotFoundError):
        save_bundle(tmp_path / "missing" / "p.npz", make_problem(sizes=((8, 10),)))
    assert path.read_bytes() == before and os.listdir(tmp_path) == ["p.npz"]


# ---------------------------------------------------------------- file names


def test_safe_file_names():
    names = [
        "../../x",
        "a/b",
        "a\\b",
        "",
        "..",
        ".hidden",
        "CON",
        "con.jpg",
        "IMG 01.JPG",
        "img_01.jpg",
        "Img_01.JPG",
        "ok-1.x",
        "café",
    ]
    out = unique_names(names)
    assert out == [
        "_._.._x",
        "a_b",
        "a_b_2",
        "unnamed",
        "_.",
        "_hidden",
        "_CON",
        "_con.jpg",
        "IMG_01.JPG",
        "img_01.jpg_2",
        "Img_01.JPG_3",
        "ok-1.x",
        "caf_",
    ]
    assert len({n.lower() for n in out}) == len(out)
    assert all(os.path.basename(n) == n and not n.startswith(".") for n in out)
    assert unique_names(["x" * 300])[0] == "x" * 100


# ---------------------------------------------------------------- outputs


def _fake_result(problem, texture=True, seed=1):
    """A Result as the solver contract describes it (no solver involved)."""
    rng = np.random.default_rng(seed)
    c = problem.channels
    views = [
        np.where(m[..., None], rng.uniform(0, 1, m.shape + (c,)), np.nan).astype(np.float32) for m in problem.masks
    ]
    tex = seen = None
    if texture:
        n = problem.texture.size
        seen = rng.uniform(size=(n, n)) > 0.3
        tex = np.where(seen[..., None], rng.uniform(0, 1, (n, n, c)), np.nan).astype(np.float32)
    return Result(
        sigma=rng.standard_normal((problem.n_views, c, 9)),
        views=views,
        energy=[10.0, 5.0, 4.5],
        iterations=2,
        texture=tex,
        seen=seen,
        info={"scale": np.float64(0.5), "hist": np.arange(3)},
    )


def test_write_outputs_keeps_everything_inside_the_folder(tmp_path):
    p = make_problem(names=["../../x", "a/b", "A/B"])
    result = _fake_result(p)
    out = tmp_path / "run" / "out"
    files = write_outputs(out, p, result, SolverParams(lam=2.0), elapsed=1.25, bundle="b.npz")

    written = sorted(os.path.relpath(os.path.join(d, f), tmp_path) for d, _, fs in os.walk(tmp_path) for f in fs)
    assert written == sorted(
        [
            "run/out/albedo.exr",
            "run/out/lighting.exr",
            "run/out/lighting.json",
            "run/out/report.json",
            "run/out/views/_._.._x.exr",
            "run/out/views/a_b.exr",
            "run/out/views/A_B_2.exr",
        ]
    )
    assert files["views"] == ["views/_._.._x.exr", "views/a_b.exr", "views/A_B_2.exr"]

    for i, rel in enumerate(files["views"]):
        rgba, ch = read_exr(out / rel)
        mask = p.masks[i]
        assert ch == ["R", "G", "B", "A"]
        np.testing.assert_array_equal(rgba[..., 3], mask.astype(np.float32))
        np.testing.assert_array_equal(rgba[mask, :3], result.views[i][mask])
        assert not rgba[~mask, :3].any()

    rgba, _ = read_exr(out / "albedo.exr")
    np.testing.assert_array_equal(rgba[..., 3], result.seen.astype(np.float32))
    np.testing.assert_array_equal(rgba[result.seen, :3], result.texture[result.seen])
    assert not rgba[~result.seen, :3].any()

    light = json.loads((out / "lighting.json").read_text())
    assert light["sh_basis"] == SH_BASIS == ["n1", "n2", "n3", "1", "n1*n2", "n1*n3", "n2*n3", "n1^2-n2^2", "3*n3^2-1"]
    assert [v["name"] for v in light["views"]] == ["../../x", "a/b", "A/B"]
    assert [v["file"] for v in light["views"]] == files["views"]
    np.testing.assert_array_equal(np.array([v["sh"] for v in light["views"]]), result.sigma)
    # The world lighting: the views' mean, as the environment image beside lighting.json.
    assert files["envmap"] == light["world"]["file"] == "lighting.exr"
    world = radiance_sh(result.sigma.mean(axis=0))
    np.testing.assert_allclose(light["world"]["radiance_sh"], world)
    np.testing.assert_array_equal(read_exr(out / "lighting.exr")[0], envmap_image(world))

    report = json.loads((out / "report.json").read_text())
    assert report["params"]["lam"] == 2.0 and report["params"]["domain"] == "texture"
    assert report["iterations"] == 2 and report["energy"] == [10.0, 5.0, 4.5]
    assert report["time_s"] == 1.25 and report["info"] == {"scale": 0.5, "hist": [0, 1, 2]}


def test_write_outputs_grey_image_domain(tmp_path):
    p = make_problem(channels=1, texture=False, sizes=((12, 16), (10, 14)))
    result = _fake_result(p, texture=False)
    result.energy = [3.0, float("nan")]  # not valid JSON: written as null
    files = write_outputs(tmp_path, p, result, SolverParams(domain="image"))
    assert "albedo" not in files and not (tmp_path / "albedo.exr").exists()
    rgba, _ = read_exr(tmp_path / files["views"][1])
    m = p.masks[1]
    for k in range(3):  # grey repeated into R, G and B
        np.testing.assert_array_equal(rgba[m, k], result.views[1][m, 0])
    light = json.loads((tmp_path / "lighting.json").read_text())
    assert light["channels"] == ["Y"] and np.shape(light["views"][0]["sh"]) == (1, 9)
    env, channels = read_exr(tmp_path / "lighting.exr")  # grey lighting, an RGB sky for Blender
    assert channels == ["R", "G", "B"] and (env[..., 0] == env[..., 2]).all()
    assert json.loads((tmp_path / "report.json").read_text())["energy"] == [3.0, None]


def test_write_outputs_rejects_a_result_that_does_not_fit(tmp_path):
    p = make_problem(texture=False)
    result = _fake_result(p, texture=False)
    result.sigma = result.sigma[:2]
    with pytest.raises(ValueError, match=r"sigma has shape \(2, 3, 9\), expected \(3, 3, 9\)"):
        write_outputs(tmp_path / "o", p, result, SolverParams())
    assert not (tmp_path / "o").exists()


# ---------------------------------------------------------------- command line


def _run(*args):
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    return subprocess.run(
        [sys.executable, "-m", "core", *map(str, args)], cwd=ROOT, env=env, capture_output=True, text=True, timeout=60
    )


def test_help():
    r = _run("--help")
    assert r.returncode == 0 and "solve" in r.stdout
    r = _run("solve", "--help")
    assert r.returncode == 0
    for option in ("--out", "--domain", "--lambda", "--mu", "--max-iter", "--delta"):
        assert option in r.stdout


def test_bad_input_exits_with_one_line(tmp_path):
    out = tmp_path / "out"
    text = tmp_path / "scene.npz"
    text.write_text("not a bundle")
    no_texture = tmp_path / "image_only.npz"
    save_bundle(no_texture, make_problem(texture=False, sizes=((8, 10),)))
    cases = [
        ((tmp_path / "missing.npz",), "missing.npz"),
        ((text,), "scene.npz: not an .npz archive"),
        ((no_texture, "--domain", "texture"), "needs a texture layout"),
    ]
    for args, message in cases:
        r = _run("solve", *args, "--out", out)
        assert r.returncode == 1, r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], r.stderr
        assert not out.exists()
    (tmp_path / "file").write_text("")
    r = _run("solve", no_texture, "--out", tmp_path / "file")
    assert r.returncode == 1 and "not a folder" in r.stderr
    r = _run("solve", no_texture, "--out", out, "--lambda", "-1")
    assert r.returncode == 1 and r.stderr == "error: lambda must be a number of at least 0 or auto, got -1\n"
    r = _run("solve", no_texture, "--out", out, "--lambda", "soft")  # not a number: a usage error
    assert r.returncode == 2 and "--lambda" in r.stderr and "got 'soft'" in r.stderr


@pytest.mark.parametrize("domain", ["texture", "image"])
def test_solve_end_to_end(tmp_path, capsys, domain):
    p = make_problem(names=["left", "../../x", "left"])
    bundle = tmp_path / "problem.npz"
    save_bundle(bundle, p)
    out = tmp_path / "out"
    status = main(["solve", str(bundle), "--out", str(out), "--domain", domain, "--max-iter", "3", "--lambda", "1"])
    assert status == 0
    assert "delight:" in capsys.readouterr().err  # progress went to stderr

    names = ["left", "_._.._x", "left_2"]
    assert sorted(os.listdir(out / "views")) == sorted(f"{n}.exr" for n in names)
    for i, n in enumerate(names):
        rgba, ch = read_exr(out / "views" / f"{n}.exr")
        assert ch == ["R", "G", "B", "A"] and rgba.shape == (24, 32, 4)
        np.testing.assert_array_equal(rgba[..., 3], p.masks[i].astype(np.float32))
        assert np.isfinite(rgba).all() and not rgba[~p.masks[i], :3].any()
        assert rgba[p.masks[i], :3].max() > 0
    light = json.loads((out / "lighting.json").read_text())
    assert np.shape([v["sh"] for v in light["views"]]) == (3, 3, 9)
    report = json.loads((out / "report.json").read_text())
    assert report["params"]["domain"] == domain and report["params"]["max_iter"] == 3
    assert 1 <= report["iterations"] <= 3 and report["time_s"] >= 0
    assert all(e is not None for e in report["energy"])
    if domain == "texture":
        rgba, _ = read_exr(out / "albedo.exr")
        assert rgba.shape == (16, 16, 4) and set(np.unique(rgba[..., 3])) <= {0.0, 1.0}
        assert rgba[..., 3].any()
    else:
        assert not (out / "albedo.exr").exists()


def test_solve_passes_the_solver_options(tmp_path):
    bundle = tmp_path / "problem.npz"
    save_bundle(bundle, make_problem())
    out = tmp_path / "out"
    assert (
        main(
            [
                "solve",
                str(bundle),
                "--out",
                str(out),
                "--max-iter",
                "2",
                "--data-model",
                "interpolate",
                "--gauss-newton",
            ]
        )
        == 0
    )
    params = json.loads((out / "report.json").read_text())["params"]
    assert params["data_model"] == "interpolate" and params["gauss_newton"] is True
    rgba, _ = read_exr(out / "albedo.exr")
    assert np.isfinite(rgba).all() and rgba[..., 3].any()


def test_the_readmes_python_example_runs_as_written(tmp_path):
    # The README's snippet, run on a bundle of a synthetic sphere: the names it uses exist and say what it says.
    from core.evaluate.synthetic import sphere_scene

    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as fh:
        blocks = fh.read().split("```python\n")[1:]
    code = [b.split("```")[0] for b in blocks if "load_bundle" in b]
    assert len(code) == 1, "the README has one Python example of the solver"
    scene = sphere_scene(n_views=6, texture_size=32, seed=2)
    path = tmp_path / "scene.npz"
    save_bundle(str(path), scene.problem)
    names = {}
    exec(code[0].replace('"scene.npz"', repr(str(path))), names)  # noqa: S102 (our own README)
    ours, paper = names["ours"], names["paper"]
    assert ours.texture.shape == (32, 32, 3) and ours.sigma.shape == (6, 3, 9)
    assert np.all(np.diff(ours.energy) <= 0) and np.all(np.diff(paper.energy) <= 0)
    # "NaN where no photo saw"
    assert np.array_equal(np.isnan(ours.texture).any(axis=-1), ~ours.seen) and ours.seen.any()
