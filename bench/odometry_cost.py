"""Cost per record of the team tracker with every robot's odometry, beside
the same tracker without it, on the same logs in the same run (mutloc
issue 37, "Odometry": teams of 5 and 10 robots).

Logs: :func:`mutloc.sim.team.random_team` of N robots (30 % of mutual
pairs seen one way), each driving a circle at up to 0.72 m/s
(:func:`mutloc.sim.team.team_motion`), 30 fps, 1 px, 3 s; each robot's
odometry at 50 Hz with 1 % / 0.3 deg/m drift.  Per run a new seed (a new
log); per N the median over ``--runs`` of the CPU time of the whole track
(:func:`mutloc.track.team.track_team_log`, default options: the smoother
included) divided by the records, with and without odometry alternating.
A first run per N (not counted) compiles the kernels.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/odometry_cost.py [--runs 3] [--robots 5 10]

Writes bench/results/odometry_cost.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from _machine import machine, result_file  # noqa: E402

from mutloc.core.odometry import Odometry  # noqa: E402
from mutloc.sim.odometry import drifting_odometry, odometry_times  # noqa: E402
from mutloc.sim.team import random_team, team_motion, team_sequence  # noqa: E402
from mutloc.track.filtering import FilterOptions  # noqa: E402
from mutloc.track.team import track_team_log  # noqa: E402

FPS, DURATION = 30.0, 3.0


def make_log(n: int, seed: int):
    scene = random_team(n, np.random.default_rng(seed), one_way=0.3)
    motion = dict(amplitude=0.3, speed=0.6)
    seq = team_sequence(scene, int(FPS * DURATION), FPS, sigma=1.0, seed=seed, **motion)
    at = team_motion(scene, seed=seed, **motion)
    times = odometry_times(0.0, DURATION, 50.0)
    odo = {r: Odometry(times, drifting_odometry(lambda t, r=r: at(t)[r], times, seed=seed, stream=k), source=r)
           for k, r in enumerate(scene.names)}
    return scene.rig, [(t, o) for t, _, o in seq], odo


def per_record(rig, log, odometry) -> float:
    t0 = time.process_time()
    track_team_log(rig, log, "r0", progress=False, filter=FilterOptions(odometry=odometry))
    return (time.process_time() - t0) / len(log)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--robots", type=int, nargs="+", default=[5, 10])
    args = ap.parse_args()
    out = {"machine": machine(), "per_record_ms": {}}
    for n in args.robots:
        rig, log, odo = make_log(n, 100)
        per_record(rig, log, odo), per_record(rig, log, {})  # compile
        without, with_ = [], []
        for run in range(args.runs):
            rig, log, odo = make_log(n, run)
            without.append(per_record(rig, log, {}) * 1e3)
            with_.append(per_record(rig, log, odo) * 1e3)
        out["per_record_ms"][n] = {"without": [round(x, 2) for x in without], "with": [round(x, 2) for x in with_],
                                   "median_without": round(float(np.median(without)), 2),
                                   "median_with": round(float(np.median(with_)), 2)}
        print(f"{n} robots: {np.median(without):.2f} ms per record without odometry, {np.median(with_):.2f} ms with "
              f"(runs: {without} / {with_})", flush=True)
    out["load_average_at_end"] = list(os.getloadavg())
    path = Path(result_file("odometry_cost.json"))
    path.write_text(json.dumps(out, indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
