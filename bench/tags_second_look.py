#!/usr/bin/env python
"""Pairs where one robot's tag is seen far off its normal: the first look, the look again where the pose puts
the missing tag (:mod:`mutloc.track.tag_look`), and the whole image searched at full resolution.

    python bench/tags_second_look.py [--n 12] [--tilts 0,40,50,55,60,65,70] [--distances 2,3]

Each scene (``tests/test_tags_real.pair_scene``): robots p and q facing each other ``distance`` apart
(headings jittered by up to 0.25 rad, sideways up to 7 % of the distance, small tilts), one 12 cm tag36h11
tag per robot 12 cm below its camera; q's tag faces its camera's way, p's is turned by ``tilt`` about p's
vertical axis (a tag on a slanted mount), so q sees it about ``tilt`` off its normal while p sees q's
roughly face-on; rendered by mutloc's renderer (optical blur 0.8 px, noise 2 DN, sRGB) in a textured room.  Per setting, over the scenes: how often q's image gave p's tag (its
four corners used by the pose), and the pose's translation error (median / p90 cm; no pose counts as
infinite) against the rendered one, and the found tag's worst corner's error (median px):

- ``first look``: :func:`mutloc.track.frames.detect_markers` (the AprilTag library at quad decimation 2,
  then the edge fit) and one solve;
- ``looked again``: the first look, then the missing tag looked for where the first solve puts it and the
  solve again (:func:`mutloc.track.tag_look.with_tags_looked_for`: what :func:`mutloc.track.localize_images`
  does, without its check that the streams are not swapped, which detects each robot's own markers too);
- ``full resolution``: both images searched whole at quad decimation 1 (``detect_tags(params=
  {"quad_decimate": 1.0})``), one solve;
- ``localize_images``: the user's call itself (recall and pose only; it should equal ``looked again``).

Then the CPU time per frame pair of each (best of 3 over the scenes of 50-60 degrees, a fresh copy of the
images each call), on one core.  Writes bench/results/tags_second_look_results.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT.parent / "tests"))

from _machine import machine  # noqa: E402
from test_tags_real import pair_scene  # noqa: E402

from mutloc.detect.tags import corner_detections, corner_marker_names, detect_tags, tag_corner_points  # noqa: E402
from mutloc.errors import MutlocError  # noqa: E402
from mutloc.track import localize_images  # noqa: E402
from mutloc.track.frames import detect_markers, prepare_pair  # noqa: E402
from mutloc.track.tag_look import first_solve, with_tags_looked_for  # noqa: E402

def scene(tilt_deg: float, distance: float, seed: int):
    """(rig, T_qp, images) of one pair, p's tag turned by ``tilt_deg`` (``tests/test_tags_real.pair_scene``)."""
    return pair_scene(seed, distance, tilt_p_deg=tilt_deg)


def first_look(rig, imgs):
    ex, s, t = prepare_pair(rig, imgs, None, None, "image")
    dets = {o: detect_markers(ex, o, imgs[o], targets=[t if o == s else s]) for o in (s, t)}
    est, _ = first_solve(ex, dets, s, t)
    return est, dets


def looked_again(rig, imgs):
    ex, s, t = prepare_pair(rig, imgs, None, None, "image")
    dets = {o: detect_markers(ex, o, imgs[o], targets=[t if o == s else s]) for o in (s, t)}
    est, err = first_solve(ex, dets, s, t)
    dets, est, _ = with_tags_looked_for(ex, imgs, dets, est, err, s, t)
    return est, dets


def user_call(rig, imgs):
    """What a user calls: :func:`localize_images` (also checks that the streams are not swapped)."""
    try:
        res = localize_images(rig, imgs)
    except MutlocError:
        return None, None
    return res.estimate, res.detections


def full_resolution(rig, imgs):
    ex, s, t = prepare_pair(rig, imgs, None, None, "image")
    dets = {}
    for o in (s, t):
        other = t if o == s else s
        found = detect_tags(imgs[o], ex.robot(other).markers, camera=ex.robot(o).camera,
                            params={"quad_decimate": 1.0})
        for name, det in list(found.detections.items()):
            found.detections.update(corner_detections(det))
            del found.detections[name]
        dets[o] = found
    est, _ = first_solve(ex, dets, s, t)
    return est, dets


SETTINGS = {"first look": first_look, "looked again": looked_again, "full resolution": full_resolution}
CHECKS = {"localize_images": user_call}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=12)
    ap.add_argument("--tilts", default="0,40,50,55,60,65,70")
    ap.add_argument("--distances", default="2,3")
    ap.add_argument("--json", type=Path, default=ROOT / "results" / "tags_second_look_results.json")
    args = ap.parse_args()
    tilts = [float(x) for x in args.tilts.split(",")]
    dists = [float(x) for x in args.distances.split(",")]
    print(machine())
    rows = []
    timing_scenes = []
    print(f"{'tilt':>5s} {'dist':>5s} " + " ".join(f"{k:>30s}" for k in {**SETTINGS, **CHECKS}))
    for dist in dists:
        for tilt in tilts:
            out = {"tilt_deg": tilt, "distance_m": dist}
            cells = []
            scenes = [scene(tilt, dist, 1000 * int(dist * 10) + 7 * int(tilt) + seed) for seed in range(args.n)]
            if 50 <= tilt <= 60:
                timing_scenes += [(rig, imgs) for rig, _, imgs in scenes]
            for name, fn in {**SETTINGS, **CHECKS}.items():
                found, cm, corner = 0, [], []
                for rig, T, imgs in scenes:
                    est, dets = fn(rig, imgs)
                    truth = rig.robot("q").camera.project(T.apply(tag_corner_points(rig.robot("p").markers["TP"])))
                    got = [dets["q"].detections.get(c) for c in corner_marker_names("TP")] if dets else [None]
                    if all(d is not None for d in got):
                        found += 1
                        corner.append(float(max(np.hypot(*(d.uv - x)) for d, x in zip(got, truth))))
                    cm.append(float("inf") if est is None else 100 * est.pose.translation_error(T))
                med, p90 = np.median(cm), np.quantile(cm, 0.9, method="higher")
                out[name] = {"found": found, "n": args.n, "cm_median": med, "cm_p90": p90,
                             "corner_px_median": float(np.median(corner)) if corner else None}
                c = f"{np.median(corner):.2f}" if corner else "-"
                cells.append(f"{found:2d}/{args.n} {c:>5s} px {med:6.3f} / {p90:6.3f} cm")
            rows.append(out)
            print(f"{tilt:5.0f} {dist:5.1f} " + " ".join(f"{c:>30s}" for c in cells), flush=True)
    print()
    times = {}
    for name, fn in SETTINGS.items():
        best = float("inf")
        for _ in range(3):
            t0 = time.process_time()
            for rig, imgs in timing_scenes:
                fn(rig, {o: im.copy() for o, im in imgs.items()})
            best = min(best, (time.process_time() - t0) / len(timing_scenes))
        times[name] = 1000 * best
    print("CPU per frame pair (ms, scenes of 50-60 deg): " + ", ".join(f"{k} {v:.1f}" for k, v in times.items()))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"machine": machine(), "rows": rows, "cpu_ms": times}, indent=1))


if __name__ == "__main__":
    main()
