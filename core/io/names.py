"""Safe, unique file-name stems from names users typed (objects, cameras, views)."""

from __future__ import annotations

import re

__all__ = ["safe_name", "unique_names"]

_UNSAFE = re.compile(r"[^A-Za-z0-9._-]")
# Names Windows refuses as file stems, whatever the extension.
_RESERVED = {"con", "prn", "aux", "nul", *(f"com{i}" for i in range(10)), *(f"lpt{i}" for i in range(10))}
_MAX_STEM = 100


def safe_name(name) -> str:
    """A file-name stem made from a user's name: one path component, portable.

    Every character outside ``[A-Za-z0-9._-]`` (path separators included)
    becomes ``_``; a leading dot becomes ``_`` too, so that ``..`` and hidden
    files cannot appear; Windows device names get a ``_`` prefix.
    """
    s = _UNSAFE.sub("_", str(name))
    s = re.sub(r"^\.", "_", s)[:_MAX_STEM] or "unnamed"
    if s.lower().split(".")[0] in _RESERVED:
        s = "_" + s
    return s


def unique_names(names) -> list[str]:
    """:func:`safe_name` of each name, made unique (case-insensitively, for macOS and Windows)."""
    out, taken = [], set()
    for name in names:
        base = safe_name(name)
        s, k = base, 2
        while s.lower() in taken:
            s, k = f"{base}_{k}", k + 1
        taken.add(s.lower())
        out.append(s)
    return out
