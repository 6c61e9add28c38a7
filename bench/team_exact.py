#!/usr/bin/env python
"""Noise-free random teams (3-8 robots): how many the team solver solves
exactly, and what goes wrong with the others (issue 24, item 4).

    python bench/team_exact.py [--scenes 200] [--seed 2024] [--kind tags] [--one-way 0.3]

For every scene (``random_team`` with a random size 3-8): localize_team on
the exact pixels.  A robot is *determinable* when the information matrix at
the truth (reference fixed) has no null direction touching its pose.  A
scene is *exact* when every determinable robot has a pose within 1e-6 m /
1e-5 deg of the truth (a robot in >= 4 observations may still be
undeterminable: tags give two points per robot, about whose line a robot
seen only there turns freely); TooFewObservationsError is a correct refusal
when no robot is determinable.  Other outcomes: an exception (its type), a
determinable robot without a pose, a pose off the truth (if every such robot
is flagged unverified: another exact pose of three observations).  Prints
the counts and each other scene's index.
"""

from __future__ import annotations

import argparse
import time
from collections import Counter

import numpy as np

import mutloc
from mutloc.errors import MutlocError, TooFewObservationsError
from mutloc.sim.team import random_team
from mutloc.core.team import solve_team
from mutloc.team import team_problem


def determinable(scene, problem, names) -> np.ndarray:
    """Robots whose pose the observations determine (reference fixed): no
    component in the null space of the information matrix at the truth."""
    truth = scene.truth()
    inobs = np.zeros(len(names), dtype=bool)
    inobs[np.r_[problem.cam, problem.own]] = True
    inobs[0] = True
    at = solve_team(problem, 0, initial=(np.array([truth[n].R for n in names]), np.array([truth[n].t for n in names]),
                                         inobs), max_iter=0)
    out = np.zeros(len(names), dtype=bool)
    out[0] = True
    if len(at.order) == 0:
        return out
    H = at.information
    d = np.sqrt(np.maximum(np.diag(H), 1e-300))
    w, V = np.linalg.eigh(H / d[:, None] / d[None, :])
    null = V[:, w < 1e-9 * max(w.max(), 1e-300)]
    for k, i in enumerate(at.order):
        out[i] = d[6 * k] > 0 and (null.size == 0 or np.abs(null[6 * k:6 * k + 6]).max() < 1e-6)
    return out


def check(scene) -> tuple[str, str]:
    obs = scene.observations()
    problem, names, _ = team_problem(scene.rig, obs)
    seen = np.bincount(np.r_[problem.cam, problem.own], minlength=len(names))
    det = determinable(scene, problem, names)
    try:
        team = mutloc.localize_team(scene.rig, obs)
    except MutlocError as e:
        if isinstance(e, TooFewObservationsError) and not det[1:].any():
            return "refused (nothing determinable)", ""
        return type(e).__name__, str(e)[:160]
    truth = scene.truth()
    lost = [n for n in team.unlocalized if det[names.index(n)]]
    if lost:
        return "determinable robot unlocalized", f"{lost} unverified={team.unverified}"
    off = [n for n, T in team.poses.items()
           if T.translation_error(truth[n]) > 1e-6 or T.rotation_error_deg(truth[n]) > 1e-5]
    if off and not set(off) <= set(team.unverified):
        return "off-truth", f"{off} unverified={team.unverified}"
    if off:
        return "another exact pose (unverified)", f"{off}"
    if any(seen[names.index(n)] >= 4 for n in team.unlocalized):
        return "exact (a robot in >= 4 observations undeterminable)", ""
    return "exact", ""


OK = ("exact", "refused (nothing determinable)", "exact (a robot in >= 4 observations undeterminable)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=200)
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--kind", default="balls", help="marker kind of the simulated robots (balls, tags)")
    ap.add_argument("--one-way", type=float, default=0.3, help="probability of dropping one direction of a pair")
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    kinds: Counter = Counter()
    t0 = time.perf_counter()
    for i in range(args.scenes):
        scene = random_team(int(rng.integers(3, 9)), rng, kind=args.kind, one_way=args.one_way)
        kind, msg = check(scene)
        kinds[kind] += 1
        if kind not in OK:
            print(f"scene {i} ({len(scene.names)} robots): {kind} {msg}")
    ok = sum(kinds[k] for k in OK)
    print(dict(kinds), f"as expected {ok}/{args.scenes}", f"{time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
