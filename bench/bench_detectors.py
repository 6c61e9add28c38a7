#!/usr/bin/env python
"""Detector benchmark: frames per second and pixel accuracy of the image
front end, on frames rendered by mutloc.sim (960x540 and 1920x1080).

    python bench/bench_detectors.py            # full run (~3-5 minutes, mostly rendering)
    python bench/bench_detectors.py --quick    # fewer frames and repeats

Measured (one core: NUMBA_NUM_THREADS=1, cv2.setNumThreads(1)):

* ``detect_balls``: four balls of one robot in view, with the camera;
* ``detect_tags``: the two tag36h11 tags of the standard rig;
* ``BlinkTracker.update``: a rendered sequence of blinking lights (a fresh
  tracker per repeat, every frame of the sequence fed in order);
* ``track``: end to end over two pre-rendered in-memory streams of
  :class:`~mutloc.track.sources.Frame` (balls; progress off), paired frames
  per second.

All frames are rendered before any timing.  FPS is the median over repeats
of (frames / wall-clock seconds); the CPU-time figure (``time.process_time``)
is printed beside it since it is less sensitive to a busy machine.  Errors
are against :func:`mutloc.sim.render.project_markers` (exact projection of
the marker centres).  Prints a table and writes bench/results/detectors_results.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from mutloc.core.rig import Marker, Rig, Robot  # noqa: E402
from mutloc.detect.balls import detect_balls  # noqa: E402
from mutloc.detect.blink import BlinkTracker  # noqa: E402
from mutloc.detect.tags import detect_tags  # noqa: E402
from mutloc.sim.render import moving_world, project_markers, relative_pose, render  # noqa: E402
from mutloc.sim.world import standard_rig  # noqa: E402
from mutloc.track.sources import Frame  # noqa: E402
from mutloc.track.tracker import track  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402

cv2.setNumThreads(1)

SIZES = ((960, 540), (1920, 1080))
F_960 = 800.0  # focal length at 960 px width; scaled with the width
SOURCE, TARGET = "p", "q"  # p is seen by q's camera
BLINK_SCENE = {"distance": 3.0, "period": 24.0}
TARGETS = {"balls_960_fps": 100.0, "track_fps": 30.0}

# Four balls on p (the standard rig has two per robot): the standard pair
# plus two more above them, in the four standard colours.
_FOUR_BALLS = {"M1": ((-0.15, -0.05, -0.03), (0, 0, 255)), "M2": ((0.15, -0.05, -0.03), (255, 255, 0)),
               "M3": ((-0.08, -0.17, -0.03), (255, 0, 0)), "M4": ((0.08, -0.17, -0.03), (0, 255, 0))}


def four_ball_rig(size: tuple[int, int], f: float) -> Rig:
    """The standard ball rig with four balls on p (q keeps its two)."""
    base = standard_rig("balls", size=size, f=f)
    p = base.robot(SOURCE)
    radius = next(iter(p.markers.values())).extra.get("radius", 0.03)
    ms = {n: Marker(n, SOURCE, np.array(pos, float), color=rgb, extra={"radius": radius})
          for n, (pos, rgb) in _FOUR_BALLS.items()}
    q = base.robot(TARGET)
    qm = {f"Q{i}": Marker(f"Q{i}", TARGET, m.position, color=m.color, extra=dict(m.extra))
          for i, m in enumerate(q.markers.values())}
    return Rig({SOURCE: Robot(SOURCE, p.camera, ms), TARGET: Robot(TARGET, q.camera, qm)})


def timed(fn, n_items: int, repeat: int) -> tuple[float, float]:
    """(median wall FPS, median CPU FPS) of ``fn()`` processing ``n_items`` frames per call."""
    wall, cpu = [], []
    for _ in range(repeat):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        wall.append(n_items / (time.perf_counter() - t0))
        cpu.append(n_items / max(time.process_time() - c0, 1e-9))
    return float(np.median(wall)), float(np.median(cpu))


def errors_px(found: dict, truth: dict) -> list[float]:
    return [float(np.hypot(*(np.asarray(found[k]) - np.asarray(truth[k])))) for k in found if k in truth]


def median_or_none(x: list[float]) -> float | None:
    return float(np.median(x)) if x else None


# ---------------------------------------------------------------------------
# rendering (not timed)
# ---------------------------------------------------------------------------


def render_stills(kind: str, size: tuple[int, int], times: list[float], seed: int):
    f = F_960 * size[0] / 960.0
    rig = four_ball_rig(size, f) if kind == "balls" else standard_rig(kind, size=size, f=f)
    world = moving_world(rig, distance=1.6, seed=seed)
    frames = [render(world, TARGET, t, seed=seed, noise_sigma=2.0) for t in times]
    truth = [project_markers(world, TARGET, t) for t in times]
    return rig, frames, truth


def render_sequence(kind: str, size: tuple[int, int], n: int, fps: float, seed: int, observers,
                    distance: float = 1.6, period: float = 8.0):
    f = F_960 * size[0] / 960.0
    rig = standard_rig(kind, size=size, f=f)
    world = moving_world(rig, distance=distance, period=period, seed=seed)
    ts = [k / fps for k in range(n)]
    imgs = {o: [render(world, o, t, seed=seed, noise_sigma=2.0) for t in ts] for o in observers}
    return rig, world, ts, imgs


# ---------------------------------------------------------------------------
# benchmarks
# ---------------------------------------------------------------------------


def bench_balls(size, n_still, repeat, seed) -> dict:
    times = list(np.linspace(0.0, 6.0, n_still))
    rig, frames, truth = render_stills("balls", size, times, seed)
    markers, cam = rig.robot(SOURCE).markers, rig.robot(TARGET).camera
    errs, found, total = [], 0, 0
    for img, tr in zip(frames, truth):
        res = detect_balls(img, markers, camera=cam)  # also warms up JIT / caches
        px = res.pixels()
        errs += errors_px(px, tr)
        found += len(px)
        total += len(tr)

    def run():
        for img in frames:
            detect_balls(img, markers, camera=cam)

    wall, cpu = timed(run, len(frames), repeat)
    return {"fps": wall, "fps_cpu": cpu, "median_error_px": median_or_none(errs),
            "found": found, "in_view": total, "frames": len(frames)}


def bench_tags(size, n_still, repeat, seed) -> dict:
    times = list(np.linspace(0.0, 6.0, n_still))
    rig, frames, truth = render_stills("tags", size, times, seed)
    markers, cam = rig.robot(SOURCE).markers, rig.robot(TARGET).camera
    errs, found, total = [], 0, 0
    for img, tr in zip(frames, truth):
        px = detect_tags(img, markers, camera=cam).pixels()
        errs += errors_px(px, tr)
        found += len(px)
        total += len(tr)

    def run():
        for img in frames:
            detect_tags(img, markers, camera=cam)

    wall, cpu = timed(run, len(frames), repeat)
    return {"fps": wall, "fps_cpu": cpu, "median_error_px": median_or_none(errs),
            "found": found, "in_view": total, "frames": len(frames)}


def bench_blink(size, n_frames, fps, repeat, seed) -> dict:
    # With the default tracker settings the lights must be small and slow in
    # the image: at 1.6 m on the default 8 s path (~10 px radius, ~190 px/s at
    # 960x540) no light was ever identified, so p stands 3 m off and moves on
    # a 24 s path.
    rig, world, ts, imgs = render_sequence("lights", size, n_frames, fps, seed, [TARGET], **BLINK_SCENE)
    frames = imgs[TARGET]
    markers = rig.robot(SOURCE).markers
    truth = [project_markers(world, TARGET, t) for t in ts]
    cam = rig.robot(TARGET).camera  # lights are reported at their centres' projection
    tracker = BlinkTracker(markers, fps, camera=cam)
    err_on, err_all, first = [], [], None
    for k, (img, t) in enumerate(zip(frames, ts)):
        res = tracker.update(img, t)
        for name, d in res.detections.items():
            if name not in truth[k]:
                continue
            e = float(np.hypot(*(np.asarray(d.uv) - np.asarray(truth[k][name]))))
            err_all.append(e)
            if d.info.get("on"):
                err_on.append(e)
            if first is None:
                first = k

    def run():
        tr = BlinkTracker(markers, fps, camera=cam)
        for img, t in zip(frames, ts):
            tr.update(img, t)

    wall, cpu = timed(run, len(frames), repeat)
    return {"fps": wall, "fps_cpu": cpu, "median_error_px": median_or_none(err_on),
            "median_error_px_all_reports": median_or_none(err_all), "reports": len(err_all),
            "reports_on": len(err_on), "first_identified_frame": first, "frames": len(frames),
            "sequence_fps": fps, "scene": dict(BLINK_SCENE)}


def bench_track(size, n_frames, fps, repeat, seed) -> dict:
    rig, world, ts, imgs = render_sequence("balls", size, n_frames, fps, seed, [SOURCE, TARGET])

    def streams():
        return {r: iter([Frame(k, t, imgs[r][k]) for k, t in enumerate(ts)]) for r in (SOURCE, TARGET)}

    traj = track(rig, streams(), SOURCE, TARGET, progress=False, fps=fps)  # warm-up + accuracy
    et = []
    for row in traj.solved:
        T = relative_pose(world, SOURCE, TARGET, row.t)
        et.append(float(np.linalg.norm(row.estimate.t - T.t)))

    wall, cpu = timed(lambda: track(rig, streams(), SOURCE, TARGET, progress=False, fps=fps), len(ts), repeat)
    return {"fps": wall, "fps_cpu": cpu, "pairs": len(ts), "solved": len(traj.solved),
            "median_translation_error_m": median_or_none(et)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer frames and repeats")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=result_file("detectors_results.json"))
    args = ap.parse_args(argv)
    n_still, rep_still = (3, 5) if args.quick else (6, 15)
    n_seq, rep_seq = (36, 3) if args.quick else (60, 5)
    n_track = {960: 24 if args.quick else 45, 1920: 12 if args.quick else 24}
    fps = 30.0

    t_start = time.perf_counter()
    result: dict = {"machine": machine(), "command": " ".join(["python"] + sys.argv), "one_core": True,
                    "targets": TARGETS, "results": {}}
    for size in SIZES:
        key = f"{size[0]}x{size[1]}"
        r: dict = {}
        print(f"[{key}] balls ...", flush=True)
        r["detect_balls"] = bench_balls(size, n_still, rep_still, args.seed)
        print(f"[{key}] tags ...", flush=True)
        r["detect_tags"] = bench_tags(size, n_still, rep_still, args.seed)
        print(f"[{key}] blinking lights ...", flush=True)
        r["BlinkTracker.update"] = bench_blink(size, n_seq, fps, rep_seq, args.seed)
        print(f"[{key}] track ...", flush=True)
        r["track"] = bench_track(size, n_track[size[0]], fps, max(2, rep_seq - 2), args.seed)
        result["results"][key] = r
    result["total_seconds"] = time.perf_counter() - t_start

    m = result["machine"]
    print()
    print(f"machine: {m['cpu']} ({m['cores']} cores, load avg at start {m['load_average_at_start']}), one core used")
    print(f"{'resolution':10} {'stage':20} {'FPS':>8} {'FPS cpu':>8} {'err px':>7}  notes")
    for key, r in result["results"].items():
        for stage, e in r.items():
            err = e.get("median_error_px")
            err_s = f"{err:7.3f}" if err is not None else "      -"
            if stage in ("detect_balls", "detect_tags"):
                note = f"found {e['found']}/{e['in_view']} over {e['frames']} frames"
            elif stage == "BlinkTracker.update":
                note = (f"{e['frames']}-frame sequence @ {e['sequence_fps']:.0f} Hz; identified from frame "
                        f"{e['first_identified_frame']}; {e['reports_on']} lit reports "
                        f"(all {e['reports']}: median {e['median_error_px_all_reports'] or float('nan'):.2f} px)")
            else:
                te = e["median_translation_error_m"]
                note = (f"{e['pairs']} paired frames, {e['solved']} solved"
                        + (f", median |t| error {100 * te:.2f} cm" if te is not None else ""))
            target = None
            if stage == "detect_balls" and key == "960x540":
                target = TARGETS["balls_960_fps"]
            elif stage == "track":
                target = TARGETS["track_fps"]
            if target is not None:
                note += f"  [target >= {target:.0f} FPS: {'met' if e['fps'] >= target else 'NOT met'}]"
            print(f"{key:10} {stage:20} {e['fps']:8.1f} {e['fps_cpu']:8.1f} {err_s}  {note}")
    print(f"total {result['total_seconds']:.0f} s")
    Path(args.out).write_text(json.dumps(result, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
