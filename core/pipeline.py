"""The bpy-free middle of a run: problem -> solve -> fuse, on the scene as arrays.

The Blender layer reads the scene and bakes it (:mod:`core.scene`, :mod:`core.geometry.bake`), calls
:func:`compute`, and writes the results. :func:`compute` never touches bpy, so it can run in a worker thread.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .errors import Cancelled, DelightError
from .geometry.texels import texture_layout
from .scene import SceneInputs
from .solve.problem import Problem
from .solve.solver import SolverParams, solve
from .texture import fill_unseen, fuse_views, sample_texture

__all__ = ["DEFAULTS", "METHODS", "Options", "Computed", "compute", "stage_progress", "check_cancel"]

#: The solver's defaults, chosen by albedo RMSE on the fixtures; every front end shows these.
DEFAULTS = SolverParams()
#: TV weight of the albedo stage, chosen by leave-one-scene-out over the fixtures (docs/measurements.md).
ALBEDO_LAMBDA = 1.0

__all__ = ["METHODS", "Options", "Prepared", "Computed", "RunReport", "prepare", "compute", "finish", "run",
           "sample_texture"]

METHODS = ("texture", "image", "project")

LIGHTING_MODES = ("auto", "per_view", "shared", "coupled")

# Share of the progress bar for each stage.
_SPAN = {"gather": (0.0, 0.05), "bake": (0.05, 0.3), "solve": (0.3, 0.9), "fuse": (0.9, 0.95),
         "write": (0.95, 1.0)}


@dataclass
class Options:
    """What to delight and how. ``None`` means "the default" where allowed.

    Parameters
    ----------
    object_name : str, optional
        The mesh object; default the active object.
    camera_names : list of str, optional
        The cameras; default all (or the selected ones with ``selected_only``).
    images_dir : str, optional
        Folder to look for photos by camera name, when a camera has none.
    selected_only : bool
        Use the selected cameras when no names are given.
    lam, mu, max_iter : float or None, float, int
        The solver's TV weight (of the lighting stage when there are two),
        consistency weight (image domain) and outer iterations. ``lam=None``
        picks lambda: the fixed-light value with two stages, else from how
        much the lighting differs between the photos
        (:mod:`core.solve.lambda_choice`).
    albedo_lam : float or None
        TV weight of the albedo stage (:func:`core.solve.lighting.solve_two_stage`);
        None solves in one stage, as the paper.
    lighting : str
        ``"auto"`` (:func:`core.solve.lighting.choose_lighting`), ``"per_view"``,
        ``"shared"`` or ``"coupled"`` (:class:`core.solve.solver.SolverParams`).
    working_res_mp : float
        Photos are downscaled to at most this many megapixels.
    texture_size : int
        N of the N x N albedo texture.
    method : str
        ``"texture"`` or ``"image"`` (the solver's two domains), or
        ``"project"`` (no delighting: the photos fused, for comparison).
    out_dir : str, optional
        Output folder; default the .blend's folder.
    save_blend : bool
        Save the .blend after wiring the material.
    overwrite : bool
        Replace existing output files.
    mask_clipped : bool
        Leave the pixels that touch an 8-bit photo's ceiling out of the solve
        (:attr:`core.scene.ViewInput.clipped`).
    occlusion : bool
        Shade with the occlusion-aware SH transfer (:mod:`core.geometry.transfer`)
        instead of the paper's ``nu(n)``.
    solver : dict, optional
        Further :class:`core.solve.solver.SolverParams` fields, for experts and
        benchmarks (the fields above take precedence).
    """

    object_name: str | None = None
    camera_names: list | None = None
    images_dir: str | None = None
    selected_only: bool = False
    lam: float | None = None
    mu: float = DEFAULTS.mu
    max_iter: int = DEFAULTS.max_iter
    working_res_mp: float = 1.0
    texture_size: int = 1024
    method: str = "texture"
    out_dir: str | None = None
    save_blend: bool = False
    overwrite: bool = False
    albedo_lam: float | None = ALBEDO_LAMBDA
    lighting: str = "auto"
    mask_clipped: bool = False
    occlusion: bool = True
    solver: dict | None = None

    def validate(self):
        """Raise :class:`DelightError` for a bad value."""
        if self.method not in METHODS:
            raise DelightError(f"unknown method {self.method!r} (choose one of {', '.join(METHODS)})")
        for name, v, lo in (("lambda", self.lam, 0.0), ("mu", self.mu, 0.0)):
            if v is None and name == "lambda":
                continue
            if not np.isfinite(v) or v < lo:
                raise DelightError(f"{name} must be a finite number >= {lo}, got {v}")
        if self.albedo_lam is not None and (not np.isfinite(self.albedo_lam) or self.albedo_lam < 0):
            raise DelightError(f"the albedo lambda must be a finite number >= 0, got {self.albedo_lam}")
        if self.lighting not in LIGHTING_MODES:
            raise DelightError(f"unknown lighting {self.lighting!r} (choose one of {', '.join(LIGHTING_MODES)})")
        if int(self.max_iter) < 1:
            raise DelightError(f"the iteration count must be at least 1, got {self.max_iter}")
        if not np.isfinite(self.working_res_mp) or self.working_res_mp <= 0:
            raise DelightError(f"the working resolution must be > 0 megapixels, got {self.working_res_mp}")
        if not 8 <= int(self.texture_size) <= 16384:
            raise DelightError(f"the texture size must be between 8 and 16384, got {self.texture_size}")


@dataclass
class Computed:
    """The results as arrays (output of :func:`compute`)."""

    albedo: np.ndarray              # (N, N, C) filled texture, row 0 at the top
    seen: np.ndarray                # (N, N) bool
    views: list                     # per view (H, W, C) reflectance
    sigma: np.ndarray | None        # (m, C, 9) lighting, None for "project"
    energy: list
    iterations: int
    info: dict = field(default_factory=dict)


def stage_progress(progress, stage):
    """A progress callback for one stage, mapped into its share of the bar."""
    lo, hi = _SPAN[stage]

    def report(fraction=0.0, message=""):
        if progress is not None:
            progress(lo + (hi - lo) * min(max(float(fraction), 0.0), 1.0), f"{stage}: {message}" if message else stage)
    return report


def check_cancel(cancel):
    if cancel is not None and cancel():
        raise Cancelled("cancelled")


def _layout(mesh, n):
    return texture_layout(mesh.tri_uv, mesh.tri_pos, mesh.tri_vert, n)


def _unclipped(mask, clipped):
    """The mask without the clipped pixels, unless that leaves nothing (or nothing is known)."""
    if clipped is None:
        return mask
    keep = mask & ~clipped
    return keep if keep.any() else mask


def compute(options: Options, inputs: SceneInputs, bakes: list, times: dict | None = None, progress=None,
            cancel=None) -> Computed:
    """Build the problem, solve and fuse (pure arrays; safe in a worker thread).

    ``times`` (if given) receives the seconds spent in "solve" and "fuse".

    Raises
    ------
    Cancelled
        ``cancel()`` returned True.
    ValueError
        From the core, for inconsistent arrays.
    """
    opt = options
    times = {} if times is None else times
    n = int(opt.texture_size)
    photos = [v.photo for v in inputs.views]
    masks = [b.mask for b in bakes]
    solve_masks = masks
    if opt.mask_clipped and opt.method != "project":
        solve_masks = [_unclipped(m, v.clipped) for m, v in zip(masks, inputs.views)]
    uvs = [b.uv for b in bakes]
    weights = [b.view_weight for b in bakes]
    solve_progress = stage_progress(progress, "solve")

    t = time.perf_counter()
    solve_progress(0.0, "building the problem")
    layout = _layout(inputs.mesh, n)
    check_cancel(cancel)
    correspondences = None
    if opt.method == "image":
        from .geometry.correspondences import find_correspondences
        correspondences = find_correspondences([v.camera for v in inputs.views], [b.position for b in bakes],
                                               solve_masks, [b.normal for b in bakes])
        check_cancel(cancel)
    transfer = None
    if opt.occlusion and opt.method != "project":
        from .geometry.transfer import pixel_transfer
        solve_progress(0.0, "occlusion")
        transfer = pixel_transfer(inputs.mesh.tri_pos, uvs, masks, [b.normal for b in bakes],
                                  [b.position for b in bakes], weights)
        check_cancel(cancel)
    problem = Problem(images=photos, masks=solve_masks, normals=[b.normal for b in bakes],
                      correspondences=correspondences, uv=uvs,
                      texture=layout if opt.method == "texture" else None,
                      view_weight=weights, names=[v.name for v in inputs.views], transfer=transfer)
    result = None
    lam, variation, lighting = opt.lam, None, opt.lighting
    if opt.method != "project":
        from .solve.lambda_choice import LAMBDA_FIXED, auto_lambda, describe_lambda
        from .solve.lighting import choose_lighting
        if lam is None or lighting == "auto":
            auto, variation = auto_lambda(problem)
            if lam is None:
                # With two stages the lighting stage wants a strong TV whatever the light does.
                lam = LAMBDA_FIXED if opt.albedo_lam is not None else auto
                solve_progress(0.0, describe_lambda(lam, variation, auto=True))
            if lighting == "auto":
                lighting = choose_lighting(variation)
        params = SolverParams(**dict(opt.solver or {}, domain=opt.method, lam=float(lam), mu=float(opt.mu),
                                     max_iter=int(opt.max_iter), albedo_lam=opt.albedo_lam, lighting=lighting))
        result = solve(problem, params, progress=solve_progress, cancel=cancel)
    times["solve"] = time.perf_counter() - t
    check_cancel(cancel)

    t = time.perf_counter()
    fuse_progress = stage_progress(progress, "fuse")
    fuse_progress(0.0, "texture")
    if opt.method == "texture":
        seen = np.asarray(result.seen, dtype=bool)
        albedo = fill_unseen(result.texture, seen, layout.inside, margin=4)
        views = [sample_texture(albedo, uv, m) for uv, m in zip(uvs, masks)]
    else:
        # Image domain: fuse the per-view reflectance; project: the photos themselves.
        maps = result.views if result is not None else problem.images
        fused = fuse_views(maps, problem.masks, uvs, n, view_weight=weights, inside=layout.inside, margin=4)
        albedo, seen = fused[..., :-1], fused[..., -1] > 0
        views = list(maps)
    times["fuse"] = time.perf_counter() - t
    fuse_progress(1.0, "done")
    check_cancel(cancel)
    return Computed(albedo=np.asarray(albedo, dtype=np.float32), seen=seen, views=views,
                    sigma=None if result is None else np.asarray(result.sigma),
                    energy=[] if result is None else [float(e) for e in result.energy],
                    iterations=0 if result is None else int(result.iterations),
                    info={} if result is None else dict(result.info, lam=lam, lighting_variation=variation,
                                                        albedo_lam=opt.albedo_lam, lighting_mode=lighting,
                                                        occlusion=bool(opt.occlusion)))
