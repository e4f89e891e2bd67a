"""The scene's geometry seen by the cameras: pinhole cameras, ray casting and the per-pixel bake, the texel grid
of the UV map, correspondences between views, bilinear lookups, the spherical-harmonics basis of the normal.
"""

from .bake import ViewBake, bake_view, bake_views
from .bilinear import clamped_corners, interpolate, masked_corners
from .camera import Camera
from .correspondences import Correspondences, find_correspondences, neighbour_views
from .raycast import RayHits, raycast
from .sh import DIFFUSE, SH_BASIS_NAMES, sh_basis, sphere_directions
from .texels import (
    STRETCH_FACTOR,
    TextureLayout,
    bilinear_texels,
    nearest_texel,
    texel_index,
    texel_of_uv,
    texture_layout,
    triangle_areas,
    uv_of_texel,
    uv_stretched,
)

__all__ = [
    "Camera",
    "RayHits",
    "raycast",
    "ViewBake",
    "bake_view",
    "bake_views",
    "TextureLayout",
    "texel_of_uv",
    "uv_of_texel",
    "texel_index",
    "bilinear_texels",
    "nearest_texel",
    "texture_layout",
    "uv_stretched",
    "triangle_areas",
    "STRETCH_FACTOR",
    "Correspondences",
    "find_correspondences",
    "neighbour_views",
    "clamped_corners",
    "masked_corners",
    "interpolate",
    "sh_basis",
    "sphere_directions",
    "DIFFUSE",
    "SH_BASIS_NAMES",
]
