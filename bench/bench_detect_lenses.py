#!/usr/bin/env python
"""Detection through any lens: frames per second of :func:`mutloc.detect.detect_image` per lens and
image size, the pinhole path as the peer in the same run.

    python bench/bench_detect_lenses.py            # 5 runs of 6 frames per case, then lights and cylinders
    python bench/bench_detect_lenses.py --quick    # 3 runs of 3 frames
    python bench/bench_detect_lenses.py --bodies-only   # lights and cylinders only (detect_lenses_bodies_results.json)
    python bench/bench_detect_lenses.py --bodies-only --no-lights --quick   # cylinders and balls, 8 frames

Cases: a tag36h11 tag and a red ball (one detector call each per frame, both timed) in

* a pinhole 1280x800 camera (the detectors as they always ran: no views),
* the SPEC's fisheye 1280x800 (f = 290 px; the image reaches 131 degrees off the axis at its sides,
  145 at its corners: 13 views) and the same with ``field_deg=95`` (a 190-degree lens's own field: 7 views),
* a fisheye 640x400 (f = 145 px),
* an omnidirectional (Mei, xi = 1) 1024x768 camera.

Lights and cylinders (:func:`bodies`): the simulator's robots with back-to-back fisheyes
(``mutloc.sim.body_scenes``), p driving past q's side so that its markers sweep 60-100 degrees off the
axis of q's front camera (:func:`~mutloc.sim.body_scenes.passing_body_world`); truth is the simulator's
projection of each light's centre / band centre.  Lights: one :class:`BlinkTracker` on q/front's raw
640x400 fisheye sequence (60 frames, no room); the error of every lit measurement, the detection rate (of
the frames after the first 0.7 s in which the light is visible, those where the tracker reports it within
1 px) per band of angles off the axis, and the tracker's frames/s; peer: the same tracker on the standard
pinhole pair (``standard_rig("lights")``, 640x400, f = 400 px) moving 2 m ahead.  Cylinders: 1280x800
fisheye frames in a room, q/front and q/back at 8 times, band error and detection rate (of the cylinders
whose centre is not hidden, those found with every band within 1 px) per band of angles and
:func:`detect_image` frames/s; peers: coloured balls in the same fisheye frames (the same robots and
poses, the simulator's balls above the bodies; error of the centre, rate within 1 px) and the standard pinhole
pair at 1280x800 (f = 800 px), 1.5 m.

Every call gets a new image (frames are ray-traced beforehand, the marker moved each frame, as in
tests/test_detect_lenses.py).  The views (remap tables) are built once per camera before timing -- a
per-camera cost, reported apart.  One core (NUMBA_NUM_THREADS=1, cv2.setNumThreads(1)).  FPS is the
median over runs of frames / wall-clock seconds.  Prints a table and writes
bench/results/detect_lenses_results.json.
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
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from mutloc.core.camera import Camera  # noqa: E402
from mutloc.core.lenses import FisheyeCamera, OmniCamera  # noqa: E402
from mutloc.core.rig import MarkerKind  # noqa: E402
from mutloc.detect import detect_image, image_detector  # noqa: E402
from mutloc.detect.views import detect_in_views, needs_views, views_for  # noqa: E402

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


#: Bands of angles off the axis (degrees) the bodies' figures are given in.
ANGLE_BANDS = ((0.0, 60.0), (60.0, 80.0), (80.0, 90.0), (90.0, 100.0))


def _band(off: float) -> str:
    for lo, hi in ANGLE_BANDS:
        if lo <= off < hi:
            return f"{lo:.0f}-{hi:.0f}"
    return "other"


def _off_deg(camera, uv) -> float:
    b = camera.pixels_to_bearings(np.asarray(uv, float))
    if not np.all(np.isfinite(b)):
        return float("nan")
    return float(np.degrees(np.arccos(np.clip(b[2] / np.linalg.norm(b), -1.0, 1.0))))


def _lights_run(world, key, camera, markers, frames: int, fps: float = 30.0) -> dict:
    from mutloc.detect.blink import BlinkTracker
    from mutloc.sim.render import project_markers, render

    imgs = [render(world, key, i / fps, seed=i, noise_sigma=1.0) for i in range(frames)]
    truths = [project_markers(world, key, i / fps, check_occlusion=True) for i in range(frames)]
    tracker = BlinkTracker(markers, fps, camera=camera)
    warm = round(0.7 * fps)
    errs: list[float] = []
    rate: dict[str, list[int]] = {}
    elapsed = 0.0
    for i, (img, truth) in enumerate(zip(imgs, truths)):
        t0 = time.perf_counter()
        res = tracker.update(img, i / fps)
        elapsed += time.perf_counter() - t0
        for name, uv in truth.items():
            d = res.detections.get(name)
            e = float(np.linalg.norm(d.uv - np.asarray(uv))) if d is not None else float("inf")
            if d is not None and d.info["on"]:
                errs.append(e)
            if i >= warm:
                r = rate.setdefault(_band(_off_deg(camera, uv)), [0, 0])
                r[0] += e <= 1.0
                r[1] += 1
    e = np.array(errs) if errs else np.array([np.nan])
    return {"frames": frames, "fps": frames / elapsed, "lit_measurements": len(errs),
            "error_median_px": float(np.median(e)), "error_p90_px": float(np.percentile(e, 90)),
            "error_max_px": float(np.max(e)), "detection_rate": {k: f"{a}/{b}" for k, (a, b) in sorted(rate.items())}}


def _cylinders_run(cases, rig, markers) -> dict:
    from mutloc.sim.render import project_markers, render

    errs: list[float] = []
    rate: dict[str, list[int]] = {}
    elapsed = 0.0
    for world, key, t in cases:
        camera = rig.mount(key).camera
        if needs_views(camera):
            views_for(camera)  # built once per camera, before timing
        img = render(world, key, t, seed=1, noise_sigma=1.0)
        shown = project_markers(world, key, t, check_occlusion=True)  # centres not hidden (e.g. by q's body)
        T = world.camera_pose(key, t).inverse() @ world.robot("p").pose_at(t)
        truth = {n: camera.project(T.apply(m.position)) for n, m in rig.robot("p").markers.items()
                 if m.extra.get("cylinder_of")}
        t0 = time.perf_counter()
        res = detect_image(MarkerKind.CYLINDER, img, markers, camera)
        elapsed += time.perf_counter() - t0
        for cyl in markers:
            bands = [n for n in truth if n.startswith(cyl + "#")]
            uv0 = truth[bands[len(bands) // 2]]
            if cyl not in shown:
                continue
            found = all(n in res.detections for n in bands)
            e = [float(np.linalg.norm(res.detections[n].uv - truth[n])) for n in bands] if found else []
            errs += e
            r = rate.setdefault(_band(_off_deg(camera, uv0)), [0, 0])
            r[0] += bool(found and max(e) <= 1.0)
            r[1] += 1
    e = np.array(errs) if errs else np.array([np.nan])
    return {"frames": len(cases), "fps": len(cases) / elapsed, "bands_measured": len(errs),
            "error_median_px": float(np.median(e)), "error_p90_px": float(np.percentile(e, 90)),
            "error_max_px": float(np.max(e)), "detection_rate": {k: f"{a}/{b}" for k, (a, b) in sorted(rate.items())}}


def _balls_run(cases, rig, markers) -> dict:
    """:func:`_cylinders_run` for coloured balls: the error of each found ball's centre against the
    simulator's projection of it; rate: balls not hidden found within 1 px."""
    from mutloc.sim.render import project_markers, render

    errs: list[float] = []
    rate: dict[str, list[int]] = {}
    elapsed = 0.0
    for world, key, t in cases:
        camera = rig.mount(key).camera
        views_for(camera)  # built once per camera, before timing
        img = render(world, key, t, seed=1, noise_sigma=1.0)
        shown = project_markers(world, key, t, check_occlusion=True)
        t0 = time.perf_counter()
        res = detect_image(MarkerKind.BALL, img, markers, camera)
        elapsed += time.perf_counter() - t0
        for name, uv in shown.items():
            d = res.detections.get(name)
            e = float(np.linalg.norm(d.uv - np.asarray(uv))) if d is not None else float("inf")
            if d is not None:
                errs.append(e)
            r = rate.setdefault(_band(_off_deg(camera, uv)), [0, 0])
            r[0] += e <= 1.0
            r[1] += 1
    e = np.array(errs) if errs else np.array([np.nan])
    return {"frames": len(cases), "fps": len(cases) / elapsed, "balls_measured": len(errs),
            "error_median_px": float(np.median(e)), "error_p90_px": float(np.percentile(e, 90)),
            "error_max_px": float(np.max(e)), "detection_rate": {k: f"{a}/{b}" for k, (a, b) in sorted(rate.items())}}


def bodies(quick: bool, lights: bool = True) -> list[dict]:
    """Lights and cylinders: fisheye out to the rim and the pinhole peer, in one run (see the docstring)."""
    rows: list[dict] = []
    n = 40 if quick else 60
    if lights:
        rows += _lights_rows(n)
    rows += _cylinder_rows(quick)
    return rows


def _lights_rows(n: int) -> list[dict]:
    from mutloc.sim.body_scenes import fisheye_pair_rig, passing_body_world
    from mutloc.sim.render import moving_world
    from mutloc.sim.world import standard_rig

    rows = []
    rig = fisheye_pair_rig("lights", size=(640, 400))
    world = passing_body_world(rig, lateral=1.1, speed=0.3 * 60.0 / n)
    rows.append({"markers": "lights", "case": "fisheye 640x400 (q/front, p passing 60-100 deg)",
                 **_lights_run(world, "q/front", rig.mount("q/front").camera, rig.robot("p").markers, n)})
    print("  lights fisheye: done", file=sys.stderr)
    prig = standard_rig("lights", size=(640, 400), f=400.0)
    pworld = moving_world(prig, room=False)
    rows.append({"markers": "lights", "case": "pinhole 640x400 f=400 (peer, standard pair 2 m)",
                 **_lights_run(pworld, "q", prig.robot("q").camera, prig.robot("p").markers, n)})
    print("  lights pinhole: done", file=sys.stderr)
    return rows


def _cylinder_rows(quick: bool) -> list[dict]:
    """Cylinders through the fisheye, coloured balls in the same scenes (same robots, poses, views), and
    cylinders through the pinhole peer."""
    from mutloc.core.pose import Pose
    from mutloc.sim.body_scenes import fisheye_pair_rig, passing_body_world
    from mutloc.sim.render import two_robot_world
    from mutloc.sim.world import standard_rig
    from mutloc.track.frames import expanded_rig

    rows = []
    rig0 = fisheye_pair_rig("cylinders")
    crig = expanded_rig(rig0)
    cworld = passing_body_world(rig0, lateral=1.0, room=True, seed=0)
    times = (0.0, 0.5, 1.0, 1.5) if quick else (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75)
    cases = [(cworld, "q/front", t) for t in times] + [(cworld, "q/back", t + 1.5) for t in times]
    rows.append({"markers": "cylinders", "case": "fisheye 1280x800 (q/front, q/back, p passing, room)",
                 **_cylinders_run(cases, crig, rig0.robot("p").markers)})
    print("  cylinders fisheye: done", file=sys.stderr)
    brig = fisheye_pair_rig("balls")
    bworld = passing_body_world(brig, lateral=1.0, room=True, seed=0)
    bcases = [(bworld, key, t) for _, key, t in cases]
    rows.append({"markers": "balls", "case": "fisheye 1280x800 (same robots, poses and times; balls)",
                 **_balls_run(bcases, brig, brig.robot("p").markers)})
    print("  balls fisheye: done", file=sys.stderr)
    srig0 = standard_rig("cylinders", size=(1280, 800), f=800.0)
    srig = expanded_rig(srig0)
    pcases = []
    for i, t in enumerate(times):
        T_qp = Pose(np.eye(3), np.array([0.3 * math.sin(2.0 * t), 0.0, 1.5]))
        pcases.append((two_robot_world(srig0, T_qp, seed=i), "q", 0.0))
    rows.append({"markers": "cylinders", "case": "pinhole 1280x800 f=800 (peer, 1.5 m, room)",
                 **_cylinders_run(pcases, srig, srig0.robot("p").markers)})
    print("  cylinders pinhole: done", file=sys.stderr)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--bodies-only", action="store_true", help="lights and cylinders only")
    ap.add_argument("--no-lights", action="store_true", help="with --bodies-only: cylinders (and balls) only")
    ap.add_argument("--out", default=result_file("detect_lenses_results.json"))
    args = ap.parse_args()
    if args.bodies_only and args.out == result_file("detect_lenses_results.json"):
        args.out = result_file("detect_lenses_bodies_results.json")
    cv2.setNumThreads(1)
    runs, per_run = (3, 3) if args.quick else (5, 6)
    result: dict = {"machine": machine(), "command": " ".join(["python"] + sys.argv), "one_core": True,
                    "runs": runs, "frames_per_run": per_run, "cases": []}
    markers = {"tag": T._tag_marker(), "ball": T._ball_marker()}
    kinds = {"tag": MarkerKind.TAG, "ball": MarkerKind.BALL}
    for name, camera, field, off in ([] if args.bodies_only else CASES):
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
    result["bodies"] = bodies(args.quick, lights=not args.no_lights)
    print(f"{'markers':9s} {'case':52s} {'fps':>7s} {'median px':>9s} {'p90 px':>7s} {'max px':>7s}  detection rate")
    for r in result["bodies"]:
        print(f"{r['markers']:9s} {r['case']:52s} {r['fps']:7.1f} {r['error_median_px']:9.3f} "
              f"{r['error_p90_px']:7.3f} {r['error_max_px']:7.3f}  {r['detection_rate']}")
    Path(args.out).write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
