"""The packed albedo image in the .blend (the files are written by :mod:`core.io.outputs`)."""

from __future__ import annotations

import numpy as np

from .core.io.outputs import rgba
from .photos import working_space

__all__ = ["make_albedo_image"]


def make_albedo_image(name: str, albedo: np.ndarray, seen: np.ndarray):
    """Create the packed float image ``name`` holding the RGBA albedo.

    An image of that name that an earlier run made (tagged ``delight``) is
    replaced: its users are remapped to the new one and it is removed, so
    re-runs do not stack images. Any other image of that name is left alone
    and Blender gives ours a unique name.
    """
    import bpy

    pixels = rgba(albedo, np.asarray(seen, dtype=np.float32), zero_outside=False)
    n_rows, n_cols = pixels.shape[:2]
    old = bpy.data.images.get(name)
    if old is not None and (not old.get("delight") or old.library is not None):
        old = None
    img = bpy.data.images.new(name + ".delight-new" if old else name, n_cols, n_rows, alpha=True, float_buffer=True)
    img["delight"] = True
    # The values are in the working space, as the photos were read. The alpha
    # is a "seen" mask, not coverage, so it must not premultiply the colour.
    img.colorspace_settings.name = working_space()
    img.alpha_mode = "CHANNEL_PACKED"
    img.pixels.foreach_set(np.ascontiguousarray(pixels[::-1]).ravel())  # Blender's row 0 is the bottom
    img.file_format = "OPEN_EXR"  # float32 EXR in the .blend; PNG would quantise
    img.update()
    img.pack()
    if old is not None:
        old.user_remap(img)
        bpy.data.images.remove(old)
        img.name = name
    return img
