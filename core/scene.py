"""The scene as plain arrays: the target mesh, and each camera with its photo (the pipeline's input)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

__all__ = ["MeshArrays", "FullPhoto", "ViewInput", "SceneInputs"]


@dataclass
class MeshArrays:
    """The evaluated mesh as loop triangles, in world space.

    Attributes
    ----------
    tri_pos : (T, 3, 3) float64
        World positions of the triangles' corners.
    tri_uv : (T, 3, 2) float32
        UV of the corners in the active UV map.
    tri_vert : (T, 3) intp
        Vertex indices of the corners (shared corners identify shared edges).
    uv_map : str
        Name of the active UV map.
    tri_normal : (T, 3, 3) float32, optional
        Unit world-space corner normals: what Cycles shades with (smooth faces
        interpolate them, flat faces repeat the face normal, custom normals
        and sharp edges are honoured).
    """

    tri_pos: np.ndarray
    tri_uv: np.ndarray
    tri_vert: np.ndarray
    uv_map: str
    tri_normal: np.ndarray | None = None


@dataclass
class FullPhoto:
    """A photo at its own resolution, larger than the working one, read only when the detail stage needs it."""

    camera: object  # core.geometry.camera.Camera on the full-resolution pixel grid
    # () -> (photo, clipped), read anew on each call: the photo (H, W, 3) float32 linear, row 0 at the top, or an
    # 8-bit one as its codes (core.io.photos.CodedPhoto); clipped (H, W) bool or None
    load: Callable


@dataclass
class ViewInput:
    """One camera and its photo, at the working resolution."""

    name: str
    camera: object  # core.geometry.camera.Camera on the photo's (possibly downscaled) pixel grid
    photo: np.ndarray  # (H, W, 3) float32 linear, row 0 at the top
    source: str
    # (H, W) bool at the working resolution: pixels that touch an 8-bit photo's ceiling in some channel
    # (core.io.photos.clipped_pixels); None for float photos, which do not clip.
    clipped: np.ndarray | None = None
    # The photo at its full resolution when ``photo`` is a downscaled copy (None: ``photo`` is the full one).
    full: FullPhoto | None = None


@dataclass
class SceneInputs:
    """Everything the bake and the solver need from the scene."""

    object_name: str
    mesh: MeshArrays
    views: list = field(default_factory=list)
    skipped: list = field(default_factory=list)  # why cameras were left out, one line each
