#!/usr/bin/env python
"""Pairs of robots with several cameras, any lens: exactness, efficiency, honesty and cost of `localize`.

    python bench/bench_bodies.py              # 2000 random pairs per study
    python bench/bench_bodies.py --n 500      # quicker

Each robot is a body with 2-3 cameras looking out around it, each a fisheye (180-200 deg, Kannala-Brandt),
an omnidirectional (Mei) or a pinhole lens (mutloc.sim.bodies.random_body); the robots stand 1.5-5 m apart
at any headings (so often facing away from each other: back cameras only).  Pixels are the exact
projections through each lens (plus sigma = 1 px noise where said).

- noise-free: the exact pose (rotation < 1e-8 rad, translation < 1e-7 m) per scene with >= 4 observations;
- sigma = 1 px: status counts, NEES (6-D, the estimate's covariance) and RMSE over the Cramér-Rao bound
  (the pixels' Fisher information by numerical differentiation of the lens projections, at the truth),
  over every `solved` pose, and over those where both robots see each other;
- cost: `localize` per call on these scenes (a new ObservationSet every call) next to the one-pinhole-camera
  pair of the same markers seen by one camera each (`mutloc.sim.synthetic`-like pairs), one core, median of
  5 runs, the load named.

Writes bench/results/bodies_results.json.
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
from tqdm import tqdm  # noqa: E402

import mutloc  # noqa: E402
from mutloc.core.camera import Camera  # noqa: E402
from mutloc.core.geometry import so3_exp, so3_log  # noqa: E402
from mutloc.core.pose import Pose  # noqa: E402
from mutloc.core.rig import Marker, Rig, Robot  # noqa: E402
from mutloc.sim.bodies import body_observations, pixel_information, random_pair  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402


#: chi2 with 6 degrees of freedom at the two-sided tail of 5 sigma in one dimension (5.7e-7).
BEYOND_5_SIGMA_NEES = 39.49


def scene(rng: np.random.Generator):
    return random_pair(rng)


def err(est, T):
    return np.r_[so3_log(est.R @ T.R.T), est.t - T.t]


def scenes(n: int, seed: int, desc: str):
    """``n`` random pairs with at least four observations: (rng, rig, world poses, T_qp, noise-free observations)."""
    rng = np.random.default_rng(seed)
    made = 0
    with tqdm(total=n, desc=desc, leave=False) as bar:
        while made < n:
            rig, poses, T = scene(rng)
            truth = body_observations(rig, poses)
            if sum(len(v) for v in truth.values()) < 4:
                continue
            made += 1
            bar.update()
            yield rng, rig, poses, T, truth


def exactness(n: int, seed: int) -> dict:
    exact = tried = errors = 0
    worst = 0.0
    for _, rig, _, T, obs in scenes(n, seed, "noise-free"):
        tried += 1
        try:
            est = mutloc.localize(rig, obs, "p", "q", confidence=1.0)
        except mutloc.errors.MutlocError:
            errors += 1
            continue
        e = err(est, T)
        worst = max(worst, float(np.linalg.norm(e[3:])))
        exact += bool(np.linalg.norm(e[3:]) < 1e-7 and np.linalg.norm(e[:3]) < 1e-8)
    return {"scenes": tried, "exact": exact, "errors": errors, "exact_rate": exact / tried,
            "worst_translation_m": worst}


def noisy(n: int, seed: int, sigma: float = 1.0) -> dict:
    status: dict[str, int] = {}
    rows = []
    tried = 0
    for rng, rig, poses, T, truth in scenes(n, seed, "sigma 1 px"):
        tried += 1
        obs = body_observations(rig, poses, sigma=sigma, rng=rng)
        try:
            est = mutloc.localize(rig, obs, "p", "q", pixel_sigma=sigma)
            s = est.status
        except mutloc.errors.MutlocError as exc:
            status[type(exc).__name__] = status.get(type(exc).__name__, 0) + 1
            continue
        status[s] = status.get(s, 0) + 1
        if s != "solved":
            continue
        e = err(est, T)
        mutual = any(k.startswith("p") for k in truth) and any(k.startswith("q") for k in truth)
        crlb = np.linalg.inv(pixel_information(rig, truth, "p", "q", T)) * sigma**2
        rows.append((float(e @ np.linalg.solve(est.covariance, e)), float(e[3:] @ e[3:]),
                     float(np.trace(crlb[3:, 3:])), float(e[:3] @ e[:3]), float(np.trace(crlb[:3, :3])), mutual,
                     sum(len(v) for v in obs.values())))

    def summary(sel):
        a = np.array([r for r in rows if sel(r)])
        if not len(a):
            return {}
        return {"solved": len(a), "nees_mean": float(a[:, 0].mean()), "nees_median": float(np.median(a[:, 0])),
                # as improbable as 5 sigma in one dimension: NEES above chi2(6)'s quantile at 1 - 5.7e-7
                "beyond_5_sigma": int(np.sum(a[:, 0] > BEYOND_5_SIGMA_NEES)),
                "rmse_over_crlb_translation": float(np.sqrt(a[:, 1].mean() / a[:, 2].mean())),
                "rmse_over_crlb_rotation": float(np.sqrt(a[:, 3].mean() / a[:, 4].mean()))}

    return {"scenes": tried, "status": status, "all_solved": summary(lambda r: True),
            "mutual_solved": summary(lambda r: r[5]), "mutual_6plus": summary(lambda r: r[5] and r[6] >= 6)}


def _pinhole_pair(rng: np.random.Generator):
    """The paper's set-up for the peer: one pinhole camera per robot, facing each other 1.5-5 m apart, the
    same number of markers per robot (4)."""
    K = [[700, 0, 479.5], [0, 700, 269.5], [0, 0, 1]]
    robots = {}
    for n in ("p", "q"):
        ms = {f"{n}{j}": Marker(f"{n}{j}", n, np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.1),
                                                         rng.uniform(-0.05, 0.05)])) for j in range(4)}
        robots[n] = Robot(n, Camera(K, None, (960, 540)), ms)
    rig = Rig(robots)
    d = rng.uniform(1.5, 5.0)
    T_qp = Pose(so3_exp([rng.normal(0, 0.1), np.pi + rng.normal(0, 0.2), rng.normal(0, 0.1)]),
                [rng.normal(0, 0.2), rng.normal(0, 0.1), d])
    obs = {}
    for o, other, T in (("p", "q", T_qp.inverse()), ("q", "p", T_qp)):
        cam = rig.robots[o].camera
        for mn, m in rig.robots[other].markers.items():
            uv = cam.project(T.apply(m.position))
            if np.all(np.isfinite(uv)) and cam.in_image(uv):
                obs.setdefault(o, {})[mn] = (uv + rng.normal(0, 1.0, 2)).tolist()
    return rig, obs


def cost(n: int, seed: int, runs: int = 5) -> dict:
    rng = np.random.default_rng(seed)
    bodies, pinholes = [], []
    while len(bodies) < n:
        rig, poses, _ = scene(rng)
        obs = body_observations(rig, poses, sigma=1.0, rng=rng)
        if sum(len(v) for v in obs.values()) >= 6:
            bodies.append((rig, obs))
    while len(pinholes) < n:
        rig, obs = _pinhole_pair(rng)
        if sum(len(v) for v in obs.values()) >= 6:
            pinholes.append((rig, obs))

    def per_call(cases):
        out = []
        for _ in range(runs):
            t0 = time.thread_time()
            for rig, obs in cases:  # a dict each call: a new ObservationSet, as a user's frame
                try:
                    mutloc.localize(rig, obs, "p", "q")
                except mutloc.errors.MutlocError:
                    pass
            out.append((time.thread_time() - t0) / len(cases) * 1e6)
        return float(np.median(out)), out

    per_call(bodies[:20])
    per_call(pinholes[:20])  # compiled and warm
    b, braw = per_call(bodies)
    p, praw = per_call(pinholes)
    return {"scenes": n, "bodies_us": b, "bodies_runs_us": braw, "pinhole_pair_us": p, "pinhole_runs_us": praw,
            "ratio": b / p, "bodies_median_observations": float(np.median([sum(len(v) for v in o.values())
                                                                             for _, o in bodies]))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    res = {"machine": machine(), "exactness": exactness(args.n, args.seed), "noisy": noisy(args.n, args.seed + 1),
           "cost": cost(min(args.n, 300), args.seed + 2)}
    print(json.dumps({k: v for k, v in res.items() if k != "machine"}, indent=1))
    Path(result_file("bodies_results.json")).write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
