"""The whole run: scene -> bake -> problem -> solve -> fuse -> write.

It is split in three steps so that the GUI can run the long middle one in a
worker thread:

* :func:`prepare` (main thread) reads the scene: gather and bake. It only
  reads bpy data and returns plain arrays.
* :func:`compute` (any thread) is pure NumPy/SciPy: builds the problem,
  solves, fuses. It never touches bpy.
* :func:`finish` (main thread) writes the files, then creates the image,
  wires the material and updates the panel's preview images
  (:mod:`.previews`). This is the only step that changes anything.

:func:`run` chains the three. A cancel (``cancel()`` returning True) raises
:class:`core.solver.Cancelled` before :func:`finish`, so the scene and the
output folder are left as they were.
"""
from __future__ import annotations

import os
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from .core.solver import Cancelled, SolverParams
from .core.jsonio import json_value
from .core.sh import SH_BASIS_NAMES
from .errors import DelightError

#: The solver's defaults, chosen by albedo RMSE on the fixtures; every front end shows these.
DEFAULTS = SolverParams()

__all__ = ["METHODS", "Options", "Prepared", "Computed", "RunReport", "prepare", "compute", "finish", "run",
           "sample_texture"]

METHODS = ("texture", "image", "project")

#: The basis of the lighting coefficients in lighting.json (world-space normal n).
SH_BASIS = list(SH_BASIS_NAMES)

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
        The solver's TV weight, consistency weight (image domain) and outer
        iterations. ``lam=None`` picks lambda from how much the lighting
        differs between the photos (:mod:`core.light_variation`).
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

    def validate(self):
        """Raise :class:`DelightError` for a bad value."""
        if self.method not in METHODS:
            raise DelightError(f"unknown method {self.method!r} (choose one of {', '.join(METHODS)})")
        for name, v, lo in (("lambda", self.lam, 0.0), ("mu", self.mu, 0.0)):
            if v is None and name == "lambda":
                continue
            if not np.isfinite(v) or v < lo:
                raise DelightError(f"{name} must be a finite number >= {lo}, got {v}")
        if int(self.max_iter) < 1:
            raise DelightError(f"the iteration count must be at least 1, got {self.max_iter}")
        if not np.isfinite(self.working_res_mp) or self.working_res_mp <= 0:
            raise DelightError(f"the working resolution must be > 0 megapixels, got {self.working_res_mp}")
        if not 8 <= int(self.texture_size) <= 16384:
            raise DelightError(f"the texture size must be between 8 and 16384, got {self.texture_size}")


@dataclass
class Prepared:
    """The scene read into arrays (output of :func:`prepare`)."""

    options: Options
    inputs: object                  # scene.SceneInputs
    bakes: list                     # list of bake.ViewBake, one per kept view
    out_dir: str
    times: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)


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


@dataclass
class RunReport:
    """What a run did."""

    object_name: str
    method: str
    out_dir: str
    files: list
    image_name: str
    materials: list
    times: dict
    iterations: int
    energy: list
    cameras: list
    warnings: list = field(default_factory=list)
    saved_blend: str | None = None
    lam: float | None = None                  # the TV weight used (None for "project")
    lighting_variation: float | None = None   # what auto lambda measured
    lambda_auto: bool = False

    @property
    def albedo_path(self) -> str:
        return self.files[0]

    @property
    def lambda_text(self) -> str:
        """How lambda was set, for messages: "lambda 0.5 (auto: ...)"."""
        if self.lam is None:
            return "no solve"
        from .core.light_variation import describe_lambda
        return describe_lambda(self.lam, self.lighting_variation, self.lambda_auto)


def _sub(progress, stage):
    """A progress callback for one stage, mapped into its share of the bar."""
    lo, hi = _SPAN[stage]

    def report(fraction=0.0, message=""):
        if progress is not None:
            progress(lo + (hi - lo) * min(max(float(fraction), 0.0), 1.0), f"{stage}: {message}" if message else stage)
    return report


def _check_cancel(cancel):
    if cancel is not None and cancel():
        raise Cancelled("cancelled")


def default_out_dir(blend_path: str) -> str:
    """Beside the .blend; an unsaved file has no such place."""
    if not blend_path:
        raise DelightError("the .blend file is not saved, so there is no default output folder: "
                           "choose an output folder")
    return os.path.dirname(os.path.abspath(blend_path))


def prepare(scene, options: Options, progress=None, cancel=None) -> Prepared:
    """Read the scene into arrays: gather the inputs and bake every view (main thread).

    Raises
    ------
    DelightError
        Bad options or input, existing outputs without ``overwrite``, or a
        mesh that no camera sees.
    Cancelled
        ``cancel()`` returned True.
    """
    import bpy

    from . import bake as _bake
    from . import material as _material
    from . import scene as _scene
    from . import write as _write

    options.validate()
    times = {}
    out_dir = options.out_dir or default_out_dir(bpy.data.filepath)
    out_dir = os.path.abspath(bpy.path.abspath(out_dir))
    if options.save_blend and not bpy.data.filepath:
        raise DelightError("cannot save: the .blend file has never been saved")

    t = time.perf_counter()
    _sub(progress, "gather")(0.0, "reading the scene")
    inputs = _scene.gather(scene, object_name=options.object_name, camera_names=options.camera_names,
                           images_dir=options.images_dir, working_res_mp=options.working_res_mp,
                           selected_only=options.selected_only)
    # Fail before the long part if the outputs or the material are in the way.
    _material.check_editable(bpy.data.objects[inputs.object_name])
    _write.check_outputs(_write.output_paths(out_dir, inputs.object_name, [v.name for v in inputs.views]),
                         options.overwrite)
    times["gather"] = time.perf_counter() - t
    _check_cancel(cancel)

    t = time.perf_counter()
    bakes = _bake.bake_views(scene, inputs, progress=_sub(progress, "bake"), cancel=cancel)
    times["bake"] = time.perf_counter() - t
    _check_cancel(cancel)

    # A camera that does not see the mesh adds nothing: drop it, but not all.
    warnings, keep = [], []
    for i, (v, b) in enumerate(zip(inputs.views, bakes)):
        if np.any(b.mask):
            keep.append(i)
        else:
            warnings.append(f"camera {v.name!r} does not see {inputs.object_name!r}; skipped")
    if not keep:
        raise DelightError(f"no camera sees the mesh {inputs.object_name!r}")
    if len(keep) < len(bakes):
        inputs.views = [inputs.views[i] for i in keep]
        bakes = [bakes[i] for i in keep]
    return Prepared(options=options, inputs=inputs, bakes=bakes, out_dir=out_dir, times=times,
                    warnings=warnings)


def sample_texture(texture: np.ndarray, uv: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Bilinear lookup of an (N, N, C) texture (row 0 at v = 1) at (H, W, 2) uv; NaN outside ``mask``."""
    from .core.bilinear import clamped_corners
    from .core.uvlayout import texel_of_uv

    n = texture.shape[0]
    tex = np.nan_to_num(np.asarray(texture, dtype=np.float32)).reshape(n * n, -1)
    out = np.full(uv.shape[:2] + (tex.shape[1],), np.nan, dtype=np.float32)
    y, x = texel_of_uv(uv[mask], n)
    idx, wts = clamped_corners(np.clip(x, 0, n - 1), np.clip(y, 0, n - 1), n, n)
    out[mask] = np.einsum("kj,kjc->kc", wts, tex[idx])
    return out


def _layout(mesh, n):
    from .core.uvlayout import texture_layout
    return texture_layout(mesh.tri_uv, mesh.tri_pos, mesh.tri_vert, n)


def compute(prepared: Prepared, progress=None, cancel=None) -> Computed:
    """Build the problem, solve and fuse (pure arrays; safe in a worker thread).

    Raises
    ------
    Cancelled
        ``cancel()`` returned True.
    ValueError
        From the core, for inconsistent arrays.
    """
    from .core.fusion import fill_unseen, fuse_views
    from .core.problem import Problem
    from .core.solver import solve

    opt, inputs, bakes, times = prepared.options, prepared.inputs, prepared.bakes, prepared.times
    n = int(opt.texture_size)
    photos = [v.photo for v in inputs.views]
    masks = [b.mask for b in bakes]
    uvs = [b.uv for b in bakes]
    weights = [b.view_weight for b in bakes]
    solve_progress = _sub(progress, "solve")

    t = time.perf_counter()
    solve_progress(0.0, "building the problem")
    layout = _layout(inputs.mesh, n)
    _check_cancel(cancel)
    correspondences = None
    if opt.method == "image":
        from .core.correspondences import find_correspondences
        correspondences = find_correspondences([v.camera for v in inputs.views], [b.position for b in bakes],
                                               masks, [b.normal for b in bakes])
        _check_cancel(cancel)
    problem = Problem(images=photos, masks=masks, normals=[b.normal for b in bakes],
                      correspondences=correspondences, uv=uvs,
                      texture=layout if opt.method == "texture" else None,
                      view_weight=weights, names=[v.name for v in inputs.views])
    result = None
    lam, variation = opt.lam, None
    if opt.method != "project":
        if lam is None:
            from .core.light_variation import auto_lambda, describe_lambda
            lam, variation = auto_lambda(problem)
            solve_progress(0.0, describe_lambda(lam, variation, auto=True))
        params = SolverParams(domain=opt.method, lam=float(lam), mu=float(opt.mu), max_iter=int(opt.max_iter))
        result = solve(problem, params, progress=solve_progress, cancel=cancel)
    times["solve"] = time.perf_counter() - t
    _check_cancel(cancel)

    t = time.perf_counter()
    fuse_progress = _sub(progress, "fuse")
    fuse_progress(0.0, "texture")
    if opt.method == "texture":
        seen = np.asarray(result.seen, dtype=bool)
        albedo = fill_unseen(result.texture, seen, layout.inside, margin=4)
        views = [sample_texture(albedo, uv, m) for uv, m in zip(uvs, masks)]
    else:
        # Image domain: fuse the per-view reflectance; project: the photos themselves.
        maps = result.views if result is not None else problem.images
        fused = fuse_views(maps, masks, uvs, n, view_weight=weights, inside=layout.inside, margin=4)
        albedo, seen = fused[..., :-1], fused[..., -1] > 0
        views = list(maps)
    times["fuse"] = time.perf_counter() - t
    fuse_progress(1.0, "done")
    _check_cancel(cancel)
    return Computed(albedo=np.asarray(albedo, dtype=np.float32), seen=seen, views=views,
                    sigma=None if result is None else np.asarray(result.sigma),
                    energy=[] if result is None else [float(e) for e in result.energy],
                    iterations=0 if result is None else int(result.iterations),
                    info={} if result is None else dict(result.info, lam=lam, lighting_variation=variation))


def _lighting_json(prepared, computed):
    names = [v.name for v in prepared.inputs.views]
    views = []
    for i, name in enumerate(names):
        entry = {"name": name, "sh": None}
        if computed.sigma is not None:
            s = computed.sigma[i]
            ch = ["R", "G", "B"] if s.shape[0] == 3 else ["Y"] * s.shape[0]
            entry["sh"] = {c: [float(x) for x in s[k]] for k, c in enumerate(ch)}
        views.append(entry)
    return {"method": prepared.options.method,
            "basis": SH_BASIS,
            "normals": "world space, unit length",
            "note": "shading = sum_k sh[k] * basis[k](n); sh is null for method 'project' (no lighting estimated)",
            "views": views}


def _report_json(prepared, computed, paths, times):
    import bpy
    opt = prepared.options
    return json_value({
        "object": prepared.inputs.object_name,
        "uv_map": prepared.inputs.mesh.uv_map,
        "method": opt.method,
        "parameters": {"lambda": computed.info.get("lam", opt.lam), "lambda_auto": opt.lam is None,
                       "lighting_variation": computed.info.get("lighting_variation"),
                       "mu": opt.mu, "max_iter": opt.max_iter,
                       "working_res_mp": opt.working_res_mp, "texture_size": opt.texture_size,
                       "images_dir": opt.images_dir},
        "cameras": [{"name": v.name, "file": os.path.relpath(paths.views[v.name], paths.out_dir),
                     "photo": v.source, "size": [int(v.photo.shape[1]), int(v.photo.shape[0])],
                     "pixels_on_mesh": int(np.count_nonzero(b.mask))}
                    for v, b in zip(prepared.inputs.views, prepared.bakes)],
        "times_s": times,
        "iterations": computed.iterations,
        "energy": computed.energy,
        "solver_info": computed.info,
        "texels_seen": int(np.count_nonzero(computed.seen)),
        "warnings": prepared.warnings,
        "blend_file": bpy.data.filepath,
        "blender": bpy.app.version_string,
    })


def finish(scene, prepared: Prepared, computed: Computed, progress=None) -> RunReport:
    """Write the files, then the packed image and the material (main thread).

    The files are written all or nothing before the scene is touched.
    """
    import bpy

    from . import material as _material
    from . import previews as _previews
    from . import write as _write

    opt, inputs = prepared.options, prepared.inputs
    times = dict(prepared.times)
    stage = _sub(progress, "write")
    t = time.perf_counter()
    obj = bpy.data.objects.get(inputs.object_name)
    if obj is None:
        raise DelightError(f"the object {inputs.object_name!r} is gone from the scene")
    _material.check_editable(obj)   # before any file is written
    names = [v.name for v in inputs.views]
    paths = _write.output_paths(prepared.out_dir, inputs.object_name, names)
    stage(0.0, f"files in {paths.out_dir}")

    def report():
        # report.json holds the time spent writing the other files.
        times["write"] = time.perf_counter() - t
        return _report_json(prepared, computed, paths, times)

    files = _write.write_outputs(paths, computed.albedo, computed.seen,
                                 views=dict(zip(names, computed.views)),
                                 masks={v.name: b.mask for v, b in zip(inputs.views, prepared.bakes)},
                                 lighting=json_value(_lighting_json(prepared, computed)), report=report,
                                 overwrite=opt.overwrite)
    stage(0.6, "material")
    image = _write.make_albedo_image(f"{inputs.object_name}_albedo", computed.albedo, computed.seen)
    mats = _material.wire_albedo(obj, image, inputs.mesh.uv_map)
    _previews.update(inputs.object_name, prepared, computed)   # pictures for the panel
    saved = None
    if opt.save_blend:
        stage(0.9, "saving the .blend")
        bpy.ops.wm.save_mainfile(filepath=bpy.data.filepath)
        saved = bpy.data.filepath
    times["write"] = time.perf_counter() - t
    stage(1.0, "done")
    return RunReport(object_name=inputs.object_name, method=opt.method, out_dir=paths.out_dir, files=files,
                     image_name=image.name, materials=[m.name for m in mats], times=times,
                     iterations=computed.iterations, energy=computed.energy, cameras=names,
                     warnings=list(prepared.warnings), saved_blend=saved,
                     lam=computed.info.get("lam"), lighting_variation=computed.info.get("lighting_variation"),
                     lambda_auto=opt.lam is None)


def run(scene, options: Options, progress=None, cancel=None) -> RunReport:
    """Delight ``options.object_name`` in ``scene`` in-line: prepare, compute, finish.

    Parameters
    ----------
    scene : bpy.types.Scene
    options : Options
    progress : callable(fraction, message), optional
    cancel : callable() -> bool, optional

    Raises
    ------
    DelightError
        Bad input; nothing was changed.
    Cancelled
        ``cancel()`` returned True; nothing was changed.
    """
    prepared = prepare(scene, options, progress, cancel)
    computed = compute(prepared, progress, cancel)
    return finish(scene, prepared, computed, progress)
