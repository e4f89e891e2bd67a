"""The process's memory: its peak so far, and giving the freed memory back to the system."""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

__all__ = ["peak_mb", "release_free_memory"]


def peak_mb() -> float | None:
    """The process's peak resident memory so far, in MB (None where the system does not say)."""
    try:
        import resource
    except ImportError:  # Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 1024  # bytes on macOS, KiB elsewhere


def _malloc_trim():
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
    except (OSError, AttributeError):  # not glibc (musl has no malloc_trim)
        return None


_TRIM = _malloc_trim()


def release_free_memory() -> None:
    """Give the pages that freed arrays leave inside glibc's heaps back to the system (elsewhere: nothing).

    The solver's threads free arrays of tens of MB every iteration; glibc keeps the freed pages of its
    per-thread heaps, so the process grows by as much again as it holds (docs/measurements.md).
    """
    if _TRIM is not None:
        _TRIM(0)
