"""The errors a run reports to the user: bad input, and a cancel; and how a command line reports them."""

__all__ = ["DelightError", "Cancelled", "REPORTED", "report_failure"]


class DelightError(Exception):
    """Bad input or a failed step, with a message meant for the user.

    Raised before anything in the scene or on disk was changed.
    """


class Cancelled(Exception):
    """The user cancelled the run (``cancel()`` returned True)."""


#: What a front end reports in words rather than as a traceback: bad input (a DelightError, or a ValueError
#: from the core's own checks of its arrays) and a cancel.
REPORTED = (DelightError, ValueError, Cancelled)


def report_failure(exc: BaseException, stream) -> int:
    """Print the one line for a failed command-line run on ``stream`` and return the exit status.

    A cancel (:class:`Cancelled`, Ctrl+C) gives ``delight: interrupted; nothing was written`` and 130;
    anything else ``error: <message>`` and 1.
    """
    if isinstance(exc, (Cancelled, KeyboardInterrupt)):
        print("delight: interrupted; nothing was written", file=stream, flush=True)
        return 130
    print(f"error: {exc}", file=stream, flush=True)
    return 1
