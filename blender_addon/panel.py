"""The "Delight" tab in the 3D Viewport sidebar, and its settings on the scene."""
from __future__ import annotations

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from . import previews
from .pipeline import DEFAULTS
from .operator import CAMERA_ITEMS, METHOD_ITEMS, DELIGHT_OT_run, get_status

__all__ = ["DelightSettings", "VIEW3D_PT_delight", "operator_settings"]


def _is_mesh(self, obj):
    return obj.type == "MESH"


class DelightSettings(bpy.types.PropertyGroup):
    """The panel's choices, saved with the scene (``scene.delight``)."""

    target: PointerProperty(name="Mesh", type=bpy.types.Object, poll=_is_mesh,
                            description="Mesh to delight; empty: the active object")
    cameras: EnumProperty(name="Cameras", items=CAMERA_ITEMS, default="ALL")
    camera_collection: PointerProperty(name="Collection", type=bpy.types.Collection)
    images_dir: StringProperty(name="Images", subtype="DIR_PATH",
                               description="Folder with photos named like the cameras, "
                                           "for cameras without a background image")
    method: EnumProperty(name="Method", items=METHOD_ITEMS, default="texture")
    auto_lambda: BoolProperty(name="Auto Lambda", default=True,
                              description="Pick lambda from how much the lighting changes between the photos")
    lam: FloatProperty(name="Lambda", default=DEFAULTS.lam, min=0.0, soft_max=100.0)
    mu: FloatProperty(name="Mu", default=DEFAULTS.mu, min=0.0)
    max_iter: IntProperty(name="Iterations", default=DEFAULTS.max_iter, min=1, soft_max=500)
    working_res: FloatProperty(name="Working MP", default=1.0, min=0.001, soft_max=16.0)
    texture_size: IntProperty(name="Texture Size", default=1024, min=8, max=16384)
    out_dir: StringProperty(name="Output", subtype="DIR_PATH", default="",
                            description="Output folder; empty: a folder delight_<mesh> beside the .blend")
    overwrite: BoolProperty(name="Overwrite Files", default=False)


def operator_settings(settings) -> dict:
    """The operator's properties for the panel's settings."""
    return dict(
        object_name=settings.target.name if settings.target else "",
        cameras=settings.cameras,
        camera_collection=settings.camera_collection.name if settings.camera_collection else "",
        images_dir=settings.images_dir, auto_lambda=settings.auto_lambda, lam=settings.lam, mu=settings.mu,
        max_iter=settings.max_iter,
        working_res=settings.working_res, texture_size=settings.texture_size, method=settings.method,
        out_dir=settings.out_dir, overwrite=settings.overwrite)


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

        col = layout.column(heading="Solve")
        col.prop(s, "method")
        sub = col.column()
        sub.active = s.method != "project"
        sub.prop(s, "auto_lambda")
        row = sub.row()
        row.active = not s.auto_lambda
        row.prop(s, "lam")
        if s.method == "image":
            sub.prop(s, "mu")
        sub.prop(s, "max_iter")
        col.prop(s, "working_res")
        col.prop(s, "texture_size")

        col = layout.column(heading="Output")
        col.prop(s, "out_dir")
        col.prop(s, "overwrite")

        op = layout.operator(DELIGHT_OT_run.bl_idname, icon="SHADING_TEXTURE")
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
            for img in images:   # compare (photo | reflectance), then the lighting spheres
                for line in _wrap(previews.caption(img), 40):   # the pixels hold no text
                    box.label(text=line)
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
