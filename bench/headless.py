"""Run the headless add-on (``python -m blender_addon``) in a fresh child process, timed, with its peak memory.

Shared by ``bench/accuracy.py`` and ``bench/speed.py``. One child per run, so
runs never inherit each other's peak memory or caches.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import threading
import time
from dataclasses import dataclass

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: Where a benchmark writes its record by default: the recorded runs that docs/measurements.md cites.
RESULTS = os.path.join(ROOT, "bench", "results")

__all__ = ["ROOT", "RESULTS", "Run", "run_headless", "machine", "commit"]


@dataclass
class Run:
    """One finished child run."""

    args: list
    out_dir: str
    returncode: int
    wall_s: float  # the whole process: Python start, bpy import, .blend load, pipeline
    peak_mb: float  # the child's ru_maxrss
    report: dict | None  # its report.json (None on failure)
    log: str  # stdout + stderr


def run_headless(blend, out_dir, *args, monitor=None) -> Run:
    """``python -m blender_addon BLEND --out OUT_DIR --overwrite ARGS``; wait, and measure it.

    ``monitor(process, log_path)``, if given, runs in a thread while the child runs (to sample its memory).
    """
    cmd = [sys.executable, "-m", "blender_addon", str(blend), "--out", str(out_dir), "--overwrite", *map(str, args)]
    # BLAS threads as a user has them: the tool keeps BLAS to one thread itself (core.parallel.blas_on_one_thread).
    env = dict(os.environ, PYTHONPATH=ROOT)
    env.pop("OPENBLAS_NUM_THREADS", None)
    os.makedirs(out_dir, exist_ok=True)
    log_path = os.path.join(out_dir, "run.log")
    t = time.perf_counter()
    with open(log_path, "w") as log:
        p = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
        if monitor is not None:
            threading.Thread(target=monitor, args=(p, log_path), daemon=True).start()
        # wait4 gives this child's own rusage (RUSAGE_CHILDREN would mix all children).
        _, status, usage = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t
    with open(log_path) as fh:
        text = fh.read()
    report = None
    rpath = os.path.join(out_dir, "report.json")
    if p.returncode == 0 and os.path.exists(rpath):
        with open(rpath) as fh:
            report = json.load(fh)
    return Run(
        args=cmd[2:],
        out_dir=str(out_dir),
        returncode=p.returncode,
        wall_s=wall,
        peak_mb=usage.ru_maxrss / 1024.0,
        report=report,
        log=text,
    )


def machine() -> str:
    """CPU model, core count, RAM: what a reader needs to compare times."""
    cpu = platform.processor() or "unknown CPU"
    try:
        with open("/proc/cpuinfo") as fh:
            cpu = next(line.split(":", 1)[1].strip() for line in fh if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    mem = ""
    try:
        with open("/proc/meminfo") as fh:
            kb = int(next(line.split()[1] for line in fh if line.startswith("MemTotal")))
        mem = f", {kb / 2**20:.0f} GB RAM"
    except (OSError, StopIteration, ValueError):
        pass
    return f"{cpu}, {os.cpu_count()} cores{mem}, {platform.system()} {platform.release()}"


def commit() -> str:
    """The short commit, with ``+dirty`` if tracked files differ from it."""
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = (
            subprocess.run(["git", "diff", "--quiet", "HEAD", "--", "core", "blender_addon"], cwd=ROOT).returncode != 0
        )
        return sha + ("+dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
