#!/usr/bin/env python
"""Pairs and teams of robots with several cameras, any lens: exactness, efficiency, honesty and cost of
`localize` and `localize_team`.

    python bench/bench_bodies.py --n 2000 --teams 400   # the figures in docs/benchmarks.md
    python bench/bench_bodies.py --n 200                # a smoke run (teams: n / 4)
    python bench/bench_bodies.py --n 2000 --teams 400 --refusals   # pixels past a lens's rim: refused vs set aside

Each robot is a body with 2-3 cameras looking out around it, each a fisheye (180-200 deg, Kannala-Brandt),
an omnidirectional (Mei) or a pinhole lens (mutloc.sim.bodies.random_body); the robots stand 1.5-5 m apart
at any headings (so often facing away from each other: back cameras only).  Pixels are the exact
projections through each lens (plus sigma = 1 px noise where said).

- noise-free: the exact pose (rotation < 1e-8 rad, translation < 1e-7 m) per scene with >= 4 observations;
- sigma = 1 px: status counts, NEES (6-D, the estimate's covariance) and RMSE over the Cramér-Rao bound
  (the pixels' Fisher information by numerical differentiation of the lens projections, at the truth),
  over every `solved` pose, and over those where both robots see each other;
- cost: `localize` per call on these scenes (a new ObservationSet every call) next to the one-pinhole-camera
  pair of the same markers seen by one camera each (`mutloc.sim.synthetic`-like pairs), and next to one-pinhole
  pairs with as many observations as each body scene, one core, median of 5 runs, the load named;
- teams of 3-5 such robots (mutloc.sim.bodies.random_team: on a circle, any headings) next to teams of
  one-pinhole robots at the same positions facing the centre: noise-free exactness per robot pose; sigma = 1 px
  statuses per robot, per-robot NEES, RMSE over the joint Cramér-Rao bound (team_pixel_information at the
  truth), the poses beyond 5 sigma listed; cost per `localize_team` call.

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
from mutloc.sim.bodies import (body_observations, pixel_information, random_pair, random_team,  # noqa: E402
                               team_pixel_information)

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


def _pinhole_pair(rng: np.random.Generator, markers: tuple[int, int] = (4, 4)):
    """The paper's set-up for the peer: one pinhole camera per robot, facing each other 1.5-5 m apart,
    ``markers`` markers on p and q (4 each)."""
    K = [[700, 0, 479.5], [0, 700, 269.5], [0, 0, 1]]
    robots = {}
    for n, k in zip(("p", "q"), markers):
        ms = {f"{n}{j}": Marker(f"{n}{j}", n, np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.1),
                                                         rng.uniform(-0.05, 0.05)])) for j in range(k)}
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
    load0 = os.getloadavg()[0]
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
    # the fair peer: for each body scene a pinhole pair seeing exactly as many markers (split as evenly as
    # the two robots allow, all in view)
    equal = []
    for _, bobs in bodies:
        m = sum(len(v) for v in bobs.values())
        while True:
            rig, obs = _pinhole_pair(rng, ((m + 1) // 2, m // 2))
            if sum(len(v) for v in obs.values()) == m:
                equal.append((rig, obs))
                break

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
    per_call(equal[:20])
    b, braw = per_call(bodies)
    p, praw = per_call(pinholes)
    e, eraw = per_call(equal)
    count = [sum(len(v) for v in o.values()) for _, o in bodies]
    return {"scenes": n, "bodies_us": b, "bodies_runs_us": braw, "pinhole_pair_us": p, "pinhole_runs_us": praw,
            "ratio": b / p, "pinhole_equal_us": e, "pinhole_equal_runs_us": eraw, "ratio_equal": b / e,
            "bodies_median_observations": float(np.median(count)),
            "bodies_observations_range": [int(min(count)), int(max(count))],
            "pinhole_median_observations": float(np.median([sum(len(v) for v in o.values()) for _, o in pinholes])),
            "load_before_after": [load0, os.getloadavg()[0]]}


def _team_scenes(n: int, seed: int, pinhole: bool, desc: str):
    """``n`` random teams of 3-5 robots (``random_team``: bodies, or the one-pinhole peer) with some
    observations: (rng, rig, world poses, noise-free observations)."""
    rng = np.random.default_rng(seed)
    made = 0
    with tqdm(total=n, desc=desc, leave=False) as bar:
        while made < n:
            rig, poses = random_team(rng, int(rng.integers(3, 6)), pinhole=pinhole)
            truth = body_observations(rig, poses)
            if sum(len(v) for v in truth.values()) < 4:
                continue
            made += 1
            bar.update()
            yield rng, rig, poses, truth


def _back_to_back(rig, poses: dict, a: str, b: str) -> bool:
    """Whether robots ``a`` and ``b`` face away from each other (each one's forward axis -- a body's x, a
    one-camera robot's optical z -- pointing away from the other)."""
    d = poses[b].t - poses[a].t
    fwd = {r: poses[r].R[:, 0 if rig.robots[r].is_body else 2] for r in (a, b)}
    return bool(fwd[a] @ d < 0 and fwd[b] @ -d < 0)


def team_study(n: int, seed: int, pinhole: bool, sigma: float = 1.0) -> dict:
    """Teams (``localize_team``, reference r0): noise-free exactness per robot pose; at ``sigma`` px the
    statuses per robot, per-robot NEES and RMSE over the joint Cramér-Rao bound."""
    kind = "pinhole" if pinhole else "bodies"
    exact = robots = unloc = 0
    errors: dict[str, int] = {}
    by_status: dict[str, list[int]] = {}
    worst = 0.0
    for _, rig, poses, obs in _team_scenes(n, seed, pinhole, f"team {kind} noise-free"):
        try:
            est = mutloc.localize_team(rig, obs, "r0", confidence=1.0)
        except mutloc.errors.MutlocError as exc:
            errors[type(exc).__name__] = errors.get(type(exc).__name__, 0) + 1
            continue
        unloc += len(est.unlocalized)
        for r in est.robots:
            robots += 1
            e = err(est.poses[r], poses["r0"].inverse() @ poses[r])
            worst = max(worst, float(np.linalg.norm(e[3:])))
            ok = bool(np.linalg.norm(e[3:]) < 1e-7 and np.linalg.norm(e[:3]) < 1e-8)
            exact += ok
            s = "ambiguous" if r in est.ambiguous else est.robot_status(r)
            by_status.setdefault(s, [0, 0])[0] += ok
            by_status[s][1] += 1
    noise_free = {"teams": n, "robots_localized": robots, "exact": exact, "exact_rate": exact / max(robots, 1),
                  "exact_of_status": by_status, "unlocalized": unloc, "teams_refused": errors,
                  "worst_translation_m": worst}

    status: dict[str, int] = {}
    first_message: list[str] = []
    rows = []
    n_obs = []
    outliers = []
    for team, (rng, rig, poses, truth) in enumerate(_team_scenes(n, seed + 1, pinhole, f"team {kind} sigma 1 px")):
        obs = body_observations(rig, poses, sigma=sigma, rng=rng)
        n_obs.append(sum(len(v) for v in obs.values()))
        try:
            est = mutloc.localize_team(rig, obs, "r0", pixel_sigma=sigma)
        except mutloc.errors.MutlocError as exc:
            status[type(exc).__name__] = status.get(type(exc).__name__, 0) + 1
            if len(first_message) < 3:
                first_message.append(str(exc))
            continue
        status["unlocalized"] = status.get("unlocalized", 0) + len(est.unlocalized)
        rel = {r: poses["r0"].inverse() @ poses[r] for r in poses}
        info = team_pixel_information(rig, truth, "r0", rel, list(est.robots))
        crlb = np.linalg.inv(info) * sigma**2
        for i, r in enumerate(est.robots):
            s = "ambiguous" if r in est.ambiguous else est.robot_status(r)
            status[s] = status.get(s, 0) + 1
            if s != "solved":
                continue
            e = err(est.poses[r], rel[r])
            c = crlb[6 * i:6 * i + 6, 6 * i:6 * i + 6]
            partners = {rig.owner(m) for k, v in truth.items() if rig.observer(k)[0] == r for m in v} | \
                {rig.observer(k)[0] for k, v in truth.items() for m in v if rig.owner(m) == r}
            away = bool(partners) and all(_back_to_back(rig, poses, r, o) for o in partners)
            nees = float(e @ np.linalg.solve(est.covariance(r), e))
            rows.append((nees, float(e[3:] @ e[3:]),
                         float(np.trace(c[3:, 3:])), float(e[:3] @ e[:3]), float(np.trace(c[:3, :3])), away))
            if nees > BEYOND_5_SIGMA_NEES:
                ties = sum(len(v) for k, v in obs.items() for m in v if r in (rig.observer(k)[0], rig.owner(m)))
                outliers.append({"team": team, "robot": r, "nees": nees, "robots": len(poses), "ties": ties,
                                 "back_to_back_only": away, "translation_error_m": float(np.linalg.norm(e[3:])),
                                 "rotation_error_deg": float(np.degrees(np.linalg.norm(e[:3])))})

    def summary(sel):
        a = np.array([r for r in rows if sel(r)])
        if not len(a):
            return {}
        return {"solved": len(a), "nees_mean": float(a[:, 0].mean()), "nees_median": float(np.median(a[:, 0])),
                "beyond_5_sigma": int(np.sum(a[:, 0] > BEYOND_5_SIGMA_NEES)),
                "rmse_over_crlb_translation": float(np.sqrt(a[:, 1].mean() / a[:, 2].mean())),
                "rmse_over_crlb_rotation": float(np.sqrt(a[:, 3].mean() / a[:, 4].mean())),
                # each pose's squared error over its own bound, averaged: not dominated by the weakest poses
                "normalized_translation": float(np.sqrt(np.mean(a[:, 1] / a[:, 2]))),
                "normalized_rotation": float(np.sqrt(np.mean(a[:, 3] / a[:, 4])))}

    return {"noise_free": noise_free, "teams": n, "status_per_robot": status, "beyond_5_sigma": outliers,
            "error_examples": first_message,
            "median_observations": float(np.median(n_obs)), "all_solved": summary(lambda r: True),
            "back_to_back_only": summary(lambda r: r[5])}


def team_cost(n: int, seed: int, runs: int = 5) -> dict:
    """CPU time per ``localize_team`` call (a new observation dict every call) on body teams and on the
    one-pinhole peer teams, median of ``runs`` runs."""
    load0 = os.getloadavg()[0]
    cases = {}
    for pinhole in (False, True):
        cases["pinhole" if pinhole else "bodies"] = [
            (rig, body_observations(rig, poses, sigma=1.0, rng=rng))
            for rng, rig, poses, _ in _team_scenes(n, seed, pinhole, "team cost scenes")]

    def per_call(items):
        out = []
        for _ in range(runs):
            t0 = time.thread_time()
            for rig, obs in items:
                try:
                    mutloc.localize_team(rig, obs, "r0")
                except mutloc.errors.MutlocError:
                    pass
            out.append((time.thread_time() - t0) / len(items) * 1e6)
        return float(np.median(out)), out

    res = {}
    for k, items in cases.items():
        per_call(items[:10])
    for k, items in cases.items():
        med, raw = per_call(items)
        res[k] = {"us": med, "runs_us": raw,
                  "median_observations": float(np.median([sum(len(v) for v in o.values()) for _, o in items]))}
    res["ratio"] = res["bodies"]["us"] / res["pinhole"]["us"]
    res["teams"] = n
    res["load_before_after"] = [load0, os.getloadavg()[0]]
    return res


def refusals(n: int, teams: int, seed: int, runs: int = 3) -> dict:
    """Pairs and teams at sigma = 1 px refused (ObservationError: a noisy pixel past a fisheye's rim) with
    such pixels refused (``mutloc.core.rays.SET_ASIDE_PAST_RIM = False``, as before) and set aside (now), on
    the same observations; CPU time per ``localize`` call on the pair scenes both ways (median of ``runs``)."""
    import mutloc.core.rays as rays

    pairs = [(rig, body_observations(rig, poses, sigma=1.0, rng=rng)) for rng, rig, poses, _, _ in
             scenes(n, seed + 1, "refusals: pairs")]
    team_cases = [(rig, body_observations(rig, poses, sigma=1.0, rng=rng)) for rng, rig, poses, _ in
                  _team_scenes(teams, seed + 4, False, "refusals: teams")]
    out: dict = {"pairs": len(pairs), "teams": len(team_cases)}
    for aside in (False, True):
        rays.SET_ASIDE_PAST_RIM = aside
        key = "set_aside" if aside else "refused_before"
        np_, nt, lens = 0, 0, 0
        for rig, obs in pairs:
            try:
                est = mutloc.localize(rig, obs, "p", "q")
                lens += sum(r.get("at") == "lens" for r in est.rejected)
            except mutloc.errors.ObservationError:
                np_ += 1
            except mutloc.errors.MutlocError:
                pass
        tlens = 0
        for rig, obs in team_cases:
            try:
                est = mutloc.localize_team(rig, obs, "r0")
                tlens += sum(r.get("at") == "lens" for r in est.rejected)
            except mutloc.errors.ObservationError:
                nt += 1
            except mutloc.errors.MutlocError:
                pass
        out[key] = {"pairs_refused": np_, "teams_refused": nt, "pair_pixels_set_aside": lens,
                    "team_pixels_set_aside": tlens}
    load0 = os.getloadavg()[0]
    times: dict = {"refused_before": [], "set_aside": []}
    for _ in range(runs):
        for aside in (False, True):
            rays.SET_ASIDE_PAST_RIM = aside
            t0 = time.thread_time()
            for rig, obs in pairs:
                try:
                    mutloc.localize(rig, obs, "p", "q")
                except mutloc.errors.MutlocError:
                    pass
            times["set_aside" if aside else "refused_before"].append((time.thread_time() - t0) / len(pairs) * 1e6)
    rays.SET_ASIDE_PAST_RIM = True
    out["localize_us"] = {k: {"median": float(np.median(v)), "runs": v} for k, v in times.items()}
    out["load_before_after"] = [load0, os.getloadavg()[0]]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--teams", type=int, default=None, help="teams per team study (default n / 4)")
    ap.add_argument("--refusals", action="store_true",
                    help="only: pairs and teams refused for a pixel past a lens's rim, before (refused) and now "
                         "(set aside), and the cost per localize call both ways")
    args = ap.parse_args()
    teams = args.teams or max(args.n // 4, 10)
    if args.refusals:
        res = {"machine": machine(), "refusals": refusals(args.n, teams, args.seed)}
        print(json.dumps(res["refusals"], indent=1))
        Path(result_file("bodies_refusals.json")).write_text(json.dumps(res, indent=1) + "\n")
        return
    res = {"machine": machine(), "exactness": exactness(args.n, args.seed), "noisy": noisy(args.n, args.seed + 1),
           "cost": cost(min(args.n, 300), args.seed + 2),
           "team_bodies": team_study(teams, args.seed + 3, False), "team_pinhole": team_study(teams, args.seed + 3, True),
           "team_cost": team_cost(min(teams, 100), args.seed + 5)}
    print(json.dumps({k: v for k, v in res.items() if k != "machine"}, indent=1))
    Path(result_file("bodies_results.json")).write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
