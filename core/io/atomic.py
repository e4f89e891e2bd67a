"""Atomic file writes: write a temporary file next to the target, then rename.

A failure (or Ctrl-C) while writing never leaves a partial file, and never
changes an existing file at the target path.
"""

from __future__ import annotations

import contextlib
import os
import secrets

__all__ = ["atomic_path"]


@contextlib.contextmanager
def atomic_path(path, suffix=""):
    """Yield a temporary path in the target's folder; move it to ``path`` on success.

    The temporary file is created empty with the default permissions (those
    of an ``open(path, "w")``, so the umask applies) and removed if the block
    raises.

    Parameters
    ----------
    path : str or os.PathLike
        Final path. Its folder must exist.
    suffix : str
        Ending of the temporary name, for writers that look at extensions.
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise FileNotFoundError(f"cannot write {path}: folder {folder} does not exist")
    for _ in range(100):
        tmp = os.path.join(folder, f".tmp-{secrets.token_hex(6)}{suffix}")
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            break
        except FileExistsError:
            continue
    else:  # pragma: no cover - 100 collisions of 48 random bits
        raise FileExistsError(f"cannot create a temporary file in {folder}")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        raise
