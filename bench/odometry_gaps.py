"""Two-second stretches where nothing is seen, with and without odometry
(mutloc issue 37, "Odometry").

Scene (the simulator: :func:`mutloc.sim.team.random_team` of two robots,
moving by :func:`mutloc.sim.team.team_motion` -- each drives a circle of
0.3 m radius at 0.8-1.2 x 0.6 m/s, so up to 0.72 m/s, its heading swinging
8 degrees): both cameras at 30 fps, 1 px noise, 10 s; every observation in
[3, 5) s and [6.5, 8.5) s dropped (someone walks between them).  Each
robot's odometry at 50 Hz from its true motion with the simulator's drift
(:func:`mutloc.sim.odometry.drifting_odometry`, 1 % of the distance and
0.3 deg/m), read with the default ``--odometry-noise`` (twice that) or
``--matched`` (the drift's own figures).  Tracked with
:func:`mutloc.track.team.track_team_log` (default options, fixed-lag
smoother), r0 the reference, the same log with and without odometry, and
with only one robot's odometry (``r1`` alone, ``r0`` -- the reference --
alone).

Per run: rows in the stretches with a pose, median / p90 translation
error (cm) in the stretches and outside, the mean NEES / 6 (1 for an
honest covariance), poses beyond 5 sigma (the pose's
NEES above the chi-square 6-dof quantile of 5 sigma's two-sided
probability, 5.7e-7: 45.0).

    .venv/bin/python bench/odometry_gaps.py [--seeds N] [--matched]

Writes bench/results/odometry_gaps.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _machine import machine, result_file  # noqa: E402

from mutloc.core.geometry import so3_log  # noqa: E402
from mutloc.core.observations import ObservationSet  # noqa: E402
from mutloc.core.odometry import Odometry, OdometryNoise  # noqa: E402
from mutloc.sim.odometry import drifting_odometry, odometry_times  # noqa: E402
from mutloc.sim.team import TeamScene, random_team, team_motion  # noqa: E402
from mutloc.track.filtering import FilterOptions  # noqa: E402
from mutloc.track.team import track_team_log  # noqa: E402

DURATION = 10.0
FPS = 30.0
GAPS = ((3.0, 5.0), (6.5, 8.5))
#: NEES of a 6-dof pose beyond which it is "beyond 5 sigma" (chi2 6 dof at 1 - 5.7e-7).
NEES_5SIGMA = 45.0


def scenario(seed: int, speed: float = 0.6):
    """(rig, log with the stretches dropped, truth per record, each robot's odometry poses and stamps)."""
    scene = random_team(2, np.random.default_rng(seed), one_way=0.0)
    at = team_motion(scene, seed=seed, amplitude=0.3, speed=speed, yaw_deg=8.0)
    rng = np.random.default_rng([seed, 77])
    log, truth = [], []
    for k in range(int(DURATION * FPS)):
        t = k / FPS
        snap = TeamScene(scene.rig, at(t), scene.links, scene.max_range)
        obs = snap.observations(1.0, rng)
        if any(a <= t < b for a, b in GAPS):
            obs = obs.take(np.empty(0, np.int64))
        log.append((t, ObservationSet.trusted(obs.observer, obs.marker, obs.uv, time=t)))
        truth.append(snap.truth()["r1"])
    times = odometry_times(0.0, DURATION, 50.0)
    odo = {n: (times, drifting_odometry(lambda t, n=n: at(t)[n], times, drift_pct=1.0, deg_per_m=0.3, seed=seed,
                                        stream=k)) for k, n in enumerate(scene.names)}
    return scene.rig, log, truth, odo


def in_gap(t: float) -> bool:
    return any(a <= t < b for a, b in GAPS)


def score(rows, log, truth) -> dict:
    out = {}
    for where, pick in (("stretches", in_gap), ("outside", lambda t: not in_gap(t))):
        errs, nees, n, posed = [], [], 0, 0
        for row, (t, _), T in zip(rows, log, truth):
            if not pick(t):
                continue
            n += 1
            e = row.estimate
            if e is None:
                continue
            posed += 1
            d = np.r_[so3_log(T.R @ e.pose.R.T), T.t - e.pose.t]
            errs.append(float(np.linalg.norm(d[3:])))
            nees.append(float(d @ np.linalg.solve(e.covariance, d)))
        errs = np.array(errs) * 100
        out[where] = {"rows": n, "with_pose": posed,
                      "median_cm": round(float(np.median(errs)), 2) if posed else None,
                      "p90_cm": round(float(np.percentile(errs, 90)), 2) if posed else None,
                      "beyond_5_sigma": int(sum(x > NEES_5SIGMA for x in nees)),
                      "nees_over_6": round(float(np.mean(nees)) / 6, 2) if posed else None}
    return out


def run(seed: int, matched: bool) -> dict:
    rig, log, truth, odo = scenario(seed)
    noise = OdometryNoise(distance=0.01, deg_per_m=0.3) if matched else None
    odometry = {n: Odometry(ts, poses, source=f"sim {n}", noise=noise) for n, (ts, poses) in odo.items()}
    res = {}
    for label, use in (("without", {}), ("with", odometry), ("r1 only", {"r1": odometry["r1"]}),
                       ("r0 (reference) only", {"r0": odometry["r0"]})):
        t0 = time.perf_counter()
        traj = track_team_log(rig, log, "r0", progress=False, filter=FilterOptions(odometry=use))
        res[label] = {**score(traj.tracks["r1"].rows, log, truth), "seconds": round(time.perf_counter() - t0, 2)}
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--matched", action="store_true", help="the odometry's noise the drift's own (not the default)")
    args = ap.parse_args()
    out = {"machine": machine(), "matched": args.matched, "runs": {}}
    for seed in range(args.seeds):
        out["runs"][seed] = run(seed, args.matched)
        for label, r in out["runs"][seed].items():
            s, o = r["stretches"], r["outside"]
            print(f"seed {seed} {label:>20}: stretches {s['with_pose']}/{s['rows']} with a pose, median "
                  f"{s['median_cm']} cm, p90 {s['p90_cm']} cm, {s['beyond_5_sigma']} beyond 5 sigma, NEES/6 "
                  f"{s['nees_over_6']}; outside "
                  f"{o['with_pose']}/{o['rows']}, median {o['median_cm']} cm, p90 {o['p90_cm']} cm, "
                  f"{o['beyond_5_sigma']} beyond 5 sigma ({r['seconds']} s)", flush=True)
    path = Path(result_file("odometry_gaps_matched.json" if args.matched else "odometry_gaps.json"))
    path.write_text(json.dumps(out, indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
