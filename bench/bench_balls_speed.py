#!/usr/bin/env python
"""detect_balls of this tree against another revision's, in the same run: same detections? how fast?

    python bench/bench_balls_speed.py --rev REV [--rounds 15] [--quick]

The revision's ball detector (its package ``src/mutloc/detect/balls/``, taken
with ``git show``) is imported beside this tree's as
``mutloc.detect.balls_old`` (the rest of mutloc is this tree's).  Both run
on the same frames: bench_detectors' rendered stills (four balls, sensor
noise) at 960x540 and 1920x1080.

1. Equivalence: every frame through both detectors, with the camera,
   without, for linear images (``srgb=False``) and at full-resolution search
   (``downscale=1``); the largest difference of the pixel centres, radii and
   scores, and the markers found by one only.
2. Speed, one core (``NUMBA_NUM_THREADS=1``, ``cv2.setNumThreads(1)``; pin
   the process with ``taskset -c 0`` as well): per round each detector runs
   once over the frames, each call on a fresh copy of its frame (nothing
   can be cached between calls), the two interleaved and alternating in
   order so that load on a shared machine hits both alike.  FPS from the
   median round, in CPU time (``time.process_time``, the headline on a busy
   machine) and wall time.

Writes bench/results/balls_speed_results.json.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import bench_detectors as bd  # noqa: E402
from _machine import machine, result_file  # noqa: E402

from mutloc.detect.balls import BallParams, detect_balls  # noqa: E402

PKG = "src/mutloc/detect/balls/"


def git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=HERE, check=True, capture_output=True, text=True).stdout


def load_rev(rev: str):
    """``(detect_balls, BallParams, sha)`` of ``rev``'s ball detector, imported as mutloc.detect.balls_old.

    Its files go to a folder named after the commit (kept between runs, so
    Numba's cache of its kernels stays valid).
    """
    sha = git("rev-parse", "--verify", f"{rev}^{{commit}}").strip()
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "mutloc" / "bench-revs" / sha
    folder = cache / "balls_old"
    files = git("ls-tree", "-r", "--full-tree", "--name-only", sha, PKG).split()
    if not files:
        raise SystemExit(f"{rev} has no {PKG}")
    for f in files:
        dst = folder / f[len(PKG):]
        text = git("show", f"{sha}:{f}")
        if not dst.exists() or dst.read_text() != text:  # unchanged files keep their mtime (Numba's cache)
            dst.parent.mkdir(parents=True, exist_ok=True)
            dst.write_text(text)
    spec = importlib.util.spec_from_file_location("mutloc.detect.balls_old", folder / "__init__.py",
                                                  submodule_search_locations=[str(folder)])
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod.detect_balls, mod.BallParams, sha


def scene_sets(n_still: int, seed: int):
    out = []
    for size in ((960, 540), (1920, 1080)):
        rig, frames, _ = bd.render_stills("balls", size, list(np.linspace(0.0, 6.0, n_still)), seed)
        out.append((f"{size[0]}x{size[1]}", frames, rig.robot(bd.SOURCE).markers, rig.robot(bd.TARGET).camera))
    return out


def compare(old, OldParams, new, sets) -> dict:
    """Largest differences between the two detectors' detections (and alternatives) over every frame and variant."""
    variants = {"camera": ({}, {}), "no camera": ({"camera": None}, {"camera": None}),
                "linear (srgb=False)": ({"params": OldParams(srgb=False)}, {"params": BallParams(srgb=False)}),
                "downscale=1": ({"params": OldParams(downscale=1)}, {"params": BallParams(downscale=1)})}
    out = {}
    for vname, (ko, kn) in variants.items():
        n = only_one = 0
        d_uv = d_r = d_s = 0.0
        missing_differ = 0
        for _, frames, markers, camera in sets:
            for img in frames:
                a = old(img.copy(), markers, **{"camera": camera, **ko})
                b = new(img.copy(), markers, **{"camera": camera, **kn})
                missing_differ += a.missing_reasons != b.missing_reasons
                for da_map, db_map in [(a.detections, b.detections)] + [
                        (dict(enumerate(a.alternatives.get(k, []))), dict(enumerate(b.alternatives.get(k, []))))
                        for k in set(a.alternatives) | set(b.alternatives)]:
                    only_one += len(set(da_map) ^ set(db_map))
                    for k in set(da_map) & set(db_map):
                        da, db = da_map[k], db_map[k]
                        n += 1
                        d_uv = max(d_uv, float(np.max(np.abs(np.asarray(da.uv) - np.asarray(db.uv)))))
                        d_r = max(d_r, abs(float(da.info["radius_px"]) - float(db.info["radius_px"])))
                        d_s = max(d_s, abs(float(da.score) - float(db.score)))
        out[vname] = {"detections_compared": n, "found_by_one_only": only_one,
                      "missing_reasons_differ": missing_differ,
                      "max_abs_diff_uv_px": d_uv, "max_abs_diff_radius_px": d_r, "max_abs_diff_score": d_s}
    return out


def speed(old, new, sets, rounds: int) -> dict:
    out = {}
    for name, frames, markers, camera in sets:
        acc = {"old": ([], []), "new": ([], [])}
        for r in range(rounds):
            order = (("old", old), ("new", new)) if r % 2 == 0 else (("new", new), ("old", old))
            for key, fn in order:
                copies = [f.copy() for f in frames]  # a new image every call (not timed)
                c0, t0 = time.process_time(), time.perf_counter()
                for img in copies:
                    fn(img, markers, camera=camera)
                acc[key][0].append((time.process_time() - c0) / len(frames))
                acc[key][1].append((time.perf_counter() - t0) / len(frames))
        res = {k: {"fps_cpu": 1.0 / float(np.median(c)), "fps_wall": 1.0 / float(np.median(w)),
                   "fps_cpu_best": 1.0 / float(np.min(c))} for k, (c, w) in acc.items()}
        res["new_over_old_cpu"] = res["new"]["fps_cpu"] / res["old"]["fps_cpu"]
        out[name] = res
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rev", default="main", help="the revision to compare with (default: main)")
    ap.add_argument("--rounds", type=int, default=15)
    ap.add_argument("--stills", type=int, default=12, help="frames per resolution")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="6 stills, 5 rounds")
    ap.add_argument("--out", default=result_file("balls_speed_results.json"))
    args = ap.parse_args(argv)
    if args.quick:
        args.stills, args.rounds = 6, 5
    cv2.setNumThreads(1)
    old, OldParams, sha = load_rev(args.rev)
    head = git("rev-parse", "HEAD").strip()
    dirty = bool(git("status", "--porcelain", "--", f":(top){PKG}").strip())
    sets = scene_sets(args.stills, args.seed)
    for _, frames, markers, camera in sets:  # compile / load both detectors' kernels before any timing
        old(frames[0], markers, camera=camera)
        detect_balls(frames[0], markers, camera=camera)
    result = {"machine": machine(), "command": " ".join(["python"] + sys.argv),
              "affinity": sorted(os.sched_getaffinity(0)), "old": {"rev": args.rev, "commit": sha},
              "new": {"commit": head, "uncommitted_changes": dirty}, "stills_per_size": args.stills,
              "rounds": args.rounds}
    result["equivalence"] = compare(old, OldParams, detect_balls, sets)
    result["speed"] = speed(old, detect_balls, sets, args.rounds)
    result["load_average_at_end"] = list(os.getloadavg())

    print(f"old: {args.rev} ({sha[:10]}), new: this tree ({head[:10]}{', modified' if dirty else ''}); "
          f"CPUs {result['affinity']}, load {result['machine']['load_average_at_start']}")
    for v, e in result["equivalence"].items():
        print(f"  {v:20} {e['detections_compared']:4} detections: max |d uv| {e['max_abs_diff_uv_px']:.3g} px, "
              f"|d radius| {e['max_abs_diff_radius_px']:.3g} px, |d score| {e['max_abs_diff_score']:.3g}; "
              f"found by one only {e['found_by_one_only']}, missing reasons differ {e['missing_reasons_differ']}")
    for name, s in result["speed"].items():
        print(f"  {name}: old {s['old']['fps_cpu']:6.1f} FPS cpu ({s['old']['fps_wall']:6.1f} wall), "
              f"new {s['new']['fps_cpu']:6.1f} FPS cpu ({s['new']['fps_wall']:6.1f} wall); "
              f"new/old {s['new_over_old_cpu']:.3f}  (median of {args.rounds} rounds x {args.stills} frames)")
    Path(args.out).write_text(json.dumps(result, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
