"""Blender camera -> core pinhole camera, with the exact Cycles projection.

Cycles maps a perspective camera to pixels like this (W, H the image size,
aspx, aspy the render pixel aspect, pixel centres at ``c + 0.5``, y down)::

    fit     = sensor_fit; AUTO means HORIZONTAL if aspx*W >= aspy*H else VERTICAL
    sensor  = sensor_width (AUTO, HORIZONTAL) or sensor_height (VERTICAL)
    ycor    = aspy / aspx;  viewfac = W (HORIZONTAL) or ycor * H (VERTICAL)
    fx = lens / sensor * viewfac;  fy = fx / ycor
    cx = W/2 - shift_x * viewfac;  cy = H/2 + shift_y * viewfac / ycor

We evaluate it on the photo's own pixel grid. The sensor fit is decided by
the render settings (the camera as the user set it up), and the photo must
have the render frame's aspect ratio: a photo of another shape would need a
stretch or a crop, which we refuse to guess.
"""

from __future__ import annotations

import math

import numpy as np

from .core.errors import DelightError
from .core.geometry.camera import Camera

__all__ = ["ASPECT_TOLERANCE", "check_aspect", "intrinsics", "to_core_camera"]

#: Relative aspect-ratio difference between photo and render frame accepted
#: without complaint (rounding of a downscaled photo, a few cropped pixels).
ASPECT_TOLERANCE = 0.01


def _render_size(render):
    s = render.resolution_percentage / 100.0
    return max(1, int(render.resolution_x * s)), max(1, int(render.resolution_y * s))


def check_aspect(name, render, width, height):
    """Raise :class:`DelightError` unless a ``width x height`` photo fits the render frame.

    Accepted: a relative aspect difference up to :data:`ASPECT_TOLERANCE`, or up
    to one pixel of rounding along either axis.
    """
    rw, rh = render.resolution_x, render.resolution_y
    photo, frame = width / height, rw / rh
    if abs(photo / frame - 1.0) <= ASPECT_TOLERANCE:
        return
    if abs(width * rh / rw - height) <= 1.0 or abs(height * rw / rh - width) <= 1.0:
        return
    raise DelightError(
        f"camera {name!r}: its photo is {width}x{height} (aspect {photo:.4f}) but the render frame is "
        f"{rw}x{rh} (aspect {frame:.4f}); set the render resolution to the photo's aspect ratio "
        "(the photo would otherwise be stretched)"
    )


def intrinsics(cam_data, render, width, height):
    """Cycles' pinhole intrinsics on a ``width x height`` pixel grid.

    Returns ``(fx, fy, cx, cy)`` in Blender's pixel convention (pixel centres at
    ``c + 0.5``, y down). The sensor fit AUTO is resolved with the render
    resolution.
    """
    aspx, aspy = float(render.pixel_aspect_x), float(render.pixel_aspect_y)
    fit = cam_data.sensor_fit
    # AUTO fits the larger side but always to sensor_width.
    sensor = cam_data.sensor_height if fit == "VERTICAL" else cam_data.sensor_width
    if fit == "AUTO":
        rw, rh = _render_size(render)
        fit = "HORIZONTAL" if aspx * rw >= aspy * rh else "VERTICAL"
    ycor = aspy / aspx
    viewfac = ycor * height if fit == "VERTICAL" else float(width)
    fx = cam_data.lens / sensor * viewfac
    fy = fx / ycor
    cx = width / 2.0 - cam_data.shift_x * viewfac
    cy = height / 2.0 + cam_data.shift_y * viewfac / ycor
    return fx, fy, cx, cy


def to_core_camera(cam_obj, scene, width, height, matrix_world=None, scale=(1.0, 1.0)) -> Camera:
    """Convert a Blender perspective camera to a :class:`core.geometry.camera.Camera`.

    Parameters
    ----------
    cam_obj : bpy.types.Object
        A camera object.
    scene : bpy.types.Scene
        Gives the render resolution and pixel aspect.
    width, height : int
        The photo's pixel grid the model is evaluated on.
    matrix_world : 4x4, optional
        The camera's (evaluated) world matrix; default ``cam_obj.matrix_world``.
    scale : (sx, sy)
        Factors to a resampled grid (``round(width * sx)`` etc.): intrinsics in
        pixel-edge coordinates scale exactly with an area-average resize.

    Raises
    ------
    DelightError
        Not a perspective camera, or the photo's aspect does not fit.
    """
    data = cam_obj.data
    if cam_obj.type != "CAMERA":
        raise DelightError(f"object {cam_obj.name!r} is not a camera")
    if data.type != "PERSP":
        raise DelightError(f"camera {cam_obj.name!r} is {data.type.lower()}; only perspective cameras are supported")
    check_aspect(cam_obj.name, scene.render, width, height)
    fx, fy, cx, cy = intrinsics(data, scene.render, width, height)
    sx, sy = scale
    fx, cx, fy, cy = fx * sx, cx * sx, fy * sy, cy * sy
    out_w, out_h = max(1, int(round(width * sx))), max(1, int(round(height * sy)))
    m = np.array(matrix_world if matrix_world is not None else cam_obj.matrix_world, dtype=np.float64)
    rot = m[:3, :3]
    rot = rot / np.linalg.norm(rot, axis=0, keepdims=True)  # drop object scale (columns are the axes)
    if not (np.all(np.isfinite(rot)) and math.isclose(abs(np.linalg.det(rot)), 1.0, abs_tol=1e-3)):
        raise DelightError(f"camera {cam_obj.name!r}: its world matrix is degenerate or sheared")
    # Blender camera looks down -Z with +Y up; the core looks down +Z with y down.
    r_cv = np.diag([1.0, -1.0, -1.0]) @ rot.T
    t = -r_cv @ m[:3, 3]
    k = np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])
    return Camera(K=k, R=r_cv, t=t, width=out_w, height=out_h)
