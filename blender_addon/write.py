"""The packed albedo image in the .blend (the files are written by :mod:`core.io.outputs`)."""

from __future__ import annotations

import numpy as np

from .photos import working_space

__all__ = ["make_albedo_image"]


def make_albedo_image(name: str, pixels: np.ndarray):
    """Create the packed float image ``name`` holding the RGBA albedo ``pixels``.

    ``pixels`` is ``(H, W, 4)`` float32 with row 0 at the top, as the albedo file is written
    (:func:`core.io.outputs.rgba`); its rows are reversed in place, for Blender's row 0 is the bottom: at 8192^2
    a reversed copy would be one more GB at the run's peak.

    An image of that name that an earlier run made (tagged ``delight``) is
    replaced: its users are remapped to the new one and it is removed, so
    re-runs do not stack images. Any other image of that name is left alone
    and Blender gives ours a unique name.
    """
    import bpy

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
    _reverse_rows(pixels)
    img.pixels.foreach_set(pixels.ravel())
    img.file_format = "OPEN_EXR"  # float32 EXR in the .blend; PNG would quantise
    img.update()
    img.pack()
    if old is not None:
        old.user_remap(img)
        bpy.data.images.remove(old)
        img.name = name
    return img


def _reverse_rows(a: np.ndarray) -> None:
    """``a``'s rows in reverse order, in place, a pair of rows at a time."""
    row = np.empty_like(a[0])
    for i in range(a.shape[0] // 2):
        j = a.shape[0] - 1 - i
        row[...] = a[i]
        a[i] = a[j]
        a[j] = row
