"""What any delighting could reach on each fixture: its photos divided by Cycles' own shading.

Run by hand (not a test)::

    .venv/bin/python bench/shading_ceiling.py [--only bowl_checker rock_photo]
        [--json bench/results/shading_ceiling.json]
    .venv/bin/python bench/shading_ceiling.py --unseen [--json bench/results/shading_ceiling_unseen.json]

Each fixture of ``blend_fixtures/`` is rendered again, with Cycles' diffuse passes saved per photo
(``make_fixtures.generate(..., shading_views=True)``), into ``build/bench/shading/``; the renders are kept while
``make_fixtures.py`` and Blender's version are unchanged (``--unseen``: the scenes of ``bench/unseen.py``, into
``build/bench/shading_unseen/``). Then, per fixture at its truth's size (RMSE as in
``bench/accuracy_quick.py``, mean over R, G, B):

* ``project``: the re-rendered photos fused onto the texture (``--method project``);
* ``shading_known``: the albedo with the shading known exactly (:func:`shading_views`): each photo with its
  own error but only its diffuse term, divided by Cycles' diffuse shading S, fused per texel by least squares
  (``sum w S I / sum w S^2`` over its observations). No delighting can do much better from these photos on
  this mesh; ``project / shading_known`` bounds the ratio issue 13 asks for;
* ``albedo_seen``: Cycles' Diffuse Color pass (the albedo each pixel saw) fused by ``project``: what the
  photos' resolution, the cameras and the user's mesh allow with nothing else wrong.

With Blender other than the fixtures' (5.0.1) the re-rendered photos differ from the committed ones by render
noise; ``project`` here is then not exactly the accuracy table's.
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from bench.accuracy import fixtures  # noqa: E402
from bench.accuracy_quick import _scored, load_case, problem_of, run_project, truth  # noqa: E402
from bench.headless import ROOT, commit, machine  # noqa: E402

RENDERS = os.path.join(ROOT, "build", "bench", "shading")
MAKE_FIXTURES = os.path.join(ROOT, "blend_fixtures", "make_fixtures.py")
CLIPPED = 0.999  # an 8-bit photo's linear value at code 255 is 1


def _stamp():
    import bpy

    with open(MAKE_FIXTURES, "rb") as fh:
        return f"{hashlib.sha1(fh.read()).hexdigest()[:16]} {bpy.app.version_string}"


def rendered(name, renders=RENDERS):
    """The fixture's folder rendered with its shading views (rendered now unless kept from before)."""
    import bpy  # noqa: F401  (before make_fixtures, whose bmesh comes with it)

    if os.path.dirname(MAKE_FIXTURES) not in sys.path:
        sys.path.insert(0, os.path.dirname(MAKE_FIXTURES))
    import make_fixtures

    stamp_path = os.path.join(renders, name, "stamp.txt")
    stamp = _stamp()
    if os.path.exists(stamp_path):
        with open(stamp_path) as fh:
            if fh.read() == stamp:
                return os.path.join(renders, name)
    base = make_fixtures.SCENES[name].get("base")
    if base:
        rendered(base, renders)  # first, so that the derived scene takes the current base's photos
    make_fixtures.generate(name, renders, shading_views=True, reuse_base=True)
    with open(stamp_path, "w") as fh:
        fh.write(stamp)
    return os.path.join(renders, name)


def _shading_views(folder, record):
    rel = record["files"].get("shading_views") or "shading_views/"
    return os.path.normpath(os.path.join(folder, rel))


def _with_photos(inputs, photos):
    import dataclasses

    return dataclasses.replace(inputs, views=[dataclasses.replace(v, photo=p) for v, p in zip(inputs.views, photos)])


def least_squares_albedo(inputs, bakes, photos, shadings, size):
    """Per texel ``sum w S I / sum w S^2`` over its observations, per channel; NaN where unseen.

    :func:`core.solve.lighting.division_start` without its shading floor, which guards against an estimated
    shading's dark mistakes and would only bias the shadows of an exact one.
    """
    import dataclasses

    from core.solve.discretization import texture_domain
    from core.solve.lighting import shading

    # The shading as a transfer: channel c's shading in column c, picked by a lighting of unit vectors.
    transfer = []
    for s, b in zip(shadings, bakes):
        t = np.zeros((int(b.mask.sum()), 9), np.float32)
        t[:, :3] = s[b.mask]
        transfer.append(t)
    problem = dataclasses.replace(problem_of(_with_photos(inputs, photos), bakes, size), transfer=transfer)
    d = texture_domain(problem)
    sigma = np.zeros((len(bakes), 9, 3))
    sigma[:, [0, 1, 2], [0, 1, 2]] = 1.0
    w = d.obs_weight.astype(np.float64)
    out = np.full((size * size, 3), np.nan, np.float32)
    for c in range(3):
        a = d.from_pixels(shading(d, sigma[:, :, c], np.float64))
        num = d.scatter(w * a * d.from_pixels(d.values[:, c]))
        den = d.scatter(w * a * a)
        out[d.texel_index, c] = np.where(den > 0, num / np.maximum(den, 1e-30), np.nan)
    return out.reshape(size, size, 3)


def shading_views(folder, record, inputs):
    """Per photo of ``inputs``: the photo on its diffuse term alone, Cycles' diffuse shading, the albedo seen.

    The first keeps the photo's own error (noise, 8 bits, JPEG, clipping; its gains undone) and drops what
    is not diffuse (the background mixed in at the silhouette, the specular). A silhouette pixel of an 8-bit
    photo that a bright background clipped has lost the object's share: its shading is 0, so it counts for
    nothing in :func:`least_squares_albedo`.
    """
    views = _shading_views(folder, record)
    cams = {c["name"]: c for c in record["cameras"]}
    eight_bit = record["photo"]["format"] in ("PNG", "JPEG")
    clean, shadings, seen_albedo = [], [], []
    for v in inputs.views:
        with np.load(os.path.join(views, v.name + ".npz")) as z:
            s, col, comb = z["diffuse_shading"], z["diffuse_colour"], z["combined"]
        if s.shape != v.photo.shape:
            raise SystemExit(f"error: {v.name}: shading {s.shape} against photo {v.photo.shape}")
        gain = np.asarray(cams[v.name].get("capture", {}).get("gain_rgb", [1.0, 1.0, 1.0]), np.float32)
        other = comb - col * s
        clean.append((v.photo / gain - other).astype(np.float32))
        if eight_bit:
            lost = (v.photo.max(axis=-1) >= CLIPPED) & (other.max(axis=-1) > 0.01)
            s = np.where(lost[..., None], 0.0, s)
        shadings.append(s)
        seen_albedo.append(col.astype(np.float32))
    return clean, shadings, seen_albedo


def evaluate(name, renders=RENDERS):
    from core.evaluate.metrics import scaled_rmse

    folder = rendered(name, renders)
    record, inputs, bakes = load_case(name, folder)
    size = record["albedo_gt"]["size"][0]
    gt, inside = truth(folder, record, size)
    clean, shadings, seen_albedo = shading_views(folder, record, inputs)
    row = {"fixture": name, "texture_size": size}
    row["project"] = _scored(run_project(inputs, bakes, size), gt, inside)
    known = least_squares_albedo(inputs, bakes, clean, shadings, size)
    row["shading_known"] = scaled_rmse(known, gt, np.isfinite(known[..., 0]) & inside).tolist()
    row["albedo_seen"] = _scored(run_project(_with_photos(inputs, seen_albedo), bakes, size), gt, inside)
    return row


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--only", nargs="*", help="fixture names (default: all)")
    p.add_argument("--unseen", action="store_true", help="the scenes of bench/unseen.py, not the fixtures")
    p.add_argument("--json", help="write the rows here")
    a = p.parse_args(argv)
    rows = []
    started = datetime.datetime.now().isoformat(timespec="seconds")
    if a.unseen:
        from bench.unseen import register

        names, renders = register(a.only), os.path.join(ROOT, "build", "bench", "shading_unseen")
    else:
        # The committed fixtures: they are rendered again from make_fixtures.py's own scene specs.
        names, renders = [n for n, _ in fixtures(os.path.join(ROOT, "blend_fixtures"), a.only)], RENDERS
    for name in names:
        row = evaluate(name, renders)
        rows.append(row)
        pr, sk, al = (float(np.mean(row[k])) for k in ("project", "shading_known", "albedo_seen"))
        print(
            f"{name:<20} project {pr:.4f}  shading known {sk:.4f} (x{pr / sk:.2f})  albedo seen {al:.4f} "
            f"(x{pr / al:.2f})",
            flush=True,
        )
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(dict(started=started, commit=commit(), machine=machine(), rows=rows), fh, indent=1)


if __name__ == "__main__":
    main()
