"""Cameras at their own times: accuracy of `track` on an unsynchronized log
against the synchronized log of the same scene, and against the peer a user
would otherwise reach for -- pairing each p frame with the nearest q frame
and treating the two as simultaneous.

Scenes (mutloc.sim.tracking.camera_records, the standard ball rig, 1 px
noise, 4 s, first 0.5 s left out): p driving in front of q at up to
0.5 m/s (`slow`, default motion noise), and p at up to 1.5 m/s while q pans
at up to 90 deg/s (`fast`, motion noise 5 rad/s^2, 3 m/s^2 per sqrt(Hz)).
Cameras: both at 30 fps in step (`sync`); q half a frame after p (`half`:
records alternate p-only and q-only); q at 15 fps, 11 ms after p (`30+15`).

    .venv/bin/python bench/bench_unsync.py [--seeds N] [--tracker pair|team]

``--tracker team``: the team tracker on the pair (q the reference), the
same logs.  Writes bench/results/unsync.json (``unsync_team.json``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _machine import machine, result_file  # noqa: E402

from mutloc.core.filter import MotionNoise  # noqa: E402
from mutloc.core.geometry import so3_exp  # noqa: E402
from mutloc.core.observations import ObservationSet  # noqa: E402
from mutloc.core.pose import Pose  # noqa: E402
from mutloc.sim.render import default_path  # noqa: E402
from mutloc.sim.tracking import camera_records  # noqa: E402
from mutloc.sim.world import standard_rig  # noqa: E402
from mutloc.track.filtering import FilterOptions  # noqa: E402
from mutloc.track.tracker import track_log  # noqa: E402


def _team_log(rig, frames, **kw):
    """The team tracker on the pair: p's rows in q's frame."""
    from mutloc.track.team import track_team_log

    return track_team_log(rig, frames, reference="q", **kw).tracks["p"]


def fast_path():
    base = default_path(2.0, 2.5, 0.3)

    def T(t):
        return Pose(so3_exp([0.0, math.radians(15.0) * math.sin(2 * math.pi * t), 0.0]), np.zeros(3)) @ base(t)

    return T


def nearest_pairs(recs):
    """The peer: each p frame merged with the nearest q frame, stamped at p's time."""
    p = [(t, f) for t, f, c in zip(recs.times, recs.frames, recs.cameras) if "p" in c]
    q = [(t, f) for t, f, c in zip(recs.times, recs.frames, recs.cameras) if "q" in c]
    qt = np.array([t for t, _ in q])
    out = []
    for t, f in p:
        _, g = q[int(np.argmin(np.abs(qt - t)))]
        both = ObservationSet(list(f.observer) + list(g.observer), list(f.marker) + list(g.marker),
                              np.vstack([f.uv, g.uv]), float(t))
        out.append((t, both))
    return out


def score(traj, times, truth, after=0.5):
    err, nees, n = [], [], 0
    for row, t, T in zip(traj.rows, times, truth):
        if t < after:
            continue
        n += 1
        if row.estimate is None:
            continue
        d = row.estimate.t - T.t
        err.append(float(np.linalg.norm(d)))
        nees.append(float(d @ np.linalg.solve(row.estimate.covariance[3:, 3:], d) / 3))
    return {"median_translation_m": float(np.median(err)), "rows": n, "with_pose": len(err),
            "median_nees": float(np.median(nees)), "over_5_sigma": int(sum(x > 25 / 3 for x in nees))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--tracker", choices=("pair", "team"), default="pair")
    args = ap.parse_args()
    track = track_log if args.tracker == "pair" else _team_log
    rig = standard_rig()
    scenes = {"slow": (default_path(2.0, 8.0, 0.3), MotionNoise()),
              "fast": (fast_path(), MotionNoise(angular=5.0, linear=3.0))}
    cams = {"sync": ({}, {}), "half": ({"q": 1 / 60}, {}), "30+15": ({"q": 0.011}, {"q": 15.0})}
    out = {"machine": machine(), "seeds": args.seeds, "tracker": args.tracker, "scenes": {}}
    t0 = time.perf_counter()
    for name, (path, noise) in scenes.items():
        opts = FilterOptions(noise=noise)
        res: dict[str, list] = {}
        for seed in range(args.seeds):
            for cam, (offsets, rates) in cams.items():
                recs = camera_records(rig, path, duration=4.0, offsets=offsets, rates=rates, seed=seed)
                traj = track(rig, list(zip(recs.times, recs.frames)), progress=False, filter=opts)
                res.setdefault(cam, []).append(score(traj, recs.times, recs.truth))
                if cam == "half":
                    pairs = nearest_pairs(recs)
                    traj = track(rig, pairs, progress=False, filter=opts)
                    ptimes = np.array([t for t, _ in pairs])
                    ptruth = Pose.concatenate([path(float(t)) for t in ptimes])
                    res.setdefault("half, nearest pairs", []).append(score(traj, ptimes, ptruth))
            print(f"{name} seed {seed} done ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
        summary = {}
        for cam, runs in res.items():
            summary[cam] = {"median_translation_m": float(np.median([r["median_translation_m"] for r in runs])),
                            "median_nees": float(np.median([r["median_nees"] for r in runs])),
                            "rows_with_pose": f"{sum(r['with_pose'] for r in runs)}/{sum(r['rows'] for r in runs)}",
                            "over_5_sigma": sum(r["over_5_sigma"] for r in runs)}
        base = summary["sync"]["median_translation_m"]
        for cam, s in summary.items():
            s["ratio_to_sync"] = s["median_translation_m"] / base
            print(f"{name:5s} {cam:20s} median {100 * s['median_translation_m']:.3f} cm ({s['ratio_to_sync']:.2f}x "
                  f"sync)  NEES/3 {s['median_nees']:.2f}  poses {s['rows_with_pose']}  >5 sigma {s['over_5_sigma']}")
        out["scenes"][name] = summary
    path = Path(result_file("unsync.json" if args.tracker == "pair" else "unsync_team.json"))
    path.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
