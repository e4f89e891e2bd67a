"""The output folder: one set of files, written all or nothing, never over a file Delight did not write.

Both front ends (``python -m core solve`` and the Blender add-on) write through
:func:`write_outputs`. The files, relative to the output folder:

``<albedo>.exr``
    The texture, RGBA float32, row 0 at the top; A = 1 where a view saw the
    texel. ``albedo.exr`` from ``python -m core``, ``<object>_albedo.exr``
    from the add-on.
``views/<view>.exr``
    Per-view reflectance, RGBA float32; A = the pixels on the mesh.
``lighting.json``
    The lighting of each view, as :func:`lighting_json` builds it::

        {"sh_basis": ["n1", "n2", "n3", "1", "n1*n2", "n1*n3", "n2*n3", "n1^2-n2^2", "3*n3^2-1"],
         "channels": ["R", "G", "B"],
         "normals": "world space, unit length",
         "method": "texture",
         "world": {"file": "lighting.exr", "sh": [[9 floats] per channel],
                   "radiance_sh": [[9 floats] per channel]} or null,
         "views": [{"name": "<view>", "file": "views/<view>.exr",
                    "sh": [[9 floats] per channel] or null}]}

    The shading of view v, channel c at unit normal n is
    ``sum_k sh[c][k] * basis_k(n)``; ``sh`` is null when no lighting was
    estimated (the add-on's method ``project``). ``channels`` is ``["Y"]``
    for grey views. ``world.sh`` is the mean of the views' ``sh``
    (:func:`core.io.envmap.world_lighting`) and ``world.radiance_sh`` the
    environment's radiance ``sum_k radiance_sh[c][k] * basis_k(w)`` coming
    from the unit world direction w, which lights a Lambertian albedo to that
    shading (:func:`core.io.envmap.radiance_sh`).

    With the sun term (the option ``sun``), ``world.sun`` is
    ``{"direction": [x, y, z] towards the sun, "strength": [per channel]}`` and
    each view has ``"sun_strength"``: where a point sees the sun, its shading
    gains ``strength * max(0, n . direction)``.
``lighting.exr``
    ``world.radiance_sh`` as an equirectangular RGB float32 image in
    Blender's world convention, clamped at 0
    (:func:`core.io.envmap.envmap_image`), plus the sun as a small disc
    (:func:`core.io.envmap.add_sun`); not written when no lighting was
    estimated.
``report.json``
    What the run did (each front end has its own keys), plus ``"files"``: the
    files the run wrote, relative, ``report.json`` among them.

``<view>`` is the view's name made safe as a file name
(:func:`core.io.names.unique_names`), so nothing lands outside the folder.

Guarantees of :func:`write_outputs`:

* **All or nothing.** Every file is first written into a hidden staging
  folder ``.delight-*`` inside the output folder. Then, with Ctrl-C held
  back, the files in the way are moved into that folder's backup part and the
  new ones moved into place, each by one rename; if any rename fails (or
  Ctrl-C came meanwhile), the ones done are undone. A failure or cancel at any moment leaves the earlier
  outputs or the new ones, never a mix, and the staging folder is removed.
* **Only Delight's own files are replaced.** A file in the way is replaced
  without ``overwrite`` only if the earlier run's ``report.json`` lists it.
  The earlier run's files that this run does not write again are removed, so
  the folder holds one run's outputs. Other files are left alone.
* **Inputs are never written.** :func:`check_inputs` refuses an output that
  is one of the run's input files, with or without ``overwrite``.

:func:`prepare_outputs` runs the checks (and proves the folder writable)
before the long part of a run; :func:`write_outputs` runs them again.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import shutil
import signal
import tempfile
import threading
from dataclasses import dataclass, field

import numpy as np

from ..errors import Cancelled, DelightError
from ..geometry.sh import SH_BASIS_NAMES
from ..parallel import resolve_threads, thread_map
from .envmap import add_sun, envmap_image, radiance_sh, world_lighting
from .exr import compression_threads, write_exr
from .jsonio import json_value
from .names import unique_names

__all__ = [
    "LIGHTING",
    "ENVMAP",
    "REPORT",
    "NORMALS",
    "Plan",
    "check_room",
    "view_files",
    "channel_names",
    "lighting_json",
    "lighting_files",
    "lighting_outputs",
    "rgba",
    "own_files",
    "plan_outputs",
    "check_inputs",
    "check_writable",
    "prepare_outputs",
    "write_outputs",
]

LIGHTING = "lighting.json"
ENVMAP = "lighting.exr"
REPORT = "report.json"
NORMALS = "world space, unit length"

# What Delight writes: a safe name (core.io.names) in the folder or in views/.
_OWN_NAME = re.compile(r"^(views/)?[A-Za-z0-9_-][A-Za-z0-9._-]*$")
_STAGING_PREFIX = ".delight-"


def view_files(names) -> list[str]:
    """``views/<safe name>.exr`` for each view name (unique, even case-insensitively)."""
    return [f"views/{s}.exr" for s in unique_names(names)]


def channel_names(n_channels: int) -> list[str]:
    """``["R", "G", "B"]`` for colour, ``["Y"]`` for grey."""
    if n_channels == 3:
        return ["R", "G", "B"]
    if n_channels == 1:
        return ["Y"]
    raise ValueError(f"{n_channels} channels: expected 1 (grey) or 3 (RGB)")


def lighting_json(names, files, sigma, n_channels: int = 3, method: str | None = None, sun=None) -> dict:
    """The contents of ``lighting.json`` (schema in the module docstring).

    Parameters
    ----------
    names, files : list of str
        The views' names and their files (:func:`view_files`).
    sigma : (m, C, 9) array or None
        Each view's SH coefficients per channel; None when none were estimated.
    n_channels : int
        C, used when ``sigma`` is None.
    method : str, optional
        How the result was computed (``"texture"``, ``"image"``, ``"project"``).
    sun : (3,) array, optional
        The direction towards the sun when ``sigma`` has a tenth coefficient, the sun term's
        (:class:`core.geometry.sun.SunLight`): written as ``"sun"``, world and per view.
    """
    sun_strength = None
    if sigma is not None:
        sigma = np.asarray(sigma, dtype=np.float64)
        k = 10 if sun is not None else 9
        if sigma.shape[0] != len(names) or sigma.shape[2:] != (k,):
            raise ValueError(f"sigma has shape {sigma.shape}, expected ({len(names)}, C, {k})")
        n_channels = sigma.shape[1]
        if sun is not None:
            sigma, sun_strength = sigma[..., :9], sigma[..., 9]
    out = {"sh_basis": list(SH_BASIS_NAMES), "channels": channel_names(n_channels), "normals": NORMALS}
    if method is not None:
        out["method"] = method
    world = None if sigma is None else world_lighting(sigma)
    out["world"] = (
        None if world is None else {"file": ENVMAP, "sh": world.tolist(), "radiance_sh": radiance_sh(world).tolist()}
    )
    if sun_strength is not None:
        d = np.asarray(sun, np.float64) / np.linalg.norm(sun)
        out["world"]["sun"] = {"direction": d.tolist(), "strength": sun_strength.mean(axis=0).tolist()}
    out["views"] = [
        {"name": str(name), "file": f, "sh": None if sigma is None else sigma[i].tolist()}
        for i, (name, f) in enumerate(zip(names, files))
    ]
    if sun_strength is not None:
        for view, strength in zip(out["views"], sun_strength):
            view["sun_strength"] = strength.tolist()
    return out


def lighting_files(estimated: bool = True) -> list[str]:
    """The lighting's files: ``lighting.json``, and ``lighting.exr`` when a lighting is estimated."""
    return [LIGHTING, ENVMAP] if estimated else [LIGHTING]


def lighting_outputs(names, files, sigma, n_channels: int = 3, method: str | None = None, sun=None) -> dict:
    """The lighting's files by name (:func:`lighting_files`) -> contents, for :func:`write_outputs`.

    ``lighting.json`` (:func:`lighting_json`, same parameters) and, unless
    ``sigma`` is None, the world lighting as an environment image, with the sun as a disc
    (:func:`core.io.envmap.add_sun`) when there is one.
    """
    out = {LIGHTING: lighting_json(names, files, sigma, n_channels, method, sun)}
    if sigma is not None:
        world = world_lighting(sigma)
        out[ENVMAP] = envmap_image(radiance_sh(world[:, :9]))
        if sun is not None:
            out[ENVMAP] = add_sun(out[ENVMAP], sun, world[:, 9])
    return out


def rgba(values, alpha, zero_outside: bool = True) -> np.ndarray:
    """``(H, W, 4)`` float32 RGBA from ``(H, W[, C])`` values and an ``(H, W)`` alpha.

    Grey values are repeated into R, G and B; NaN and infinities become 0;
    with ``zero_outside`` the colour is 0 where alpha is 0.
    """
    v = np.asarray(values, dtype=np.float32)
    if v.ndim == 2:
        v = v[:, :, None]
    a = np.asarray(alpha, dtype=np.float32)
    out = np.empty(v.shape[:2] + (4,), dtype=np.float32)

    def rows(r0):  # a block of rows at a time, on every core: each block's arrays stay in the cache
        r = slice(r0, r0 + _RGBA_ROWS)
        block = v[r, :, :3]
        colour = np.where(np.isfinite(block), block, np.float32(0))
        if zero_outside:
            colour *= (a[r] != 0)[..., None]
        o = out[r]
        o[..., :3] = colour  # grey (one channel) into R, G and B alike
        o[..., 3] = a[r]

    thread_map(rows, range(0, v.shape[0], _RGBA_ROWS))
    return out


# Rows of :func:`rgba` made at a time.
_RGBA_ROWS = 64


# ---------------------------------------------------------------- checks


@dataclass
class Plan:
    """What a write will do in ``out_dir`` (relative paths, ``/``-separated).

    ``files`` are written (``report.json`` last); ``replace`` are those of
    them already there (Delight's own, or any with ``overwrite``); ``stale``
    are the earlier run's files not written again, removed.
    """

    out_dir: str
    files: list
    replace: list = field(default_factory=list)
    stale: list = field(default_factory=list)

    def touched(self) -> list[str]:
        """Absolute paths of every file the write creates, replaces or removes."""
        return [_abs(self.out_dir, rel) for rel in [*self.files, *self.stale]]


def _abs(out_dir, rel):
    return os.path.join(out_dir, *rel.split("/"))


def own_files(out_dir) -> set:
    """The files the earlier run wrote, as its ``report.json`` lists them (empty if there is none).

    Only names Delight could have written count, and only inside ``out_dir``.
    """
    try:
        with open(os.path.join(out_dir, REPORT), encoding="utf-8") as fh:
            report = json.load(fh)
    except (OSError, ValueError):
        return set()
    files = report.get("files") if isinstance(report, dict) else None
    if not isinstance(files, list) or REPORT not in files:
        return set()
    root = os.path.realpath(out_dir)
    return {
        f
        for f in files
        if isinstance(f, str)
        and _OWN_NAME.match(f)
        and os.path.dirname(os.path.realpath(_abs(out_dir, f))) in (root, os.path.join(root, "views"))
    }


def _is_dir(path):
    return os.path.isdir(path) and not os.path.islink(path)


def plan_outputs(out_dir, files, overwrite: bool = False) -> Plan:
    """Check that ``files`` can go into ``out_dir``; return the :class:`Plan`.

    Raises
    ------
    DelightError
        ``out_dir`` or its ``views`` is a file, a folder has an output's name,
        or a file Delight did not write is in the way and ``overwrite`` is off.
    """
    plan, foreign = _plan(out_dir, files, overwrite)
    if foreign:
        raise foreign[0]
    return plan


def _plan(out_dir, files, overwrite):
    """:func:`plan_outputs`, with the errors for files in the way returned, not raised."""
    out_dir = os.path.abspath(os.fspath(out_dir))
    files = [f for f in files if f != REPORT] + [REPORT]
    if len(set(files)) != len(files) or not all(_OWN_NAME.match(f) for f in files):
        raise ValueError(f"output names must be distinct safe names, in the folder or in views/: {files}")
    if os.path.lexists(out_dir) and not os.path.isdir(out_dir):
        raise DelightError(f"the output folder {out_dir} is a file, not a folder; choose another output folder")
    views = os.path.join(out_dir, "views")
    if any(f.startswith("views/") for f in files) and os.path.lexists(views) and not os.path.isdir(views):
        raise DelightError(f"cannot write per-view maps: {views} is a file; choose another output folder")
    own = own_files(out_dir) if os.path.isdir(out_dir) else set()
    plan, foreign = Plan(out_dir=out_dir, files=files), []
    for rel in files:
        path = _abs(out_dir, rel)
        if not os.path.lexists(path):
            continue
        if _is_dir(path):
            raise DelightError(f"cannot write {path}: a folder of that name exists; choose another output folder")
        if rel not in own and not overwrite:
            foreign.append(
                DelightError(
                    f"{path} already exists and was not written by Delight; "
                    "choose another output folder or pass --overwrite"
                )
            )
        plan.replace.append(rel)
    plan.stale = sorted(
        f for f in own - set(files) if os.path.lexists(_abs(out_dir, f)) and not _is_dir(_abs(out_dir, f))
    )
    return plan, foreign


def _file_ids(path):
    """``(device, inode)`` of an existing path, else None."""
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        return None
    return st.st_dev, st.st_ino


def check_inputs(inputs, outputs) -> None:
    """Raise :class:`DelightError` if an output path is one of the input files.

    The same file counts whatever its path (links, ``..``, hard links), so a
    run can never write over a photo or the .blend, overwrite or not.

    Parameters
    ----------
    inputs : iterable of str
        Every file the run reads; empty entries are skipped.
    outputs : iterable of str
        Every file the write creates, replaces or removes (:meth:`Plan.touched`).
    """
    by_id, by_path = {}, {}
    for p in inputs:
        if not p:
            continue
        p = os.fspath(p)
        by_path.setdefault(os.path.normcase(os.path.realpath(p)), p)
        ids = _file_ids(p)
        if ids is not None:
            by_id.setdefault(ids, p)
    for out in outputs:
        hit = by_path.get(os.path.normcase(os.path.realpath(out)))
        if hit is None:
            ids = _file_ids(out)
            hit = by_id.get(ids) if ids is not None else None
        if hit is not None:
            raise DelightError(f"the output {out} would overwrite the input {hit}; choose another output folder")


def _nearest_existing(path):
    while not os.path.lexists(path):
        parent = os.path.dirname(path)
        if parent == path:
            break
        path = parent
    return path


def _cannot_write(where, exc) -> DelightError:
    if exc.errno in (errno.EACCES, errno.EPERM):
        why = "permission denied; choose another output folder"
    elif exc.errno == errno.EROFS:
        why = "the file system is read-only; choose another output folder"
    elif exc.errno in (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)):
        why = "the disk is full; free some space or choose another output folder"
    else:
        why = f"{exc.strerror or exc}; choose another output folder"
    return DelightError(f"cannot write to {where}: {why}")


def check_writable(out_dir) -> None:
    """Prove that files can be created where the write will create them (a probe file, removed).

    That is ``out_dir`` and its ``views`` if they exist, else the nearest
    existing folder above, where ``out_dir`` would be made. Nothing is left.

    Raises
    ------
    DelightError
        Permission denied, a read-only file system, or a file where a folder
        should be.
    """
    out_dir = os.path.abspath(os.fspath(out_dir))
    base = _nearest_existing(out_dir)
    if not os.path.isdir(base):
        raise DelightError(f"cannot write to {out_dir}: {base} is a file, not a folder; choose another output folder")
    places = [base]
    if base == out_dir and os.path.isdir(os.path.join(out_dir, "views")):
        places.append(os.path.join(out_dir, "views"))
    for place in places:
        try:
            fd, probe = tempfile.mkstemp(prefix=_STAGING_PREFIX + "probe-", dir=place)
            os.close(fd)
            os.remove(probe)
        except OSError as exc:
            raise _cannot_write(place, exc) from None


def check_room(out_dir, need_bytes: int) -> None:
    """Raise :class:`DelightError` if the disk that will hold ``out_dir`` has less than ``need_bytes`` free."""
    base = _nearest_existing(os.path.abspath(os.fspath(out_dir)))
    free = shutil.disk_usage(base).free
    if need_bytes > free:
        raise DelightError(
            f"cannot write to {out_dir}: the outputs need about {need_bytes / 1e6:.0f} MB and the "
            f"disk has {free / 1e6:.0f} MB free; free some space or choose another output folder"
        )


def prepare_outputs(out_dir, files, overwrite: bool = False, inputs=(), need_bytes: int = 0) -> Plan:
    """Every check before a run: :func:`plan_outputs`, :func:`check_inputs`, :func:`check_writable`,
    and :func:`check_room` for ``need_bytes`` (an estimate of the outputs' size; 0: not checked).

    A clash with an input is reported first, whatever else is in the way.
    """
    plan, foreign = _plan(out_dir, files, overwrite)
    check_inputs(inputs, plan.touched())
    if foreign:
        raise foreign[0]
    check_writable(plan.out_dir)
    if need_bytes:
        check_room(plan.out_dir, need_bytes)
    return plan


# ---------------------------------------------------------------- writing


def _write_json(path, obj):
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(json_value(obj), fh, indent=2, allow_nan=False)
        fh.write("\n")


def _write_one(path, content):
    if callable(content):
        content(path)
    elif isinstance(content, np.ndarray):
        write_exr(path, content)
    elif isinstance(content, (dict, list)):
        _write_json(path, content)
    else:
        raise TypeError(f"cannot write {type(content).__name__} to {path}")


def _makedirs(path) -> list:
    """``os.makedirs``; return the folders it created, outermost first."""
    made = []
    top = path
    while not os.path.lexists(top):
        made.append(top)
        top = os.path.dirname(top)
    os.makedirs(path, exist_ok=True)
    return made[::-1]


def _remove_empty(folders):
    for d in reversed(folders):
        with contextlib.suppress(OSError):
            os.rmdir(d)


@contextlib.contextmanager
def _ctrl_c_held():
    """Hold Ctrl-C back in the block (which can look at the list yielded), raise it at the end.

    Only in the main thread with Python's own handler (``python -m``, the
    bpy module); a host's own handler (Blender's) is left alone.
    """
    held = []
    active = (
        threading.current_thread() is threading.main_thread()
        and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    )
    if active:
        old = signal.signal(signal.SIGINT, lambda *_: held.append(True))
    try:
        yield held
    finally:
        if active:
            signal.signal(signal.SIGINT, old)
    if held:
        raise KeyboardInterrupt


class _RollbackFailed(DelightError):
    pass


def _swap(plan, new_dir, old_dir, interrupted):
    """Move the files in the way into ``old_dir``, the new ones into place; undo all on any error.

    ``interrupted()`` True at the end (Ctrl-C held back meanwhile) undoes it too.
    """
    out = plan.out_dir
    moved, placed, made = [], [], []
    try:
        for rel in [*plan.replace, *plan.stale]:
            os.replace(_abs(out, rel), _abs(old_dir, rel))
            moved.append(rel)
        for rel in plan.files:
            dst = _abs(out, rel)
            if not os.path.isdir(os.path.dirname(dst)):
                os.mkdir(os.path.dirname(dst))
                made.append(os.path.dirname(dst))
            os.replace(_abs(new_dir, rel), dst)
            placed.append(rel)
        if interrupted():
            raise KeyboardInterrupt
    except BaseException as exc:
        try:
            for rel in reversed(placed):
                os.replace(_abs(out, rel), _abs(new_dir, rel))
            for rel in reversed(moved):
                os.replace(_abs(old_dir, rel), _abs(out, rel))
        except OSError as undo:
            raise _RollbackFailed(
                f"writing into {out} failed ({exc}) and the earlier outputs could not be put "
                f"back ({undo}); they are in {old_dir}"
            ) from exc
        _remove_empty(made)
        raise


def write_outputs(
    out_dir, files: dict, report, overwrite: bool = False, inputs=(), cancel=None, threads=None
) -> list[str]:
    """Write a run's files into ``out_dir``, all or nothing (see the module docstring).

    Parameters
    ----------
    out_dir : str or os.PathLike
        The output folder; created if needed.
    files : dict
        Relative path (``/``-separated, as :func:`view_files` gives) ->
        contents: an array (written as EXR), a dict or list (JSON), or a
        callable ``write(path)``. Written several at a time, on worker
        threads (so a callable must not touch bpy).
    report : dict or callable() -> dict
        Contents of ``report.json``, written last; ``"files"`` (the relative
        paths written) is added. A callable is called after the other files
        were written, so that it can include their time.
    overwrite : bool
        Replace files in the way that Delight did not write.
    inputs : iterable of str
        The run's input files, never written (:func:`check_inputs`).
    cancel : callable() -> bool, optional
        Checked before the first file, after each one, and before the files are moved into place.
    threads : int or None
        Files written at once (None: one per core).

    Returns
    -------
    list of str
        Absolute paths of the files written, in the order of ``files``, then
        ``report.json``.

    Raises
    ------
    DelightError
        A check failed, or a file could not be written (permission, full
        disk); the folder is as it was.
    Cancelled
        ``cancel()`` returned True; the folder is as it was.
    """
    if REPORT in files:
        raise ValueError(f"{REPORT} is written from `report`, not `files`")
    rels = list(files)
    plan = prepare_outputs(out_dir, rels, overwrite, inputs)
    out = plan.out_dir

    def check_cancel():
        if cancel is not None and cancel():
            raise Cancelled("cancelled")

    check_cancel()
    made, staging, done = [], None, False
    try:
        made = _makedirs(out)
        staging = tempfile.mkdtemp(prefix=_STAGING_PREFIX, dir=out)
        new_dir, old_dir = os.path.join(staging, "new"), os.path.join(staging, "old")
        for d in (new_dir, old_dir):
            os.makedirs(os.path.join(d, "views"))
        # Several files at once: the EXR's compression runs outside the interpreter's lock.
        check_cancel()
        with compression_threads(resolve_threads(threads)):  # and each EXR's blocks of lines at once
            thread_map(lambda rel: _write_one(_abs(new_dir, rel), files[rel]), rels, threads, lambda _: check_cancel())
        contents = dict(report() if callable(report) else report)
        contents["files"] = plan.files
        _write_json(_abs(new_dir, REPORT), contents)
        # Checked again: the folder may have changed during the run.
        plan = prepare_outputs(out, rels, overwrite, inputs)
        check_cancel()
        with _ctrl_c_held() as held:
            _swap(plan, new_dir, old_dir, lambda: bool(held))
        done = True
    except _RollbackFailed:
        staging = None  # it holds the earlier outputs now
        raise
    except OSError as exc:
        raise _cannot_write(out, exc) from None
    finally:
        if staging is not None:
            shutil.rmtree(staging, ignore_errors=True)
        if not done:
            _remove_empty(made)
    return [_abs(out, rel) for rel in plan.files]
