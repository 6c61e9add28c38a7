#!/usr/bin/env python
"""Noise-free random teams (3-8 robots): how many the team solver solves
exactly, and what goes wrong with the others (issue 24, item 4).

    python bench/team_exact.py [--scenes 200] [--seed 2024]

For every scene (``random_team`` with a random size 3-8): localize_team on
the exact pixels; a scene is *exact* when every robot that appears in at
least one observation has a pose within 1e-6 m / 1e-5 deg of the truth.
Failures are classified: an exception (its type), a robot in >= 4
observations without a pose, a pose off the truth.  Prints the counts and
each failing scene's index.  A scene whose reference is in fewer than
three observations is correctly refused (TooFewObservationsError).
"""

from __future__ import annotations

import argparse
import time
from collections import Counter

import numpy as np

import mutloc
from mutloc.errors import MutlocError, TooFewObservationsError
from mutloc.sim.team import random_team
from mutloc.team import team_problem


def check(scene) -> tuple[str, str]:
    obs = scene.observations()
    problem, names, _ = team_problem(scene.rig, obs)
    seen = np.bincount(np.r_[problem.cam, problem.own], minlength=len(names))
    try:
        team = mutloc.localize_team(scene.rig, obs)
    except MutlocError as e:
        if isinstance(e, TooFewObservationsError) and seen[0] < 3:
            return "refused (reference in < 3 observations)", ""
        return type(e).__name__, str(e)[:160]
    truth = scene.truth()
    lost = [n for n in team.unlocalized if seen[names.index(n)] >= 4]
    if lost:
        return "unlocalized>=4", f"{lost} unverified={team.unverified}"
    off = [n for n, T in team.poses.items()
           if T.translation_error(truth[n]) > 1e-6 or T.rotation_error_deg(truth[n]) > 1e-5]
    if off:
        return "off-truth", f"{off} unverified={team.unverified}"
    return "exact", ""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=200)
    ap.add_argument("--seed", type=int, default=2024)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    kinds: Counter = Counter()
    t0 = time.perf_counter()
    for i in range(args.scenes):
        scene = random_team(int(rng.integers(3, 9)), rng)
        kind, msg = check(scene)
        kinds[kind] += 1
        if kind not in ("exact", "refused (reference in < 3 observations)"):
            print(f"scene {i} ({len(scene.names)} robots): {kind} {msg}")
    print(dict(kinds), f"exact {kinds['exact']}/{args.scenes}", f"{time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
