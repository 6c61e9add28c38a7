#!/usr/bin/env python
"""detect_balls of another revision against this tree's: speed in the same run, and how many detections differ.

    PYTHONPATH=src python bench/compare_balls.py [--rev main] [--rounds 15]

The revision's detector is its package ``detect/balls/`` (or, before it
was split, the single file ``detect/balls.py``), imported beside this
tree's.  Both run on the same frames (bench_detectors' mutloc.sim stills at
960x540 and 1920x1080, and ball_tools' demo frames), interleaved round by
round so machine load affects both alike; one core, CPU time.  First counts
the detections that differ (uv, score) or are found by one only, with a
camera, without, for linear images and at full-resolution search.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import bench_detectors as bd  # noqa: E402
from ball_tools import demo_image  # noqa: E402

from mutloc.detect.balls import BallParams, detect_balls  # noqa: E402


def load_old(rev: str):
    """``detect_balls`` and ``BallParams`` of ``rev``'s detector, imported inside mutloc.detect as balls_old."""
    tmp = Path(tempfile.mkdtemp())
    tree = subprocess.run(["git", "ls-tree", "--full-tree", "--name-only", rev, "src/mutloc/detect/balls/"], cwd=HERE,
                          check=True, capture_output=True, text=True).stdout.split()
    if tree:  # the package: extracted whole, its relative imports resolve in mutloc.detect
        for f in tree:
            (tmp / Path(f).name).write_text(subprocess.run(["git", "show", f"{rev}:{f}"], cwd=HERE, check=True,
                                                           capture_output=True, text=True).stdout)
        spec = importlib.util.spec_from_file_location("mutloc.detect.balls_old", tmp / "__init__.py",
                                                      submodule_search_locations=[str(tmp)])
    else:
        src = subprocess.run(["git", "show", f"{rev}:src/mutloc/detect/balls.py"], cwd=HERE, check=True,
                             capture_output=True, text=True).stdout
        (tmp / "balls_old.py").write_text(src)
        spec = importlib.util.spec_from_file_location("mutloc.detect.balls_old", tmp / "balls_old.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod.detect_balls, getattr(mod, "BallParams", None)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rev", default="main")
    ap.add_argument("--rounds", type=int, default=15)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    (old, OldParams), new = load_old(args.rev), detect_balls

    sets = []
    for size in ((960, 540), (1920, 1080)):
        rig, frames, _ = bd.render_stills("balls", size, list(np.linspace(0, 6, 12)), 0)
        sets.append((f"sim {size[0]}x{size[1]}", frames, rig.robot(bd.SOURCE).markers, rig.robot(bd.TARGET).camera))
    demo = [demo_image(seed) for seed in range(6)]
    sets.append(("demo 960x540", [d[0] for d in demo], demo[0][1], demo[0][2]))

    def kw(**p):  # the old single-file detector took the parameters as keywords
        return {"params": OldParams(**p)} if OldParams is not None else p

    # (old keywords, new keywords)
    variants = [({}, {}), ({"camera": None}, {"camera": None}),
                (kw(srgb=False), {"params": BallParams(srgb=False)}),
                (kw(downscale=1, hue_tol_deg=20.0), {"params": BallParams(downscale=1, hue_tol_deg=20.0)})]
    n = differ = only_one = 0
    for name, frames, markers, camera in sets:
        for img in frames:
            for ko, kn in variants:
                a = old(img, markers, **{"camera": camera, **ko})
                b = new(img, markers, **{"camera": camera, **kn})
                only_one += len(set(a.detections) ^ set(b.detections))
                for k in set(a.detections) & set(b.detections):
                    da, db = a.detections[k], b.detections[k]
                    n += 1
                    differ += not (np.array_equal(da.uv, db.uv) and da.score == db.score)
    print(f"detections in both: {n}, differing in uv or score: {differ}; found by one only: {only_one}")

    for name, frames, markers, camera in sets:
        t_old, t_new = [], []
        for r in range(args.rounds):
            order = ((old, t_old), (new, t_new)) if r % 2 == 0 else ((new, t_new), (old, t_old))
            for fn, acc in order:
                t0 = time.process_time()
                for img in frames:
                    fn(img, markers, camera=camera)
                acc.append((time.process_time() - t0) / len(frames))
        fo, fn_ = 1 / np.median(t_old), 1 / np.median(t_new)
        print(f"{name}: old {fo:.0f} FPS, new {fn_:.0f} FPS (median of {args.rounds} rounds, CPU time, one core); "
              f"new/old {fn_ / fo:.3f}")


if __name__ == "__main__":
    main()
