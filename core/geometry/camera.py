"""Pinhole cameras as plain arrays.

The core uses the computer-vision convention: camera coordinates have x to
the right, y down and z forward, and a world point X maps to camera
coordinates ``R @ X + t``. Pixel coordinates follow :mod:`core.solve.problem`: the
centre of pixel ``(row r, col c)`` is at ``(x, y) = (c, r)``. A Blender
camera (looking down -Z with +Y up, pixel centres at ``c + 0.5``) converts
with ``R_cv = diag(1, -1, -1) @ R_blender`` and ``cx_core = cx_blender - 0.5``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Camera"]


@dataclass
class Camera:
    """A pinhole camera with intrinsics ``K`` and world-to-camera ``(R, t)``.

    Parameters
    ----------
    K : (3, 3) array
        ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in core pixel coordinates.
    R : (3, 3) array
        Rotation, world to camera.
    t : (3,) array
        Translation, world to camera.
    width, height : int
        Image size in pixels.
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int

    def __post_init__(self):
        self.K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        self.R = np.asarray(self.R, dtype=np.float64).reshape(3, 3)
        self.t = np.asarray(self.t, dtype=np.float64).reshape(3)
        if not (np.all(np.isfinite(self.K)) and np.all(np.isfinite(self.R)) and np.all(np.isfinite(self.t))):
            raise ValueError("camera: K, R and t must be finite")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"camera: bad image size {self.width}x{self.height}")

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates."""
        return -self.R.T @ self.t

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points ``(..., 3)`` in camera space, float64, the same shape.

        One ``(N, 3)`` product (a stack of small products is several times slower), offset in place: no second
        array over every point.
        """
        points = np.asarray(points)
        pc = points.reshape(-1, 3) @ self.R.T
        pc += self.t
        return pc.reshape(points.shape)

    def project(self, points: np.ndarray):
        """Project world points ``(..., 3)``; return pixel ``(..., 2)`` and depth ``(...)``.

        Depth is the camera-space z (positive in front of the camera).
        """
        x, y, z = self.pixel_coordinates(points)
        return np.stack([x, y], axis=-1), z

    def pixel_coordinates(self, points: np.ndarray):
        """:meth:`project`'s pixel x, pixel y and depth, as three ``(...)`` arrays."""
        pc = self.to_camera(points)
        z = pc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = self.K[0, 0] * pc[..., 0] / z + self.K[0, 1] * pc[..., 1] / z + self.K[0, 2]
            y = self.K[1, 1] * pc[..., 1] / z + self.K[1, 2]
        return x, y, z

    def ray_directions(self) -> np.ndarray:
        """Unit world-space ray directions through every pixel centre, ``(H, W, 3)``."""
        ys, xs = np.mgrid[0 : self.height, 0 : self.width].astype(np.float64)
        d = np.stack([xs, ys, np.ones_like(xs)], axis=-1) @ np.linalg.inv(self.K).T
        d = d @ self.R  # camera to world: R^T d, written for row vectors
        return d / np.linalg.norm(d, axis=-1, keepdims=True)
