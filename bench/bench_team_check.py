#!/usr/bin/env python
"""Is a team's `solved` honest when the detections are better than the stated noise?

    python bench/bench_team_check.py --teams 400     # the figures in docs/benchmarks.md
    python bench/bench_team_check.py --teams 40      # a smoke run

Random teams of 3-5 robots (mutloc.sim.bodies.random_team): bodies with 2-3 cameras of any lens at any
headings, and the one-pinhole peer (one forward pinhole camera each, facing the circle's centre).  Each team
is localized by `localize_team` (reference r0, stated `pixel_sigma` 1 px) on its exact pixels (noise-free:
actual noise below the stated one) and on pixels with sigma = 1 px noise, twice on the same observations:

- before: the team judged at the stated noise only (its joint chi-square test;
  `mutloc.core.team.JUDGE_AT_MEASURED_NOISE = False`);
- after: besides, each robot's ties tested at the noise the team's residuals show, when they reject the
  stated one as too large (`mutloc.core.team.misfit_robots`; misfit robots are restarted from other poses, and those
  still misfit are `unverified`).

Per robot: `solved` / `unverified` (ambiguous included) counts, `solved` poses beyond 5 sigma of their own
covariance (NEES above chi2(6)'s quantile at the two-sided 5-sigma tail, 39.49) against the simulator's
truth, and noise-free `solved` poses that are not exact (rotation >= 1e-6 rad or translation >= 1e-6 m);
teams refused (by error type).  CPU time per call of both settings, the load named.

Writes bench/results/team_check_results.json.
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

import mutloc  # noqa: E402
import mutloc.core.team as core_team  # noqa: E402
from mutloc.core.geometry import so3_log  # noqa: E402
from mutloc.sim.bodies import body_observations, random_team  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402

#: chi2 with 6 degrees of freedom at the two-sided tail of 5 sigma in one dimension (5.7e-7).
BEYOND_5_SIGMA_NEES = 39.49


def teams(n: int, seed: int, pinhole: bool, sigma: float) -> list:
    """``n`` random teams with at least four observations: (rig, truth poses T_r0_r, observations)."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        rig, poses = random_team(rng, int(rng.integers(3, 6)), pinhole=pinhole)
        obs = body_observations(rig, poses, sigma=sigma, rng=rng) if sigma > 0 else body_observations(rig, poses)
        if sum(len(v) for v in obs.values()) < 4:
            continue
        out.append((rig, {r: poses["r0"].inverse() @ poses[r] for r in poses}, obs))
    return out


def judge(cases: list, judged: bool) -> dict:
    core_team.JUDGE_AT_MEASURED_NOISE = judged
    counts: dict[str, int] = {"solved": 0, "unverified": 0, "misfit": 0, "beyond_5_sigma": 0, "not_exact": 0,
                              "unlocalized": 0}
    refused: dict[str, int] = {}
    far = []
    t = 0.0
    for team, (rig, truth, obs) in enumerate(cases):
        t0 = time.thread_time()
        try:
            est = mutloc.localize_team(rig, obs, "r0", pixel_sigma=1.0)
        except mutloc.errors.MutlocError as exc:
            t += time.thread_time() - t0
            refused[type(exc).__name__] = refused.get(type(exc).__name__, 0) + 1
            continue
        t += time.thread_time() - t0
        counts["unlocalized"] += len(est.unlocalized)
        counts["misfit"] += len(est.misfit)
        for r in est.robots:
            if est.robot_status(r) != "solved":
                counts["unverified"] += 1
                continue
            counts["solved"] += 1
            T = truth[r]
            e = np.r_[so3_log(est.poses[r].R @ T.R.T), est.poses[r].t - T.t]
            nees = float(e @ np.linalg.solve(est.covariance(r), e))
            counts["not_exact"] += bool(np.linalg.norm(e[:3]) >= 1e-6 or np.linalg.norm(e[3:]) >= 1e-6)
            if nees > BEYOND_5_SIGMA_NEES:
                counts["beyond_5_sigma"] += 1
                far.append({"team": team, "robot": r, "nees": nees,
                            "rotation_error_deg": float(np.degrees(np.linalg.norm(e[:3]))),
                            "translation_error_m": float(np.linalg.norm(e[3:]))})
    core_team.JUDGE_AT_MEASURED_NOISE = True
    return {**counts, "refused": refused, "beyond": far, "ms_per_call": 1e3 * t / max(len(cases), 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--teams", type=int, default=400)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    res: dict = {"machine": machine(), "teams": args.teams}
    for kind, pinhole in (("bodies", False), ("pinhole", True)):
        for label, sigma in (("noise_free", 0.0), ("sigma_1px", 1.0)):
            cases = teams(args.teams, args.seed + (1 if pinhole else 0) + (2 if sigma else 0), pinhole, sigma)
            judge(cases[:5], True)  # compiled and warm
            load = os.getloadavg()[0]
            before, after = judge(cases, False), judge(cases, True)
            res[f"{kind}_{label}"] = {"before": before, "after": after, "load_before": load}
            print(f"{kind:8s} {label:10s} before: solved {before['solved']}, unverified {before['unverified']}, "
                  f"beyond 5 sigma {before['beyond_5_sigma']}, not exact {before['not_exact']}, refused "
                  f"{sum(before['refused'].values())}, {before['ms_per_call']:.2f} ms | after: solved "
                  f"{after['solved']}, unverified {after['unverified']} (misfit {after['misfit']}), beyond 5 sigma "
                  f"{after['beyond_5_sigma']}, not exact {after['not_exact']}, refused "
                  f"{sum(after['refused'].values())}, {after['ms_per_call']:.2f} ms  (load {load:.1f})", flush=True)
    Path(result_file("team_check_results.json")).write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
