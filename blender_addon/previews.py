"""Pictures of the last run, kept in the .blend so that the panel can show them.

After a run, :func:`update` puts two images into ``bpy.data`` (packed, with a
fake user so that they are saved with the file):

* ``<object>_delight_compare``: one photo beside the reflectance estimated for
  that view (the view that sees the most of the mesh), on the photo's exposure;
* ``<object>_delight_lighting``: the lighting estimated for each view, as a
  sphere seen from the front (from -Y, +Z up), all on one exposure, four to a
  row. A ``project`` run estimates no lighting, so it removes this image.

A re-run replaces the pixels of the same images (no ``.001`` copies). The
pixels hold no text: each image keeps a caption (:func:`caption`) that the
panel shows beside it. The pixel arrays come from :mod:`core.evaluate.pictures`;
only the copy into Blender's images is here (Blender packs them).
"""

from __future__ import annotations

import bpy
import numpy as np

from .core.evaluate.pictures import grid, lighting_spheres, to_srgb8

__all__ = ["COMPARE", "LIGHTING", "image_names", "update", "find", "caption"]

COMPARE = "{}_delight_compare"
LIGHTING = "{}_delight_lighting"
#: Longest side of each half of the before/after picture, in pixels.
COMPARE_SIZE = 320
#: Spheres per row in the lighting picture.
COLUMNS = 4
#: Custom property of each image holding its caption.
CAPTION = "delight_caption"


def image_names(object_name: str) -> tuple:
    """The names of the (compare, lighting) images of an object."""
    return COMPARE.format(object_name), LIGHTING.format(object_name)


def _shrink(rgb, size):
    """Every k-th pixel so that the longest side is at most ``size`` (a preview, not a resample)."""
    k = max(1, int(np.ceil(max(rgb.shape[:2]) / size)))
    return rgb[::k, ::k]


def _put(name: str, rgb8: np.ndarray, text: str):
    """Create or overwrite the packed 8-bit image ``name`` with uint8 sRGB pixels (row 0 at the top)."""
    h, w = rgb8.shape[:2]
    img = bpy.data.images.get(name)
    if img is not None and img.library is not None:
        return None  # linked from a library: not ours to change
    if img is None:
        img = bpy.data.images.new(name, w, h, alpha=False)
    elif tuple(img.size) != (w, h):
        img.scale(w, h)
    # 8-bit image in sRGB: Image.pixels holds the codes / 255, bottom row first.
    px = np.ones((h, w, 4), dtype=np.float32)
    px[..., :3] = rgb8[::-1] / np.float32(255)
    img.pixels.foreach_set(px.ravel())
    img.use_fake_user = True
    img[CAPTION] = text
    img.pack()
    if img.preview is not None:
        img.preview.reload()
    return img


def _remove(name: str):
    img = bpy.data.images.get(name)
    if img is not None and img.library is None:
        bpy.data.images.remove(img)


def update(object_name: str, prepared, computed) -> list:
    """Make or replace the object's preview images from a finished run; return the images."""
    views, bakes = prepared.inputs.views, prepared.bakes
    best = int(np.argmax([np.count_nonzero(b.mask) for b in bakes]))
    photo = np.asarray(views[best].photo, dtype=np.float32)
    ours = np.where(bakes[best].mask[..., None], computed.views[best], np.nan)
    kind = "projected" if computed.sigma is None else "reflectance"
    compare = grid([to_srgb8(_shrink(photo, COMPARE_SIZE)), to_srgb8(_shrink(ours, COMPARE_SIZE))], columns=2)
    names = image_names(object_name)
    out = [_put(names[0], compare, f"{views[best].name}: photo | {kind}")]
    if computed.sigma is None:
        _remove(names[1])
    else:
        spheres = grid(lighting_spheres(computed.sigma, size=64, sun=computed.sun_direction), columns=COLUMNS)
        out.append(_put(names[1], spheres, "Lighting, left to right: " + ", ".join(v.name for v in views)))
    return [img for img in out if img is not None]


def caption(img) -> str:
    """The text shown beside a preview image (empty if it has none)."""
    return str(img.get(CAPTION, ""))


def find(object_name: str) -> list:
    """The object's preview images that exist, compare first."""
    return [img for img in (bpy.data.images.get(n) for n in image_names(object_name)) if img is not None]
