"""The scene's geometry seen by the cameras: pinhole cameras, ray casting and the per-pixel bake, the texel grid
of the UV map, correspondences between views, bilinear lookups.
"""
from .camera import Camera
from .raycast import RayHits, raycast
from .bake import ViewBake, bake_view, bake_views
from .texels import (TextureLayout,
    texel_of_uv,
    uv_of_texel,
    texel_index,
    bilinear_texels,
    texture_layout,
    uv_stretched,
    STRETCH_FACTOR)
from .correspondences import Correspondences, find_correspondences, neighbour_views
from .bilinear import clamped_corners, interpolate, masked_corners

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
    "texture_layout",
    "uv_stretched",
    "STRETCH_FACTOR",
    "Correspondences",
    "find_correspondences",
    "neighbour_views",
    "clamped_corners",
    "masked_corners",
    "interpolate",
]
