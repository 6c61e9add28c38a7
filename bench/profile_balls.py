#!/usr/bin/env python
"""Where detect_balls spends its time: milliseconds per frame in each stage.

    PYTHONPATH=src python bench/profile_balls.py [--set 960|1920|demo] [--rev REV] [--rounds 10]

Wraps the stages the driver calls (coarse search, per-blob refinement and
its rim sampling, fit and score, the rig check, ...) and the OpenCV calls of
the coarse search with timers, runs the frames of compare_balls.py's set
(bench_detectors' 960x540 or 1920x1080 stills, or ball_tools' demo frames)
``--rounds`` times on one core and prints the inclusive wall time per frame
of each (nested stages are inside their callers' figures) and how often
each is called.  ``--rev``: profile another revision's package instead
(imported as compare_balls.py does).  The timers add a few microseconds per
call; the total is for comparing stages, not a frame rate.
"""

from __future__ import annotations

import argparse
import collections
import importlib
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import bench_detectors as bd  # noqa: E402
from ball_tools import demo_image  # noqa: E402
from compare_balls import load_old  # noqa: E402

#: (module, function) pairs timed where they are looked up (the driver's and the coarse search's namespaces).
STAGES = {
    "detector": ["find_blobs", "refine_blob", "value_floor", "light_gains", "sample_rim", "smooth_rim", "fit_rim",
                 "score_candidate", "recentre", "choose_consistent", "assign", "ellipse_info"],
    "search": ["hue_masks", "coarse_blobs", "_coarse_rows", "_blob_chroma", "ransac_circle", "fill_fraction"],
}
CV2 = ["resize", "cvtColor", "findContours", "inRange", "LUT", "extractChannel", "bitwise_and"]


def frames_of(which: str):
    """(frames, markers, camera) of one of compare_balls.py's sets."""
    if which == "demo":
        demo = [demo_image(seed) for seed in range(6)]
        return [d[0] for d in demo], demo[0][1], demo[0][2]
    size = (960, 540) if which == "960" else (1920, 1080)
    rig, frames, _ = bd.render_stills("balls", size, list(np.linspace(0, 6, 12)), 0)
    return frames, rig.robot(bd.SOURCE).markers, rig.robot(bd.TARGET).camera


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", choices=("960", "1920", "demo"), default="960")
    ap.add_argument("--rev", default=None)
    ap.add_argument("--rounds", type=int, default=10)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    pkg = "mutloc.detect.balls"
    if args.rev is not None:
        load_old(args.rev)
        pkg = "mutloc.detect.balls_old"
    det = importlib.import_module(f"{pkg}.detector")
    acc: dict[str, float] = collections.defaultdict(float)
    calls: collections.Counter[str] = collections.Counter()

    def timed(owner, name: str, label: str) -> None:
        fn = getattr(owner, name)

        def wrapper(*a, **k):
            t = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                acc[label] += time.perf_counter() - t
                calls[label] += 1

        setattr(owner, name, wrapper)

    for mod, names in STAGES.items():
        m = importlib.import_module(f"{pkg}.{mod}")
        for name in names:
            if hasattr(m, name):
                timed(m, name, f"{mod}.{name}")
    for name in CV2:
        timed(cv2, name, f"cv2.{name}")

    frames, markers, camera = frames_of(args.set)
    for img in frames:  # compiles / warms up
        det.detect_balls(img, markers, camera=camera)
    acc.clear()
    calls.clear()
    t0 = time.perf_counter()
    for _ in range(args.rounds):
        for img in frames:
            det.detect_balls(img, markers, camera=camera)
    n = args.rounds * len(frames)
    print(f"{args.rev or 'this tree'}, set {args.set}: {1000 * (time.perf_counter() - t0) / n:.2f} ms per frame "
          f"with the timers ({n} frames)")
    for label, total in sorted(acc.items(), key=lambda kv: -kv[1]):
        print(f"  {label:28s} {1000 * total / n:7.3f} ms/frame  {calls[label] / n:6.1f} calls/frame")


if __name__ == "__main__":
    main()
