"""The reflectance problem and its solver, in the order a solve reads them.

- :mod:`.problem`: the photos, masks, normals and UVs of one solve (:class:`Problem`);
  :mod:`.discretization` turns it into observations and rows of differences, on the texels or on the pixels;
  :mod:`.pyramid` makes its coarser copies.
- :mod:`.params`: what a solve takes and gives (:class:`SolverParams`, :class:`Result`).
- :mod:`.stages`: the entry point :func:`solve`, the paper's one stage or the lighting and then the albedo.
  Their TV weights: :mod:`.lambda_choice` (the lighting's) and :mod:`.albedo_weight` (the albedo's, from the
  photos' colour texture).
- :mod:`.solver`: the alternating majorization-minimization (the paper's section 4), over :mod:`.huber`'s
  loss, with :mod:`.lighting`'s models for the sigma-step; the rho-step's CG (:mod:`.cg`), preconditioner
  (:mod:`.multigrid`) and products (:mod:`.spmv`); :mod:`.gauss_newton`'s optional joint step.
- What the two stages add to the paper: :mod:`.ambiguity` (the lighting moved along the albedo-lighting
  ambiguity), :mod:`.edges` (TV weighted down across changes of colour), :mod:`.highlights` (clipped
  highlights left out).
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
