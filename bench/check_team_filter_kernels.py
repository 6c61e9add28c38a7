#!/usr/bin/env python
"""The team filter's Numba kernels (core/team_kernels.py) against the NumPy
implementation they replaced (core/team_filter.py at commit 3e3e7a7, read
with ``git show``): the same records through both, every pose, velocity and
covariance compared after every record.

    python bench/check_team_filter_kernels.py [--robots 4 10] [--seeds 0 1 2] [--duration 3]

Prints the largest absolute differences; exits 1 if any exceeds 1e-9.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import types
from pathlib import Path

import numpy as np

from mutloc.core.filter import MotionNoise
from mutloc.core.team_filter import TeamFilter
from mutloc.sim.team import TeamScene, random_team, team_camera_records, team_motion
from mutloc.team import localize_team, team_problem

REFERENCE_COMMIT = "3e3e7a7"


def reference_module() -> types.ModuleType:
    """The NumPy team filter as it was before the kernels."""
    root = Path(__file__).resolve().parent.parent
    src = subprocess.run(["git", "show", f"{REFERENCE_COMMIT}:src/mutloc/core/team_filter.py"], cwd=root,
                         check=True, capture_output=True, text=True).stdout
    mod = types.ModuleType("mutloc.core._team_filter_reference")
    mod.__package__ = "mutloc.core"
    sys.modules[mod.__name__] = mod
    exec(compile(src, "team_filter@" + REFERENCE_COMMIT, "exec"), mod.__dict__)
    return mod


def compare(n: int, seed: int, duration: float, old_cls) -> dict:
    rng = np.random.default_rng(seed)
    scene = random_team(n, rng, one_way=0.0)
    recs = team_camera_records(scene, duration, sigma=1.0, seed=seed)
    names = scene.names
    snap = TeamScene(scene.rig, team_motion(scene, seed=seed)(0.0), scene.links)
    team = localize_team(scene.rig, snap.observations(1.0, rng), names[0])
    filters = [cls(names, names[0], MotionNoise(), pixel_sigma=1.0) for cls in (TeamFilter, old_cls)]
    for f in filters:
        f.reset(0.0, {r: team.poses[r] for r in team.robots}, team.joint_covariance)
    worst = {"R": 0.0, "t": 0.0, "vel": 0.0, "P": 0.0, "chi2_rel": 0.0, "residuals_px": 0.0}
    decisions = 0
    for t, _, _, obs in recs:
        ups = []
        for f in filters:
            f.predict(t)
            if len(obs):
                ups.append(f.update(team_problem(scene.rig, obs)[0]))
        if ups:
            a, b = ups
            decisions += int(a.accepted != b.accepted or a.dropped.tolist() != b.dropped.tolist())
            worst["chi2_rel"] = max(worst["chi2_rel"], abs(a.test.chi2 - b.test.chi2) / max(1.0, b.test.chi2))
            if a.residuals_px.shape == b.residuals_px.shape:
                worst["residuals_px"] = max(worst["residuals_px"], float(np.max(np.abs(a.residuals_px - b.residuals_px),
                                                                                initial=0.0)))
        new, old = filters
        for k in ("R", "t", "vel", "P"):
            worst[k] = max(worst[k], float(np.max(np.abs(getattr(new, k) - getattr(old, k)))))
    return {"robots": n, "seed": seed, "records": len(recs), "different_decisions": decisions, **worst}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, nargs="+", default=[4, 10])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--duration", type=float, default=3.0)
    args = ap.parse_args(argv)
    old = reference_module().TeamFilter
    bad = False
    for n in args.robots:
        for seed in args.seeds:
            r = compare(n, seed, args.duration, old)
            print(", ".join(f"{k} {v:.2e}" if isinstance(v, float) else f"{k} {v}" for k, v in r.items()), flush=True)
            bad |= r["different_decisions"] > 0 or max(r[k] for k in ("R", "t", "vel", "P", "residuals_px")) > 1e-9
    print("FAIL: differences above 1e-9" if bad else "OK: all within 1e-9, same decisions")
    return int(bad)


if __name__ == "__main__":
    raise SystemExit(main())
