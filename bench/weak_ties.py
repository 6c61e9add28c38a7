#!/usr/bin/env python
"""A robot of a team tied by too few observations (issue 38 item 2): how
the team tracker reports it -- statuses, error against the simulator's
truth, NEES of the reported covariance (6 degrees of freedom: honest is a
mean of about 6, below is conservative), the translation sigma as it grows,
and when its track is dropped.

Three robots (``random_team``, every pair seeing each other both ways),
every camera at once at 30 fps, 1 px noise, 6 s; after the first second the
last robot's own camera sees nothing and only ``keep`` (0, 1 or 2, drawn at
random per record) of the others' observations of its markers are kept.
No timing: the load does not change the figures.

    python bench/weak_ties.py [--seeds 3]

Writes bench/results/weak_ties.json.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402

from mutloc.core.geometry import so3_log  # noqa: E402
from mutloc.sim.team import random_team, team_sequence  # noqa: E402
from mutloc.track.team import track_team_log  # noqa: E402


def run(seed: int, keep: int, duration: float = 6.0, start: float = 1.0) -> dict:
    scene = random_team(3, np.random.default_rng(seed), one_way=0.0)
    weak = scene.names[-1]
    seq = team_sequence(scene, int(30 * duration), 30.0, sigma=1.0, seed=seed)
    rng = np.random.default_rng([seed, 38])
    recs = []
    for t, _, obs in seq:
        if t >= start:
            owner = [scene.rig.owner(m) for m in obs.marker]
            idx = [i for i, (o, w) in enumerate(zip(obs.observer, owner)) if weak not in (o, w)]
            mine = [i for i, (o, w) in enumerate(zip(obs.observer, owner)) if o != weak and w == weak]
            if keep and mine:
                idx += rng.choice(mine, size=min(keep, len(mine)), replace=False).tolist()
            obs = obs.take(np.array(sorted(idx), dtype=np.int64))
        recs.append((t, obs))
    rows = track_team_log(scene.rig, recs, progress=False).tracks[weak].rows
    st, err, nees, sig, last = Counter(), [], [], [], None
    for row, (t, snap, _) in zip(rows, seq):
        if t < start:
            continue
        st[str(row.status)] += 1
        if row.estimate is None:
            continue
        T = snap.truth()[weak]
        e = np.r_[so3_log(T.R @ row.estimate.R.T), T.t - row.estimate.t]
        cov = row.estimate.covariance
        err.append(float(np.linalg.norm(e[3:])))
        nees.append(float(e @ np.linalg.solve(cov, e)))
        sig.append(float(np.sqrt(np.trace(cov[3:, 3:]))))
        last = float(t)
    return {"statuses": dict(st), "error_m_median": float(np.median(err)) if err else None,
            "error_m_max": max(err) if err else None, "nees_mean": float(np.mean(nees)) if nees else None,
            "nees_p90": float(np.percentile(nees, 90)) if nees else None, "sigma_t_first": sig[0] if sig else None,
            "sigma_t_last": sig[-1] if sig else None, "last_pose_s_after_start": None if last is None else last - start}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--out", default=result_file("weak_ties.json"))
    args = ap.parse_args(argv)
    results: dict = {"machine": machine()}
    for keep in (0, 1, 2):
        for seed in range(args.seeds):
            r = run(seed, keep)
            results[f"keep{keep}_seed{seed}"] = r
            print(f"keep {keep} seed {seed}: {r}", flush=True)
    Path(args.out).write_text(json.dumps(results, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
