#!/usr/bin/env python
"""Does the first-subset shortcut of ``estimate(accept=...)`` (what
``localize`` uses) find the same optimum and the same candidates as the full
search over every minimal subset?  Random scenes of every layout kind,
2-2, 3-1 and 3-3 observations, noise-free and sigma = 1 px.

    python bench/first_subset_agreement.py            # 1,000 scenes per cell
    python bench/first_subset_agreement.py --n 3000

Prints, per cell, how often the shortcut was taken and how many poses
(beyond 1e-6) or candidate stacks differ.
"""

from __future__ import annotations

import argparse

import numpy as np
from tqdm import tqdm

import mutloc
from mutloc.core.camera import Camera
from mutloc.core.consistency import chi2_quantile
from mutloc.core.estimate import PairProblem, estimate
from mutloc.errors import MutlocError
from mutloc.sim.synthetic import batch_scenes

K = np.array([[800.0, 0, 479.5], [0, 800.0, 269.5], [0, 0, 1]])
CAM = Camera(K, None, None)


def _problem(mp, mq, up, uq) -> PairProblem:
    return PairProblem.trusted(np.r_[np.zeros(len(mq), np.int64), np.ones(len(mp), np.int64)],
                               np.ascontiguousarray(np.vstack([mq, mp])), None,
                               np.ascontiguousarray(np.vstack([up, uq])), (K, K), (CAM.dist, CAM.dist))


def cell(rng, n: int, kind: str, n_p: int, n_q: int, sigma: float) -> dict:
    R, t, mp, mq = batch_scenes(rng, n, kind, n_p, n_q, distance=(1.0, 3.0))
    gate = chi2_quantile(0.99, 2 * (n_p + n_q) - 6)
    taken = pose_diff = cand_diff = error_diff = 0
    for i in range(n):
        up = CAM.project((mq[i] - t[i]) @ R[i]) + rng.normal(scale=sigma, size=(n_q, 2))
        uq = CAM.project(mp[i] @ R[i].T + t[i]) + rng.normal(scale=sigma, size=(n_p, 2))
        out = []
        for accept in (None, gate):
            try:
                out.append(estimate(_problem(mp[i], mq[i], up, uq), accept=accept))
            except MutlocError:
                out.append(None)
        full, fast = out
        if (full is None) != (fast is None):
            error_diff += 1
            continue
        if full is None:
            continue
        taken += bool(fast.extra.get("first_subset"))
        dt = np.abs(full.pose.t - fast.pose.t).max() / (1 + np.linalg.norm(full.pose.t))
        if np.abs(full.pose.R - fast.pose.R).max() > 1e-6 or dt > 1e-6:
            pose_diff += 1
        c1, c2 = full.candidates, fast.candidates
        if c1.R.shape != c2.R.shape or not np.allclose(c1.R, c2.R) or not np.allclose(c1.t, c2.t):
            cand_diff += 1
    return {"taken": taken, "pose_diff": pose_diff, "cand_diff": cand_diff, "error_diff": error_diff}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1000, help="scenes per cell")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    cells = [(k, a, b, s) for k in ("usual", "random", "facing") for a, b in ((2, 2), (3, 1), (3, 3))
             for s in (0.0, 1.0)]
    total = {"taken": 0, "pose_diff": 0, "cand_diff": 0, "error_diff": 0}
    for kind, a, b, sigma in tqdm(cells, desc="cells"):
        r = cell(rng, args.n, kind, a, b, sigma)
        for k in total:
            total[k] += r[k]
        tqdm.write(f"{kind:7} {a}-{b} sigma={sigma}: shortcut taken {r['taken']}/{args.n}, poses differ "
                   f"{r['pose_diff']}, candidates differ {r['cand_diff']}, errors differ {r['error_diff']}")
    n = args.n * len(cells)
    print(f"all {n} scenes (mutloc {mutloc.__version__}): shortcut taken {total['taken']}, poses differ "
          f"{total['pose_diff']}, candidates differ {total['cand_diff']}, errors differ {total['error_diff']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
