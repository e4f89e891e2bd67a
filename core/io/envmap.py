"""The estimated lighting as an environment image: equirectangular, in Blender's world convention.

The solver's lighting ``sigma`` (9 coefficients per channel, :mod:`core.geometry.sh`)
is a *shading*: a photo is the albedo times ``sigma . T(x)``, where the
transfer T of an open point is ``nu(n)`` (:mod:`core.geometry.transfer`). The
distant radiance ``L(w) = sum_k c_k nu_k(w)`` (w the unit world direction
towards the light) gives a point the irradiance
``E(x) = integral V(x, w) max(0, n . w) L(w) dw = sum_k c_k A_l T_k(x)``
(Funk-Hecke; A_l the clamped cosine's coefficient of band l), and a Lambertian
albedo rho sends back ``rho E / pi``. So ``c_k = pi sigma_k / A_l``
(:func:`radiance_sh`: 1, 3/2 and 4 for the bands 0, 1, 2) is the environment
that relights the recovered albedo to the photos' values: with it as the world
(strength 1), a Diffuse BSDF of the albedo renders ``rho sigma . T(x)``.

The image is laid out as Blender's Environment Texture node reads it with its
default vector (Cycles' ``direction_to_equirectangular``): a direction d is
at ``u = 0.5 - atan2(d_y, d_x) / (2 pi)``, ``v = 1 - acos(d_z) / pi``, v = 1 the
top row. So +Z (up) is the top row, +X the middle column, +Y a quarter from the
left and -X the left and right edges.
"""

from __future__ import annotations

import numpy as np

from ..geometry.sh import sh_basis, sh_degree
from ..geometry.transfer import A_BAND

__all__ = [
    "ENVMAP_SIZE",
    "equirect_uv",
    "equirect_directions",
    "radiance_sh",
    "world_lighting",
    "envmap_image",
    "add_sun",
    "project_envmap",
]

#: Angular radius of the sun disc :func:`add_sun` draws (the real sun's is 0.27 degrees; a disc a few
#: pixels wide keeps its shadows about as sharp as the solve's one shadow map).
SUN_RADIUS_DEG = 2.5

#: (width, height) of the written environment image; ample for 9 coefficients.
ENVMAP_SIZE = (256, 128)

# The integral of each of the 9 basis functions squared over the sphere (they are orthogonal).
_SQUARED_NORM = np.array([1 / 3, 1 / 3, 1 / 3, 1, 1 / 15, 1 / 15, 1 / 15, 4 / 15, 4 / 5]) * 4 * np.pi


def equirect_uv(directions) -> tuple[np.ndarray, np.ndarray]:
    """Where Blender's Environment Texture reads each direction: ``(u, v)`` in [0, 1], v = 1 at the top.

    Parameters
    ----------
    directions : (..., 3) array
        World directions (Z up); need not be unit length.
    """
    d = np.asarray(directions, dtype=np.float64)
    r = np.linalg.norm(d, axis=-1)
    u = 0.5 - np.arctan2(d[..., 1], d[..., 0]) / (2 * np.pi)
    v = 1.0 - np.arccos(np.clip(d[..., 2] / np.where(r > 0, r, 1.0), -1.0, 1.0)) / np.pi
    return u, v


def equirect_directions(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """The unit direction at each pixel centre of a ``height x width`` image (row 0 at the top), and its solid angle.

    The inverse of :func:`equirect_uv`. Returns ``(H, W, 3)`` directions and
    ``(H, W)`` solid angles in steradians, summing to 4 pi.
    """
    u = (np.arange(width) + 0.5) / width
    theta = np.pi * (np.arange(height) + 0.5) / height  # from +Z: v = 1 - theta / pi, row 0 at v = 1
    phi = np.pi - 2 * np.pi * u
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    dirs = np.stack(np.broadcast_arrays(st * np.cos(phi), st * np.sin(phi), ct), axis=-1)
    # Exact area of each row's band of the sphere, split evenly between its pixels.
    edges = np.pi * np.arange(height + 1) / height
    band = 2 * np.pi * (np.cos(edges[:-1]) - np.cos(edges[1:]))
    return dirs, np.repeat((band / width)[:, None], width, axis=1)


def radiance_sh(sigma) -> np.ndarray:
    """The environment radiance's coefficients ``pi sigma_k / A_l`` of shading coefficients ``(..., 9)``."""
    s = np.asarray(sigma, dtype=np.float64)
    return s * (np.pi / A_BAND[sh_degree(s.shape[-1])])


def world_lighting(sigma) -> np.ndarray:
    """One lighting for the scene from each view's: their mean, ``(C, 9)`` from ``(m, C, 9)``.

    With the lighting shared between the views (``g_v sigma``) it is that
    lighting times the mean gain; with a lighting per view, their average.
    """
    return np.asarray(sigma, dtype=np.float64).mean(axis=0)


def envmap_image(radiance, size=ENVMAP_SIZE) -> np.ndarray:
    """The radiance ``sum_k c_k nu_k(w)`` as an equirectangular ``(H, W, 3)`` float32 image.

    Parameters
    ----------
    radiance : (C, 9) array
        :func:`radiance_sh` per channel; one channel (grey) is repeated into R, G and B.
    size : (int, int)
        Width and height.

    Notes
    -----
    Nine coefficients can dip below zero somewhere; a light cannot, so the
    image is clamped at 0 there (lighting.json keeps the exact coefficients).
    """
    c = np.asarray(radiance, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 9 or c.shape[0] not in (1, 3):
        raise ValueError(f"radiance has shape {c.shape}, expected (1, 9) or (3, 9)")
    dirs, _ = equirect_directions(*size)
    img = sh_basis(dirs, np.float64) @ c.T
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    return np.maximum(img, 0.0).astype(np.float32)


def add_sun(image, direction, strength) -> np.ndarray:
    """The image with a sun disc along ``direction`` whose light gives the shading ``strength * max(0, n . w)``.

    A distant light of radiance L over the solid angle W gives the irradiance
    ``L W max(0, n . w)``, which a Lambertian albedo rho sends back as
    ``rho L W / pi``: so the disc's radiance is ``pi strength / W``, with W
    the disc's pixels' own solid angle (:data:`SUN_RADIUS_DEG`).

    Parameters
    ----------
    image : (H, W, 3) array
        An equirectangular image (:func:`envmap_image`).
    direction : (3,) array
        Towards the sun, world space.
    strength : (C,) array
        The sun's coefficient per channel (C = 1 or 3), in the units of the shading.
    """
    out = np.array(image, dtype=np.float32)
    h, w = out.shape[:2]
    dirs, omega = equirect_directions(w, h)
    d = np.asarray(direction, np.float64) / np.linalg.norm(direction)
    cos = dirs @ d
    disc = cos >= np.cos(np.radians(SUN_RADIUS_DEG))
    if not disc.any():  # narrower than a pixel: the nearest one
        disc = cos == cos.max()
    s = np.broadcast_to(np.maximum(np.asarray(strength, np.float64), 0.0), (3,))
    out[disc] += (np.pi * s / float(omega[disc].sum())).astype(np.float32)
    return out


def project_envmap(image) -> np.ndarray:
    """The 9 coefficients per channel of an equirectangular image's radiance, ``(C, 9)``.

    The projection ``integral L(w) nu_k(w) dw / integral nu_k^2 dw`` over the
    pixels' solid angles: it recovers the coefficients of
    :func:`envmap_image` (where nothing was clamped) and gives the
    second-order part of any other environment laid out as Blender reads it.
    """
    img = np.asarray(image, dtype=np.float64)
    if img.ndim == 2:
        img = img[:, :, None]
    h, w = img.shape[:2]
    dirs, omega = equirect_directions(w, h)
    basis = sh_basis(dirs, np.float64) * omega[..., None]
    return np.einsum("hwk,hwc->ck", basis, img) / _SQUARED_NORM
