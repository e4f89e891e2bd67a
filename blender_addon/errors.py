"""The one error type the add-on reports to the user."""

__all__ = ["DelightError"]


class DelightError(Exception):
    """Bad input or a failed step, with a message meant for the user.

    Raised before anything in the scene or on disk was changed.
    """
