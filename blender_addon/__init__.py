"""Delight: estimate a true albedo from multi-view photos, cameras and a mesh.

An implementation of Melou et al. 2018, "Variational Reflectance Estimation
from Multi-view Images", as a Blender add-on (4.2+). The pure NumPy/SciPy
solver lives in the ``core`` subpackage; the modules here read the scene,
run it and write the results. Headless use: ``python -m blender_addon
SCENE.blend [options]`` or ``blender -b SCENE.blend -P blender_addon/cli.py
-- [options]`` (see :mod:`.cli`).
"""

bl_info = {
    "name": "Delight",
    "author": "Delight developers",
    "version": (0, 1, 0),
    "blender": (4, 2, 0),
    "location": "3D Viewport > Sidebar > Delight",
    "description": "Delit albedo texture from multi-view photos (Melou et al. 2018)",
    "category": "Material",
}


def register():
    from . import operator, panel

    operator.register()
    panel.register()


def unregister():
    from . import operator, panel

    panel.unregister()
    operator.unregister()
