"""Progress and cancel, the same for every stage of a run and every front end.

A progress callback is ``progress(fraction, message="")`` with ``fraction`` in [0, 1]; a cancel callback is
``cancel() -> bool``. Each stage reports its own 0..1 through :func:`stage_progress`, which maps it into the
stage's share of the whole run (:data:`STAGES`); the stages call :func:`check_cancel` between steps. The command
lines print progress with :class:`ProgressPrinter`; the GUI operator draws it.
"""
from __future__ import annotations

import sys

from .errors import Cancelled

__all__ = ["STAGES", "stage_progress", "check_cancel", "ProgressPrinter"]

#: Share of the progress bar of each stage of a run, (start, end).
STAGES = {"gather": (0.0, 0.05), "bake": (0.05, 0.3), "solve": (0.3, 0.9), "fuse": (0.9, 0.95),
          "write": (0.95, 1.0)}


def stage_progress(progress, stage: str):
    """A progress callback for one stage of :data:`STAGES`, mapped into its share of the bar.

    Its messages are prefixed with the stage's name. With ``progress=None`` it does nothing.
    """
    lo, hi = STAGES[stage]

    def report(fraction=0.0, message=""):
        if progress is not None:
            progress(lo + (hi - lo) * min(max(float(fraction), 0.0), 1.0), f"{stage}: {message}" if message else stage)
    return report


def check_cancel(cancel) -> None:
    """Raise :class:`Cancelled` if ``cancel`` (a callable, or None) says so."""
    if cancel is not None and cancel():
        raise Cancelled("cancelled")


class ProgressPrinter:
    """A progress callback for a headless run: prints ``delight:  42.0% solve: ...`` lines.

    A line is printed when the message changes or the bar moves by ``step``.

    Parameters
    ----------
    stream : file, optional
        Where the lines go; default ``sys.stdout`` at the time of each line.
    step : float
        The least move of the bar that prints a line with an unchanged message.
    """

    def __init__(self, stream=None, step: float = 0.05):
        self.stream, self.step = stream, step
        self._last = (None, -1.0)

    def __call__(self, fraction, message=""):
        fraction = float(fraction)
        if message != self._last[0] or abs(fraction - self._last[1]) >= self.step:
            print(f"delight: {100 * fraction:5.1f}% {message}", file=self.stream or sys.stdout, flush=True)
            self._last = (message, fraction)
