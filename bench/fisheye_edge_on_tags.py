#!/usr/bin/env python
"""Tags seen nearly edge-on at the side of a fisheye image (issue 36 item 3): detection rate and corner
error against the angle off the optical axis and the tag's tilt, and what limits it.

    python bench/fisheye_edge_on_tags.py                  # 8 trials per cell
    python bench/fisheye_edge_on_tags.py --n 4 --offs 85,92 --tilts 0,60,75

Each trial: one tag36h11 tag (``--size`` m, 0.20 by default: the simulated bodies' side tags) ``--dist`` m
from the simulator's fisheye (``mutloc.sim.body_scenes``: 1280x800, f = 261 px, Kannala-Brandt, 199 degrees
across), its centre ``off`` degrees off the optical axis at azimuth 0 or 180 (the image's left or right
side, the azimuth jittered by up to 10 degrees), turned ``tilt`` degrees off facing the camera about its
own vertical axis (a tag on a robot's side seen from another robot's camera: foreshortened across the
image's radius, where the lens compresses too).  Rendered by tests/test_detect_lenses.py's ray tracer
(every raw pixel's ray, 4x4 sub-pixels, in linear light, sRGB, noise 1.5 DN, smooth clutter behind);
truth is the lens's projection of the tag's corners.  A tag counts as found when its four corners are within
1 px of the truth; the worst corner's error is reported (median / p90 over the tags found).

Settings, each on the same images:

* ``shipped``: :func:`mutloc.detect.detect_image` (the lens's 7-13 rectified views, the AprilTag library
  at its quad decimation 2, then the edge fit);
* ``quad_decimate 1``: the same with ``params={"quad_decimate": 1.0}``;
* ``view on the tag``: one view centred on the tag's true direction (``view_towards``, 20 degrees half
  field, the raw density), ``quad_decimate`` 1 -- what a second look where a pose puts the tag gets;
* ``view on the tag x2``: the same at twice the raw density (the view upsampled: is resolution the limit?).

The tag's size in the raw image is given as its shortest and longest side (px, median over the trials);
a tag36h11 tag is 8 cells across its black square, so its narrowest cells are the shortest side / 8.
Writes bench/results/fisheye_edge_on_tags_results.json.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests"))
import test_detect_lenses as T  # noqa: E402  (the ray-traced renderer)
from _machine import machine, result_file  # noqa: E402

from mutloc.core.lenses import FisheyeCamera  # noqa: E402
from mutloc.core.rig import MarkerKind  # noqa: E402
from mutloc.detect import detect_image  # noqa: E402
from mutloc.detect.tags import detect_tags  # noqa: E402
from mutloc.detect.views import detection_to_raw, view_towards  # noqa: E402
from mutloc.sim.body_scenes import FISHEYE_DIST, FISHEYE_FOCAL, FISHEYE_SIZE  # noqa: E402

CAMERA = FisheyeCamera([[FISHEYE_FOCAL, 0, (FISHEYE_SIZE[0] - 1) / 2], [0, FISHEYE_FOCAL, (FISHEYE_SIZE[1] - 1) / 2],
                        [0, 0, 1]], FISHEYE_DIST, FISHEYE_SIZE)


def _look(img, markers, direction, density):
    view = view_towards(CAMERA, direction, half_fov_deg=20.0, density=density)
    if view is None:
        return None
    res = detect_tags(view.rectify(img), markers, camera=view.camera, params={"quad_decimate": 1.0})
    d = res.detections.get("T")
    return None if d is None else detection_to_raw(d, view)


SETTINGS = {
    "shipped": lambda img, m, C: detect_image(MarkerKind.TAG, img, m, CAMERA).detections.get("T"),
    "quad_decimate 1": lambda img, m, C: detect_image(MarkerKind.TAG, img, m, CAMERA,
                                                      params={"quad_decimate": 1.0}).detections.get("T"),
    "view on the tag": lambda img, m, C: _look(img, m, C, 1.0),
    "view on the tag x2": lambda img, m, C: _look(img, m, C, 2.0),
}


def trial(off: float, tilt: float, k: int, dist: float):
    rng = np.random.default_rng(1000 * k + int(10 * off) + int(10 * tilt))
    az = 180.0 * (k % 2) + float(rng.uniform(-10.0, 10.0))
    C = dist * T._direction(off, az)
    sign = 1.0 if rng.uniform() < 0.5 else -1.0
    img, truth = T.render_tag(CAMERA, C, T._facing(C, sign * tilt), tid=3, seed=k)
    return img, truth, C


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=8)
    ap.add_argument("--offs", default="80,85,90,95")
    ap.add_argument("--tilts", default="0,45,60,70,75,80")
    ap.add_argument("--dist", type=float, default=1.2)
    ap.add_argument("--size", type=float, default=0.20)
    ap.add_argument("--settings", default=",".join(SETTINGS))
    ap.add_argument("--out", default=result_file("fisheye_edge_on_tags_results.json"))
    args = ap.parse_args()
    cv2.setNumThreads(1)
    T.TAG_SIZE = args.size  # the renderer's and the marker's
    markers = T._tag_marker(3)
    settings = args.settings.split(",")
    result = {"machine": machine(), "command": " ".join(["python"] + sys.argv), "dist_m": args.dist,
              "tag_m": args.size, "trials": args.n, "rows": []}
    print(f"{'off':>4s} {'tilt':>4s} {'sides px':>9s}  " + "  ".join(f"{s:>24s}" for s in settings))
    for off in (float(x) for x in args.offs.split(",")):
        for tilt in (float(x) for x in args.tilts.split(",")):
            found = {s: [] for s in settings}
            secs = {s: 0.0 for s in settings}
            boxes = []
            for k in range(args.n):
                img, truth, C = trial(off, tilt, k, args.dist)
                sides = np.linalg.norm(truth - np.roll(truth, 1, axis=0), axis=1)
                boxes.append([sides.min(), sides.max()])
                for s in settings:
                    t0 = time.perf_counter()
                    d = SETTINGS[s](img, markers, C)
                    secs[s] += time.perf_counter() - t0
                    if d is not None and d.corners is not None:
                        e = float(np.linalg.norm(np.asarray(d.corners) - truth, axis=1).max())
                        found[s].append(e)
            box = np.median(np.array(boxes), axis=0)
            fin = bool(np.all(np.isfinite(box)))  # else corners past the lens's field
            row = {"off_deg": off, "tilt_deg": tilt,
                   "side_px_min_max": [float(box[0]), float(box[1])] if fin else None,
                   "cell_px_min": float(box[0]) / 8.0 if fin else None}
            cells = []
            for s in settings:
                e = np.array(found[s])
                ok = e[e <= 1.0]
                row[s] = {"found": int(len(ok)), "decoded": int(len(e)), "of": args.n,
                          "worst_corner_median_px": float(np.median(ok)) if len(ok) else None,
                          "worst_corner_p90_px": float(np.percentile(ok, 90)) if len(ok) else None,
                          "s_per_frame": secs[s] / args.n}
                cells.append(f"{len(ok):2d}/{args.n}" + (f" ({len(e) - len(ok)} off)" if len(e) > len(ok) else "")
                             + (f" {np.median(ok):.2f}/{np.percentile(ok, 90):.2f}px" if len(ok) else ""))
            result["rows"].append(row)
            print(f"{off:4.0f} {tilt:4.0f} {box[0]:4.0f}x{box[1]:<4.0f}  " + "  ".join(f"{c:>24s}" for c in cells),
                  flush=True)
    Path(args.out).write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
