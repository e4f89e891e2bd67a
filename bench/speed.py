"""End-to-end speed: 13 photos of 960x540 onto a 2048^2 texture, time per stage and peak memory.

Run by hand (not a test)::

    .venv/bin/python bench/speed.py [--work build/bench/speed] [--json bench/results/speed.json] [--method texture]
        [--threads N] [--scaling]
    .venv/bin/python bench/speed.py --case 13x1mp|13x12mp|50x24mp|150x12mp [--case-args '--working-res 0.5']

``--case`` runs one of the large-photo cases of :mod:`bench.full_res` instead.

It renders ``lambert_sky`` at 960x540 with 13 cameras and few samples once (``make_fixtures.generate``; a
speed test, not an accuracy one; kept in ``--work`` and reused), then runs the headless add-on with default
parameters and ``--texture-size 2048`` in a fresh child process (:mod:`bench.headless`) and prints the time of
each stage from its ``report.json``, the whole process's wall time (Python start, ``import bpy`` and loading the
.blend included) and its peak resident memory, with the peak at the end of each stage and the solve's parts.
``--scaling`` runs it at 1, 2 and ``os.cpu_count()`` threads (``--threads``) and prints the speed-up.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import shlex
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from bench.headless import RESULTS, ROOT, commit, machine, run_headless  # noqa: E402

RESOLUTION = (960, 540)
N_CAMERAS = 13
SAMPLES = 4
TEXTURE = 2048
TARGET_S = 30.0
STAGES = ("gather", "bake", "align", "solve", "fuse", "write")


def render_scene(work):
    """The 960x540 scene in ``work/lambert_sky`` (rendered in a child process unless already there)."""
    blend = os.path.join(work, "lambert_sky", "scene.blend")
    record = os.path.join(work, "lambert_sky", "scene.json")
    if os.path.exists(blend) and os.path.exists(record):
        with open(record) as fh:
            r = json.load(fh)
        if r["render"]["resolution"] == list(RESOLUTION) and len(r["cameras"]) == N_CAMERAS:
            return blend
    code = (
        "import sys; sys.path.insert(0, 'blend_fixtures'); import bpy; import make_fixtures as m; "
        f"m.generate('lambert_sky', {work!r}, resolution={RESOLUTION!r}, n_cameras={N_CAMERAS}, "
        f"samples={SAMPLES}, view_gt=False)"
    )
    print(f"rendering {N_CAMERAS} x {RESOLUTION[0]}x{RESOLUTION[1]} at {SAMPLES} samples into {work} ...", flush=True)
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=True, env=dict(os.environ, PYTHONPATH=ROOT))
    return blend


def solve_parts(info: dict) -> dict:
    """Seconds of the solve's parts (``solver_info``): occlusion, lighting stage, albedo stage build and iterations."""
    parts = {"occlusion": info.get("occlusion_seconds")}
    light = info.get("lighting_stage") or {}
    parts["lighting stage"] = light.get("seconds")
    parts["albedo build"] = info.get("build_seconds")
    parts["albedo iterations"] = info.get("solve_seconds")
    return {k: float(v) for k, v in parts.items() if v is not None}


def run_once(blend, work, method, threads=None) -> dict:
    """One headless run onto the 2048^2 texture; its stage times, peaks and whole-process figures."""
    extra = [] if threads is None else ["--threads", threads]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    r = run_headless(
        blend,
        os.path.join(work, "out_" + method),
        "--object",
        "Subject",
        "--texture-size",
        TEXTURE,
        "--method",
        method,
        *extra,
    )
    if r.returncode != 0:
        raise SystemExit(f"error: the run failed:\n{r.log[-3000:]}")
    rep = r.report
    times = {k: float(rep["times_s"].get(k, 0.0)) for k in STAGES}
    return {
        "threads": threads,
        "photos": len(rep["cameras"]),
        "photo_size": rep["cameras"][0]["size"],
        "iterations": rep["iterations"],
        "times_s": times,
        "stage_peak_mb": rep.get("peak_mb", {}),
        "solve_parts_s": solve_parts(rep.get("solver_info", {})),
        "stages_total_s": sum(times.values()),
        "process_wall_s": r.wall_s,
        "peak_mb": r.peak_mb,
        "load_before": load,
        "load_after": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
        "solver_info": rep.get("solver_info", {}),
    }


def print_run(row):
    times, peaks = row["times_s"], row["stage_peak_mb"]
    print("| " + " | ".join(STAGES) + " | stages total | process (wall) | peak memory |")
    print("|" + "---|" * (len(STAGES) + 3))
    print(
        "| "
        + " | ".join(f"{times[k]:.1f} s" for k in STAGES)
        + f" | {row['stages_total_s']:.1f} s | {row['process_wall_s']:.1f} s | {row['peak_mb']:.0f} MB |"
    )
    if peaks:
        print("| " + " | ".join(f"{peaks[k]:.0f} MB" if peaks.get(k) else "" for k in STAGES) + " | | | |")
    print("\nsolve: " + ", ".join(f"{k} {v:.1f} s" for k, v in row["solve_parts_s"].items()))


def print_scaling(rows):
    """Stage times at each thread count, and the speed-up over one thread."""
    base = rows[0]
    print("\n| threads | " + " | ".join(STAGES) + " | process (wall) | speed-up | peak memory | load |")
    print("|" + "---|" * (len(STAGES) + 5))
    for row in rows:
        times = row["times_s"]
        print(
            f"| {row['threads'] or 'all'} | "
            + " | ".join(f"{times[k]:.1f} s" for k in STAGES)
            + f" | {row['process_wall_s']:.1f} s | {base['process_wall_s'] / row['process_wall_s']:.2f}x"
            + f" | {row['peak_mb']:.0f} MB | {row['load_before']:.1f} |"
        )


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--work", default=None, help="default build/bench/speed (build/bench/full_res for --case)")
    p.add_argument(
        "--json", default=None, help="default bench/results/speed.json (bench/results/speed_<case>.json for --case)"
    )
    p.add_argument("--method", default="texture", choices=["texture", "image", "project"])
    p.add_argument("--threads", type=int, help="threads of the run (default: every core)")
    p.add_argument(
        "--scaling",
        action="store_true",
        help="run at 1, 2 and os.cpu_count() threads, then the default, and print the speed-up",
    )
    p.add_argument(
        "--case",
        default="2k",
        choices=["2k", "13x1mp", "13x12mp", "50x24mp", "150x12mp"],
        help="2k: this scene; the others: large photos (bench/full_res.py)",
    )
    p.add_argument(
        "--case-args", default="", help="more arguments of a --case's headless run, e.g. '--working-res 0.5'"
    )
    a = p.parse_args(argv)
    if a.case != "2k":
        from bench.full_res import main as full_res

        return full_res(a.case, a.work, a.json, shlex.split(a.case_args))
    a.work = a.work or os.path.join(ROOT, "build", "bench", "speed")
    a.json = a.json or os.path.join(RESULTS, "speed.json")
    os.makedirs(a.work, exist_ok=True)
    blend = render_scene(os.path.abspath(a.work))
    started = datetime.datetime.now().isoformat(timespec="seconds")
    # Scaling: 1, 2 and the machine's count, then the default (every core, a thread per colour channel).
    counts = [*sorted({1, 2, os.cpu_count() or 1}), None] if a.scaling else [a.threads]
    rows = [run_once(blend, a.work, a.method, n) for n in counts]
    row = rows[-1]
    result = {
        "started": started,
        "commit": commit(),
        "machine": machine(),
        "method": a.method,
        "texture": TEXTURE,
        "target_s": TARGET_S,
        **row,
    }
    if a.scaling:
        result["scaling"] = [{k: v for k, v in r.items() if k != "solver_info"} for r in rows]
    os.makedirs(os.path.dirname(os.path.abspath(a.json)), exist_ok=True)
    with open(a.json, "w") as fh:
        json.dump(result, fh, indent=1)
    print(f"\ncommit {result['commit']}, {result['machine']}, {started}, load average {row['load_before']:.1f}")
    print(
        f"{row['photos']} photos of {row['photo_size'][0]}x{row['photo_size'][1]} -> "
        f"{TEXTURE}^2 texture, method {a.method}, {row['iterations']} iterations, "
        f"threads {row['threads'] or 'all'}\n"
    )
    print_run(row)
    if a.scaling:
        print_scaling(rows)
    verdict = "meets" if row["process_wall_s"] <= TARGET_S else "misses"
    print(f"\n{verdict} the target of {TARGET_S:.0f} s end to end; wrote {a.json}")


if __name__ == "__main__":
    main()
