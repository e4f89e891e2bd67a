"""The reflectance problem and its solver: the model (SH shading, Huber), its discretisations, the majorization-
minimization loop with CG and multigrid, coarse-to-fine levels, and the choice of lambda.
"""
from .problem import Correspondences, TextureLayout, Problem
from .sh import sh_basis, sh_products, DIFFUSE, SH_BASIS_NAMES
from .huber import huber, huber_inplace, majorant, mm_weight
from .discretization import Discretization, image_domain, texture_domain
from .cg import pcg
from .spmv import matvec_into
from .multigrid import Hierarchy, block_grid, surface_grid
from .pyramid import coarsen, upsample_pixels, upsample_bilinear, supported_size, with_texture_size
from .lambda_choice import (lighting_variation,
    choose_lambda,
    auto_lambda,
    describe_lambda,
    VARYING_THRESHOLD,
    LAMBDA_FIXED,
    LAMBDA_VARYING)
from .solver import SolverParams, Result, solve, energy

__all__ = [
    "Correspondences",
    "TextureLayout",
    "Problem",
    "sh_basis",
    "sh_products",
    "DIFFUSE",
    "SH_BASIS_NAMES",
    "huber",
    "huber_inplace",
    "majorant",
    "mm_weight",
    "Discretization",
    "image_domain",
    "texture_domain",
    "pcg",
    "matvec_into",
    "Hierarchy",
    "block_grid",
    "surface_grid",
    "coarsen",
    "upsample_pixels",
    "upsample_bilinear",
    "supported_size",
    "with_texture_size",
    "lighting_variation",
    "choose_lambda",
    "auto_lambda",
    "describe_lambda",
    "VARYING_THRESHOLD",
    "LAMBDA_FIXED",
    "LAMBDA_VARYING",
    "SolverParams",
    "Result",
    "solve",
    "energy",
]
