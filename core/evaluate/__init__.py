"""Measuring results: accuracy against ground truth, synthetic problems with a known albedo, pictures of a run."""

from .metrics import scaled_rmse
from .pictures import BACKGROUND, grid, lighting_spheres, shade_sphere, sphere_normals, to_srgb8
from .synthetic import SyntheticScene, sphere_scene

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
