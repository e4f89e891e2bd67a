"""Write the results: output files, then the packed albedo image.

Files go into ``out_dir``::

    <object>_albedo.exr     RGBA float32, linear, N x N, row 0 at the top;
                            A = 1 where a camera saw the texel, 0 where filled
    views/<camera>.exr      per-view reflectance, RGBA (A = 1 on the mesh)
    lighting.json           per camera: name and 9 SH coefficients per channel
    report.json             parameters, stage times, iterations, energy

Every file is first written into a temporary folder inside ``out_dir`` and
moved into place only once all of them were written, so an error leaves no
partial output. Names come from user data (object and camera names), so they
are sanitised: nothing can be written outside ``out_dir``.
"""
from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field

import numpy as np

from .core.io.exr import write_exr
from .core.io.names import safe_name, unique_names
from .core.errors import DelightError

__all__ = ["OutputPaths", "safe_name", "unique_names", "output_paths", "check_outputs",
           "write_outputs", "make_albedo_image"]



@dataclass
class OutputPaths:
    """Where each output goes (absolute paths)."""

    out_dir: str
    albedo: str
    lighting: str
    report: str
    views: dict = field(default_factory=dict)   # camera name -> path

    def all(self) -> list[str]:
        return [self.albedo, *self.views.values(), self.lighting, self.report]


def output_paths(out_dir, object_name: str, camera_names) -> OutputPaths:
    """The output paths for an object and its cameras, all inside ``out_dir``."""
    out_dir = os.path.abspath(os.fspath(out_dir))
    stems = unique_names(camera_names)
    views = {cam: os.path.join(out_dir, "views", stem + ".exr") for cam, stem in zip(camera_names, stems)}
    return OutputPaths(out_dir=out_dir,
                       albedo=os.path.join(out_dir, safe_name(object_name) + "_albedo.exr"),
                       lighting=os.path.join(out_dir, "lighting.json"),
                       report=os.path.join(out_dir, "report.json"),
                       views=views)


def check_outputs(paths: OutputPaths, overwrite: bool) -> None:
    """Raise :class:`DelightError` if an output exists and ``overwrite`` is False, or ``out_dir`` is unusable."""
    if os.path.exists(paths.out_dir) and not os.path.isdir(paths.out_dir):
        raise DelightError(f"the output folder {paths.out_dir} is a file")
    views_dir = os.path.join(paths.out_dir, "views")
    if os.path.exists(views_dir) and not os.path.isdir(views_dir):
        raise DelightError(f"cannot write per-view maps: {views_dir} is a file")
    for p in paths.all():
        if os.path.isdir(p):
            raise DelightError(f"cannot write {p}: a folder of that name exists")
        if os.path.exists(p) and not overwrite:
            raise DelightError(f"{p} already exists (use overwrite to replace it)")


def _rgba(rgb: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """(H, W, 4) float32 from (H, W, C) colour (C = 1 or 3; NaN -> 0) and an (H, W) alpha."""
    rgb = np.asarray(rgb, dtype=np.float32)
    if rgb.ndim == 2:
        rgb = rgb[:, :, None]
    if rgb.shape[2] == 1:
        rgb = np.repeat(rgb, 3, axis=2)
    out = np.empty(rgb.shape[:2] + (4,), dtype=np.float32)
    out[..., :3] = np.nan_to_num(rgb, nan=0.0, posinf=0.0, neginf=0.0)
    out[..., 3] = alpha
    return out


def _json(path, data):
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(data, fh, indent=2, allow_nan=False)
        fh.write("\n")


def write_outputs(paths: OutputPaths, albedo: np.ndarray, seen: np.ndarray, views: dict, masks: dict,
                  lighting: dict, report: dict, overwrite: bool = False) -> list[str]:
    """Write every output file, all or nothing.

    Parameters
    ----------
    paths : OutputPaths
    albedo : (N, N, C) array
        The filled texture, row 0 at the top.
    seen : (N, N) bool
        Texels some camera saw (alpha 1); the others were filled (alpha 0).
    views, masks : dict camera name -> (H, W, C) array, (H, W) bool
        Per-view reflectance and the pixels on the mesh.
    lighting : dict
        JSON-serialisable contents of ``lighting.json``.
    report : dict or callable() -> dict
        Contents of ``report.json``; a callable is called after the other
        files were written, so that it can include their time.
    overwrite : bool
        Replace existing outputs; otherwise an existing one raises
        :class:`DelightError` before anything is written.

    Returns
    -------
    list of str
        The paths written.
    """
    check_outputs(paths, overwrite)
    os.makedirs(paths.out_dir, exist_ok=True)
    staging = tempfile.mkdtemp(prefix=".delight-tmp-", dir=paths.out_dir)
    try:
        def staged(p):
            return os.path.join(staging, os.path.relpath(p, paths.out_dir))

        os.makedirs(os.path.join(staging, "views"))
        write_exr(staged(paths.albedo), _rgba(albedo, np.asarray(seen, dtype=np.float32)))
        for cam, p in paths.views.items():
            m = np.asarray(masks[cam], dtype=bool)
            write_exr(staged(p), _rgba(np.where(m[..., None], views[cam], 0.0), m.astype(np.float32)))
        _json(staged(paths.lighting), lighting)
        _json(staged(paths.report), report() if callable(report) else report)
        # Checked again right before the move: the run may have taken minutes.
        check_outputs(paths, overwrite)
        if paths.views:
            os.makedirs(os.path.join(paths.out_dir, "views"), exist_ok=True)
        for p in paths.all():
            os.replace(staged(p), p)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return paths.all()


def make_albedo_image(name: str, albedo: np.ndarray, seen: np.ndarray):
    """Create the packed float image ``name`` holding the RGBA albedo.

    An image of that name that an earlier run made (tagged ``delight``) is
    replaced: its users are remapped to the new one and it is removed, so
    re-runs do not stack images. Any other image of that name is left alone
    and Blender gives ours a unique name.
    """
    import bpy

    rgba = _rgba(albedo, np.asarray(seen, dtype=np.float32))
    n_rows, n_cols = rgba.shape[:2]
    old = bpy.data.images.get(name)
    if old is not None and (not old.get("delight") or old.library is not None):
        old = None
    img = bpy.data.images.new(name + ".delight-new" if old else name, n_cols, n_rows,
                              alpha=True, float_buffer=True)
    img["delight"] = True
    # Non-Color: the values are used as they are (linear). The alpha is a
    # "seen" mask, not coverage, so it must not premultiply the colour.
    img.colorspace_settings.name = "Non-Color"
    img.alpha_mode = "CHANNEL_PACKED"
    img.pixels.foreach_set(np.ascontiguousarray(rgba[::-1]).ravel())  # Blender's row 0 is the bottom
    img.file_format = "OPEN_EXR"   # float32 EXR in the .blend; PNG would quantise
    img.update()
    img.pack()
    if old is not None:
        old.user_remap(img)
        bpy.data.images.remove(old)
        img.name = name
    return img
