"""The reflectance problem and its solver: the model (SH shading, Huber), its discretisations, the majorization-
minimization loop with CG and multigrid, coarse-to-fine levels, and the choice of lambda.
"""

from ..geometry.sh import DIFFUSE, SH_BASIS_NAMES, sh_basis
from .cg import pcg
from .discretization import Discretization, image_domain, texture_domain
from .huber import huber, huber_inplace, majorant, mm_weight
from .lambda_choice import (
    LAMBDA_FIXED,
    LAMBDA_VARYING,
    VARYING_THRESHOLD,
    auto_lambda,
    choose_lambda,
    describe_lambda,
    lighting_variation,
)
from .lighting import weighted_gram
from .multigrid import Hierarchy, block_grid, surface_grid
from .params import Result, SolverParams
from .problem import Correspondences, Problem, TextureLayout
from .pyramid import coarsen, supported_size, upsample_bilinear, upsample_pixels, with_texture_size
from .solver import energy, solve_joint
from .spmv import matvec_into
from .stages import solve

__all__ = [
    "Correspondences",
    "TextureLayout",
    "Problem",
    "sh_basis",
    "weighted_gram",
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
    "solve_joint",
    "energy",
]
