"""The albedo stage's TV weight, chosen from the photos' colour texture.

An albedo with fine changes of colour everywhere (stone, photographs, fine noise) wants a weak TV that keeps
them; flat patches with a few edges want a strong one, which smooths the shading left in them.
:func:`colour_measures` measures both on the photos divided by the lighting stage's shading, and
:func:`adapted_albedo_lam` turns them into the weight. The constants were fitted by leave-one-scene-out over
many rendered scenes (docs/measurements.md).
"""

from __future__ import annotations

import numpy as np

from .discretization import texture_domain
from .lighting import division_start

__all__ = [
    "ALBEDO_LAMBDA",
    "COLOUR_TEXTURE_REFERENCE",
    "COLOUR_TEXTURE_POWER",
    "COLOUR_TEXTURE_RANGE",
    "COLOUR_SPARSITY_REFERENCE",
    "COLOUR_SPARSITY_POWER",
    "adapted_albedo_lam",
    "colour_measures",
    "colour_texture",
]

#: TV weight of the albedo stage (with ``SolverParams.albedo_edges``), chosen by leave-one-scene-out over the
#: fixtures (docs/measurements.md); with ``SolverParams.albedo_adapt``, the weight at COLOUR_TEXTURE_REFERENCE.
ALBEDO_LAMBDA = 20.0
#: With ``albedo_adapt`` the albedo stage's weight is ``albedo_lam * (f / COLOUR_TEXTURE_REFERENCE) **
#: -COLOUR_TEXTURE_POWER`` within ``albedo_lam`` times COLOUR_TEXTURE_RANGE, f the photos' colour texture
#: (:func:`colour_texture`): an albedo with fine changes of colour everywhere wants a weak TV that keeps them,
#: flat patches a strong one that takes the shading left in them. Fitted by leave-one-scene-out over the 13
#: fixtures, where the best weight spans 0.05 to 80 (docs/measurements.md).
COLOUR_TEXTURE_REFERENCE = 0.044
COLOUR_TEXTURE_POWER = 6.0
COLOUR_TEXTURE_RANGE = (1 / 400, 4.0)
#: That factor is multiplied by ``(h / COLOUR_SPARSITY_REFERENCE) ** COLOUR_SPARSITY_POWER``, h how sparse those
#: changes of colour are (:func:`colour_measures`): fine texture that changes everywhere (noise, fabric) wants a
#: weaker TV than its colour texture alone gives, a few sharp edges between flat patches a stronger one. Fitted
#: with the reference weight by leave-one-scene-out over 40 scenes, and checked on 6 more (docs/measurements.md).
COLOUR_SPARSITY_REFERENCE = 0.385
COLOUR_SPARSITY_POWER = 6.0


def colour_measures(problem, sigma: np.ndarray) -> tuple[float, float]:
    """``(texture, sparsity)``: how much fine colour texture the photos show, and how sparse its changes are.

    Both from the changes of chromaticity between neighbouring texels of the photos divided by their shading
    (:func:`division_start`, nearest texel), on the problem's texture (:func:`core.solve.stages.solve_two_stage`
    gives it the lighting stage's, at most 128², where the rule was fitted). Chromaticity (``3 rho / sum(rho)``)
    hardly changes with the shading, so where the lighting left shading in the division these measure the
    albedo's own changes of colour. ``texture`` is their median; ``sparsity`` their Hoyer sparsity,
    ``(sqrt(n) - |s|_1 / |s|_2) / (sqrt(n) - 1)``: 0 where every pair changes alike, 1 where one pair holds all
    the change. NaN, NaN for grey photos or when no two neighbouring texels are seen.
    """
    if problem.channels != 3:  # grey photos: no colour to change
        return float("nan"), float("nan")
    size = problem.texture.size
    d = texture_domain(problem, data_model="nearest")
    img = np.full((size * size, 3), np.nan)
    img[d.texel_index] = division_start(d, sigma)
    img = img.reshape(size, size, 3)
    total = img.sum(axis=-1)
    seen = np.isfinite(total) & (total > 0)
    chroma = 3 * img / np.maximum(total, 1e-4)[..., None]
    steps = []
    for axis in (0, 1):
        step = np.diff(chroma, axis=axis)
        both = np.delete(seen, -1, axis) & np.delete(seen, 0, axis)
        steps.append(np.sqrt((step[both] ** 2).sum(axis=-1)))
    steps = np.concatenate(steps)
    if not steps.size:
        return float("nan"), float("nan")
    texture = float(np.median(steps))
    norm = float(np.sqrt(np.sum(steps**2)))
    root = np.sqrt(steps.size)
    sparsity = float((root - steps.sum() / norm) / (root - 1)) if norm > 0 and steps.size > 1 else float("nan")
    return texture, sparsity


def colour_texture(problem, sigma: np.ndarray) -> float:
    """How much fine colour texture the photos show: :func:`colour_measures`' first."""
    return colour_measures(problem, sigma)[0]


def adapted_albedo_lam(albedo_lam: float, texture: float, sparsity: float = float("nan")) -> float:
    """The albedo stage's TV weight for the photos' colour texture and its sparsity (:func:`colour_measures`):
    ``albedo_lam`` where the texture is NaN; the texture's factor alone where the sparsity is."""
    if not np.isfinite(texture):
        return albedo_lam
    lo, hi = COLOUR_TEXTURE_RANGE
    factor = (max(texture, 1e-12) / COLOUR_TEXTURE_REFERENCE) ** -COLOUR_TEXTURE_POWER
    if np.isfinite(sparsity):
        factor *= (max(sparsity, 1e-12) / COLOUR_SPARSITY_REFERENCE) ** COLOUR_SPARSITY_POWER
    return float(albedo_lam * np.clip(factor, lo, hi))
