"""Find each camera's photo and read it as a linear float array.

Where a photo is looked for, in order:

1. ``camera.data.background_images[0].image`` (Photogrammetry Importer, fSpy);
2. an image plane: a mesh ``<stem>_image_plane`` for camera ``<stem>_cam``
   whose material has an Image Texture node (Photogrammetry Importer's option);
3. a file in a folder given by the user, whose name (without extension)
   matches the camera's name, or its stem without ``_cam``.

Decoding: for 8-bit images ``Image.pixels`` holds the sRGB codes / 255 whatever
the colour-space setting, so we apply the exact sRGB EOTF (photos are sRGB).
Float images (EXR, HDR, 16-bit) come out of ``Image.pixels`` already
scene-linear.

Nothing is left changed: an image loaded from the folder is removed after
reading, and pixel buffers we caused to load are freed again.
"""
from __future__ import annotations

import os

import numpy as np

from .core.errors import DelightError
from .core.io.photos import srgb_to_linear

__all__ = ["EXTENSIONS", "image_pixels", "find_photo"]

#: File endings tried in the images folder, in order of preference.
EXTENSIONS = (".exr", ".tif", ".tiff", ".png", ".jpg", ".jpeg", ".hdr", ".bmp", ".webp", ".tga")


def _image_path(img):
    import bpy

    if img.packed_file is not None:
        return f"{img.filepath or img.name} (packed)"
    return bpy.path.abspath(img.filepath, library=img.library) if img.filepath else "(no file)"


def image_pixels(img, camera_name, info=None):
    """Read a ``bpy.types.Image`` as ``(H, W, 3)`` float32 linear, row 0 at the top.

    ``info`` (a dict), if given, receives ``"float"``: whether the image is
    stored as floats (else 8-bit codes, which clip at 1.0).

    Raises
    ------
    DelightError
        The image has no pixels (missing or unreadable file), or a float
        image holds NaN or infinite values.
    """
    was_loaded = img.has_data
    try:
        w, h = img.size  # touching size/pixels loads the buffer
        if w == 0 or h == 0 or not img.has_data:
            raise DelightError(f"camera {camera_name!r}: cannot read its photo {img.name!r} from "
                               f"{_image_path(img)} (missing or unreadable file)")
        ch = img.channels
        flat = np.empty(w * h * ch, dtype=np.float32)
        img.pixels.foreach_get(flat)
        is_float = img.is_float
        if info is not None:
            info["float"] = bool(is_float)
    finally:
        if not was_loaded and img.has_data and not img.is_dirty:
            img.buffers_free()
    px = flat.reshape(h, w, ch)[::-1]  # Image.pixels row 0 is the bottom
    if ch >= 3:
        rgb = px[:, :, :3]
    else:  # grey (+ alpha)
        rgb = np.repeat(px[:, :, :1], 3, axis=2)
    rgb = np.ascontiguousarray(rgb, dtype=np.float32)
    if is_float:
        bad = ~np.isfinite(rgb).all(axis=2)
        if bad.any():
            raise DelightError(f"camera {camera_name!r}: its photo {img.name!r} ({_image_path(img)}) has "
                               f"{int(bad.sum())} NaN or infinite pixels")
        return rgb
    return srgb_to_linear(rgb)


def _from_background(cam_obj):
    bgs = cam_obj.data.background_images
    if len(bgs) and bgs[0].source == "IMAGE" and bgs[0].image is not None:
        return bgs[0].image
    return None


def _plane_names(cam_name):
    stems = [cam_name[:-4]] if cam_name.endswith("_cam") else []
    return [s + "_image_plane" for s in stems + [cam_name]]


def _from_image_plane(scene, cam_obj):
    for name in _plane_names(cam_obj.name):
        plane = scene.objects.get(name)
        if plane is None or plane.type != "MESH":
            continue
        for slot in plane.material_slots:
            mat = slot.material
            if mat is None or mat.node_tree is None:
                continue
            for node in mat.node_tree.nodes:
                if node.type == "TEX_IMAGE" and node.image is not None:
                    return node.image
    return None


def _stems(cam_name):
    stems = [cam_name]
    if cam_name.endswith("_cam"):
        stems.append(cam_name[:-4])
    return stems


def _from_folder(images_dir, cam_name):
    """Path of the file in ``images_dir`` named after the camera, or None."""
    try:
        entries = os.listdir(images_dir)
    except OSError:
        return None
    by_lower = {}
    for e in sorted(entries):
        by_lower.setdefault(e.lower(), e)
    for stem in _stems(cam_name):
        # The camera may carry the photo's full file name ("IMG_1.JPG_cam").
        if os.path.splitext(stem)[1].lower() in EXTENSIONS and stem.lower() in by_lower:
            return os.path.join(images_dir, by_lower[stem.lower()])
        for ext in EXTENSIONS:
            hit = by_lower.get((stem + ext).lower())
            if hit is not None and os.path.isfile(os.path.join(images_dir, hit)):
                return os.path.join(images_dir, hit)
    return None


def _load_file(path, camera_name, info=None):
    """Read an image file through Blender, leaving ``bpy.data.images`` as it was."""
    import bpy

    before = set(bpy.data.images)
    try:
        img = bpy.data.images.load(path, check_existing=True)
    except RuntimeError as exc:
        raise DelightError(f"camera {camera_name!r}: cannot read its photo {path}: {exc}") from None
    try:
        return image_pixels(img, camera_name, info)
    finally:
        if img not in before:
            bpy.data.images.remove(img)


def find_photo(scene, cam_obj, images_dir=None, info=None):
    """The camera's photo as ``(H, W, 3)`` float32 linear, and where it came from.

    ``info`` (a dict), if given, receives ``"float"`` (see :func:`image_pixels`).

    Returns
    -------
    photo : ndarray
    source : str
        ``"background image 'name'"``, ``"image plane 'obj' (image 'name')"``
        or the file path.

    Raises
    ------
    DelightError
        No photo in any of the places (they are named), or it cannot be read.
    """
    img = _from_background(cam_obj)
    if img is not None:
        return image_pixels(img, cam_obj.name, info), f"background image {img.name!r}"
    img = _from_image_plane(scene, cam_obj)
    if img is not None:
        return image_pixels(img, cam_obj.name, info), f"image plane {_plane_names(cam_obj.name)[0]!r} " \
                                                 f"(image {img.name!r})"
    looked = ["its background images", f"an image plane object {' or '.join(map(repr, _plane_names(cam_obj.name)))}"]
    if images_dir:
        import bpy

        folder = os.path.abspath(bpy.path.abspath(images_dir))
        if not os.path.isdir(folder):
            raise DelightError(f"images folder {folder} does not exist")
        path = _from_folder(folder, cam_obj.name)
        if path is not None:
            return _load_file(path, cam_obj.name, info), path
        looked.append(f"files named {' or '.join(map(repr, _stems(cam_obj.name)))} + an image extension in {folder}")
    else:
        looked.append("an images folder (none given)")
    raise DelightError(f"camera {cam_obj.name!r} has no photo: looked at {', '.join(looked)}")
