"""Full-resolution photos kept on disk while a run needs them, so that memory holds one at a time.

The scene is read once (decoding a photo through Blender's colour management is slow, and only the main thread
may do it); each photo is downscaled to the working resolution for the solve, and the detail stage
(:mod:`core.texture.detail`) reads the full-resolution copy again later, from any thread. :class:`PhotoCache`
keeps those copies (an 8-bit photo as its codes, any other as half floats) in a hidden folder
``.delight-photos-*`` inside the output folder (on the disk the outputs go to, which is checked for room; a
system temporary folder may live in memory), and removes the folder when closed, when the run fails, or at the
latest when the cache is collected. A run that was killed cannot remove its folder; the next run into the same
output folder does (:func:`remove_stale`).
"""

from __future__ import annotations

import functools
import os
import shutil
import socket
import tempfile
import threading
import time
import weakref

import numpy as np

from ..errors import DelightError
from .outputs import check_writable
from .photos import CodedPhoto

__all__ = ["PhotoCache", "PREFIX", "remove_stale"]

PREFIX = ".delight-photos-"
# The largest half float: brighter values are clipped to it.
_HALF_MAX = 65504.0
# Free space left on the disk beyond the copies.
_SPARE_BYTES = 256 * 2**20
# Which run a cache folder belongs to: "host pid".
_OWNER = "owner"
# A cache folder without an owner (made before owners were written) counts as stale after this long.
_OWNERLESS_STALE_S = 3600


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # exists, but not ours to signal
        return True
    return True


def remove_stale(parent) -> list:
    """Remove the cache folders in ``parent`` left by runs of this machine that are no longer running.

    Returns the folders removed. A folder of another machine (a shared disk) or of a live process stays.
    """
    removed = []
    try:
        names = [n for n in os.listdir(parent) if n.startswith(PREFIX)]
    except OSError:
        return removed
    for name in names:
        folder = os.path.join(parent, name)
        try:
            with open(os.path.join(folder, _OWNER)) as fh:
                host, pid = fh.read().split()
            stale = host == socket.gethostname() and not _alive(int(pid))
        except (OSError, ValueError):
            try:
                stale = time.time() - os.path.getmtime(folder) > _OWNERLESS_STALE_S
            except OSError:
                stale = False
        if stale and os.path.isdir(folder) and not os.path.islink(folder):
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder)
    return removed


def _half(photo, rows=256):
    """``photo`` as float16, clipped to its range, a few rows at a time (no full-size float32 temporary)."""
    out = np.empty(photo.shape, np.float16)
    for r0 in range(0, photo.shape[0], rows):
        out[r0 : r0 + rows] = np.clip(photo[r0 : r0 + rows], -_HALF_MAX, _HALF_MAX)
    return out


def _load(path, clipped_path, tables_path=None):
    if tables_path:
        photo = CodedPhoto(np.load(path), np.load(tables_path))
    else:
        photo = np.load(path).astype(np.float32)
    return photo, (np.load(clipped_path) if clipped_path else None)


def _remove(folder, made):
    if folder is not None:
        shutil.rmtree(folder, ignore_errors=True)
    for d in reversed(made):  # the folders made for the cache, outermost first in `made`
        try:
            os.rmdir(d)
        except OSError:
            break


class PhotoCache:
    """Photos as ``.npy`` files (codes or half floats) in a hidden folder of ``parent``, each read back by a loader.

    Parameters
    ----------
    parent : str
        The folder that holds the cache (the output folder). It and the cache folder are made at the first
        :meth:`put`; :meth:`close` removes the cache folder, and ``parent`` again if the cache made it and it is
        empty.
    """

    def __init__(self, parent):
        self.parent = os.path.abspath(os.fspath(parent))
        self.folder = None
        self.count = 0
        self.bytes = 0
        self._finalizer = None
        self._lock = threading.Lock()  # put may be called from several threads at once

    def _open(self):
        check_writable(self.parent)
        made, top = [], self.parent
        while not os.path.lexists(top):
            made.append(top)
            top = os.path.dirname(top)
        try:
            os.makedirs(self.parent, exist_ok=True)
            remove_stale(self.parent)
            self.folder = tempfile.mkdtemp(prefix=PREFIX, dir=self.parent)
            with open(os.path.join(self.folder, _OWNER), "w") as fh:
                fh.write(f"{socket.gethostname()} {os.getpid()}")
        except OSError as exc:
            _remove(self.folder, made[::-1])
            raise DelightError(f"cannot keep the full-resolution photos in {self.parent}: {exc}") from None
        self._finalizer = weakref.finalize(self, _remove, self.folder, made[::-1])

    def put(self, photo, clipped=None):
        """Keep ``photo`` (and its ``(H, W)`` clipped pixels); return ``load() -> (photo, clipped)``.

        ``photo``: ``(H, W, C)`` float32, kept as half floats, or an 8-bit photo's codes (a
        :class:`core.io.photos.CodedPhoto`, without gains), kept and read back as they are.

        Raises
        ------
        DelightError
            Too little room on the disk for the copy, or it could not be written.
        """
        coded = isinstance(photo, CodedPhoto)
        if coded and photo.gains is not None:
            raise ValueError("PhotoCache.put: a coded photo is kept without gains")
        need = (photo.codes.nbytes + photo.tables.nbytes if coded else photo.size * 2) + (
            clipped.size if clipped is not None else 0
        )
        with self._lock:  # the folder made once, each copy its own number and room
            if self.folder is None:
                self._open()
            free = shutil.disk_usage(self.folder).free
            if need + _SPARE_BYTES > free:
                raise DelightError(
                    f"too little room in {self.parent} for the full-resolution photos' temporary copies "
                    f"({self.bytes / 1e6:.0f} MB kept, {free / 1e6:.0f} MB free, {need / 1e6:.0f} MB more needed): "
                    "free some space, choose another output folder, or turn off Full-resolution detail"
                )
            number = self.count
            self.count += 1
            self.bytes += need
        path = os.path.join(self.folder, f"{number}.npy")
        clipped_path = tables_path = None
        try:
            if coded:
                tables_path = os.path.join(self.folder, f"{number}_tables.npy")
                np.save(path, photo.codes)
                np.save(tables_path, photo.tables)
            else:
                np.save(path, _half(photo))
            if clipped is not None:
                clipped_path = os.path.join(self.folder, f"{number}_clipped.npy")
                np.save(clipped_path, np.asarray(clipped, bool))
        except OSError as exc:
            raise DelightError(f"cannot keep a full-resolution photo in {self.folder}: {exc}") from None
        return functools.partial(_load, path, clipped_path, tables_path)

    def close(self):
        """Remove the copies (and the folders the cache made). The loaders fail after this."""
        if self._finalizer is not None:
            self._finalizer()
