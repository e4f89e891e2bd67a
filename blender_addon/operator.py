"""The Delight operator (``delight.run``).

In the GUI it is modal: the scene is read (gather and bake) on the main
thread, the solve runs in a worker thread, a timer drains its progress into a
progress bar (in the panel and the status bar: stage, iteration, time left),
Esc cancels, and the results are written on the main thread at the end. A
cancel or an error leaves the scene as it was, and any failure is one line in
the report (an unexpected one's traceback goes to the system console only). In
background mode, and on redo (Adjust Last Operation), it runs in-line and
prints its progress.
"""

from __future__ import annotations

import math
import queue
import sys
import threading
import traceback

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from . import pipeline
from .core.errors import Cancelled, DelightError, is_expected
from .core.failures import failure_message
from .core.options import OPTIONS
from .core.progress import ProgressPrinter, ProgressState

__all__ = [
    "DELIGHT_OT_run",
    "Job",
    "spec_property",
    "spec_labels",
    "set_status",
    "get_status",
    "progress_bar",
    "draw_progress",
    "draw_status_bar",
    "begin_progress",
    "end_progress",
]


def spec_labels(name: str) -> dict:
    """The label and tooltip of the setting ``name`` of :data:`core.options.SPEC`, as bpy property keywords."""
    o = OPTIONS[name]
    return dict(name=o.label, description=o.help)


def spec_property(name: str, clamp: bool = False):
    """A bpy property for the setting ``name`` of :data:`core.options.SPEC`.

    It has the setting's label, tooltip, default and slider (soft) range.

    Parameters
    ----------
    name : str
    clamp : bool
        Give the property the setting's hard range, so the UI cannot make a value out of it (the panel).
        Without it the property takes any number, and the run refuses a bad one with the words of
        :func:`core.options.check`, as the command lines do (the operator: bpy would clamp silently).
    """
    o = OPTIONS[name]
    kw = spec_labels(name)
    kw["default"] = o.ui_default
    if o.kind in ("int", "float"):
        kw.update({k: getattr(o, k) for k in ("soft_min", "soft_max") if getattr(o, k) is not None})
        if o.kind == "float":
            # Float properties store float32 and clamp to +-FLT_MAX by default: infinite bounds keep inf and
            # nan as they were given, for check() to refuse.
            kw.update(min=-math.inf, max=math.inf)
        if clamp:
            kw.update({k: getattr(o, k) for k in ("min", "max") if getattr(o, k) is not None})
        prop = FloatProperty if o.kind == "float" else IntProperty
    elif o.kind == "bool":
        prop = BoolProperty
    elif o.kind == "choice":
        prop, kw["items"] = EnumProperty, list(o.choices)
    elif o.kind in ("str", "dir"):
        prop = StringProperty
        if o.kind == "dir":
            kw["subtype"] = "DIR_PATH"
    else:
        raise ValueError(f"setting {name!r} ({o.kind}) has no bpy property")
    return prop(**kw)


def set_status(text: str):
    """The last run's status, kept on the window manager (not in the scene, not in undo)."""
    wm = bpy.context.window_manager
    if wm is not None and hasattr(type(wm), "delight_status"):
        wm.delight_status = text


def get_status() -> str:
    wm = bpy.context.window_manager
    return getattr(wm, "delight_status", "") if wm is not None else ""


# -- the progress bar (GUI) ------------------------------------------------------------------------
_RUN = None  # the ProgressState of the run going on in the GUI, or None
_ESC = "Delight: Esc cancels"


def progress_bar():
    """What the progress bar shows while a run goes in the GUI: ``(factor, text)``; None when none goes.

    The text is the stage, the iteration and the time left: "solve: iteration 12/40 — about 35 s left".
    """
    return None if _RUN is None else _RUN.bar()


def draw_progress(layout) -> bool:
    """Draw the progress bar into ``layout`` if a run goes; return whether it did."""
    bar = progress_bar()
    if bar is None:
        return False
    factor, text = bar
    layout.progress(factor=factor, type="BAR", text=text)
    return True


def draw_status_bar(self, context):
    """The bar at the end of the status bar (appended to ``STATUSBAR_HT_header`` while a run goes)."""
    row = self.layout.row()
    row.ui_units_x = 18  # a header row is only as wide as its items ask
    draw_progress(row)


def begin_progress(max_iter=None) -> ProgressState:
    """Start showing a run's progress (the panel's bar and the status bar's); return its progress callback."""
    global _RUN
    end_progress()
    _RUN = ProgressState(max_iter)
    bpy.types.STATUSBAR_HT_header.append(draw_status_bar)
    return _RUN


def end_progress():
    """Stop showing progress: the panel shows its button again and the status bar loses the bar."""
    global _RUN
    _RUN = None
    bpy.types.STATUSBAR_HT_header.remove(draw_status_bar)


def _redraw_progress(context, status_text):
    """Redraw the panel (the sidebar of every 3D view) and set the status text, which redraws the status bar."""
    for window in context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                for region in area.regions:
                    if region.type == "UI":
                        region.tag_redraw()
    if context.workspace is not None:
        context.workspace.status_text_set(status_text)


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
            self.computed = pipeline.compute(
                self.prepared, progress=lambda f, m="": self.messages.put((f, m)), cancel=self.cancel_event.is_set
            )
        except BaseException as exc:  # reported on the main thread
            self.error = exc

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


class DELIGHT_OT_run(bpy.types.Operator):
    """Estimate the albedo of a mesh from its photos and cameras, and put it on its material"""

    bl_idname = "delight.run"
    bl_label = "Delight"
    bl_options = {"REGISTER", "UNDO"}

    # Any value passes here; the run checks it (core.options.check), as the command lines do.
    object_name: spec_property("object_name")
    cameras: spec_property("cameras")
    camera_collection: spec_property("camera_collection")
    images_dir: spec_property("images_dir")
    auto_lambda: spec_property("auto_lambda")
    lam: spec_property("lam")
    albedo_lam: spec_property("albedo_lam")
    albedo_adapt: spec_property("albedo_adapt")
    lighting: spec_property("lighting")
    occlusion: spec_property("occlusion")
    sun: spec_property("sun")
    align_photos: spec_property("align_photos")
    mask_clipped: spec_property("mask_clipped")
    fill_outlines: spec_property("fill_outlines")
    mu: spec_property("mu")
    max_iter: spec_property("max_iter")
    working_res: spec_property("working_res_mp")
    working_total: spec_property("working_total_mp")
    detail: spec_property("detail")
    texture_size: spec_property("texture_size")
    method: spec_property("method")
    out_dir: spec_property("out_dir")
    overwrite: spec_property("overwrite")

    _job = None
    _timer = None
    _prepared = None
    _drawn = None  # the bar as last drawn

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
            raise DelightError(
                "the .blend file is not saved, so '//' means nothing: save it or choose an absolute output folder"
            )
        return pipeline.Options(
            object_name=self.object_name or None,
            camera_names=names,
            images_dir=bpy.path.abspath(self.images_dir) if self.images_dir else None,
            selected_only=self.cameras == "SELECTED",
            lam=None if self.auto_lambda else self.lam,
            albedo_lam=self.albedo_lam,
            albedo_adapt=self.albedo_adapt,
            lighting=self.lighting,
            occlusion=self.occlusion,
            sun=self.sun,
            align_photos=self.align_photos,
            mask_clipped=self.mask_clipped,
            fill_outlines=self.fill_outlines,
            mu=self.mu,
            max_iter=self.max_iter,
            working_res_mp=self.working_res,
            working_total_mp=self.working_total,
            detail=self.detail,
            texture_size=self.texture_size,
            method=self.method,
            out_dir=bpy.path.abspath(out) if out else None,
            overwrite=self.overwrite,
        )

    def _done(self, report):
        msg = (
            f"Delight: {report.object_name} -> {report.image_name} "
            f"({report.iterations} iterations, {report.lambda_text}, {sum(report.times.values()):.1f} s), "
            f"files in {report.out_dir}"
        )
        for w in report.warnings:
            self.report({"WARNING"}, w)
        self.report({"INFO"}, msg)
        set_status(msg)
        return {"FINISHED"}

    def _fail(self, exc):
        """Report a failed run in one line; an unexpected error's traceback goes to the console only."""
        if isinstance(exc, Cancelled):
            self.report({"WARNING"}, "Delight cancelled; nothing was changed")
            set_status("Cancelled")
            return {"CANCELLED"}
        if not is_expected(exc):
            traceback.print_exception(type(exc), exc, exc.__traceback__)
        message = failure_message(exc, front="panel")
        self.report({"ERROR"}, f"Delight: {message}")
        set_status(f"Error: {message}")
        return {"CANCELLED"}

    # -- in-line (background, redo) ----------------------------------------------------------------
    def execute(self, context):
        progress = ProgressPrinter(sys.stdout) if bpy.app.background else None
        try:
            report = pipeline.run(context.scene, self.pipeline_options(), progress=progress)
        except Exception as exc:  # any failure is one line in the report, never a traceback
            return self._fail(exc)
        return self._done(report)

    # -- modal (GUI) -----------------------------------------------------------------------------
    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        if _RUN is not None:
            self.report({"WARNING"}, "Delight is already running (Esc cancels it)")
            return {"CANCELLED"}
        wm = context.window_manager
        state = begin_progress(self.max_iter if self.method != "project" else None)
        # The scene is read on the main thread, so nothing redraws meanwhile: the cursor shows the progress.
        wm.progress_begin(0, 100)
        try:

            def progress(f, m=""):
                state(f, m)
                wm.progress_update(int(100 * f))

            self._prepared = pipeline.prepare(context.scene, self.pipeline_options(), progress=progress)
        except Exception as exc:
            self._cleanup(context)
            return self._fail(exc)
        finally:
            wm.progress_end()
        self._job = Job(self._prepared).start()
        self._timer = wm.event_timer_add(0.1, window=context.window)
        wm.modal_handler_add(self)
        self._drawn = None
        _redraw_progress(context, _ESC)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC" and event.value == "PRESS":
            self._job.cancel()
            _redraw_progress(context, "Delight: cancelling")
            return {"RUNNING_MODAL"}
        if event.type != "TIMER" or event.timer != self._timer:
            return {"PASS_THROUGH"}
        if _RUN is not None:
            for fraction, message in self._job.poll():
                _RUN(fraction, message)
            bar = _RUN.bar()
            if bar != self._drawn:  # redraw only when the bar changed
                self._drawn = bar
                _redraw_progress(context, "Delight: cancelling" if self._job.cancel_event.is_set() else _ESC)
        if not self._job.done:
            return {"RUNNING_MODAL"}
        job = self._job
        self._cleanup(context)
        if job.error is not None:
            return self._fail(job.error)
        if job.cancel_event.is_set():
            return self._fail(Cancelled("cancelled"))
        try:
            report = pipeline.finish(context.scene, self._prepared, job.computed)
        except Exception as exc:
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
        end_progress()
        _redraw_progress(context, None)  # the panel shows its button again, the status bar its own text


classes = (DELIGHT_OT_run,)


def register():
    bpy.types.WindowManager.delight_status = StringProperty(name="Delight Status")
    for c in classes:
        bpy.utils.register_class(c)


def unregister():
    end_progress()
    for c in reversed(classes):
        bpy.utils.unregister_class(c)
    del bpy.types.WindowManager.delight_status
