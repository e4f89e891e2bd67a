"""Find each camera's photo and read it as a linear float array.

Where a photo is looked for, in order:

1. ``camera.data.background_images[0].image`` (Photogrammetry Importer, fSpy);
2. an image plane: a mesh ``<stem>_image_plane`` for camera ``<stem>_cam``
   whose material has an Image Texture node (Photogrammetry Importer's option);
3. a file in a folder given by the user, whose name (without extension)
   matches the camera's name, or its stem without ``_cam``.

Decoding goes through Blender's colour management, so the image's colour space
(the user's choice, shown in the Image Editor) is respected and every photo ends
up in the file's linear working space: float images (EXR, HDR, 16-bit) come out
of ``Image.pixels`` already converted; for 8-bit images ``Image.pixels`` holds the
raw codes / 255 whatever the colour space, so Blender converts them by writing a
float EXR into a temporary folder (:func:`_byte_image_linear`): a small image of probe colours, whose result
gives every code's colour (:func:`_code_tables`), or where the colour space mixes the channels in a way that
tables cannot follow, the whole photo.

Nothing is left changed: an image loaded from the folder is removed after
reading, and pixel buffers we caused to load are freed again.
"""

from __future__ import annotations

import os

import numpy as np

from .core.errors import DelightError
from .core.io.exr import read_exr
from .core.io.photos import CodedPhoto, clipped_pixels

__all__ = ["EXTENSIONS", "read_pixels", "image_pixels", "find_photo"]

#: File endings tried in the images folder, in order of preference.
EXTENSIONS = (".exr", ".tif", ".tiff", ".png", ".jpg", ".jpeg", ".hdr", ".bmp", ".webp", ".tga")


def _image_path(img):
    import bpy

    if img.packed_file is not None:
        return f"{img.filepath or img.name} (packed)"
    return bpy.path.abspath(img.filepath, library=img.library) if img.filepath else "(no file)"


def working_space():
    """Name of the linear colour space Blender works in (Blender 4.x has only Linear Rec.709)."""
    import bpy

    colorspace = getattr(bpy.data, "colorspace", None)
    return getattr(colorspace, "working_space", None) or "Linear Rec.709"


def _byte_image_linear(img, opaque=False):
    """An 8-bit image as (H, W, 3) float32 in the working space, row 0 at the top, converted by Blender.

    ``opaque``: every alpha code is 255, so the conversion writes no alpha (the same colours, without a fourth
    channel to write, read and drop).
    """
    import tempfile

    import bpy

    scene = bpy.data.scenes.new("delight colour conversion")
    try:
        settings = scene.render.image_settings
        settings.file_format, settings.color_depth = "OPEN_EXR", "32"
        settings.color_mode = "RGB" if opaque else "RGBA"
        if getattr(settings, "has_linear_colorspace", False):
            settings.color_management = "OVERRIDE"
            settings.linear_colorspace_settings.name = working_space()
        with tempfile.TemporaryDirectory(prefix="delight_colour_") as tmp:
            path = os.path.join(tmp, "photo.exr")
            img.save_render(path, scene=scene)
            rgba = read_exr(path)[0]
    finally:
        bpy.data.scenes.remove(scene)
    if opaque:
        return rgba
    rgb = np.ascontiguousarray(rgba[..., :3], dtype=np.float32)
    alpha = rgba[..., 3:4]
    if not (alpha == 1.0).all():  # save_render premultiplies by alpha; a photo's colour is wanted straight
        np.divide(rgb, alpha, out=rgb, where=alpha > 0)
        rgb[alpha[..., 0] <= 0] = 0.0
    return rgb


def _probe_codes():
    """``(16, 256, 3)`` uint8: each channel's 256 codes alone, the greys, the cube's corners and random colours."""
    ramp, zero = np.arange(256), np.zeros(256, np.int64)
    corners = np.array([[r, g, b] for r in (0, 255) for g in (0, 255) for b in (0, 255)])
    colours = np.random.default_rng(0).integers(0, 256, (12 * 256 - len(corners), 3))
    alone = [np.stack([ramp if k == j else zero for j in range(3)], axis=1) for k in range(3)]
    return np.concatenate([*alone, np.stack([ramp] * 3, axis=1), corners, colours]).reshape(16, 256, 3).astype(np.uint8)


def _code_tables(img):
    """How Blender converts ``img``'s 8-bit codes: ``(3, 256, 3)`` float32 tables, or None.

    A colour space is a curve per channel and then a matrix (sRGB, Non-Color, the linear and log spaces, a working
    space other than Rec.709), so a colour is the sum of what each of its codes gives alone:
    ``tables[0][r] + tables[1][g] + tables[2][b]``. Blender converts a small image of probe colours in
    ``img``'s colour space (:func:`_byte_image_linear`, as the whole photo would be); where the sum does not give
    back its colours (a display transform that mixes the channels), None: the photo is converted whole.
    """
    import bpy

    codes = _probe_codes()
    probe = bpy.data.images.new("delight colour probe", codes.shape[1], codes.shape[0], alpha=True)
    try:
        try:
            probe.colorspace_settings.name = img.colorspace_settings.name
        except (TypeError, ValueError):  # a colour space the probe cannot take (not in this configuration)
            return None
        rgba = np.concatenate([codes, np.full((*codes.shape[:2], 1), 255, np.uint8)], axis=2)
        probe.pixels.foreach_set((rgba[::-1] / np.float32(255)).astype(np.float32).ravel())
        out = _byte_image_linear(probe, opaque=True).reshape(-1, 3).astype(np.float64)
    finally:
        bpy.data.images.remove(probe)
    black = out[0]
    tables = np.stack([out[:256], out[256:512] - black, out[512:768] - black])
    flat = codes.reshape(-1, 3)
    summed = tables[0][flat[:, 0]] + tables[1][flat[:, 1]] + tables[2][flat[:, 2]]
    if not np.isfinite(out).all() or np.abs(summed - out).max() > 1e-6 * max(1.0, float(np.abs(out).max())):
        return None
    return tables.astype(np.float32)


# Rows of pixels turned into codes at a time: they stay in cache.
_CODE_ROWS = 64


def _coded(px, tables):
    """An 8-bit image as its codes and ``tables`` (:func:`_code_tables`), and its clipped pixels.

    ``px``: its ``Image.pixels``, ``(H, W, C)`` codes / 255. Returns a :class:`core.io.photos.CodedPhoto` and
    ``(H, W)`` bool (:func:`core.io.photos.clipped_pixels`).
    """
    h, w, ch = px.shape
    k = 3 if ch >= 3 else 1  # grey: one code for all three channels
    codes = np.empty((h, w, k), np.uint8)
    for r0 in range(0, h, _CODE_ROWS):
        rows = slice(r0, r0 + _CODE_ROWS)
        codes[rows] = px[rows, :, :k] * np.float32(255) + np.float32(0.5)  # exact: c / 255, truncated
    return CodedPhoto(codes, tables), clipped_pixels(codes)


def read_pixels(img, camera_name, label=None, info=None):
    """Read a ``bpy.types.Image`` (on the main thread); the rest is left to a callable that any thread may run.

    Returns ``(finish, (W, H))``: ``finish()`` gives the image as ``(H, W, 3)`` float32 linear, row 0 at the
    top (and fills ``info``'s ``"clipped"``); ``finish(coded=True)`` gives an 8-bit image whose colours tables
    give as its :class:`core.io.photos.CodedPhoto` instead, a quarter of the size, its colours never made
    whole. Blender's part, here, is decoding the file and, for an 8-bit image, how its colour space converts
    codes (:func:`_code_tables`); the pixels' conversion is NumPy's.

    ``label`` names the photo in messages (default: the image's name and file). ``info`` (a dict), if given,
    receives ``"float"``: whether the image is stored as floats, and for 8-bit images ``"clipped"``: the
    (H, W) pixels with a channel at or above :data:`core.io.photos.CLIP_CODE`.

    Raises
    ------
    DelightError
        The image has no pixels (missing or unreadable file), or (from ``finish``) a float image holds NaN
        or infinite values.
    """
    label = label or f"{img.name!r} ({_image_path(img)})"
    was_loaded = img.has_data
    try:
        w, h = img.size  # touching size/pixels loads the buffer
        if w == 0 or h == 0 or not img.has_data:
            raise DelightError(f"camera {camera_name!r}: cannot read its photo {label} (missing or unreadable file)")
        ch = img.channels
        is_float = img.is_float
        rgb = tables = None
        if info is not None:
            info["float"] = bool(is_float)
        flat = np.empty(w * h * ch, dtype=np.float32)
        img.pixels.foreach_get(flat)
        if not is_float:
            # Alpha, the last channel, all 255: codes / 255 are at most 1, so its least is 1 (no (H, W) temporary).
            opaque = ch not in (2, 4) or float(flat[ch - 1 :: ch].min()) == 1.0
            # With alpha, Blender's conversion premultiplies and the colour is divided back: the whole photo.
            tables = _code_tables(img) if opaque else None
            if tables is None:
                rgb = _byte_image_linear(img, opaque)
    finally:
        if not was_loaded and img.has_data and not img.is_dirty:
            img.buffers_free()

    def finish(coded=False):
        px = flat.reshape(h, w, ch)[::-1]  # Image.pixels row 0 is the bottom
        if not is_float:
            if rgb is None:
                out, clipped = _coded(px, tables)
                if not coded:
                    out = out.colours()
            else:
                out, clipped = rgb, clipped_pixels(px[:, :, : min(ch, 3)])
            if info is not None:  # clipping is judged on the codes, whatever the colour space
                info["clipped"] = clipped
            return out
        if ch >= 3:
            out = px[:, :, :3]
        else:  # grey (+ alpha)
            out = np.repeat(px[:, :, :1], 3, axis=2)
        out = np.ascontiguousarray(out, dtype=np.float32)
        if not np.isfinite(out).all():  # one pass over the photo; the pixels are counted only to say how many
            bad = int((~np.isfinite(out).all(axis=2)).sum())
            raise DelightError(f"camera {camera_name!r}: its photo {label} has {bad} NaN or infinite pixels")
        return out

    return finish, (w, h)


def image_pixels(img, camera_name, label=None, info=None):
    """Read a ``bpy.types.Image`` as ``(H, W, 3)`` float32 linear, row 0 at the top (:func:`read_pixels`)."""
    return read_pixels(img, camera_name, label, info)[0]()


def _sequence_frame_path(scene, bg):
    """The file of an image-sequence background at the scene's current frame, as the viewport shows it."""
    import bpy

    img, user = bg.image, bg.image_user
    # As Blender's BKE_image_user_frame_get maps the scene frame to a file of the sequence.
    frame, n = scene.frame_current - user.frame_start + 1, user.frame_duration
    if n > 0:
        frame = (frame - 1) % n + 1 if user.use_cyclic else min(max(frame, 0), n)
    kept = user.frame_current
    try:
        user.frame_current = frame + user.frame_offset
        path = img.filepath_from_user(image_user=user)
    finally:
        user.frame_current = kept
    return bpy.path.abspath(path, library=img.library)


def _from_background(scene, cam_obj):
    """The camera's background photo: an Image, or the path of one frame of an image sequence."""
    bgs = cam_obj.data.background_images
    if not len(bgs):
        return None
    bg = bgs[0]
    if bg.source == "MOVIE_CLIP":
        if bg.clip is None:
            return None
        raise DelightError(
            f"camera {cam_obj.name!r}: its background is the movie clip {bg.clip.name!r}, one "
            "camera for many photos (Photogrammetry Importer's 'animated camera'); Delight needs "
            "one camera per photo: re-import without the animated camera option"
        )
    img = bg.image
    if img is None:
        return None
    if img.source == "MOVIE":
        raise DelightError(
            f"camera {cam_obj.name!r}: its background {img.name!r} is a movie, which Delight "
            "cannot read frame by frame: export the frames as images (an image sequence or a "
            "folder of photos named like the cameras)"
        )
    if img.source == "SEQUENCE":
        return _sequence_frame_path(scene, bg)
    return img


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


def _load_file(path, camera_name, check_existing=True, info=None):
    """Read an image file through Blender, leaving ``bpy.data.images`` as it was.

    ``check_existing=False`` for one frame of a sequence, whose datablock holds another frame.
    """
    import bpy

    before = set(bpy.data.images)
    try:
        img = bpy.data.images.load(path, check_existing=check_existing)
    except RuntimeError as exc:
        raise DelightError(f"camera {camera_name!r}: cannot read its photo {path}: {exc}") from None
    try:
        return read_pixels(img, camera_name, label=path, info=info)
    finally:
        if img not in before:
            bpy.data.images.remove(img)


def find_photo(scene, cam_obj, images_dir=None, info=None):
    """The camera's photo, read (:func:`read_pixels`), and where it came from.

    ``info`` (a dict), if given, receives ``"float"`` and ``"clipped"`` (see :func:`read_pixels`).

    Returns
    -------
    finish : callable(coded=False) -> (H, W, 3) float32 array
        The photo, linear, row 0 at the top (or an 8-bit one's codes, :func:`read_pixels`); any thread may call
        it.
    size : (W, H)
    source : str
        ``"background image 'name'"``, ``"image plane 'obj' (image 'name')"``
        or the file path.

    Raises
    ------
    DelightError
        No photo in any of the places (they are named), or it cannot be read.
    """
    img = _from_background(scene, cam_obj)
    if isinstance(img, str):
        frame = f"background image sequence frame {img}"
        return (*_load_file(img, cam_obj.name, check_existing=False, info=info), frame)
    if img is not None:
        return (*read_pixels(img, cam_obj.name, info=info), f"background image {img.name!r}")
    img = _from_image_plane(scene, cam_obj)
    if img is not None:
        plane = f"image plane {_plane_names(cam_obj.name)[0]!r} (image {img.name!r})"
        return (*read_pixels(img, cam_obj.name, info=info), plane)
    looked = ["its background images", f"an image plane object {' or '.join(map(repr, _plane_names(cam_obj.name)))}"]
    if images_dir:
        import bpy

        folder = os.path.abspath(bpy.path.abspath(images_dir))
        if not os.path.isdir(folder):
            raise DelightError(f"images folder {folder} does not exist")
        path = _from_folder(folder, cam_obj.name)
        if path is not None:
            return (*_load_file(path, cam_obj.name, info=info), path)
        looked.append(f"files named {' or '.join(map(repr, _stems(cam_obj.name)))} + an image extension in {folder}")
    else:
        looked.append("an images folder (none given)")
    raise DelightError(f"camera {cam_obj.name!r} has no photo: looked at {', '.join(looked)}")
