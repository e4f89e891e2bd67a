"""Problem data for multi-view reflectance estimation.

A :class:`Problem` holds everything the solver needs, as plain NumPy arrays:
for each of the m views a linear image, a mask and per-pixel unit normals;
optionally the pixel correspondences between views (image domain) and the
per-pixel texture coordinates plus a :class:`TextureLayout` (texture domain).

Conventions
-----------
* Images are ``(H, W, C)`` float32, linear, C = 1 or 3. Row 0 is the top row.
* Continuous pixel coordinates ``(x, y)`` put the centre of pixel
  ``(row r, col c)`` at ``(c, r)``: x to the right, y down.
* UV coordinates are Blender's: u to the right, v up, both in [0, 1].
* A texture of size N is an ``(N, N, ...)`` array with row 0 at the top
  (v = 1), as EXR viewers expect. Texel ``(r, c)`` has its centre at
  ``u = (c + 0.5) / N``, ``v = 1 - (r + 0.5) / N``.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from ..geometry.correspondences import Correspondences
from ..geometry.texels import TextureLayout
from ..masks import masked

__all__ = ["Problem", "SUN_COLUMNS", "row_blocks", "stacked_rows"]

#: Width of a transfer with a sun term: order 2's 9 SH coefficients, then the sun's (Problem.transfer).
SUN_COLUMNS = 10


def _fail(msg):
    raise ValueError(msg)


def row_blocks(counts, width: int, dtype=np.float32) -> list:
    """Consecutive row blocks ``(counts[i], width)`` of one new array, to fill in place (a transfer per view).

    :func:`stacked_rows` gives the whole array back without copying it.
    """
    rows = np.empty((int(np.sum(counts)), width), dtype)
    return np.split(rows, np.cumsum(counts)[:-1])


def stacked_rows(blocks) -> np.ndarray:
    """The rows of ``blocks`` one after another: the array they are consecutive blocks of, else a new one."""
    base = blocks[0].base
    if isinstance(base, np.ndarray) and base.ndim == 2 and base.flags.c_contiguous:
        start, step = base.__array_interface__["data"][0], base.strides[0]
        rows = 0
        for b in blocks:
            if not b.size and b.shape[1:] == base.shape[1:]:
                continue  # an empty block's pointer says nothing
            if b.base is not base or b.shape[1:] != base.shape[1:] or b.__array_interface__["data"][0] != start:
                break
            start += b.shape[0] * step
            rows += b.shape[0]
        else:
            if rows == base.shape[0] and base.dtype == blocks[0].dtype:
                return base
    return np.concatenate(blocks)


@dataclass
class Problem:
    """Inputs of the reflectance estimation, validated on construction.

    Parameters
    ----------
    images : list of (H, W, C) arrays
        Linear images, one per view; C is 1 or 3 and the same for all views.
    masks : list of (H, W) bool arrays
        Pixels that see the surface (Omega^i). Must not be empty.
    normals : list of (H, W, 3) arrays
        Unit world-space normals, checked inside the masks only.
    correspondences : Correspondences, optional
        Needed by the image-domain solver's consistency term.
    uv : list of (H, W, 2) arrays, optional
        Texture coordinates of each hit pixel, needed by the texture domain
        and by fusion.
    texture : TextureLayout, optional
        Needed by the texture-domain solver.
    view_weight : list of (H, W) arrays, optional
        Confidence of each pixel in [0, 1], typically the cosine between the
        normal and the viewing ray; grazing views count less. Default 1.
    names : list of str, optional
        View names, used in messages and output file names.
    transfer : list of (P_i, K) arrays, optional
        Per masked pixel (in the order ``image[mask]`` gives them), the SH
        transfer that replaces ``nu(normal)`` in the shading ``sigma . nu``
        (occlusion-aware, :mod:`core.geometry.transfer`); K is 9 (the paper's
        order 2), 16 or 25 (orders 3 and 4), or 10: order 2 and a sun term
        (:class:`core.geometry.sun.SunLight`) as the last column, whose
        coefficient the solver keeps >= 0.
        Default: the paper's ``nu`` of the normals.
    clipped : list of (H, W) bool arrays, optional
        Pixels of 8-bit photos that clipped in some channel (:func:`core.io.photos.clipped_pixels`): their
        values are lower bounds of the light that reached the camera. None for a view (a float photo) or
        for all: none clipped.
    light_texture : TextureLayout, optional
        The layout the lighting stage coarsens to its own size (:func:`core.solve.stages.lighting_stage`),
        rasterised at a size of its own so that the lighting does not depend on ``texture``'s. Default:
        ``texture``.
    """

    images: list
    masks: list
    normals: list
    correspondences: Correspondences | None = None
    uv: list | None = None
    texture: TextureLayout | None = None
    view_weight: list | None = None
    names: list = field(default_factory=list)
    transfer: list | None = None
    clipped: list | None = None
    light_texture: TextureLayout | None = None

    def __post_init__(self):
        m = len(self.images)
        if m == 0:
            _fail("problem: no views")
        if not self.names:
            self.names = [f"view{i}" for i in range(m)]
        if len(self.names) != m:
            _fail(f"problem: {len(self.names)} names for {m} views")
        for what, seq in (
            ("masks", self.masks),
            ("normals", self.normals),
            ("uv", self.uv),
            ("view_weight", self.view_weight),
            ("clipped", self.clipped),
        ):
            if seq is not None and len(seq) != m:
                _fail(f"problem: {len(seq)} {what} for {m} images")
        self.images = [np.asarray(a, dtype=np.float32) for a in self.images]
        self.images = [a[:, :, None] if a.ndim == 2 else a for a in self.images]
        self.masks = [np.asarray(a, dtype=bool) for a in self.masks]
        self.normals = [np.asarray(a, dtype=np.float32) for a in self.normals]
        channels = self.images[0].shape[2] if self.images[0].ndim == 3 else None
        for i, (img, mask, nrm) in enumerate(zip(self.images, self.masks, self.normals)):
            v = f"view {i} ({self.names[i]})"
            if img.ndim != 3 or img.shape[2] not in (1, 3):
                _fail(f"{v}: image must be (H, W, 1) or (H, W, 3), got {img.shape}")
            if img.shape[2] != channels:
                _fail(f"{v}: has {img.shape[2]} channels, view 0 has {channels}")
            hw = img.shape[:2]
            if mask.shape != hw:
                _fail(f"{v}: mask shape {mask.shape} does not match image {hw}")
            if nrm.shape != hw + (3,):
                _fail(f"{v}: normals shape {nrm.shape}, expected {hw + (3,)}")
            if not mask.any():
                _fail(f"{v}: the mask is empty (no pixel sees the surface)")
            bad = ~np.isfinite(masked(img, mask)).all(axis=1)
            if bad.any():
                _fail(f"{v}: {int(bad.sum())} pixels inside the mask are NaN or infinite")
            nm = masked(nrm, mask)
            if not np.isfinite(nm).all():
                _fail(f"{v}: normals inside the mask are NaN or infinite")
            length = np.linalg.norm(nm, axis=1)
            if np.any(np.abs(length - 1) > 1e-2):
                worst = float(length[np.argmax(np.abs(length - 1))])
                _fail(f"{v}: normals inside the mask must have unit length (found length {worst:.3g})")
            if self.uv is not None:
                uv = self.uv[i] = np.asarray(self.uv[i], dtype=np.float32)
                if uv.shape != hw + (2,):
                    _fail(f"{v}: uv shape {uv.shape}, expected {hw + (2,)}")
                if not np.isfinite(masked(uv, mask)).all():
                    _fail(f"{v}: uv inside the mask is NaN or infinite")
            if self.view_weight is not None:
                w = self.view_weight[i] = np.asarray(self.view_weight[i], dtype=np.float32)
                if w.shape != hw:
                    _fail(f"{v}: view_weight shape {w.shape}, expected {hw}")
                wm = w[mask]
                if not np.isfinite(wm).all() or wm.min() < 0:
                    _fail(f"{v}: view_weight inside the mask must be finite and >= 0")
        if self.clipped is not None and all(c is None for c in self.clipped):
            self.clipped = None
        if self.clipped is not None:
            self.clipped = [
                np.zeros(img.shape[:2], bool) if c is None else np.asarray(c, dtype=bool)
                for c, img in zip(self.clipped, self.images)
            ]
            for i, (c, img) in enumerate(zip(self.clipped, self.images)):
                if c.shape != img.shape[:2]:
                    _fail(f"view {i} ({self.names[i]}): clipped shape {c.shape}, expected {img.shape[:2]}")
        if self.transfer is not None:
            self._check_transfer()
        if self.correspondences is not None:
            self._check_correspondences()
        self._check_layout(self.texture)

    def _check_layout(self, texture):
        if texture is not None and self.uv is None:
            _fail("problem: a texture layout needs per-pixel uv")

    def on_layout(self, texture: TextureLayout) -> Problem:
        """The same photos on another texture layout, without checking them again (they were, once)."""
        self._check_layout(texture)
        out = copy.copy(self)
        out.texture = texture
        return out

    def _check_transfer(self):
        if len(self.transfer) != self.n_views:
            _fail(f"problem: {len(self.transfer)} transfers for {self.n_views} images")
        self.transfer = [np.asarray(t, dtype=np.float32) for t in self.transfer]
        for i, (t, mask) in enumerate(zip(self.transfer, self.masks)):
            n = int(np.count_nonzero(mask))
            if (
                t.ndim != 2
                or t.shape[0] != n
                or t.shape[1] not in (9, SUN_COLUMNS, 16, 25)
                or t.shape[1] != self.transfer[0].shape[1]
            ):
                _fail(
                    f"view {i} ({self.names[i]}): transfer shape {t.shape}, expected ({n}, 9): one row per masked "
                    "pixel (or 10, 16 or 25 coefficients, the same in every view)"
                )
            if not np.isfinite(t).all():
                _fail(f"view {i} ({self.names[i]}): transfer is NaN or infinite")

    def _check_correspondences(self):
        c = self.correspondences
        m = self.n_views
        for name, views in (("view_a", c.view_a), ("view_b", c.view_b)):
            if views.size and (views.min() < 0 or views.max() >= m):
                _fail(f"correspondences: {name} index out of range [0, {m})")
        if len(c) == 0:
            return
        sizes = np.array([mk.size for mk in self.masks])
        if c.pixel_a.min() < 0 or np.any(c.pixel_a >= sizes[c.view_a]):
            k = int(np.flatnonzero((c.pixel_a < 0) | (c.pixel_a >= sizes[c.view_a]))[0])
            _fail(f"correspondences: pair {k} has pixel_a {c.pixel_a[k]} out of range for view {c.view_a[k]}")
        hs = np.array([mk.shape[0] for mk in self.masks])
        ws = np.array([mk.shape[1] for mk in self.masks])
        x, y = c.xy_b[:, 0], c.xy_b[:, 1]
        out = (x < -0.5) | (y < -0.5) | (x > ws[c.view_b] - 0.5) | (y > hs[c.view_b] - 0.5)
        if out.any():
            k = int(np.flatnonzero(out)[0])
            _fail(f"correspondences: pair {k} has xy_b {tuple(c.xy_b[k])} outside view {c.view_b[k]}")
        flat_mask = [mk.ravel() for mk in self.masks]
        for i in np.unique(c.view_a):
            sel = c.view_a == i
            if not flat_mask[i][c.pixel_a[sel]].all():
                _fail(f"correspondences: some pixel_a of view {i} lie outside its mask")

    @property
    def n_views(self) -> int:
        return len(self.images)

    @property
    def channels(self) -> int:
        return int(self.images[0].shape[2])

    def pixel_index(self, i: int) -> np.ndarray:
        """Flat indices of the masked pixels of view i, in row-major order."""
        return np.flatnonzero(self.masks[i].ravel())
