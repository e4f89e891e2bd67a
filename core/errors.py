"""The errors a run reports to the user: bad input, and a cancel."""

__all__ = ["DelightError", "Cancelled"]


class DelightError(Exception):
    """Bad input or a failed step, with a message meant for the user.

    Raised before anything in the scene or on disk was changed.
    """


class Cancelled(Exception):
    """The user cancelled the run (``cancel()`` returned True)."""
