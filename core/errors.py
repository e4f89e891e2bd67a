"""The errors a run reports to the user: bad input, and a cancel (:mod:`core.failures` words any failure)."""

from __future__ import annotations

__all__ = ["DelightError", "Cancelled", "REPORTED", "is_expected"]


class DelightError(Exception):
    """Bad input or a failed step, with a message meant for the user.

    Raised before anything in the scene or on disk was changed.
    """


class Cancelled(Exception):
    """The user cancelled the run (``cancel()`` returned True).

    ``written`` is the output folder when the cancel (Ctrl+C) came after the new files were in place, and the
    message says so; else None: the output folder is as it was.
    """

    def __init__(self, message="cancelled", written=None):
        super().__init__(message)
        self.written = written


#: What a front end reports in words rather than as a traceback: bad input (a DelightError, or a ValueError
#: from the core's own checks of its arrays) and a cancel.
REPORTED = (DelightError, ValueError, Cancelled)


def is_expected(exc: BaseException) -> bool:
    """True for the failures a user can act on (bad input, a cancel, out of memory, a file system error).

    The others are bugs: their traceback is worth keeping (on the console, or with ``--debug``).
    """
    return isinstance(exc, (*REPORTED, KeyboardInterrupt, MemoryError, OSError))
