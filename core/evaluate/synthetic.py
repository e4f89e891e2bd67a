"""Synthetic problems with known albedo: a sphere seen by perspective cameras.

Ray casting, normals, UVs and the texture layout are analytic, so tests and
benchmarks can check recovered albedo against exact ground truth without
Blender. UVs are equirectangular: ``u = lon / 2 pi + 1/2``, ``v = lat / pi + 1/2``
(z up), with the seam at lon = +-pi.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.bilinear import interpolate
from ..geometry.camera import Camera
from ..geometry.sh import sh_basis
from ..geometry.texels import bilinear_texels
from ..solve.problem import Problem, TextureLayout

__all__ = ["SyntheticScene", "sphere_scene"]


@dataclass
class SyntheticScene:
    problem: Problem
    cameras: list
    albedo_views: list  # (H, W, C) ground truth per view, NaN outside masks
    albedo_texture: np.ndarray  # (N, N, C) ground truth on the texels
    sigma: np.ndarray  # (m, C, 9) true lighting
    positions: list  # (H, W, 3) hit points, NaN outside masks

    def errors(self, result) -> tuple[float, float]:
        """A texture-domain solve of this scene against its truth: the shading error (relative, one scale per
        channel) and the albedo's RMSE (the paper's protocol), each the mean over the channels."""
        from ..solve.discretization import texture_domain
        from ..solve.lighting import shading_error
        from .metrics import scaled_rmse

        d = texture_domain(self.problem)
        shading = float(shading_error(d, result.sigma, self.sigma).mean())
        return shading, float(np.mean(scaled_rmse(result.texture, self.albedo_texture, result.seen)))


def _look_at(eye, target=(0, 0, 0), up=(0, 0, 1)):
    f = np.asarray(target, float) - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    if np.linalg.norm(r) < 1e-6:
        r = np.cross(f, (0, 1, 0))
    r /= np.linalg.norm(r)
    d = np.cross(f, r)  # camera y points down
    R = np.stack([r, d, f])
    return R, -R @ eye


def _albedo(points, cells, colors, smooth=False):
    """Albedo on the sphere: the colour of the nearest cell centre, or a smooth blend of them."""
    flat = points.reshape(-1, 3)
    out = np.full((flat.shape[0], colors.shape[1]), np.nan)
    ok = np.all(np.isfinite(flat), axis=1)
    if smooth:
        w = np.exp(4 * (flat[ok] @ cells.T))
        out[ok] = (w @ colors) / w.sum(axis=1, keepdims=True)
    else:
        out[ok] = colors[np.argmax(flat[ok] @ cells.T, axis=1)]
    return out.reshape(points.shape[:-1] + (colors.shape[1],))


def _sphere_uv(p):
    lon = np.arctan2(p[..., 1], p[..., 0])
    lat = np.arcsin(np.clip(p[..., 2], -1, 1))
    return np.stack([lon / (2 * np.pi) + 0.5, lat / np.pi + 0.5], axis=-1)


def _lighting(rng, n_views, channels, varying):
    """SH lighting: ambient plus a directional part; positive on the whole sphere."""
    tint = 1 + 0.1 * rng.standard_normal(channels)

    def one(direction):
        s = np.zeros(9)
        s[3] = 0.7
        s[0:3] = 0.6 * direction
        s[4:] = 0.08 * rng.standard_normal(5)
        return s

    base = rng.standard_normal(3)
    base /= np.linalg.norm(base)
    sig = np.empty((n_views, channels, 9))
    for v in range(n_views):
        d = rng.standard_normal(3) if varying else base
        d = d / np.linalg.norm(d)
        s = one(d) if (varying or v == 0) else sig[0, 0] / tint[0]
        sig[v] = s[None, :] * tint[:, None]
    return sig


def sphere_scene(
    n_views=6,
    height=60,
    width=80,
    channels=3,
    texture_size=64,
    n_cells=12,
    varying_light=False,
    noise=0.0,
    seed=0,
    distance=3.5,
    smooth_albedo=False,
    textured=False,
) -> SyntheticScene:
    """A unit sphere with a piecewise-constant albedo, seen by ``n_views`` cameras on two rings.

    The albedo is defined on the sphere (nearest of ``n_cells`` random cell
    centres, or a smooth blend of their colours), so the ground truth is exact
    per pixel and per texel. With ``textured``, the sphere instead carries
    that albedo as an image texture (its values at the texel centres) and
    each pixel sees the texture's bilinear interpolation at its UV, as a
    renderer samples an image texture; the texels are then the exact truth.
    """
    rng = np.random.default_rng(seed)
    N = texture_size
    rows, cols = np.mgrid[0:N, 0:N]
    lon = ((cols + 0.5) / N - 0.5) * 2 * np.pi
    lat = (0.5 - (rows + 0.5) / N) * np.pi
    tex_pos = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)
    cells = rng.standard_normal((n_cells, 3))
    cells /= np.linalg.norm(cells, axis=1, keepdims=True)
    colors = rng.uniform(0.15, 0.9, size=(n_cells, channels))
    sigma = _lighting(rng, n_views, channels, varying_light)
    texture_albedo = _albedo(tex_pos, cells, colors, smooth_albedo)
    f = 0.9 * min(width, height) / 2 / np.tan(np.arcsin(1 / distance))
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    images, masks, normals, uvs, weights, cams, gts, poss = [], [], [], [], [], [], [], []
    for v in range(n_views):
        az = 2 * np.pi * v / n_views
        el = 0.35 if v % 2 == 0 else -0.25
        eye = distance * np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])
        R, t = _look_at(eye)
        cam = Camera(K, R, t, width, height)
        d = cam.ray_directions()
        b = d @ eye
        disc = b * b - (eye @ eye - 1)
        mask = disc > 0
        tt = -b - np.sqrt(np.where(mask, disc, 0))
        p = eye + tt[..., None] * d
        p[~mask] = np.nan
        n = np.where(mask[..., None], p, 0)
        uv = np.where(mask[..., None], _sphere_uv(np.nan_to_num(p)), 0)
        if textured:
            flat, wts = bilinear_texels(uv[mask], np.ones((N, N), bool))
            alb = np.full(mask.shape + (channels,), np.nan)
            alb[mask] = interpolate(texture_albedo.reshape(N * N, -1), flat, wts)
        else:
            alb = _albedo(p, cells, colors, smooth_albedo)
        shade = np.einsum("hwk,ck->hwc", sh_basis(n, np.float64), sigma[v])
        img = np.where(mask[..., None], alb * shade, 0)
        if noise:
            img = img + noise * rng.standard_normal(img.shape) * mask[..., None]
        images.append(img.astype(np.float32))
        masks.append(mask)
        normals.append(n.astype(np.float32))
        uvs.append(uv.astype(np.float32))
        weights.append(np.clip(-(n * d).sum(-1), 0, 1).astype(np.float32))
        cams.append(cam)
        gts.append(alb.astype(np.float32))
        poss.append(p)
    r = np.arange(N)
    seam = np.concatenate(
        [
            np.stack([r * N, r * N + N - 1], axis=1),  # lon = -pi <-> +pi
            np.stack([r[: N // 2], (r[: N // 2] + N // 2) % N], axis=1),  # across the north pole
            np.stack([(N - 1) * N + r[: N // 2], (N - 1) * N + (r[: N // 2] + N // 2) % N], axis=1),
        ]
    )
    layout = TextureLayout(tex_pos, seam)
    problem = Problem(
        images,
        masks,
        normals,
        uv=uvs,
        texture=layout,
        view_weight=weights,
        names=[f"cam{v:02d}" for v in range(n_views)],
    )
    return SyntheticScene(problem, cams, gts, texture_albedo.astype(np.float32), sigma, poss)
