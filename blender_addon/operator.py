"""The Delight operator (``delight.run``).

In the GUI it is modal: the scene is read (gather and bake) on the main
thread, the solve runs in a worker thread, a timer shows its progress, Esc
cancels, and the results are written on the main thread at the end. A cancel
or an error leaves the scene as it was. In background mode, and on redo, it
runs in-line and prints its progress.
"""
from __future__ import annotations

import queue
import threading
import traceback

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from . import pipeline
from .core.errors import Cancelled
from .core.errors import DelightError
from .pipeline import DEFAULTS

__all__ = ["DELIGHT_OT_run", "Job", "METHOD_ITEMS", "CAMERA_ITEMS", "set_status", "get_status"]

METHOD_ITEMS = [
    ("texture", "Texture", "Solve one albedo per texel (fast, the default)"),
    ("image", "Image", "Solve per photo pixel with cross-view consistency, then fuse"),
    ("project", "Project only", "No delighting: fuse the photos as they are, for comparison"),
]
CAMERA_ITEMS = [
    ("ALL", "All", "Every camera in the scene"),
    ("SELECTED", "Selected", "The selected cameras"),
    ("COLLECTION", "Collection", "The cameras in one collection"),
]


def set_status(text: str):
    """The last run's status, kept on the window manager (not in the scene, not in undo)."""
    wm = bpy.context.window_manager
    if wm is not None and hasattr(type(wm), "delight_status"):
        wm.delight_status = text


def get_status() -> str:
    wm = bpy.context.window_manager
    return getattr(wm, "delight_status", "") if wm is not None else ""


class Job:
    """:func:`pipeline.compute` in a worker thread, with a progress queue and a cancel flag.

    The main thread calls :meth:`poll` to drain progress messages and checks
    :attr:`done`; then :attr:`computed` or :attr:`error` holds the outcome.
    """

    def __init__(self, prepared):
        self.prepared = prepared
        self.messages = queue.Queue()
        self.cancel_event = threading.Event()
        self.computed = None
        self.error = None
        self._thread = threading.Thread(target=self._work, name="delight-solve", daemon=True)

    def _work(self):
        try:
            self.computed = pipeline.compute(self.prepared, progress=lambda f, m="": self.messages.put((f, m)),
                                             cancel=self.cancel_event.is_set)
        except BaseException as exc:  # reported on the main thread
            self.error = exc
            if not isinstance(exc, (Cancelled, DelightError, ValueError)):
                traceback.print_exc()

    def start(self):
        self._thread.start()
        return self

    def cancel(self):
        self.cancel_event.set()

    @property
    def done(self) -> bool:
        return not self._thread.is_alive()

    def join(self, timeout=None):
        self._thread.join(timeout)

    def poll(self) -> list:
        """Progress messages ``(fraction, text)`` since the last poll."""
        out = []
        while True:
            try:
                out.append(self.messages.get_nowait())
            except queue.Empty:
                return out


def _print_progress(fraction, message=""):
    print(f"delight: {100 * fraction:5.1f}% {message}", flush=True)


class DELIGHT_OT_run(bpy.types.Operator):
    """Estimate the albedo of a mesh from its photos and cameras, and put it on its material"""

    bl_idname = "delight.run"
    bl_label = "Delight"
    bl_options = {"REGISTER", "UNDO"}

    object_name: StringProperty(name="Object", description="Mesh to delight; empty: the active object")
    cameras: EnumProperty(name="Cameras", items=CAMERA_ITEMS, default="ALL")
    camera_collection: StringProperty(name="Camera Collection",
                                      description="Collection whose cameras are used (Cameras: Collection)")
    images_dir: StringProperty(name="Images Folder", subtype="DIR_PATH",
                               description="Where to find a photo named like its camera, "
                                           "for cameras without a background image")
    auto_lambda: BoolProperty(name="Auto Lambda", default=True,
                              description="Pick lambda from how much the lighting changes between the photos "
                                          "(5 under one lighting, 0.5 when it changes)")
    lam: FloatProperty(name="Lambda", default=DEFAULTS.lam, min=0.0, soft_max=100.0,
                       description="Smoothness (total variation) weight, when Auto Lambda is off")
    mu: FloatProperty(name="Mu", default=DEFAULTS.mu, min=0.0, description="Cross-view consistency weight (Image)")
    max_iter: IntProperty(name="Iterations", default=DEFAULTS.max_iter, min=1, soft_max=500)
    working_res: FloatProperty(name="Working Resolution", default=1.0, min=0.001, soft_max=16.0, unit="NONE",
                               description="Photos are downscaled to at most this many megapixels")
    texture_size: IntProperty(name="Texture Size", default=1024, min=8, max=16384)
    method: EnumProperty(name="Method", items=METHOD_ITEMS, default="texture")
    out_dir: StringProperty(name="Output Folder", subtype="DIR_PATH", default="",
                            description="Where the EXR textures and reports go; "
                                        "empty: a folder delight_<mesh> beside the .blend")
    overwrite: BoolProperty(name="Overwrite", default=False, description="Replace existing output files")

    _job = None
    _timer = None
    _prepared = None

    # -- options ---------------------------------------------------------------------------------
    def pipeline_options(self) -> pipeline.Options:
        names = None
        if self.cameras == "COLLECTION":
            coll = bpy.data.collections.get(self.camera_collection)
            if coll is None:
                raise DelightError(f"no collection named {self.camera_collection!r}")
            names = [o.name for o in coll.all_objects if o.type == "CAMERA"]
            if not names:
                raise DelightError(f"the collection {coll.name!r} has no cameras")
        out = self.out_dir.strip()
        if out.startswith("//") and not bpy.data.filepath:
            raise DelightError("the .blend file is not saved, so '//' means nothing: "
                               "save it or choose an absolute output folder")
        return pipeline.Options(
            object_name=self.object_name or None, camera_names=names,
            images_dir=bpy.path.abspath(self.images_dir) if self.images_dir else None,
            selected_only=self.cameras == "SELECTED", lam=None if self.auto_lambda else self.lam, mu=self.mu,
            max_iter=self.max_iter,
            working_res_mp=self.working_res, texture_size=self.texture_size, method=self.method,
            out_dir=bpy.path.abspath(out) if out else None, overwrite=self.overwrite)

    def _done(self, report):
        msg = (f"Delight: {report.object_name} -> {report.image_name} "
               f"({report.iterations} iterations, {report.lambda_text}, {sum(report.times.values()):.1f} s), "
               f"files in {report.out_dir}")
        for w in report.warnings:
            self.report({"WARNING"}, w)
        self.report({"INFO"}, msg)
        set_status(msg)
        return {"FINISHED"}

    def _fail(self, exc):
        if isinstance(exc, Cancelled):
            self.report({"WARNING"}, "Delight cancelled; nothing was changed")
            set_status("Cancelled")
        else:
            self.report({"ERROR"}, f"Delight: {exc}")
            set_status(f"Error: {exc}")
        return {"CANCELLED"}

    # -- in-line (background, redo) ----------------------------------------------------------------
    def execute(self, context):
        progress = _print_progress if bpy.app.background else None
        try:
            report = pipeline.run(context.scene, self.pipeline_options(), progress=progress)
        except (DelightError, ValueError, Cancelled) as exc:
            return self._fail(exc)
        return self._done(report)

    # -- modal (GUI) -----------------------------------------------------------------------------
    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        wm = context.window_manager
        wm.progress_begin(0, 100)
        try:
            def progress(f, m=""):
                wm.progress_update(int(100 * f))
                context.workspace.status_text_set(f"Delight: {m}")
            self._prepared = pipeline.prepare(context.scene, self.pipeline_options(), progress=progress)
        except (DelightError, ValueError, Cancelled) as exc:
            self._cleanup(context)
            return self._fail(exc)
        except BaseException:
            self._cleanup(context)
            raise
        self._job = Job(self._prepared).start()
        self._timer = wm.event_timer_add(0.1, window=context.window)
        wm.modal_handler_add(self)
        context.workspace.status_text_set("Delight: solving (Esc cancels)")
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC" and event.value == "PRESS":
            self._job.cancel()
            context.workspace.status_text_set("Delight: cancelling...")
            return {"RUNNING_MODAL"}
        if event.type != "TIMER" or event.timer != self._timer:
            return {"PASS_THROUGH"}
        for fraction, message in self._job.poll():
            context.window_manager.progress_update(int(100 * fraction))
            context.workspace.status_text_set(f"Delight: {message}  (Esc cancels)")
        if not self._job.done:
            return {"RUNNING_MODAL"}
        job = self._job
        self._cleanup(context)
        if job.error is not None:
            if not isinstance(job.error, (DelightError, ValueError, Cancelled)):
                raise job.error
            return self._fail(job.error)
        if job.cancel_event.is_set():
            return self._fail(Cancelled("cancelled"))
        try:
            report = pipeline.finish(context.scene, self._prepared, job.computed)
        except (DelightError, ValueError) as exc:
            return self._fail(exc)
        finally:
            self._prepared = None
        return self._done(report)

    def cancel(self, context):
        # Blender ends the operator (file load, window closed): stop the worker.
        if self._job is not None:
            self._job.cancel()
        self._cleanup(context)

    def _cleanup(self, context):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        self._job = None
        wm.progress_end()
        if context.workspace is not None:
            context.workspace.status_text_set(None)


classes = (DELIGHT_OT_run,)


def register():
    bpy.types.WindowManager.delight_status = StringProperty(name="Delight Status")
    for c in classes:
        bpy.utils.register_class(c)


def unregister():
    for c in reversed(classes):
        bpy.utils.unregister_class(c)
    del bpy.types.WindowManager.delight_status
