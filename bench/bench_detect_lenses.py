#!/usr/bin/env python
"""Detection through any lens: frames per second of :func:`mutloc.detect.detect_image` per lens and
image size, the pinhole path as the peer in the same run.

    python bench/bench_detect_lenses.py            # 5 runs of 6 frames per case
    python bench/bench_detect_lenses.py --quick    # 3 runs of 3 frames

Cases: a tag36h11 tag and a red ball (one detector call each per frame, both timed) in

* a pinhole 1280x800 camera (the detectors as they always ran: no views),
* the SPEC's fisheye 1280x800 (f = 290 px; the image reaches 131 degrees off the axis at its sides,
  145 at its corners: 13 views) and the same with ``field_deg=95`` (a 190-degree lens's own field: 7 views),
* a fisheye 640x400 (f = 145 px),
* an omnidirectional (Mei, xi = 1) 1024x768 camera.

Every call gets a new image (frames are ray-traced beforehand, the marker moved each frame, as in
tests/test_detect_lenses.py).  The views (remap tables) are built once per camera before timing -- a
per-camera cost, reported apart.  One core (NUMBA_NUM_THREADS=1, cv2.setNumThreads(1)).  FPS is the
median over runs of frames / wall-clock seconds.  Prints a table and writes
bench/results/detect_lenses_results.json.
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

from mutloc.core.camera import Camera  # noqa: E402
from mutloc.core.lenses import FisheyeCamera, OmniCamera  # noqa: E402
from mutloc.core.rig import MarkerKind  # noqa: E402
from mutloc.detect import detect_image, image_detector  # noqa: E402
from mutloc.detect.views import detect_in_views, views_for  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests"))
from _machine import machine, result_file  # noqa: E402
import test_detect_lenses as T  # noqa: E402  (the ray-traced renderer)

FISH = T.FISHEYE
CASES = [
    ("pinhole 1280x800", Camera([[290, 0, 639.5], [0, 290, 399.5], [0, 0, 1]], None, (1280, 800)), None, 40.0),
    ("fisheye 1280x800", FISH, None, 85.0),
    ("fisheye 1280x800 field 95", FISH, 95.0, 85.0),
    ("fisheye 640x400", FisheyeCamera([[145, 0, 319.5], [0, 145, 199.5], [0, 0, 1]], FISH.dist, (640, 400)), None,
     85.0),
    ("omni 1024x768", T.OMNI, None, 80.0),
]


def frames(camera, kind: str, off: float, n: int) -> list[np.ndarray]:
    out = []
    for i in range(n):
        az = 180.0 * (i % 2) + 2.0 * (i % 5 - 2)
        if kind == "tag":
            C = (0.7 if camera.size[0] < 1000 else 1.0) * T._direction(off, az)
            out.append(T.render_tag(camera, C, T._facing(C, 20.0), seed=i)[0])
        else:
            out.append(T.render_ball(camera, (0.8 if camera.size[0] < 1000 else 1.3) * T._direction(off, az), seed=i))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=result_file("detect_lenses_results.json"))
    args = ap.parse_args()
    cv2.setNumThreads(1)
    runs, per_run = (3, 3) if args.quick else (5, 6)
    result: dict = {"machine": machine(), "command": " ".join(["python"] + sys.argv), "one_core": True,
                    "runs": runs, "frames_per_run": per_run, "cases": []}
    markers = {"tag": T._tag_marker(), "ball": T._ball_marker()}
    kinds = {"tag": MarkerKind.TAG, "ball": MarkerKind.BALL}
    for name, camera, field, off in CASES:
        build_s, nviews, vpx = 0.0, 0, 0
        vs = None
        if camera.model != "pinhole":
            t0 = time.perf_counter()
            vs = views_for(camera, field_deg=field)
            build_s, nviews, vpx = time.perf_counter() - t0, len(vs), vs.pixels
        row = {"case": name, "views": nviews, "view_megapixels": vpx / 1e6, "views_build_s": build_s}
        for kind in ("tag", "ball"):
            imgs = frames(camera, kind, off, runs * per_run)

            def call(img):
                if vs is None:
                    return detect_image(kinds[kind], img, markers[kind], camera)
                return detect_in_views(image_detector(kinds[kind]), img, markers[kind], camera, views=vs)

            found = sum(bool(call(im).detections) for im in imgs[:per_run])  # warm-up (JIT), and a check
            fps = []
            for r in range(runs):
                batch = imgs[r * per_run:(r + 1) * per_run]
                t0 = time.perf_counter()
                for im in batch:
                    call(im)
                fps.append(len(batch) / (time.perf_counter() - t0))
            row[f"{kind}_fps"] = float(np.median(fps))
            row[f"{kind}_found"] = f"{found}/{per_run}"
        result["cases"].append(row)
        print(f"  {name}: done", file=sys.stderr)
    m = result["machine"]
    print(f"machine: {m['cpu']} ({m['cores']} cores, load avg at start {m['load_average_at_start']}), one core used")
    print(f"{'case':28s} {'views':>5s} {'view Mpx':>8s} {'build s':>7s} {'tag fps':>8s} {'found':>5s} "
          f"{'ball fps':>8s} {'found':>5s}")
    for r in result["cases"]:
        print(f"{r['case']:28s} {r['views']:5d} {r['view_megapixels']:8.2f} {r['views_build_s']:7.2f} "
              f"{r['tag_fps']:8.1f} {r['tag_found']:>5s} {r['ball_fps']:8.1f} {r['ball_found']:>5s}")
    Path(args.out).write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
