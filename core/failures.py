"""The one line that tells the user why a run failed, in the words of the front end that reports it."""

from __future__ import annotations

import errno
import traceback

from .errors import Cancelled, DelightError
from .options import OPTIONS

__all__ = ["DEBUG_HELP", "failure_message", "report_failure"]

#: Help of the command lines' ``--debug``.
DEBUG_HELP = "on a failure, print the traceback too (for a bug report)"


def _setting(name: str, front: str) -> str:
    """A setting as a message names it: "the working resolution (--working-res)", or its label in the panel."""
    o = OPTIONS[name]
    if front == "cli":
        return f"the {o.label.split(' (')[0].lower()} ({o.flag})"
    return f"the {o.label}"


def _os_error(exc: OSError) -> str:
    reasons = {
        errno.EACCES: "permission denied",
        errno.EPERM: "permission denied",
        errno.ENOSPC: "the disk is full",
        errno.EROFS: "the file system is read-only",
        errno.ENOENT: "no such file or folder",
    }
    if hasattr(errno, "EDQUOT"):
        reasons[errno.EDQUOT] = "the disk quota is exceeded"
    why = reasons.get(exc.errno) or exc.strerror or str(exc) or type(exc).__name__
    return f"{exc.filename}: {why}" if exc.filename is not None else why


def failure_message(exc: BaseException, front: str = "cli") -> str:
    """The one line that tells the user why a run failed (without the ``error:`` prefix).

    Parameters
    ----------
    exc : BaseException
    front : {"cli", "panel", "core"}
        Who reports it: the add-on's command line names settings by their flags and the panel by their labels
        ("core", ``python -m core``, solves a bundle made before); an unexpected error points to ``--debug``,
        or in the panel to the system console, for its traceback.
    """
    if isinstance(exc, (Cancelled, KeyboardInterrupt)):
        return str(exc) if getattr(exc, "written", None) else "interrupted; nothing was written"
    if isinstance(exc, MemoryError):
        if front == "core":
            return "out of memory: solve a smaller bundle (fewer or smaller photos, a smaller texture)"
        lower = (_setting(name, front) for name in ("working_res_mp", "working_total_mp", "texture_size"))
        return "out of memory: lower {}, {} or {}".format(*lower)
    if isinstance(exc, (DelightError, ValueError)):
        return str(exc)
    if isinstance(exc, OSError):
        return _os_error(exc)
    where = "the traceback is in the system console" if front == "panel" else "run with --debug for the traceback"
    text = str(exc).strip().splitlines()
    return f"unexpected {type(exc).__name__}{': ' + text[0] if text else ''} ({where})"


def report_failure(exc: BaseException, stream, debug: bool = False, front: str = "cli") -> int:
    """Print the one line for a failed command-line run on ``stream`` and return the exit status.

    A cancel (:class:`Cancelled`, Ctrl+C) gives ``delight: interrupted; nothing was written`` (or what was
    written) and 130; anything else ``error: <message>`` (:func:`failure_message` for ``front``) and 1. With
    ``debug`` the traceback of a failure comes first; without it no traceback is printed.
    """
    if isinstance(exc, (Cancelled, KeyboardInterrupt)):
        print(f"delight: {failure_message(exc)}", file=stream, flush=True)
        return 130
    if debug:
        traceback.print_exception(type(exc), exc, exc.__traceback__, file=stream)
    print(f"error: {failure_message(exc, front)}", file=stream, flush=True)
    return 1
