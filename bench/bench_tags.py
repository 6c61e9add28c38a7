#!/usr/bin/env python
"""Tag detectors side by side on the same rendered images: recall, corner accuracy, speed.

    python bench/bench_tags.py            # 8 scenes at 960x540, 3 at 1920x1080
    python bench/bench_tags.py --quick    # 3 + 1 scenes, fewer repeats

Images: :func:`mutloc.sim.tag_scenes.tag_scene` -- 14 tag36h11 tags of 12 cm,
1.2-3.5 m away, tilted up to 50 deg, some across the image border and some
partly behind a sphere, in a textured room; sRGB output, 0.8 px optical blur,
noise 2 DN, every other scene through JPEG at quality 90.  Truth: the tag
corners projected through the camera.

Detectors (one thread each, all starting from the same BGR frame, so the grey
conversion is part of every one of them):

* ``opencv_aruco``: ``cv2.aruco.ArucoDetector`` (DICT_APRILTAG_36h11,
  ``CORNER_REFINE_SUBPIX``) -- what mutloc's tag detector used before;
* ``apriltag3``: the AprilTag 3 library as the pupil-apriltags wheel exposes it
  (``Detector(families="tag36h11")``, its defaults: decimation 2);
* ``mutloc``: :func:`mutloc.detect.tags.detect_tags` defaults (the same
  library, then the sub-pixel edge fit in linearised grey levels);
* ``mutloc_no_refine``: ``detect_tags(refine="none")`` (the library's corners);
* ``mutloc_decimate_1.5``: ``detect_tags(params={"quad_decimate": 1.5})``
  (the library's quad search on a finer image: more small tags).

Recall: tags found / tags placed, and over the tags fully in view and not
occluded.  Corner error: for the peers the nearest true corner (their corner
order differs), for mutloc its own corner k against true corner k; over the
fully visible tags found by the detector.  False: ids reported that are not in
the image.  FPS: frames / wall-clock second, median of repeats over all scenes
(CPU seconds beside it).  Writes bench/results/tags_results.json.
"""

from __future__ import annotations

import argparse
import importlib.metadata
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

from mutloc.detect.apriltag_lib import peer_detector  # noqa: E402
from mutloc.detect.tags import detect_tags  # noqa: E402
from mutloc.sim.tag_scenes import scene_camera, tag_scene  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402

cv2.setNumThreads(1)

FAMILY = "tag36h11"
SIZES = ((960, 540), (1920, 1080))


def _opencv():
    p = cv2.aruco.DetectorParameters()
    p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), p)

    def run(image, markers):
        corners, ids, _ = det.detectMarkers(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))
        if ids is None:
            return {}
        return {int(i): c.reshape(4, 2).astype(float) for i, c in zip(ids.ravel(), corners)}
    return run


def _apriltag3():
    det = peer_detector(FAMILY)

    def run(image, markers):
        # The library's pixel origin is the top-left corner of the image: -0.5 to mutloc's.
        return {d.tag_id: d.corners - 0.5 for d in det.detect(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))}
    return run


def _mutloc(**kw):
    def run(image, markers):
        res = detect_tags(image, markers, **kw)
        return {markers[n].tag["id"]: d.corners for n, d in res.detections.items()}
    return run


DETECTORS = {"opencv_aruco": _opencv, "apriltag3": _apriltag3, "mutloc": _mutloc,
             "mutloc_no_refine": lambda: _mutloc(refine="none"),
             "mutloc_decimate_1.5": lambda: _mutloc(params={"quad_decimate": 1.5})}
ORDERED = {"mutloc", "mutloc_no_refine", "mutloc_decimate_1.5"}  # corner k is true corner k


def corner_errors(found: np.ndarray, truth: np.ndarray, ordered: bool) -> np.ndarray:
    if ordered:
        return np.linalg.norm(found - truth, axis=1)
    d = np.linalg.norm(found[:, None, :] - truth[None, :, :], axis=2)
    return d.min(axis=1)


def evaluate(scenes, name: str, repeat: int) -> dict:
    run = DETECTORS[name]()
    placed = visible = found = found_visible = false = 0
    errs = []
    for sc in scenes:
        by_id = {m.tag["id"]: n for n, m in sc.markers.items()}
        out = run(sc.image, sc.markers)
        for tid, corners in out.items():
            n = by_id.get(tid)
            if n is None:
                false += 1
                continue
            found += 1
            if sc.in_frame[n] and not sc.occluded[n]:
                found_visible += 1
                errs.append(corner_errors(corners, sc.corners[n], name in ORDERED))
        placed += len(sc.markers)
        visible += sum(sc.in_frame[n] and not sc.occluded[n] for n in sc.markers)
    walls, cpus = [], []
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        for sc in scenes:
            run(sc.image, sc.markers)
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    e = np.concatenate(errs) if errs else np.array([np.nan])
    return {"found": found, "placed": placed, "found_fully_visible": found_visible, "fully_visible": visible,
            "false": false, "corner_median_px": float(np.median(e)), "corner_p90_px": float(np.percentile(e, 90)),
            "fps": len(scenes) / float(np.median(walls)), "fps_cpu": len(scenes) / float(np.median(cpus))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=result_file("tags_results.json"))
    args = ap.parse_args()
    n_scenes = {SIZES[0]: 3 if args.quick else 8, SIZES[1]: 1 if args.quick else 3}
    repeat = 3 if args.quick else 7
    results: dict = {"machine": machine(), "pupil_apriltags": importlib.metadata.version("pupil-apriltags"),
                     "sizes": {}}
    for size in SIZES:
        cam = scene_camera(*size)
        t0 = time.time()
        scenes = [tag_scene(seed, n_tags=14, camera=cam, psf_sigma_px=0.8 * size[0] / 960,
                            jpeg_quality=90 if seed % 2 else None) for seed in range(n_scenes[size])]
        print(f"{size[0]}x{size[1]}: rendered {len(scenes)} scenes in {time.time() - t0:.0f} s", flush=True)
        for name in DETECTORS:  # warm up (compilation, library tables)
            DETECTORS[name]()(scenes[0].image, scenes[0].markers)
        rows = {name: evaluate(scenes, name, repeat) for name in DETECTORS}
        results["sizes"][f"{size[0]}x{size[1]}"] = rows
        print(f"{'detector':20s} {'found/placed':>12s} {'visible':>9s} {'false':>5s} {'corner med/p90 px':>18s} "
              f"{'FPS':>6s} {'FPS(cpu)':>8s}")
        for name, r in rows.items():
            print(f"{name:20s} {r['found']:>5d}/{r['placed']:<6d} {r['found_fully_visible']:>4d}/{r['fully_visible']:<4d} "
                  f"{r['false']:>5d} {r['corner_median_px']:>8.3f} / {r['corner_p90_px']:<7.3f} {r['fps']:>6.1f} "
                  f"{r['fps_cpu']:>8.1f}")
        ratio = rows["mutloc"]["fps_cpu"] / rows["apriltag3"]["fps_cpu"]
        results["sizes"][f"{size[0]}x{size[1]}"]["mutloc_over_apriltag3_speed"] = ratio
        print(f"mutloc / apriltag3 speed (CPU time): {ratio:.2f}\n", flush=True)
    Path(args.out).write_text(json.dumps(results, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
