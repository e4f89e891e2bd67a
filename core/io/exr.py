"""Read and write OpenEXR images as NumPy arrays.

Arrays are ``(H, W, C)`` float32, linear, with row 0 the **top** row (as in
the file; Blender's ``Image.pixels`` is the other way up).

Multi-part files
----------------
Blender 5 writes a multilayer EXR as a multi-part file, one part per render
pass (``"ViewLayer.Combined"``, ``"ViewLayer.Normal"``, ...), whose channels
repeat the part name (``"ViewLayer.Combined.R"``). :func:`read_exr` reads one
part: by default the first part that has R, G and B channels, else part 0.
Channel names are returned without that ``"<part name>."`` prefix.
"""

from __future__ import annotations

import contextlib
import os

import numpy as np
import OpenEXR

from .atomic import atomic_path
from .files import read_magic

__all__ = ["read_exr", "write_exr", "exr_parts", "compression_threads"]

_MAGIC = b"\x76\x2f\x31\x01"
_FIRST = ("R", "G", "B", "A")


@contextlib.contextmanager
def compression_threads(threads: int):
    """OpenEXR's own threads, which compress a file's blocks of lines at once, set to ``threads`` in the block.

    The library's default is none: a large texture is compressed on one core (8192² RGBA, about 10 s). The same
    bytes are written either way. One thread (the caller's) is OpenEXR's 0. The count is the process's, so it
    is set once around writes that may run at the same time, not per file.
    """
    get, set_ = getattr(OpenEXR, "global_thread_count", None), getattr(OpenEXR, "set_global_thread_count", None)
    if get is None or set_ is None:  # an older binding: as it is
        yield
        return
    before = get()
    set_(threads if threads > 1 else 0)
    try:
        yield
    finally:
        set_(before)


def _open(path, header_only=False):
    path = os.fspath(path)
    if read_magic(path, 4, "EXR file") != _MAGIC:
        raise ValueError(f"not an OpenEXR file: {path}")
    try:
        # R, G, B (and A) come as one interleaved (H, W, 3 or 4) array: a copy and a stack fewer per read.
        return OpenEXR.File(path, separate_channels=False, header_only=header_only)
    except Exception as exc:  # the binding raises a bare RuntimeError
        raise ValueError(f"cannot read OpenEXR file {path} (corrupt or truncated?): {exc}") from exc


def _short_name(channel, part_name):
    prefix = part_name + "." if part_name else ""
    return channel[len(prefix) :] if prefix and channel.startswith(prefix) else channel


def _ordered(names):
    """R, G, B, A first when present, then the others in file order."""
    first = [n for n in _FIRST if n in names]
    return first + [n for n in names if n not in first]


def exr_parts(path) -> list[tuple[str, list[str]]]:
    """List the parts of an EXR file without reading pixels.

    Returns
    -------
    list of (part name, channel names)
        Channel names as :func:`read_exr` would return them for that part.
    """
    return [(p.name(), _ordered(_channel_names(p))) for p in _open(path, header_only=True).parts]


def read_exr(path, part=None):
    """Read one part of an EXR file.

    Parameters
    ----------
    path : str or os.PathLike
    part : int or str, optional
        Part index or part name. By default the first part that has R, G and
        B channels, or part 0 if none has.

    Returns
    -------
    array : (H, W, C) float32
        The part's data window; row 0 is the top row. Half, float and uint
        pixels become float32.
    channels : list of str
        Channel names, R, G, B, A first when present, then the others in file
        order; a ``"<part name>."`` prefix is removed.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ValueError
        The file is not a readable EXR, the part does not exist, or its
        channels are subsampled or deep.
    """
    path = os.fspath(path)
    f = _open(path)
    parts = f.parts
    names = [p.name() for p in parts]
    if part is None:
        chosen = next((p for p in parts if {"R", "G", "B"} <= set(_channel_names(p))), parts[0])
    elif isinstance(part, str):
        if part not in names:
            raise ValueError(f"{path}: no part named {part!r} (parts: {names})")
        chosen = parts[names.index(part)]
    else:
        if not 0 <= int(part) < len(parts):
            raise ValueError(f"{path}: part index {part} out of range (file has {len(parts)} parts)")
        chosen = parts[int(part)]
    if chosen.type() not in (OpenEXR.scanlineimage, OpenEXR.tiledimage):
        raise ValueError(f"{path}: part {chosen.name()!r} is a deep image, which is not supported")
    groups = []  # (short names, (H, W, k) array) per array the binding gives
    for key, c in chosen.channels.items():
        px = np.asarray(c.pixels)
        if px.ndim == 3 and px.shape[2] in (3, 4):  # R, G, B (A) interleaved, under a layer's prefix or none
            full = (
                list("RGBA"[: px.shape[2]]) if key in ("RGB", "RGBA") else [f"{key}.{x}" for x in "RGBA"[: px.shape[2]]]
            )
        elif px.ndim == 2:
            full, px = [key], px[:, :, None]
        else:
            raise ValueError(f"{path}: channel {key!r} has pixel shape {px.shape}, expected 2-D")
        groups.append(([_short_name(n, chosen.name()) for n in full], px))
    if not groups:
        raise ValueError(f"{path}: part {chosen.name()!r} has no channels")
    shapes = {g[1].shape[:2] for g in groups}
    if len(shapes) > 1:
        raise ValueError(f"{path}: its channels are subsampled ({sorted(shapes)}), which is not supported")
    order = _ordered([n for names_, _ in groups for n in names_])
    if sorted(order) != sorted(_channel_names(chosen)):  # the binding grouped channels some other way
        raise ValueError(f"{path}: channels {sorted(_channel_names(chosen))} came as {order}; cannot tell them apart")
    if len(groups) == 1 and groups[0][0] == order:  # the common case: R, G, B (A) as they are
        return groups[0][1].astype(np.float32, copy=False), order
    planes = {n: px[:, :, k] for names_, px in groups for k, n in enumerate(names_)}
    out = np.empty((*shapes.pop(), len(order)), np.float32)
    for k, n in enumerate(order):
        out[:, :, k] = planes[n]
    return out, order


def _channel_names(part) -> list:
    """The part's channel names as :func:`read_exr` returns them (its prefix removed), from the header."""
    return [_short_name(c.name, part.name()) for c in part.header.get("channels", [])]


def write_exr(path, array, channels=None, half=False):
    """Write an array as a single-part, ZIP-compressed, scanline EXR.

    The file is written to a temporary file in the same folder and then moved
    into place, so a failure never leaves a partial file (and never touches
    an existing file at ``path``).

    Parameters
    ----------
    path : str or os.PathLike
    array : (H, W) or (H, W, C) array
        Linear values, row 0 at the top.
    channels : list of str, optional
        One name per channel. Default: "Y" for C = 1, "R", "G", "B" for 3,
        "R", "G", "B", "A" for 4; other C need names.
    half : bool
        Store 16-bit half floats (values beyond +-65504 become infinite)
        instead of 32-bit floats.
    """
    path = os.fspath(path)
    a = np.asarray(array)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(f"write_exr {path}: array must be (H, W) or (H, W, C) with H, W > 0, got {a.shape}")
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer) or a.dtype == bool):
        raise ValueError(f"write_exr {path}: array dtype {a.dtype} is not numeric")
    c = a.shape[2]
    if channels is None:
        defaults = {1: ["Y"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}
        if c not in defaults:
            raise ValueError(f"write_exr {path}: {c} channels need explicit channel names")
        channels = defaults[c]
    channels = [str(n) for n in channels]
    if len(channels) != c:
        raise ValueError(f"write_exr {path}: {len(channels)} channel names for {c} channels")
    if len(set(channels)) != c or not all(channels):
        raise ValueError(f"write_exr {path}: channel names must be unique and non-empty, got {channels}")
    dtype = np.float16 if half else np.float32
    data = {n: np.ascontiguousarray(a[:, :, k], dtype=dtype) for k, n in enumerate(channels)}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path, suffix=".exr") as tmp:
        try:
            OpenEXR.File(header, data).write(tmp)
        except RuntimeError as exc:  # the binding's error names only the temporary file
            raise OSError(f"cannot write EXR file {path}: {exc}") from exc
