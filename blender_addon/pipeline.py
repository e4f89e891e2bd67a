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
:class:`core.solve.solver.Cancelled` before :func:`finish`, so the scene and the
output folder are left as they were.
"""
from __future__ import annotations

import os
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from .core.errors import DelightError
from .core.io.jsonio import json_value
from .core.pipeline import DEFAULTS, METHODS, Computed, Options, check_cancel, stage_progress
from .core.pipeline import compute as _compute
from .core.solve.sh import SH_BASIS_NAMES

#: The basis of the lighting coefficients in lighting.json (world-space normal n).
SH_BASIS = list(SH_BASIS_NAMES)

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
        from .core.solve.lambda_choice import describe_lambda
        return describe_lambda(self.lam, self.lighting_variation, self.lambda_auto)


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

    from .core.geometry import bake as _bake
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
    stage_progress(progress, "gather")(0.0, "reading the scene")
    inputs = _scene.gather(scene, object_name=options.object_name, camera_names=options.camera_names,
                           images_dir=options.images_dir, working_res_mp=options.working_res_mp,
                           selected_only=options.selected_only)
    # Fail before the long part if the outputs or the material are in the way.
    _material.check_editable(bpy.data.objects[inputs.object_name])
    _write.check_outputs(_write.output_paths(out_dir, inputs.object_name, [v.name for v in inputs.views]),
                         options.overwrite)
    times["gather"] = time.perf_counter() - t
    check_cancel(cancel)

    t = time.perf_counter()
    bakes = _bake.bake_views(scene, inputs, progress=stage_progress(progress, "bake"), cancel=cancel)
    times["bake"] = time.perf_counter() - t
    check_cancel(cancel)

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


def compute(prepared: Prepared, progress=None, cancel=None) -> Computed:
    """Build the problem, solve and fuse (:func:`core.pipeline.compute`; safe in a worker thread)."""
    return _compute(prepared.options, prepared.inputs, prepared.bakes, prepared.times, progress, cancel)


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
                       "albedo_lambda": opt.albedo_lam, "lighting": computed.info.get("lighting_mode", opt.lighting),
                       "occlusion": opt.occlusion, "mask_clipped": opt.mask_clipped,
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
    stage = stage_progress(progress, "write")
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
