"""Large photos end to end: 13 x 1 MP, 13 x 12 MP, 50 x 24 MP and 150 x 12 MP, time and peak memory per stage.

Run through ``bench/speed.py --case 13x1mp|13x12mp|50x24mp`` (by hand; the tests do not run it).

Each case's scene is built once under ``build/bench/full_res/<case>/`` (not in git) and reused:

1. ``lambert_sky`` rendered with the case's cameras at a small size and 4 samples (``make_fixtures.generate``,
   a child process);
2. in a child Blender: the mesh gets a Simple subdivision modifier (the same surface with 4^k times the
   triangles), the render size becomes the photo size, and each render is resampled (bilinear) up to the photo
   size and saved as an 8-bit sRGB JPEG, which becomes its camera's background image. The photos are cheap and
   smooth: a speed and memory test, not an accuracy one.

Then the headless add-on runs on it with default settings and the case's texture size in a fresh child process
(:func:`bench.headless.run_headless`), while a thread samples the child's resident memory twice a second and
puts each sample on the stage its progress lines name ("load" before the first: Python, ``import bpy``, the
.blend). The run is stopped if the machine's available memory falls below :data:`MIN_AVAILABLE`.
"""

from __future__ import annotations

import datetime
import json
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from bench.headless import RESULTS, ROOT, commit, machine, run_headless  # noqa: E402

__all__ = ["CASES", "Case", "build_scene", "Monitor", "run_case", "main"]


@dataclass(frozen=True)
class Case:
    cameras: int
    render: tuple  # size rendered by Cycles
    photo: tuple  # size of the JPEG photos (the render resampled)
    levels: int  # Simple subdivision levels on lambert_sky's 16384 triangles
    texture: int


CASES = {
    "13x1mp": Case(13, (1152, 864), (1152, 864), 2, 8192),
    "13x12mp": Case(13, (1000, 750), (4000, 3000), 2, 4096),
    "50x24mp": Case(50, (600, 400), (6000, 4000), 3, 8192),
    "150x12mp": Case(150, (500, 375), (4000, 3000), 2, 4096),
}
SAMPLES = 4
BASE_TRIANGLES = 16384
#: Below this much available memory on the machine the run is stopped (other jobs share it).
MIN_AVAILABLE = 3 * 2**30
STAGES = ("load", "gather", "bake", "align", "solve", "fuse", "detail", "write")
_STAGE = re.compile(r"^delight:\s+[\d.]+% (\w+)")


def _child(code, **env):
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=True, env=dict(os.environ, PYTHONPATH=ROOT, **env))


def build_scene(name, work):
    """The case's .blend (built in child processes unless already there); returns its path."""
    case = CASES[name]
    work = os.path.abspath(work)
    scene_dir = os.path.join(work, name)
    blend = os.path.join(scene_dir, "scene.blend")
    record = os.path.join(scene_dir, "bench.json")
    if os.path.exists(blend) and os.path.exists(record):
        with open(record) as fh:
            if json.load(fh) == case.__dict__ | {"render": list(case.render), "photo": list(case.photo)}:
                return blend
    render_dir = os.path.join(work, "renders", f"{case.cameras}x{case.render[0]}x{case.render[1]}")
    src = os.path.join(render_dir, "lambert_sky", "scene.blend")
    if not os.path.exists(src):
        print(f"rendering {case.cameras} x {case.render[0]}x{case.render[1]} at {SAMPLES} samples ...", flush=True)
        _child(
            "import sys, bpy; sys.path.insert(0, 'blend_fixtures'); import make_fixtures as m; "
            f"m.generate('lambert_sky', {render_dir!r}, resolution={case.render!r}, n_cameras={case.cameras}, "
            f"samples={SAMPLES}, view_gt=False)"
        )
    print(f"building {name}: photos of {case.photo[0]}x{case.photo[1]}, subdivision level {case.levels} ...")
    os.makedirs(os.path.join(scene_dir, "photos"), exist_ok=True)
    _child(f"from bench.full_res import _build; _build({src!r}, {scene_dir!r}, {name!r})")
    with open(record, "w") as fh:
        json.dump(case.__dict__ | {"render": list(case.render), "photo": list(case.photo)}, fh)
    return blend


def _build(src, scene_dir, name):
    """In a child with bpy: the subdivided mesh and the resampled JPEG photos, saved as ``scene_dir/scene.blend``."""
    import bpy
    import numpy as np
    from PIL import Image
    from scipy import ndimage

    from core.io.exr import read_exr
    from core.io.photos import linear_to_srgb

    case = CASES[name]
    w, h = case.photo
    bpy.ops.wm.open_mainfile(filepath=src)
    scene = bpy.context.scene
    mod = bpy.data.objects["Subject"].modifiers.new("bench subdivision", "SUBSURF")
    mod.subdivision_type = "SIMPLE"
    mod.levels = mod.render_levels = case.levels
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = w, h, 100
    for cam in sorted((o for o in scene.objects if o.type == "CAMERA"), key=lambda o: o.name):
        bg = cam.data.background_images[0]
        old = bg.image
        rgb = read_exr(bpy.path.abspath(old.filepath))[0][..., :3]
        if rgb.shape[:2] != (h, w):
            rgb = ndimage.zoom(rgb, (h / rgb.shape[0], w / rgb.shape[1], 1), order=1, grid_mode=True, mode="nearest")
        path = os.path.join(scene_dir, "photos", cam.name + ".jpg")
        Image.fromarray(np.round(255 * linear_to_srgb(rgb)).astype(np.uint8)).save(path, quality=92)
        del rgb
        img = bpy.data.images.load(path, check_existing=False)
        img.colorspace_settings.name = "sRGB"
        bg.image = img
        bpy.data.images.remove(old)
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(scene_dir, "scene.blend"), relative_remap=True)


class Monitor:
    """Samples a child's resident memory per stage; stops it when the machine runs short of memory."""

    def __init__(self, period=0.5, min_available=MIN_AVAILABLE):
        self.period, self.min_available = period, min_available
        self.peak_mb = {}
        self.stopped = None
        self.least_available_mb = None

    @staticmethod
    def _status(pid):
        """VmRSS in kB and the state letter, or None once the process is gone."""
        try:
            with open(f"/proc/{pid}/status") as fh:
                fields = dict(line.split(":", 1) for line in fh if ":" in line)
        except OSError:
            return None
        rss = int(fields.get("VmRSS", "0 kB").split()[0])
        return rss, fields.get("State", "?").split()[0]

    @staticmethod
    def _available():
        with open("/proc/meminfo") as fh:
            return next(int(line.split()[1]) for line in fh if line.startswith("MemAvailable")) * 1024

    def __call__(self, process, log_path):
        stage = "load"
        with open(log_path) as log:
            while True:
                for line in log.readlines():
                    m = _STAGE.match(line)
                    if m:
                        stage = m.group(1)
                status = self._status(process.pid)
                if status is None or status[1] == "Z":
                    return
                self.peak_mb[stage] = max(self.peak_mb.get(stage, 0.0), status[0] / 1024)
                avail = self._available()
                mb = avail / 2**20
                self.least_available_mb = mb if self.least_available_mb is None else min(self.least_available_mb, mb)
                if avail < self.min_available:
                    self.stopped = f"stopped in {stage}: {mb:.0f} MB available on the machine"
                    os.kill(process.pid, signal.SIGTERM)  # not process.terminate(): it would reap the child
                    return
                time.sleep(self.period)


def run_case(name, work, json_path, extra=()):
    """Build (or reuse) the case's scene, run it, print and write the results.

    ``extra``: more arguments of the headless run (``python -m blender_addon``), after the case's own.
    """
    case = CASES[name]
    work = os.path.abspath(work)
    blend = build_scene(name, work)
    started = datetime.datetime.now().isoformat(timespec="seconds")
    sha = commit()  # the code the child runs
    mon = Monitor()
    t = time.perf_counter()
    r = run_headless(
        blend,
        os.path.join(work, name, "out"),
        "--object",
        "Subject",
        "--texture-size",
        case.texture,
        *extra,
        monitor=mon,
    )
    if r.returncode != 0:
        why = mon.stopped or f"the run failed:\n{r.log[-3000:]}"
        raise SystemExit(f"error: {why} (after {time.perf_counter() - t:.0f} s, peak {r.peak_mb:.0f} MB)")
    rep = r.report
    times = {k: float(rep["times_s"][k]) for k in STAGES if k in rep["times_s"]}
    cam = rep["cameras"][0]
    result = {
        "case": name,
        "started": started,
        "commit": sha,
        "machine": machine(),
        "photos": len(rep["cameras"]),
        "photo_size": cam["full_size"] or cam["size"],
        "working_size": cam["size"],
        "triangles": BASE_TRIANGLES * 4**case.levels,
        "texture": case.texture,
        "extra_args": list(extra),
        "iterations": rep["iterations"],
        "detail": rep["solver_info"].get("detail"),
        "times_s": times,
        "stages_total_s": sum(times.values()),
        "process_wall_s": r.wall_s,
        "peak_mb": r.peak_mb,
        "stage_peak_mb": {k: round(v) for k, v in mon.peak_mb.items()},
        "least_available_mb": mon.least_available_mb,
        "solver_info": {k: v for k, v in rep["solver_info"].items() if k != "elapsed"},
    }
    os.makedirs(os.path.dirname(os.path.abspath(json_path)), exist_ok=True)
    with open(json_path, "w") as fh:
        json.dump(result, fh, indent=1)
    size = result["photo_size"]
    print(f"\ncommit {result['commit']}, {result['machine']}, {started}")
    print(
        f"{result['photos']} photos of {size[0]}x{size[1]} (solved at {cam['size'][0]}x{cam['size'][1]}), "
        f"{result['triangles']} triangles -> {case.texture}^2, {rep['iterations']} iterations\n"
    )
    cols = [k for k in STAGES if k in times or k in mon.peak_mb]
    print("| | " + " | ".join(cols) + " | process |")
    print("|" + "---|" * (len(cols) + 2))
    print("| time | " + " | ".join(f"{times[k]:.0f} s" if k in times else "" for k in cols) + f" | {r.wall_s:.0f} s |")
    print(
        "| peak memory | "
        + " | ".join(f"{mon.peak_mb[k] / 1024:.1f} GB" if k in mon.peak_mb else "" for k in cols)
        + f" | {r.peak_mb / 1024:.1f} GB |"
    )
    print(f"\nwrote {json_path}")
    return result


def main(name, work=None, json_path=None, extra=()):
    work = work or os.path.join(ROOT, "build", "bench", "full_res")
    os.makedirs(work, exist_ok=True)
    return run_case(name, work, json_path or os.path.join(RESULTS, f"speed_{name}.json"), extra)
