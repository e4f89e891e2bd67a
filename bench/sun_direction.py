"""How well :func:`core.geometry.sun.find_sun` finds the sun, against the fixtures' truth.

Run by hand (not a test)::

    .venv/bin/python bench/sun_direction.py [--only photo_sun rock_photo] [--json bench/results/sun_direction.json]

Each fixture is baked once and cached as in ``bench/accuracy_quick.py``. For every fixture the search runs on
its photos and bakes; where ``scene.json`` gives a sun (``lighting.direction_to_sun``) the angle between it and
the direction found is printed, and for every fixture the best correlation, so that scenes with and without a
sun can be compared.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from bench.accuracy import fixtures  # noqa: E402
from bench.accuracy_quick import load_case  # noqa: E402
from bench.headless import ROOT, commit, machine  # noqa: E402
from core.geometry.sun import find_sun  # noqa: E402


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--fixtures", default=os.path.join(ROOT, "blend_fixtures"))
    p.add_argument("--only", nargs="*", help="fixture names (default: all)")
    p.add_argument("--directions", type=int, default=400)
    p.add_argument("--refine", type=int, default=30)
    p.add_argument("--max-pairs", type=int, default=0)
    p.add_argument("--resolution", type=int, default=256)
    p.add_argument("--json", help="write the rows here")
    args = p.parse_args(argv)
    rows = []
    for name, fixture_dir in fixtures(args.fixtures):
        if args.only and name not in args.only:
            continue
        record, inputs, bakes = load_case(name, fixture_dir)
        t = time.perf_counter()
        found = find_sun(
            [v.photo for v in inputs.views],
            [b.mask for b in bakes],
            [b.position for b in bakes],
            [b.normal for b in bakes],
            inputs.mesh.tri_pos,
            n_directions=args.directions,
            n_refine=args.refine,
            max_pairs=args.max_pairs,
            resolution=args.resolution,
        )
        seconds = time.perf_counter() - t
        true = record.get("lighting", {}).get("direction_to_sun")
        angle = None
        if true is not None:
            w = np.asarray(true, np.float64) / np.linalg.norm(true)
            angle = float(np.degrees(np.arccos(np.clip(found.direction @ w, -1.0, 1.0))))
        rows.append(
            {
                "fixture": name,
                "sun": true is not None,
                "direction": found.direction.round(4).tolist(),
                "correlation": found.score,
                "angle_to_truth_deg": angle,
                "seconds": seconds,
            }
        )
        where = "no single sun in scene.json" if angle is None else f"{angle:5.1f} deg from the true sun"
        print(f"{name:22s} correlation {found.score:.3f}  {where}  {seconds:.0f}s", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"commit": commit(), "machine": machine(), "rows": rows}, fh, indent=1)


if __name__ == "__main__":
    main()
