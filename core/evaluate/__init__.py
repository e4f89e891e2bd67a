"""Measuring results: accuracy against ground truth, synthetic problems with a known albedo, pictures of a run.
"""
from .metrics import scaled_rmse
from .synthetic import SyntheticScene, sphere_scene
from .pictures import (to_srgb8,
    sphere_normals,
    shade_sphere,
    lighting_spheres,
    grid,
    BACKGROUND)

__all__ = [
    "scaled_rmse",
    "SyntheticScene",
    "sphere_scene",
    "to_srgb8",
    "sphere_normals",
    "shade_sphere",
    "lighting_spheres",
    "grid",
    "BACKGROUND",
]
