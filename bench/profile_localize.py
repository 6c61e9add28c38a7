#!/usr/bin/env python
"""Where the time of a clean 2-2 ``localize`` goes (typed path), next to
``cv2.solveP3P`` in the same run: the compiled solve alone, ``estimate``
(the solve and its Python wrapper) and the whole ``localize``, each as CPU
time of this thread per call (best of 15 passes over the scenes).

    python bench/profile_localize.py
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

import mutloc  # noqa: E402
from mutloc.core.camera import Camera  # noqa: E402
from mutloc.core.consistency import chi2_quantile  # noqa: E402
from mutloc.core.estimate import PairProblem, estimate, first_subset_kernel  # noqa: E402
from mutloc.sim.synthetic import batch_minimal_problems, batch_scenes  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_solvers import _observations, _passes, _rig_for, cv2_problems  # noqa: E402


def best_us(fn, n_calls: int, passes: int = 15) -> float:
    """CPU time per call of ``fn`` (which makes ``n_calls`` calls), best of ``passes``."""
    best = np.inf
    for _ in range(passes):
        t0 = time.thread_time()
        fn()
        best = min(best, time.thread_time() - t0)
    return 1e6 * best / n_calls


def main() -> int:
    rng = np.random.default_rng(0)
    R, t, mp, mq = batch_scenes(rng, 500, "random", 3, 3)
    _, b, X = batch_minimal_problems(R, t, mp, mq, 3)
    cv_args = cv2_problems(b, X, 3)
    cam = Camera(np.array([[800.0, 0, 479.5], [0, 800.0, 269.5], [0, 0, 1]]), None, (960, 540))
    R, t, mp, mq = batch_scenes(rng, 100, "usual", 2, 2, distance=(1.0, 3.0))
    cases = [(_rig_for(mp[i], mq[i], cam), _observations(R[i], t[i], mp[i], mq[i], cam, rng, 1.0)) for i in range(100)]
    typed = [(rig, mutloc.ObservationSet.from_dict(obs)) for rig, obs in cases if _passes(rig, obs)]
    pairs = [o.pair(rig, "p", "q") for rig, o in typed]
    gate = chi2_quantile(0.99, 2)
    problems = [PairProblem.trusted(p.side, p.points, None, p.uv, p.table.K, p.table.dist) for p in pairs]
    kernel_args = [(pr.side, pr.points, pr.pixels, pr.K[0], pr.dist[0], pr.K[1], pr.dist[1], gate, 50,
                    np.empty((3, 3)), np.empty(3), np.empty((6, 6)), np.empty((6, 6))) for pr in problems]

    def run_cv2():
        for a in cv_args:
            cv2.solveP3P(*a)

    def run_kernel():
        for a in kernel_args:
            first_subset_kernel(*a)

    def run_estimate():
        for pr in problems:
            estimate(pr, accept=gate)

    def run_localize():
        for rig, o in typed:
            mutloc.localize(rig, o)

    for f in (run_cv2, run_kernel, run_estimate, run_localize):
        f()
    cv = best_us(run_cv2, len(cv_args))
    k = best_us(run_kernel, len(kernel_args))
    e = best_us(run_estimate, len(problems))
    loc = best_us(run_localize, len(typed))
    print(f"{len(typed)} scenes; CPU time per call, best of 15 passes")
    print(f"cv2.solveP3P                         {cv:6.2f} us")
    print(f"compiled solve (first_subset_kernel) {k:6.2f} us")
    print(f"estimate (solve + Python wrapper)    {e:6.2f} us  (wrapper {e - k:.2f})")
    print(f"localize (typed)                     {loc:6.2f} us  (outside estimate {loc - e:.2f}); "
          f"{loc / cv:.2f} x cv2.solveP3P")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
