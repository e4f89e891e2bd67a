"""The "Delight" tab in the 3D Viewport sidebar, and its settings on the scene."""

from __future__ import annotations

import bpy
from bpy.props import PointerProperty

from . import previews
from .operator import DELIGHT_OT_run, draw_progress, get_status, spec_labels, spec_property

__all__ = ["DelightSettings", "VIEW3D_PT_delight", "operator_settings"]


def _is_mesh(self, obj):
    return obj.type == "MESH"


class DelightSettings(bpy.types.PropertyGroup):
    """The panel's choices, saved with the scene (``scene.delight``).

    Built from :data:`core.options.SPEC`, with its hard ranges as the fields' limits; the run refuses what the
    limits let through (a working resolution of 0) in the words of the command lines.
    """

    target: PointerProperty(type=bpy.types.Object, poll=_is_mesh, **spec_labels("object_name"))
    cameras: spec_property("cameras")
    camera_collection: PointerProperty(type=bpy.types.Collection, **spec_labels("camera_collection"))
    images_dir: spec_property("images_dir")
    method: spec_property("method")
    auto_lambda: spec_property("auto_lambda")
    lam: spec_property("lam", clamp=True)
    albedo_lam: spec_property("albedo_lam", clamp=True)
    albedo_adapt: spec_property("albedo_adapt")
    lighting: spec_property("lighting")
    occlusion: spec_property("occlusion")
    sun: spec_property("sun")
    align_photos: spec_property("align_photos")
    mask_clipped: spec_property("mask_clipped")
    fill_outlines: spec_property("fill_outlines")
    mu: spec_property("mu", clamp=True)
    max_iter: spec_property("max_iter", clamp=True)
    working_res: spec_property("working_res_mp", clamp=True)
    working_total: spec_property("working_total_mp", clamp=True)
    detail: spec_property("detail")
    texture_size: spec_property("texture_size", clamp=True)
    out_dir: spec_property("out_dir")
    overwrite: spec_property("overwrite")


#: The settings the panel hands to the operator as they are (same property name on both).
_SAME = (
    "cameras",
    "images_dir",
    "method",
    "auto_lambda",
    "lam",
    "albedo_lam",
    "albedo_adapt",
    "lighting",
    "occlusion",
    "sun",
    "align_photos",
    "mask_clipped",
    "fill_outlines",
    "mu",
    "max_iter",
    "working_res",
    "working_total",
    "detail",
    "texture_size",
    "out_dir",
    "overwrite",
)


def operator_settings(settings) -> dict:
    """The operator's properties for the panel's settings."""
    return dict(
        object_name=settings.target.name if settings.target else "",
        camera_collection=settings.camera_collection.name if settings.camera_collection else "",
        **{name: getattr(settings, name) for name in _SAME},
    )


class VIEW3D_PT_delight(bpy.types.Panel):
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Delight"
    bl_label = "Delight"

    def draw(self, context):
        s = context.scene.delight
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False

        col = layout.column()
        col.prop(s, "target")
        if s.target is None:
            obj = context.active_object
            col.label(text=f"Active: {obj.name}" if obj and obj.type == "MESH" else "Pick a mesh", icon="INFO")
        col.prop(s, "cameras")
        if s.cameras == "COLLECTION":
            col.prop(s, "camera_collection")
        col.prop(s, "images_dir")
        col.prop(s, "align_photos")

        col = layout.column(heading="Solve")
        col.prop(s, "method")
        sub = col.column()
        sub.active = s.method != "project"
        sub.prop(s, "auto_lambda")
        row = sub.row()
        row.active = not s.auto_lambda
        row.prop(s, "lam")
        sub.prop(s, "albedo_lam")
        sub.prop(s, "albedo_adapt")
        sub.prop(s, "lighting")
        sub.prop(s, "occlusion")
        sub.prop(s, "sun")
        sub.prop(s, "mask_clipped")
        row = sub.row()
        row.active = s.method == "texture"
        row.prop(s, "fill_outlines")
        if s.method == "image":
            sub.prop(s, "mu")
        sub.prop(s, "max_iter")
        col.prop(s, "working_res")
        col.prop(s, "working_total")
        row = col.row()
        row.active = s.method != "project"
        row.prop(s, "detail")
        col.prop(s, "texture_size")

        col = layout.column(heading="Output")
        col.prop(s, "out_dir")
        col.prop(s, "overwrite")

        col = layout.column()
        if draw_progress(col):  # a run goes: its bar instead of the button
            col.label(text="Esc cancels", icon="CANCEL")
        else:
            op = col.operator(DELIGHT_OT_run.bl_idname, icon="SHADING_TEXTURE")
            for key, value in operator_settings(s).items():
                setattr(op, key, value)

        status = get_status()
        if status:
            box = layout.box()
            for line in _wrap(status, 40):
                box.label(text=line)

        obj = s.target or context.active_object
        images = previews.find(obj.name) if obj is not None else []
        if images:
            box = layout.box()
            box.label(text="Last run", icon="IMAGE_DATA")
            for img in images:  # compare (photo | reflectance), then the lighting spheres
                box.template_icon(icon_value=layout.icon(img), scale=8.0)


def _wrap(text, width):
    words, lines, line = text.split(), [], ""
    for w in words:
        if line and len(line) + 1 + len(w) > width:
            lines.append(line)
            line = w
        else:
            line = f"{line} {w}" if line else w
    return lines + [line] if line else lines


classes = (DelightSettings, VIEW3D_PT_delight)


def register():
    for c in classes:
        bpy.utils.register_class(c)
    bpy.types.Scene.delight = PointerProperty(type=DelightSettings)


def unregister():
    del bpy.types.Scene.delight
    for c in reversed(classes):
        bpy.utils.unregister_class(c)
