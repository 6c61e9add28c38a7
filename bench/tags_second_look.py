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

    python bench/tags_second_look.py --track [--frames 45]

Tracking instead: p moving in front of q (``mutloc.sim.render.moving_world``, 3 m, p's tag turned 55
degrees; 15 fps per camera for 3 s), the cameras synchronized or q's half a frame after p's (every frame
a record of its own, where no record has a pose of its own from both cameras), optical blur 0 (the
renderer's default) or 0.8 px; :func:`mutloc.track.tracker.track` as shipped (a missing tag looked for
where the record's pose and where the track put it) and with both looks switched off (the module
functions replaced by ones that find nothing: an ablation, not an option).  Translation error of every
row with a pose after the first 0.5 s (median / p90 cm) and how many rows had one.
"""

from __future__ import annotations

import argparse
import contextlib
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


@contextlib.contextmanager
def looks_switched_off(off: bool = True):
    """Within: the trackers' tag looks find nothing (the ablation of ``--track``; ``off=False``: as shipped)."""
    import mutloc.track.second_look as second_look
    import mutloc.track.tracker as tracker

    saved = tracker.look_where_tracked, second_look.missing_tags
    if off:
        tracker.look_where_tracked = lambda rig, images, dets, predicted: (dict(dets), [])
        second_look.missing_tags = lambda *a, **k: {}
    try:
        yield
    finally:
        tracker.look_where_tracked, second_look.missing_tags = saved


def track_rows(tilt: float, distance: float, frames: int, q_offset: float, psf: float, looks: bool):
    """(rows with a pose after 0.5 s, median cm, p90 cm) of one tracked sequence."""
    import dataclasses

    import mutloc.track.tracker as tracker
    from mutloc.sim.render import moving_world, relative_pose, render
    from mutloc.track.sources import Frame
    from test_tags_real import tag_rig

    rig = tag_rig(tilt_p_deg=tilt)
    world = moving_world(rig, distance=distance, period=8.0, seed=0)
    world = dataclasses.replace(world, sensor=dataclasses.replace(world.sensor, psf_sigma_px=psf))
    fps = 15.0
    streams = {r: [Frame(k, k / fps + off, render(world, r, k / fps + off, seed=1 + k, noise_sigma=2.0))
                   for k in range(frames)] for r, off in (("p", 0.0), ("q", q_offset))}
    with looks_switched_off(not looks):
        traj = tracker.track(rig, streams, progress=False)
    e = [100 * r.estimate.pose.translation_error(relative_pose(world, "p", "q", r.t)) for r in traj.rows
         if r.estimate is not None and r.t >= 0.5]
    return len(e), float(np.median(e)), float(np.quantile(e, 0.9, method="higher"))


def main_track(args) -> None:
    print(machine())
    out = []
    for psf in (0.0, 0.8):
        for name, off in (("synchronized", 0.0), ("q half a frame late", 1 / 30.0)):
            row = {"psf_px": psf, "cameras": name}
            cells = []
            for looks in (True, False):
                n, med, p90 = track_rows(55.0, 3.0, args.frames, off, psf, looks)
                row["looks" if looks else "no looks"] = {"rows": n, "cm_median": med, "cm_p90": p90}
                cells.append(f"{'looks' if looks else 'no looks'}: {n} rows, {med:.3f} / {p90:.3f} cm")
            out.append(row)
            print(f"blur {psf:.1f} px, {name:20s} " + " | ".join(cells), flush=True)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"machine": machine(), "track": out}, indent=1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=12)
    ap.add_argument("--tilts", default="0,40,50,55,60,65,70")
    ap.add_argument("--distances", default="2,3")
    ap.add_argument("--json", type=Path, default=ROOT / "results" / "tags_second_look_results.json")
    ap.add_argument("--track", action="store_true", help="tracked sequences instead of single pairs")
    ap.add_argument("--frames", type=int, default=45, help="--track: frames per camera (15 fps)")
    args = ap.parse_args()
    if args.track:
        if args.json == ROOT / "results" / "tags_second_look_results.json":
            args.json = ROOT / "results" / "tags_second_look_track_results.json"
        return main_track(args)
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
