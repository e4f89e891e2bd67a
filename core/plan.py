"""Which stages a run has, and how long each is expected to take: the progress bar's spans.

:func:`core.pipeline.compute` asks :func:`runs_detail` whether the detail stage is planned, :func:`wants_detail`
whether it is kept once the photos' colour texture is measured, and :func:`schedule` for the bar's span of each
stage (:mod:`core.progress`), in proportion to :func:`expected_seconds`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .options import Options
from .progress import shares, spans
from .solve.params import SolverParams

__all__ = [
    "DEFAULTS",
    "DETAIL_MIN_COLOUR_TEXTURE",
    "FLAT_ALBEDO_PIXELS",
    "expected_seconds",
    "flat_albedo",
    "light_size",
    "runs_detail",
    "schedule",
    "solve_parts",
    "spans_without_detail",
    "uses_detail",
    "wants_detail",
]


#: The solver's defaults, chosen by albedo RMSE on the fixtures; every front end shows these.
DEFAULTS = SolverParams()


def light_size(options: Options) -> int:
    """The lighting stage's texture size (SolverParams.light_size, as the run's solver settings give it)."""
    return int((options.solver or {}).get("light_size", DEFAULTS.light_size))


def uses_detail(options: Options) -> bool:
    """Whether a run with ``options`` may make the albedo again from the full-resolution photos, if they are
    larger (with ``detail`` "auto", :func:`core.pipeline.compute` decides from the photos' colour texture)."""
    return options.detail != "off" and options.method != "project"


def runs_detail(options: Options, inputs) -> bool:
    """Whether a run with ``options`` on ``inputs`` plans the detail stage: some photo is larger than its working
    copy. With ``detail`` "auto" a flat albedo then goes without it (:func:`wants_detail`)."""
    return uses_detail(options) and any(v.full is not None for v in inputs.views)


#: With ``detail`` "auto", the least colour texture of the photos (:func:`core.solve.albedo_weight.colour_texture`)
#: that gets the detail stage. On a flatter albedo the albedo stage at the working resolution, whose TV weight
#: is then strong (26 or more at the reference sparsity of its changes of colour), takes out shading that the
#: stage's per-pixel division keeps. Chosen by leave-one-scene-out over 21 scenes with photos larger than the
#: working resolution (docs/measurements.md).
DETAIL_MIN_COLOUR_TEXTURE = 0.042


#: On a flat albedo (a colour texture of at most DETAIL_MIN_COLOUR_TEXTURE), the most pixels on the mesh (all
#: photos together) the Texture method's albedo stage is solved on, with or without the detail stage planned,
#: every k-th pixel of every k-th row beyond (`core.pipeline._thinned`): a flat albedo needs no more, and on the large
#: captures fewer pixels, solved on fewer texels, were both quicker and more accurate; on the fixtures' fewer
#: pixels, every pixel counts (docs/measurements.md).
FLAT_ALBEDO_PIXELS = 2_000_000


def flat_albedo(texture: float) -> bool:
    """Whether the photos' colour texture ``texture`` says the albedo is flat (NaN, grey photos: not)."""
    return texture <= DETAIL_MIN_COLOUR_TEXTURE


def wants_detail(options: Options, texture: float) -> bool:
    """Whether a run that planned the detail stage keeps it, once its lighting stage has measured the photos'
    colour texture ``texture`` (NaN for grey photos, which keep it)."""
    return options.detail == "on" or not flat_albedo(texture)


def _sizes(options: Options, inputs):
    """Millions of working pixels, of full-resolution pixels (the detail stage's), of triangles and of texels."""
    mp = 1e-6
    views = inputs.views
    working = mp * sum(v.photo.shape[0] * v.photo.shape[1] for v in views)
    full = mp * sum(v.full.camera.width * v.full.camera.height for v in views if v.full is not None)
    return working, full, mp * len(inputs.mesh.tri_pos), mp * int(options.texture_size) ** 2


def _solved_texels(options: Options, inputs, flat: bool = False) -> float:
    """Millions of texels the albedo is solved on: no more than the pixels resolve (SolverParams'
    max_texels_per_pixel: 2 per pixel on the mesh, about 2/3 of the photo); before the detail stage, the
    lighting stage's texture alone; ``flat``: a flat albedo's, on at most :data:`FLAT_ALBEDO_PIXELS`."""
    working, _, _, texels = _sizes(options, inputs)
    if runs_detail(options, inputs):
        return min(texels, 1e-6 * light_size(options) ** 2)
    return min(texels, 1.3 * working, 2e-6 * FLAT_ALBEDO_PIXELS if flat else np.inf)


def expected_seconds(options: Options, inputs, flat: bool = False) -> dict:
    """Roughly how long each stage after the gather takes, from the run's sizes, in run order.

    Only the ratios count (:func:`core.progress.spans`); the seconds are of the machine they were fitted on
    (Intel Xeon, 2 cores: 13 photos of 0.5, 1 and 12 MP, 50 of 24 MP; docs/measurements.md). The bake and
    the photos' alignment go with the pixels and the triangles; the solve is :func:`solve_parts`; the fuse and
    the writing go with the texels; the detail stage with the full-resolution pixels. ``flat``: as after
    :func:`wants_detail` left the stage out, the albedo stage on at most :data:`FLAT_ALBEDO_PIXELS`.
    """
    working, full, triangles, texels = _sizes(options, inputs)
    solved = _solved_texels(options, inputs, flat)
    seconds = {
        "bake": 0.3 * working + 20.0 * triangles + 1.5,
        "solve": sum(solve_parts(options, inputs, flat).values()),
        "fuse": 0.6 * solved + 0.17 * texels,
    }
    if runs_detail(options, inputs):
        seconds["detail"] = 0.31 * full
    seconds["write"] = 0.25 * texels + 0.02 * working + 1.5
    return seconds


def solve_parts(options: Options, inputs, flat: bool = False) -> dict:
    """Roughly how long each part of the solve stage takes, as :func:`expected_seconds` (0 for a part the run
    does not have), in run order: the occlusion; the sun's search, then the problem's making (its transfer, the
    texture's layout); the lighting stage; the albedo stage. :func:`core.pipeline.compute` draws each on its
    share of the solve stage's bar. ``flat`` as :func:`expected_seconds`'.
    """
    working, _, triangles, texels = _sizes(options, inputs)
    parts = {"occlusion": 0.0, "problem": 0.0, "lighting": 0.0, "albedo": 0.0}
    if options.method == "project":
        parts["problem"] = 0.1 * working
        return parts
    if options.occlusion:
        parts["occlusion"] = 2.5 + 11.0 * triangles
    parts["problem"] = (4.0 + 30.0 * triangles if options.sun else 0.0) + 0.17 * texels
    # The lighting stage thins its pixels to at most 64 per texel of its 128² texture: past about 7 MP of photo
    # its time stops growing (docs/measurements.md).
    parts["lighting"] = max(4.1 * min(working, 7.0) - 6.0, 5.0)
    if options.albedo_lam is not None and not runs_detail(options, inputs):
        parts["albedo"] = 4.4 * _solved_texels(options, inputs, flat)
    return parts


def schedule(options: Options, inputs) -> dict:
    """The progress bar's span of each stage (:mod:`core.progress`) for a run with ``options`` on ``inputs``: in
    proportion to :func:`expected_seconds`, so that the time left is read from the bar's progress."""
    return spans(expected_seconds(options, inputs))


def spans_without_detail(options: Options, inputs, stages: dict):
    """The bar's spans once a run that planned the detail stage goes without it (:func:`wants_detail`): the
    albedo stage and the fuse share the bar from the solve's end to the detail stage's, as they are expected to
    take (:func:`expected_seconds` of a flat albedo without it). Returns the new spans and the albedo stage's span."""
    plain = replace(options, detail="off")
    parts = shares(
        {
            "albedo": solve_parts(plain, inputs, flat=True)["albedo"],
            "fuse": expected_seconds(plain, inputs, flat=True)["fuse"],
        },
        stages["solve"][1],
        stages["detail"][1],
    )
    out = {k: v for k, v in stages.items() if k != "detail"}
    out["fuse"] = parts["fuse"]
    return out, parts["albedo"]
