#!/usr/bin/env python
"""Tracking robots with several cameras: error against the simulated truth, beside one camera per robot.

    python bench/bench_track_bodies.py              # 3 seeds x 10 s at 30 fps per case
    python bench/bench_track_bodies.py --seeds 1    # quicker

The motion is `mutloc simulate --cameras back-to-back-fisheye --frames N`'s (mutloc.sim.body_scenes
.moving_body_world: p drives a smooth figure 2 m from q, q pans), the markers its two balls per robot; pixels
are the exact projections of the marker centres through each camera (mount pose and lens) plus sigma = 1 px
noise, every camera its own record at 30 fps (no rendering: the tracker is measured, not the detector).

Cases (each `mutloc.track.tracker.track_log`, default filter and smoother, --pixel-sigma 1):

- ``single pinhole, facing``: one pinhole camera per robot (640x400, 90 degrees across) where the body's front
  fisheye is, the robot's frame its optical frame (a rig with ``camera:``: the single-camera path), the robots
  facing each other; errors in the cameras' frames;
- ``two fisheyes, facing``: the same robots as bodies with back-to-back fisheyes (640x400, 199 degrees),
  facing each other (the front cameras see each other), errors between body frames;
- ``two fisheyes, back to back``: facing away (only the back cameras see each other);
- ``two fisheyes, back to back, unsynchronized``: as above, q's cameras 11 ms after p's (each record one
  camera's two observations: ``partial``).

Per case: statuses, translation error median / p90 (cm), rotation median / p90 (deg), NEES mean, rows beyond
5 sigma (NEES above chi2_6's two-sided 5-sigma quantile, 39.5), and the tracker's time per record (one core,
median of the seeds' runs, each on new observation sets).  Writes bench/results/track_bodies_results.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from mutloc.core.camera import Camera  # noqa: E402
from mutloc.core.geometry import so3_log  # noqa: E402
from mutloc.core.observations import ObservationSet  # noqa: E402
from mutloc.core.pose import Pose  # noqa: E402
from mutloc.core.rig import Marker, Mount, Rig, Robot  # noqa: E402
from mutloc.sim.body_scenes import fisheye_pair_rig, moving_body_world  # noqa: E402
from mutloc.sim.render import project_markers, relative_pose  # noqa: E402
from mutloc.track.tracker import track_log  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402

NEES_5_SIGMA = 39.49
SIZE = (640, 400)
SIGMA = 1.0


def pinhole_bodies() -> Rig:
    """The fisheye pair's robots with one 90-degree pinhole camera each at the front mount (bodies, for the
    simulator's projections; :func:`central` turns them into the single-camera path's rig)."""
    fish = fisheye_pair_rig("balls", size=SIZE)
    w, h = SIZE
    f = 0.5 * w / np.tan(np.radians(45.0))
    cam = Camera([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]], [0.0] * 5, SIZE)
    return Rig({r: Robot(r, None, fish.robot(r).markers, cameras={"front": Mount("front", cam,
                                                                              fish.robot(r).cameras["front"].pose)})
                for r in ("p", "q")})


def central(bodies: Rig) -> tuple[Rig, dict[str, Pose]]:
    """The single-camera rig (``camera:``, markers in each camera's optical frame) and each camera's mount."""
    robots, mounts = {}, {}
    for r, rb in bodies.robots.items():
        m = rb.cameras["front"]
        inv = m.pose.inverse()
        robots[r] = Robot(r, m.camera, {n: Marker(n, r, inv.apply(mk.position), color=mk.color, extra=dict(mk.extra))
                                        for n, mk in rb.markers.items()})
        mounts[r] = m.pose
    return Rig(robots), mounts


def records(rig: Rig, world, seconds: float, offset: float, rng: np.random.Generator, rename=None):
    """Every camera's view, its own record at 30 fps (q's ``offset`` s after p's), exact pixels + noise."""
    out: dict[float, dict] = {}
    for i in range(int(round(seconds * 30))):
        for key in rig.observer_keys():
            t = round(i / 30 + (offset if key.startswith("q") else 0.0), 6)
            cam = rig.mount(key).camera
            seen = {}
            for m, uv in project_markers(world, key, t).items():
                x = np.asarray(uv) + SIGMA * rng.standard_normal(2)
                if cam.in_image(x) and np.all(np.isfinite(cam.pixels_to_bearings(x[None]))):
                    seen[m] = x.tolist()
            if seen:
                out.setdefault(t, {})[rename(key) if rename else key] = seen
    return [(t, out[t]) for t in sorted(out)]


def run_case(name: str, facing: str, offset: float, single: bool, seeds: int, seconds: float) -> dict:
    bodies = pinhole_bodies() if single else fisheye_pair_rig("balls", size=SIZE)
    track_rig, mounts = central(bodies) if single else (bodies, None)
    world = moving_body_world(bodies, facing=facing, room=False)
    stats = {"rows": 0, "statuses": {}, "t_err": [], "r_err": [], "nees": [], "ms_per_record": []}
    for seed in range(seeds):
        rng = np.random.default_rng(100 + seed)
        recs = records(bodies, world, seconds, offset, rng, (lambda k: k.split("/")[0]) if single else None)
        log = [(t, ObservationSet.from_dict(o, time=t)) for t, o in recs]  # new sets for every run
        t0 = time.perf_counter()
        traj = track_log(track_rig, log, pixel_sigma=SIGMA, progress=False)
        stats["ms_per_record"].append(1000 * (time.perf_counter() - t0) / len(log))
        for row in traj.rows:
            stats["rows"] += 1
            s = row.status.value
            stats["statuses"][s] = stats["statuses"].get(s, 0) + 1
            if row.estimate is None:
                continue
            T = relative_pose(world, "p", "q", row.t)
            if single:
                T = mounts["q"].inverse() @ T @ mounts["p"]  # between the cameras' optical frames
            e = np.r_[so3_log(T.R @ row.estimate.R.T), T.t - row.estimate.t]
            stats["t_err"].append(float(np.linalg.norm(e[3:])))
            stats["r_err"].append(float(np.degrees(np.linalg.norm(e[:3]))))
            stats["nees"].append(float(e @ np.linalg.solve(row.estimate.covariance, e)))
    t_err, r_err, nees = (np.array(stats[k]) for k in ("t_err", "r_err", "nees"))
    return {"case": name, "rows": stats["rows"], "statuses": stats["statuses"], "with_pose": int(len(t_err)),
            "t_err_cm_median": float(100 * np.median(t_err)) if len(t_err) else None,
            "t_err_cm_p90": float(100 * np.percentile(t_err, 90)) if len(t_err) else None,
            "r_err_deg_median": float(np.median(r_err)) if len(r_err) else None,
            "r_err_deg_p90": float(np.percentile(r_err, 90)) if len(r_err) else None,
            "nees_mean": float(np.mean(nees)) if len(nees) else None,
            "beyond_5_sigma": int(np.sum(nees > NEES_5_SIGMA)),
            "ms_per_record_median": float(np.median(stats["ms_per_record"])),
            "ms_per_record_runs": stats["ms_per_record"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args()
    info = machine()
    cases = [("single pinhole, facing", "toward", 0.0, True), ("two fisheyes, facing", "toward", 0.0, False),
             ("two fisheyes, back to back", "away", 0.0, False),
             ("two fisheyes, back to back, unsynchronized", "away", 0.011, False)]
    for _, facing, offset, single in cases:  # every path's compiled kernels warmed first (not timed)
        run_case("warm", facing, offset, single, 1, 1.0)
    results = []
    for name, facing, offset, single in cases:
        r = run_case(name, facing, offset, single, args.seeds, args.seconds)
        results.append(r)
        print(f"{name}: {r['rows']} rows {r['statuses']}; translation median {r['t_err_cm_median']:.2f} cm, "
              f"p90 {r['t_err_cm_p90']:.2f} cm; rotation median {r['r_err_deg_median']:.3f} deg, p90 "
              f"{r['r_err_deg_p90']:.3f} deg; NEES mean {r['nees_mean']:.2f}; beyond 5 sigma "
              f"{r['beyond_5_sigma']}; {r['ms_per_record_median']:.2f} ms/record")
    info["load_average_at_end"] = list(os.getloadavg())
    out = Path(result_file("track_bodies_results.json"))
    out.write_text(json.dumps({"machine": info, "seeds": args.seeds, "seconds": args.seconds, "pixel_sigma": SIGMA,
                               "size": SIZE, "cases": results}, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
