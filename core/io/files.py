"""Opening files users name: one clear error for a missing path, a folder, or the wrong kind of file."""

from __future__ import annotations

import os

__all__ = ["read_magic"]


def read_magic(path, size: int, what: str) -> bytes:
    """The first ``size`` bytes of ``path``, after checking that it is an existing file.

    Raises FileNotFoundError ("<what> not found: <path>") or ValueError
    ("<what> <path>: not a file"); ``what`` names the kind of file in the message.
    """
    path = os.fspath(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"{what} not found: {path}")
    if not os.path.isfile(path):
        raise ValueError(f"{what} {path}: not a file")
    with open(path, "rb") as fh:
        return fh.read(size)
