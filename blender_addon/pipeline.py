"""The whole run: scene -> bake -> problem -> solve -> fuse -> write.

It is split in three steps so that the GUI can run the long middle one in a
worker thread:

* :func:`prepare` (main thread) reads the scene: gather and bake. It only
  reads bpy data and returns plain arrays.
* :func:`compute` (any thread) is pure NumPy/SciPy: builds the problem,
  solves, fuses. It never touches bpy.
* :func:`finish` (main thread) writes the files (:mod:`core.io.outputs`: all
  or nothing, never over an input or a file Delight did not write), then
  creates the image, wires the material and updates the panel's preview
  images (:mod:`.previews`). This is the only step that changes anything.

:func:`run` chains the three. A cancel (``cancel()`` returning True) raises
:class:`core.errors.Cancelled`; until the files are in place that leaves the
scene and the output folder as they were.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import numpy as np

from .core.checks import check_photos, check_uv_layout
from .core.errors import Cancelled, DelightError
from .core.io import outputs as _outputs
from .core.io.names import safe_name
from .core.io.photo_cache import PhotoCache
from .core.parallel import blas_on_one_thread
from .core.pipeline import Computed, Options, check_cancel, peak_mb, stage_progress
from .core.pipeline import compute as _compute
from .core.plan import schedule, uses_detail


@dataclass
class Prepared:
    """The scene read into arrays (output of :func:`prepare`)."""

    options: Options
    inputs: object  # scene.SceneInputs
    bakes: list  # list of bake.ViewBake, one per kept view
    out_dir: str
    times: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    peaks: dict = field(default_factory=dict)  # peak memory (MB) at the end of each stage
    photos: PhotoCache | None = None  # the full-resolution photos' temporary copies, for the detail stage
    alignment: object = None  # core.geometry.align.Alignment with the option align_photos, else None
    stages: dict | None = None  # the progress bar's spans (core.plan.schedule), set once the photos are read

    def release(self):
        """Remove the full-resolution photos' temporary copies (once the detail stage is done, or on failure)."""
        if self.photos is not None:
            self.photos.close()


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
    lam: float | None = None  # the TV weight used (None for "project")
    lighting_variation: float | None = None  # what auto lambda measured
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


def _blend_folder(blend_path: str) -> str:
    if not blend_path:
        raise DelightError(
            "the .blend file is not saved, so there is no default output folder: choose an output folder"
        )
    return os.path.dirname(os.path.abspath(blend_path))


def default_out_dir(blend_path: str, object_name: str) -> str:
    """``<blend folder>/delight_<object>``: a folder of Delight's own, apart from photos beside the .blend.

    An unsaved file has no such place (:class:`DelightError`).
    """
    return os.path.join(_blend_folder(blend_path), "delight_" + safe_name(object_name))


def _output_names(object_name, camera_names, method) -> list:
    """The files of a run besides report.json, relative to the output folder: albedo, views, lighting."""
    lighting = _outputs.lighting_files(estimated=method != "project")
    return [safe_name(object_name) + "_albedo.exr", *_outputs.view_files(camera_names), *lighting]


def _input_files(inputs) -> list:
    """Every file the run reads or the scene uses: the .blend, its libraries, the photo and image files."""
    import bpy

    files = [bpy.data.filepath]
    files += [bpy.path.abspath(lib.filepath) for lib in bpy.data.libraries]
    files += [v.source for v in inputs.views if os.path.isabs(v.source)]  # photos from the images folder
    for img in bpy.data.images:  # background images, image planes, textures
        if img.source in ("FILE", "SEQUENCE", "MOVIE", "TILED") and img.filepath:
            files.append(os.path.abspath(bpy.path.abspath(img.filepath, library=img.library)))
    return files


@blas_on_one_thread()
def prepare(scene, options: Options, progress=None, cancel=None) -> Prepared:
    """Read the scene into arrays: gather the inputs and bake every view (main thread).

    Raises
    ------
    DelightError
        Bad options or input, an output folder that cannot be written, an
        output that is an input file, a file in the way that Delight did not
        write (without ``overwrite``), or a mesh that no camera sees.
    Cancelled
        ``cancel()`` returned True.
    """
    import bpy

    from . import scene as _scene

    options.validate()
    if not options.out_dir:
        _blend_folder(bpy.data.filepath)  # no default folder: say so before reading the scene
    if options.save_blend and not bpy.data.filepath:
        raise DelightError("cannot save: the .blend file has never been saved")

    t = time.perf_counter()
    stage_progress(progress, "gather")(0.0, "reading the scene")
    target = _scene.target_object(scene, options.object_name).name
    out_dir = os.path.abspath(bpy.path.abspath(options.out_dir or default_out_dir(bpy.data.filepath, target)))
    # The detail stage reads the photos again at full resolution: keep copies on the outputs' disk meanwhile.
    photos = PhotoCache(out_dir) if uses_detail(options) else None
    try:
        return _prepare(scene, options, progress, cancel, out_dir, photos, t)
    except BaseException:
        if photos is not None:
            photos.close()
        raise


def _prepare(scene, options, progress, cancel, out_dir, photos, t):
    import bpy

    from . import material as _material
    from . import scene as _scene
    from .core.geometry import bake as _bake

    times, peaks = {}, {}
    inputs = _scene.gather(
        scene,
        object_name=options.object_name,
        camera_names=options.camera_names,
        images_dir=options.images_dir,
        working_res_mp=options.working_res_mp,
        selected_only=options.selected_only,
        keep_full=photos.put if photos is not None else None,
        progress=stage_progress(progress, "gather"),
        threads=options.threads,
        working_total_mp=options.working_total_mp,
    )
    # The bar's spans, now that the photos tell how long the stages will take.
    stages = schedule(options, inputs)
    # Fail before the long part if the outputs or the material are in the way.
    _material.check_editable(bpy.data.objects[inputs.object_name])
    # The outputs, uncompressed: an RGBA float32 albedo and one per view.
    need = 16 * (int(options.texture_size) ** 2 + sum(v.photo.shape[0] * v.photo.shape[1] for v in inputs.views))
    _outputs.prepare_outputs(
        out_dir,
        _output_names(inputs.object_name, [v.name for v in inputs.views], options.method),
        options.overwrite,
        _input_files(inputs),
        need_bytes=need,
    )
    times["gather"], peaks["gather"] = time.perf_counter() - t, peak_mb()
    check_cancel(cancel)

    t = time.perf_counter()
    bake_progress = stage_progress(progress, "bake", stages)
    bakes = _bake.bake_views(scene, inputs, progress=bake_progress, cancel=cancel, threads=options.threads)
    times["bake"], peaks["bake"] = time.perf_counter() - t, peak_mb()
    check_cancel(cancel)

    # A camera that does not see the mesh adds nothing: drop it, but not all.
    warnings, keep = list(inputs.skipped), []
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
    alignment = None
    if options.align_photos:
        from .core.geometry.align import align_views

        t = time.perf_counter()
        bake_progress(1.0, "aligning the photos")
        # On a texture of the photos' own density, not the one asked for: the cameras move the same at any size.
        inputs, bakes, alignment = align_views(inputs, bakes, threads=options.threads, cancel=cancel)
        times["align"], peaks["align"] = time.perf_counter() - t, peak_mb()
        moved = int(alignment.applied.sum())
        bake_progress(
            1.0,
            f"{moved} of {len(bakes)} cameras moved to line their photos up"
            if alignment.mesh_fits
            else "no camera moved: the photos do not line up with the mesh by one shift each",
        )
        check_cancel(cancel)
    warnings += check_uv_layout(inputs.mesh.tri_uv, inputs.mesh.tri_pos, options.texture_size)
    warnings += check_photos([v.name for v in inputs.views], [v.photo for v in inputs.views], [b.mask for b in bakes])
    return Prepared(
        options=options,
        inputs=inputs,
        bakes=bakes,
        out_dir=out_dir,
        times=times,
        warnings=warnings,
        peaks=peaks,
        photos=photos,
        alignment=alignment,
        stages=stages,
    )


def compute(prepared: Prepared, progress=None, cancel=None) -> Computed:
    """Build the problem, solve and fuse (:func:`core.pipeline.compute`; safe in a worker thread).

    The full-resolution photos' temporary copies are removed at the end, whatever the outcome.
    """
    try:
        return _compute(
            prepared.options,
            prepared.inputs,
            prepared.bakes,
            prepared.times,
            progress,
            cancel,
            peaks=prepared.peaks,
            stages=prepared.stages,
        )
    finally:
        prepared.release()


def _lighting_outputs(prepared, computed, files):
    names = [v.name for v in prepared.inputs.views]
    return _outputs.lighting_outputs(
        names, files, computed.sigma, computed.albedo.shape[2], prepared.options.method, computed.sun_direction
    )


def _camera_alignment(alignment, i):
    """One camera's line of the report: the shift applied and the one measured (pixels), or None without."""
    if alignment is None:
        return None
    return {
        "shift_px": [float(x) for x in alignment.shift[i]],
        "measured_px": [float(x) for x in alignment.measured[i]],
        "spread_px": float(alignment.spread[i]) if np.isfinite(alignment.spread[i]) else None,
        "applied": bool(alignment.applied[i]),
    }


def _report_json(prepared, computed, files, times):
    import bpy

    opt = prepared.options
    return {
        "object": prepared.inputs.object_name,
        "uv_map": prepared.inputs.mesh.uv_map,
        "method": opt.method,
        "parameters": {
            "lambda": computed.info.get("lam", opt.lam),
            "lambda_auto": opt.lam is None,
            "lighting_variation": computed.info.get("lighting_variation"),
            "albedo_lambda": computed.info.get("albedo_lam", opt.albedo_lam),
            "albedo_adapt": opt.albedo_adapt,
            "colour_texture": computed.info.get("colour_texture"),
            "lighting": computed.info.get("lighting_mode", opt.lighting),
            "occlusion": opt.occlusion,
            "sun": computed.info.get("sun", {"used": False}) if opt.sun else None,
            "align_photos": None
            if prepared.alignment is None
            else {
                "cameras_moved": int(prepared.alignment.applied.sum()),
                "mesh_fits": prepared.alignment.mesh_fits,
                "texture_size": prepared.alignment.texture_size,
            },
            "mask_clipped": opt.mask_clipped,
            "fill_outlines": {"texels": computed.info.get("outline_texels", 0)} if opt.fill_outlines else None,
            "mu": opt.mu,
            "max_iter": opt.max_iter,
            "working_res_mp": opt.working_res_mp,
            "working_total_mp": opt.working_total_mp,
            "detail": opt.detail,
            "texture_size": opt.texture_size,
            "images_dir": opt.images_dir,
        },
        "cameras": [
            {
                "name": v.name,
                "file": f,
                "photo": v.source,
                "size": [int(v.photo.shape[1]), int(v.photo.shape[0])],
                "full_size": [int(v.full.camera.width), int(v.full.camera.height)] if v.full is not None else None,
                "pixels_on_mesh": int(np.count_nonzero(b.mask)),
                "alignment": _camera_alignment(prepared.alignment, i),
            }
            for i, (v, b, f) in enumerate(zip(prepared.inputs.views, prepared.bakes, files))
        ],
        "times_s": times,
        "peak_mb": prepared.peaks,
        "iterations": computed.iterations,
        "energy": computed.energy,
        "solver_info": computed.info,
        "texels_seen": int(np.count_nonzero(computed.seen)),
        "warnings": prepared.warnings,
        "blend_file": bpy.data.filepath,
        "blender": bpy.app.version_string,
    }


def finish(scene, prepared: Prepared, computed: Computed, progress=None, cancel=None) -> RunReport:
    """Write the files, then the packed image and the material (main thread).

    The files are written all or nothing (:func:`core.io.outputs.write_outputs`)
    before the scene is touched; ``cancel`` is checked until they are in place.
    With ``options.save_blend`` the .blend is saved last, once the files are in
    place and the material is wired.

    Raises
    ------
    DelightError
        The object is gone or cannot be edited, or a file could not be written
        (nothing was changed); or the .blend could not be saved (the new files
        are in place, the .blend as it was).
    Cancelled
        ``cancel()`` returned True before the files were in place (the folder
        and the scene are as they were); or Ctrl+C came after (``written`` is
        the output folder).
    """
    import bpy

    from . import material as _material
    from . import previews as _previews
    from . import write as _write

    opt, inputs = prepared.options, prepared.inputs
    times = dict(prepared.times)
    stage = stage_progress(progress, "write", prepared.stages)
    t = time.perf_counter()
    obj = bpy.data.objects.get(inputs.object_name)
    if obj is None:
        raise DelightError(f"the object {inputs.object_name!r} is gone from the scene")
    _material.check_editable(obj)  # before any file is written
    names = [v.name for v in inputs.views]
    albedo_file, *view_files = _output_names(inputs.object_name, names, opt.method)[: 1 + len(names)]
    stage(0.0, f"files in {prepared.out_dir}")
    albedo_pixels = _outputs.rgba(computed.albedo, computed.seen, zero_outside=False)
    contents = {albedo_file: albedo_pixels}
    for b, f, values in zip(prepared.bakes, view_files, computed.views):
        contents[f] = _outputs.rgba(values, b.mask)
    contents.update(_lighting_outputs(prepared, computed, view_files))

    def report():
        # report.json holds the time spent writing the other files.
        times["write"], prepared.peaks["write"] = time.perf_counter() - t, peak_mb()
        return _report_json(prepared, computed, view_files, times)

    files = _outputs.write_outputs(
        prepared.out_dir,
        contents,
        report,
        overwrite=opt.overwrite,
        inputs=_input_files(inputs),
        cancel=cancel,
        threads=opt.threads,
    )
    del contents  # written: the image below reuses the albedo's pixels, and nothing else is held
    # The files are in place: from here on a failure says so. The .blend is saved last.
    saved = None
    try:
        stage(0.6, "material")
        image = _write.make_albedo_image(f"{inputs.object_name}_albedo", albedo_pixels)
        mats = _material.wire_albedo(obj, image, inputs.mesh.uv_map)
        _previews.update(inputs.object_name, prepared, computed)  # pictures for the panel
        if opt.save_blend:
            stage(0.9, "saving the .blend")
            path = bpy.data.filepath
            try:
                bpy.ops.wm.save_mainfile(filepath=path)
                # Blender 4.2 reports some failed saves without raising.
                if not os.path.isfile(path):
                    raise RuntimeError(f"{path} is not a file after saving")
            except RuntimeError as exc:
                why = str(exc).strip().removeprefix("Error:").strip()
                raise DelightError(
                    f"the new outputs are in {prepared.out_dir}, but the .blend could not be saved: {why}"
                ) from None
            saved = bpy.data.filepath
    except KeyboardInterrupt:
        blend = "" if not opt.save_blend else "; the .blend was saved" if saved else "; the .blend was not saved"
        raise Cancelled(
            f"interrupted after the new outputs were written to {prepared.out_dir}{blend}", written=prepared.out_dir
        ) from None
    times["write"] = time.perf_counter() - t
    stage(1.0, "done")
    return RunReport(
        object_name=inputs.object_name,
        method=opt.method,
        out_dir=prepared.out_dir,
        files=files,
        image_name=image.name,
        materials=[m.name for m in mats],
        times=times,
        iterations=computed.iterations,
        energy=computed.energy,
        cameras=names,
        warnings=list(prepared.warnings),
        saved_blend=saved,
        lam=computed.info.get("lam"),
        lighting_variation=computed.info.get("lighting_variation"),
        lambda_auto=opt.lam is None,
    )


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
        Bad input; nothing was changed. Or the .blend could not be saved
        (:func:`finish`).
    Cancelled
        ``cancel()`` returned True; nothing was changed (``cancel`` is checked
        until the files are in place). Or Ctrl+C after that (:func:`finish`).
    """
    prepared = prepare(scene, options, progress, cancel)
    computed = compute(prepared, progress, cancel)
    return finish(scene, prepared, computed, progress, cancel)
