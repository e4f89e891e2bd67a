"""Progress and cancel, the same for every stage of a run and every front end.

A progress callback is ``progress(fraction, message="")`` with ``fraction`` in [0, 1]; a cancel callback is
``cancel() -> bool``. Each stage reports its own 0..1 through :func:`stage_progress`, which maps it into the
stage's share of the whole run: :data:`STAGES` by default, or the shares a run expects (:func:`spans`, from
:func:`core.plan.schedule` once the photos are read); the stages call :func:`check_cancel` between steps.
The command lines print progress with :class:`ProgressPrinter`; the GUI operator draws a bar from a
:class:`ProgressState`. Both add the time left that :class:`TimeLeft` estimates.
"""

from __future__ import annotations

import re
import sys
import threading
import time

from .errors import Cancelled

__all__ = [
    "sub_progress",
    "STAGES",
    "STAGE_NAMES",
    "spans",
    "shares",
    "piecewise",
    "StepCounter",
    "stage_progress",
    "stage_of",
    "check_cancel",
    "TimeLeft",
    "format_time_left",
    "short_message",
    "ProgressState",
    "ProgressPrinter",
]

#: Share of the progress bar of each stage of a run, (start, end), before the run's own (:func:`spans`).
STAGES = {"gather": (0.0, 0.05), "bake": (0.05, 0.3), "solve": (0.3, 0.9), "fuse": (0.9, 0.95), "write": (0.95, 1.0)}
#: Every stage a run may have, in order: with ``detail`` when the albedo is made again from the full-resolution
#: photos (:mod:`core.texture.detail`) after a solve of the lighting alone.
STAGE_NAMES = ("gather", "bake", "solve", "fuse", "detail", "write")


def spans(seconds: dict) -> dict:
    """The bar's ``(start, end)`` of each stage, for stages that are expected to take ``seconds`` each, in order.

    The gather keeps its share of :data:`STAGES` (the bar shows it before the photos, and so the run's size,
    are known); the other stages share the rest of the bar in proportion to their seconds, so that a stage's
    rate of progress predicts the time left (:class:`TimeLeft`).
    """
    return {"gather": STAGES["gather"], **shares(seconds, STAGES["gather"][1], 1.0)}


def shares(seconds: dict, start: float = 0.0, end: float = 1.0) -> dict:
    """``(lo, hi)`` of each part of ``start``..``end``, for parts expected to take ``seconds`` each, in order:
    consecutive, in proportion to the seconds, the last ending at ``end``."""
    total = sum(max(float(s), 0.0) for s in seconds.values())
    out, at = {}, start
    for i, (part, s) in enumerate(seconds.items()):
        hi = end if i == len(seconds) - 1 else at + (end - start) * max(float(s), 0.0) / max(total, 1e-30)
        out[part] = (at, hi)
        at = hi
    return out


def sub_progress(progress, lo: float, hi: float, label: str = ""):
    """A progress callback mapped into ``(lo, hi)`` of ``progress``'s bar, its messages prefixed ``"label: "``.

    With ``progress=None`` it does nothing.
    """

    def report(fraction=0.0, message=""):
        if progress is not None:
            text = (f"{label}: {message}" if message else label) if label else message
            progress(lo + (hi - lo) * min(max(float(fraction), 0.0), 1.0), text)

    return report


def piecewise(progress, points):
    """A progress callback whose fraction ``x`` reaches ``progress`` as ``y``, linear between the ``(x, y)``
    ``points`` (increasing in both, from ``x`` 0 to 1): a callee's own shares of its bar redrawn to the caller's.
    """
    xs, ys = zip(*points)

    def report(fraction=0.0, message=""):
        if progress is None:
            return
        x = min(max(float(fraction), xs[0]), xs[-1])
        i = next(k for k in range(1, len(xs)) if x <= xs[k])
        t = (x - xs[i - 1]) / (xs[i] - xs[i - 1]) if xs[i] > xs[i - 1] else 1.0
        progress(ys[i - 1] + t * (ys[i] - ys[i - 1]), message)

    return report


class StepCounter:
    """Tells ``progress`` the share of ``total`` steps done, as threads :meth:`add` them (``message`` unchanged)."""

    def __init__(self, progress, total: int, message: str = ""):
        self.progress, self.total, self.message = progress, max(int(total), 1), message
        self.done = 0
        self._lock = threading.Lock()

    def add(self, steps: int = 1) -> None:
        with self._lock:
            self.done = min(self.done + int(steps), self.total)
            if self.progress is not None:
                self.progress(self.done / self.total, self.message)


def stage_progress(progress, stage: str, stages: dict | None = None):
    """A progress callback for one stage of ``stages`` (default :data:`STAGES`), mapped into its share of the bar.

    Its messages are prefixed with the stage's name (:func:`sub_progress`). With ``progress=None`` it does nothing.
    """
    lo, hi = (STAGES if stages is None else stages)[stage]
    return sub_progress(progress, lo, hi, stage)


def stage_of(message: str) -> str | None:
    """The stage a :func:`stage_progress` message names (``"solve: iteration 3"`` -> ``"solve"``), or None."""
    head = message.split(":", 1)[0].strip() if message else ""
    return head if head in STAGE_NAMES else None


def check_cancel(cancel) -> None:
    """Raise :class:`Cancelled` if ``cancel`` (a callable, or None) says so."""
    if cancel is not None and cancel():
        raise Cancelled("cancelled")


class TimeLeft:
    """An estimate of the seconds a run has left, from its progress fraction over time.

    Feed it ``(fraction, time)`` pairs with :meth:`update`. The rate is measured from the first pair (so time
    spent before the estimate started, such as the GUI's bake, does not count), and when the pairs name their
    stage, from the first pair after the gather: the gather's share of the bar is drawn before the photos are
    read, so it says nothing of how long the rest takes, and there is no estimate during it. The other stages'
    shares are their expected durations (:func:`spans`), so the rate of the run so far holds for the rest,
    through the stages' uneven steps (a solve's first seconds without an iteration). The estimate is smoothed
    over the updates, so that one quick or slow step does not make it jump.

    Parameters
    ----------
    warmup : float
        Seconds after the first pair before there is an estimate.
    min_progress : float
        The least progress (a fraction of the whole run) since the first pair before there is an estimate.
    smoothing : float
        Weight of each new raw estimate, in (0, 1]; 1 does not smooth.
    """

    def __init__(self, warmup: float = 2.0, min_progress: float = 0.01, smoothing: float = 0.3):
        if not 0.0 < smoothing <= 1.0:
            raise ValueError(f"smoothing must be in (0, 1], got {smoothing}")
        self.warmup, self.min_progress, self.smoothing = warmup, min_progress, smoothing
        self._start = None  # (fraction, time) of the first pair (after the gather)
        self._stage = None  # the stage of that pair
        self._estimate = None  # seconds left at self._time
        self._time = None

    def update(self, fraction: float, now: float, stage: str | None = None) -> float | None:
        """Take the run's ``fraction`` (0..1) at time ``now`` (seconds) in ``stage`` (a name, or None); return
        :meth:`estimate` at ``now``. The first pair after the gather starts the rate's measurement again.
        """
        fraction, now = min(max(float(fraction), 0.0), 1.0), float(now)
        if self._start is None or (self._stage == "gather" and stage != "gather"):
            self._start = (fraction, now)
            self._stage = stage
        f0, t0 = self._start
        if fraction >= 1.0:
            self._estimate, self._time = 0.0, now
        elif stage != "gather" and now - t0 >= self.warmup and fraction - f0 >= self.min_progress and fraction > f0:
            raw = (now - t0) * (1.0 - fraction) / (fraction - f0)
            if self._estimate is None:
                self._estimate = raw
            else:  # the last estimate, aged to now, moved towards the new one
                aged = max(self._estimate - (now - self._time), 0.0)
                self._estimate = aged + self.smoothing * (raw - aged)
            self._time = now
        return self.estimate(now)

    def estimate(self, now: float) -> float | None:
        """Seconds left at ``now`` (counting down since the last update), or None while there is no estimate."""
        if self._estimate is None:
            return None
        return max(self._estimate - max(float(now) - self._time, 0.0), 0.0)


def format_time_left(seconds: float | None) -> str:
    """``"about 35 s left"``, ``"about 4 min left"``; ``""`` for None and at the end (under a second)."""
    if seconds is None or seconds < 1:
        return ""
    if seconds < 10:
        return "a few seconds left"
    if seconds < 60:
        return f"about {5 * round(seconds / 5)} s left"
    minutes = round(seconds / 60)
    if minutes < 60:
        return f"about {minutes} min left"
    return f"about {minutes // 60} h {minutes % 60:02d} min left"


# The solver's messages (core.solve.solver): "iteration 12, energy 3.2", each coarse level prefixing its own
# "coarse level 256: ", and each stage of a two-stage solve (core.solve.stages) "lighting: " or "albedo: ".
_ENERGY = re.compile(r"(iteration \d+), energy \S+")
_COARSE = re.compile(r"(?:coarse level \S+: )+")
_MAIN_ITERATION = re.compile(r"^(solve: (?:lighting: |albedo: )?)(iteration \d+)\b")


def short_message(message: str, max_iter: int | None = None) -> str:
    """A progress message shortened for a progress bar.

    The solver's ``"solve: coarse level 256: coarse level 128: iteration 3, energy 1.2"`` becomes
    ``"solve: coarse level 128, iteration 3"``, and ``"solve: iteration 12, energy 1.2"`` becomes
    ``"solve: iteration 12/40"`` with ``max_iter=40`` (the most iterations at the full size; coarse levels have
    their own). Other messages are returned as they are.
    """
    text = _ENERGY.sub(r"\1", message)
    text = _COARSE.sub(lambda m: m.group(0).split(": ")[-2] + ", ", text)
    if max_iter:
        text = _MAIN_ITERATION.sub(lambda m: f"{m.group(1)}{m.group(2)}/{int(max_iter)}", text)
    return text


class ProgressState:
    """A progress callback that keeps the latest fraction and message, for a progress bar.

    Parameters
    ----------
    max_iter : int, optional
        The run's most iterations at the full size, shown as "iteration 12/40".
    clock : callable() -> float
        The time in seconds (``time.monotonic``).
    """

    def __init__(self, max_iter: int | None = None, clock=time.monotonic):
        self.max_iter, self.clock = max_iter, clock
        self.fraction, self.message = 0.0, ""
        self.time_left = TimeLeft()

    def __call__(self, fraction, message=""):
        self.fraction = min(max(float(fraction), 0.0), 1.0)
        if message:
            self.message = message
        self.time_left.update(self.fraction, self.clock(), stage_of(self.message))

    def bar(self) -> tuple[float, str]:
        """What the bar shows: ``(factor, text)``, e.g. ``(0.62, "solve: iteration 12/40 — about 35 s left")``."""
        text = short_message(self.message, self.max_iter) or "starting"
        left = format_time_left(self.time_left.estimate(self.clock()))
        return self.fraction, f"{text} — {left}" if left else text


class ProgressPrinter:
    """A progress callback for a headless run: prints ``delight:  42.0% solve: ... (about 35 s left)`` lines.

    A line is printed when the message changes or the bar moves by ``step``; it ends with the time left once
    :class:`TimeLeft` has an estimate.

    Parameters
    ----------
    stream : file, optional
        Where the lines go; default ``sys.stdout`` at the time of each line.
    step : float
        The least move of the bar that prints a line with an unchanged message.
    clock : callable() -> float
        The time in seconds (``time.monotonic``).
    """

    def __init__(self, stream=None, step: float = 0.05, clock=time.monotonic):
        self.stream, self.step, self.clock = stream, step, clock
        self.time_left = TimeLeft()
        self._last = (None, -1.0)

    def __call__(self, fraction, message=""):
        fraction = float(fraction)
        left = format_time_left(self.time_left.update(fraction, self.clock(), stage_of(message)))
        if message != self._last[0] or abs(fraction - self._last[1]) >= self.step:
            print(
                f"delight: {100 * fraction:5.1f}% {message}" + (f" ({left})" if left else ""),
                file=self.stream or sys.stdout,
                flush=True,
            )
            self._last = (message, fraction)
