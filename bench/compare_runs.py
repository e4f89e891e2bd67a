"""Candidate defaults compared on many scenes, and chosen among by leave-one-scene-out.

Run by hand (not a test), on rows written by ``bench/accuracy_quick.py --json``::

    .venv/bin/python bench/compare_runs.py \\
        --run default bench/results/accuracy_quick.json bench/results/accuracy_unseen.json \\
        --run lam8 build/lam8_quick.json build/lam8_unseen.json

Each ``--run`` is a label and the JSON files of one candidate, one per set of scenes, in the same order in
every run (the sets are named by the first run's files, which are the reference). Per run and per set it
prints the mean RMSE over R, G, B, then ``project`` / ours: its mean, geometric mean and least, and how
many scenes reach 2.5×; then how many scenes are better or worse than the reference by more than
``--margin``, and the largest changes.

Leave-one-scene-out: each scene in turn is held out, the run with the best geometric mean of
``project`` / ours on all the other scenes is chosen, and the held-out scene is scored with that run. A
candidate whose gain rests on one or two scenes is not chosen when they are held out, so the held-out
figures fall below its own: the test that a default was chosen on many scenes, not on a few.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402

from bench.accuracy import improvement  # noqa: E402


def load_run(paths):
    """``[{scene: (project, ours)}]``: mean RMSE over the channels, one set of scenes per file."""
    sets = []
    for path in paths:
        with open(path) as fh:
            rows = json.load(fh)["rows"]
        sets.append({r["fixture"]: (float(np.mean(r["project"])), float(np.mean(r["ours"]))) for r in rows})
    return sets


def summary(project: np.ndarray, ours: np.ndarray) -> str:
    mean, geometric, least = improvement(project, ours)
    return (
        f"{ours.mean():.4f}; project / ours {mean:.2f}x, geometric {geometric:.2f}x, least {least:.2f}x; "
        f"{int((project / ours >= 2.5).sum())} of {ours.size} at 2.5x or more"
    )


def held_out(project: np.ndarray, ours: np.ndarray) -> tuple[np.ndarray, list]:
    """Each scene scored with the run chosen on the others (``ours``: runs × scenes); and the choices."""
    gain = np.log(project[None] / ours)
    total = gain.sum(axis=1)
    picks = [int(np.argmax(total - gain[:, i])) for i in range(ours.shape[1])]
    return ours[picks, np.arange(ours.shape[1])], picks


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", nargs="+", action="append", required=True, metavar=("LABEL", "JSON"))
    p.add_argument("--margin", type=float, default=0.0005, help="a change smaller than this is no change")
    p.add_argument("--show", type=int, default=3, help="the largest changes to list per run")
    args = p.parse_args(argv)
    if any(len(r) < 2 for r in args.run):
        p.error("each --run is a label and at least one JSON file")
    labels = [r[0] for r in args.run]
    runs = [load_run(r[1:]) for r in args.run]
    if any(len(run) != len(runs[0]) for run in runs):
        p.error("every run needs as many JSON files as the first, in the same order (one per set of scenes)")
    # A set is named by the first run's file.
    set_labels = [os.path.splitext(os.path.basename(path))[0] for path in args.run[0][1:]]
    runs = [dict(zip(set_labels, run)) for run in runs]
    scenes, of_set = [], []
    for s in set_labels:
        names = sorted(set.intersection(*(set(run[s]) for run in runs)))
        missing = sorted(set().union(*(set(run[s]) for run in runs)) - set(names))
        if missing:
            print(f"{s}: left out, not in every run: {', '.join(missing)}")
        scenes += [(s, n) for n in names]
        of_set += [s] * len(names)
    of_set = np.array(of_set)
    project = np.array([runs[0][s][n][0] for s, n in scenes])
    ours = np.array([[run[s][n][1] for s, n in scenes] for run in runs])

    def report(label, values):
        print(f"{label}:")
        for s in set_labels:
            m = of_set == s
            print(f"  {s}: {summary(project[m], values[m])}")

    for i, label in enumerate(labels):
        report(label, ours[i])
        if i:
            change = ours[i] - ours[0]
            order = np.argsort(change)
            better = [j for j in order if change[j] < -args.margin]
            worse = [j for j in order[::-1] if change[j] > args.margin]
            print(f"  against {labels[0]}: {len(better)} scenes better, {len(worse)} worse by more than {args.margin}")
            for word, idx in (("better", better), ("worse", worse)):
                if idx:
                    shown = ", ".join(f"{scenes[j][1]} {ours[0, j]:.4f} -> {ours[i, j]:.4f}" for j in idx[: args.show])
                    print(f"    {word}: {shown}")
    if len(labels) > 1:
        values, picks = held_out(project, ours)
        report("leave-one-scene-out", values)
        print("  chosen: " + ", ".join(f"{labels[k]} {picks.count(k)} times" for k in sorted(set(picks))))


if __name__ == "__main__":
    main()
