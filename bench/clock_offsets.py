"""A robot's clock 40 ms off: the offset estimated from the log and the track corrected by it
(mutloc issue 37, "Clock offsets"; ``mutloc track --clock-offsets estimate``).

Scene (the simulator, :func:`mutloc.sim.scenario.write_team_simulation`): two robots, r0 the reference,
fast (``speed`` 0.7 m/s: each drives a circle of 0.3 m radius at 0.8-1.2 x that), both cameras at 30 fps,
1 px noise, ``--seconds`` long; r1's clock ``--offset`` s behind r0's (``clock_offset``, truth.json's
``clock_offsets``): each observation stamped on its observer's clock
(:func:`mutloc.sim.truth_log.truth_log`).  Per seed: the estimate
(:func:`mutloc.track.clocks.estimate_clock_offsets`, default search) against the truth, its sigma, its
run time; r1's translation error (median / p90, cm, the truth interpolated at each row's time) tracked
with :func:`mutloc.track.team.track_team_log` (default options, fixed-lag smoother) on the log with
the estimated correction, without it, and on the synchronized log (every robot on the true time) in
the same run.

    .venv/bin/python bench/clock_offsets.py [--seeds N] [--seconds S] [--offset S]

Writes bench/results/clock_offsets.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _machine import machine, result_file  # noqa: E402

from mutloc.api import load_rig  # noqa: E402
from mutloc.sim.scenario import write_team_simulation  # noqa: E402
from mutloc.sim.truth_log import truth_log  # noqa: E402
from mutloc.track.clocks import estimate_clock_offsets, shift_records  # noqa: E402
from mutloc.track.frames import expanded_rig  # noqa: E402
from mutloc.track.team import track_team_log  # noqa: E402

FPS = 30.0


def errors_cm(traj, truth) -> dict:
    ts = np.array([f["timestamp"] for f in truth["frames"]])
    xyz = np.array([f["robots"]["r1"]["t"] for f in truth["frames"]])
    e = []
    for row in traj.tracks["r1"].rows:
        if row.estimate is not None and ts[0] <= row.t <= ts[-1]:
            true = np.array([np.interp(row.t, ts, xyz[:, i]) for i in range(3)])
            e.append(100 * float(np.linalg.norm(row.estimate.pose.t - true)))
    return {"rows": len(traj.tracks["r1"].rows), "with_pose": len(e), "median_cm": round(float(np.median(e)), 2),
            "p90_cm": round(float(np.percentile(e, 90)), 2)}


def run(seed: int, seconds: float, offset: float) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        write_team_simulation(tmp, robots=2, frames=int(seconds * FPS), fps=FPS, seed=seed, images=False,
                              room=False, speed=0.7, clock_offset={"r1": offset})
        truth = json.loads((Path(tmp) / "truth.json").read_text())
        rig = expanded_rig(load_rig(Path(tmp) / "rig.yaml"))
    log = truth_log(truth, seed=seed)
    t0 = time.perf_counter()
    found = estimate_clock_offsets(rig, log, "r0")["r1"]
    seconds_estimate = time.perf_counter() - t0
    out = {"true_offset_s": truth["clock_offsets"]["r1"], "offset_s": found.offset_s, "sigma_s": found.sigma_s,
           "reason": found.reason, "estimate_seconds": round(seconds_estimate, 1)}
    if found.offset_s is not None:
        out["error_ms"] = round(1000 * (found.offset_s - out["true_offset_s"]), 2)
        out["error_over_sigma"] = round((found.offset_s - out["true_offset_s"]) / found.sigma_s, 2)
    runs = {"estimated": shift_records(rig, log, {"r1": found.offset_s or 0.0}), "without": log,
            "synchronized": truth_log(truth, seed=seed, clocks=False)}
    for label, records in runs.items():
        t0 = time.perf_counter()
        traj = track_team_log(rig, records, "r0", progress=False)
        out[label] = {**errors_cm(traj, truth), "track_seconds": round(time.perf_counter() - t0, 2)}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=6.0)
    ap.add_argument("--offset", type=float, default=0.04)
    args = ap.parse_args()
    out = {"machine": machine(), "seconds": args.seconds, "offset_s": args.offset, "runs": {}}
    for seed in range(args.seeds):
        r = out["runs"][seed] = run(seed, args.seconds, args.offset)
        est = (f"{1000 * r['offset_s']:.1f} ms +- {1000 * r['sigma_s']:.1f} (error {r['error_ms']:+.1f} ms, "
               f"{r['error_over_sigma']:+.1f} sigma)" if r["offset_s"] is not None else f"undetermined: {r['reason']}")
        print(f"seed {seed}: offset {est} in {r['estimate_seconds']} s; r1 median / p90 cm: "
              + "; ".join(f"{k} {r[k]['median_cm']} / {r[k]['p90_cm']}" for k in ("estimated", "without",
                                                                                   "synchronized")), flush=True)
    path = Path(result_file("clock_offsets.json"))
    path.write_text(json.dumps(out, indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
