#!/usr/bin/env python
"""Cylinders through a fisheye against the pinhole detector, detection alone, in one process.

    python bench/cylinders_views_speed.py [--n 8] [--cache DIR]

The frames of ``bench/bench_detect_lenses.py --bodies-only --no-lights`` (the cylinder rows): q/front and
q/back of the simulator's back-to-back 1280x800 fisheyes at 8 times each, p passing q's side with its
two banded cylinders (:func:`mutloc.sim.body_scenes.passing_body_world`, in a room), and the standard
pinhole pair at 1280x800 (f = 800 px) 1.5 m apart in a room at 8 offsets.  The frames are rendered once
(``--cache DIR`` keeps them: ``DIR/cyl_frames.pkl`` and ``DIR/pin_frames.pkl``), then ``n`` calls of
:func:`mutloc.detect.detect_image` each way, a fisheye frame and a pinhole frame alternately (a different
frame every call; the fisheye's views built before timing), and the median seconds a frame of each and
their ratio are printed with the machine's load.  One core.  Run it with another copy of mutloc's sources
first on PYTHONPATH to compare code versions on the same frames.
"""

from __future__ import annotations

import argparse
import math
import os
import pickle
import sys
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from mutloc.core.pose import Pose  # noqa: E402
from mutloc.core.rig import MarkerKind  # noqa: E402
from mutloc.detect import detect_image  # noqa: E402
from mutloc.detect.views import views_for  # noqa: E402
from mutloc.sim.body_scenes import fisheye_pair_rig, passing_body_world  # noqa: E402
from mutloc.sim.render import project_markers, render, two_robot_world  # noqa: E402
from mutloc.sim.world import standard_rig  # noqa: E402
from mutloc.track.frames import expanded_rig  # noqa: E402

TIMES = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75)


def frames(cache: Path | None):
    fc, pc = (cache / "cyl_frames.pkl", cache / "pin_frames.pkl") if cache else (None, None)
    if fc is not None and fc.exists() and pc.exists():
        return pickle.loads(fc.read_bytes())["cases"], pickle.loads(pc.read_bytes())
    rig0 = fisheye_pair_rig("cylinders")
    crig = expanded_rig(rig0)
    w = passing_body_world(rig0, lateral=1.0, room=True, seed=0)
    cases = []
    for key, t in [("q/front", t) for t in TIMES] + [("q/back", t + 1.5) for t in TIMES]:
        cam = crig.mount(key).camera
        T = w.camera_pose(key, t).inverse() @ w.robot("p").pose_at(t)
        truth = {n: cam.project(T.apply(m.position)) for n, m in crig.robot("p").markers.items()
                 if m.extra.get("cylinder_of")}
        cases.append((key, t, render(w, key, t, seed=1, noise_sigma=1.0),
                      project_markers(w, key, t, check_occlusion=True), truth))
    srig0 = standard_rig("cylinders", size=(1280, 800), f=800.0)
    pins = []
    for i, t in enumerate(TIMES):
        T_qp = Pose(np.eye(3), np.array([0.3 * math.sin(2.0 * t), 0.0, 1.5]))
        pins.append(render(two_robot_world(srig0, T_qp, seed=i), "q", 0.0, seed=1, noise_sigma=1.0))
    if fc is not None:
        cache.mkdir(parents=True, exist_ok=True)
        fc.write_bytes(pickle.dumps({"cases": cases}))
        pc.write_bytes(pickle.dumps(pins))
    return cases, pins


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=8)
    ap.add_argument("--cache", type=Path, default=None)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    cases, pins = frames(args.cache)
    rig0 = fisheye_pair_rig("cylinders")
    crig = expanded_rig(rig0)
    cams = {k: crig.mount(k).camera for k in ("q/front", "q/back")}
    markers = rig0.robot("p").markers
    for c in cams.values():
        views_for(c)
    srig0 = standard_rig("cylinders", size=(1280, 800), f=800.0)
    pcam, pm = srig0.robot("q").camera, srig0.robot("p").markers
    detect_image(MarkerKind.CYLINDER, pins[0], pm, pcam)  # warm-up (JIT)
    load0 = os.getloadavg()
    tf, tp = [], []
    for i in range(args.n):
        key, _, img, _, _ = cases[(2 * i + 1) % len(cases)]
        t0 = time.perf_counter()
        detect_image(MarkerKind.CYLINDER, img, markers, cams[key])
        tf.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        detect_image(MarkerKind.CYLINDER, pins[i % len(pins)], pm, pcam)
        tp.append(time.perf_counter() - t0)
    print(f"fisheye 1280x800 {np.median(tf):.3f} s a frame, pinhole 1280x800 {np.median(tp):.3f} s, "
          f"ratio {np.median(tf) / np.median(tp):.2f} (median of {args.n} each; load at start "
          f"{load0[0]:.1f}, at end {os.getloadavg()[0]:.1f}, 2 cores; sources: {sys.modules['mutloc'].__file__})")


if __name__ == "__main__":
    main()
