#!/usr/bin/env python
"""Generalized P3P kernel speed, next to the central mutual minimal solver
measured in the same run.

    python bench/bench_gp3p.py [--n 20000] [--runs 5] [--seed 0]

Both solvers run inside one compiled loop over ``--n`` different random
problems (a new problem every call, so no branch or cache history is
reused), per split (3-0, 2-1, 1-2, 0-3); the figure is the loop's CPU time
(of its thread) per call, the median of ``--runs`` runs, on one core.  Problems: two robots 1-5 m
apart, any orientation, markers within +-0.3 m of each robot's origin;
generalized: every ray from its own camera centre within +-0.3 m (the
non-central problem); central peer: ``solve_minimal_kernel`` (one camera at
each robot's origin; it allocates its 1 kB scratch per call) and
``solve_minimal_ws`` (caller's scratch, like the generalized kernel).  Also
the NumPy wrapper ``generalized_p3p`` per call (Python overhead included).
Prints the figures and writes bench/results/gp3p_results.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

from mutloc.core.generalized import (GP3P_MAX_SOLUTIONS, GP3P_WORK_SIZE, generalized_p3p,  # noqa: E402
                                     generalized_p3p_kernel)
from mutloc.core.minimal import WORK_SIZE as MINIMAL_WORK_SIZE, solve_minimal_kernel, solve_minimal_ws  # noqa: E402
from mutloc.sim.synthetic import batch_minimal_problems, batch_scenes  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402

SPLITS = {"3-0": 3, "2-1": 2, "1-2": 1, "0-3": 0}


def _rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    """Uniformly random rotations (n, 3, 3), from unit quaternions."""
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1),
    ], axis=1)


def generalized_problems(rng: np.random.Generator, n: int, n_u_rays: int):
    """``n`` non-central problems: (kinds (3,), origins, directions, points (n, 3, 3), R, t)."""
    R = _rotations(rng, n)
    u = rng.normal(size=(n, 3))
    t = u / np.linalg.norm(u, axis=1, keepdims=True) * rng.uniform(1.0, 5.0, size=(n, 1))
    kinds = np.array([0] * n_u_rays + [1] * (3 - n_u_rays), dtype=np.int64)
    o = rng.uniform(-0.3, 0.3, size=(n, 3, 3))
    X = rng.uniform(-0.3, 0.3, size=(n, 3, 3))
    in_u = np.einsum("nji,nkj->nki", R, X - t[:, None, :])  # W points in U
    in_w = np.einsum("nij,nkj->nki", R, X) + t[:, None, :]  # U points in W
    d = np.where((kinds == 0)[None, :, None], in_u, in_w) - o
    return kinds, o, np.ascontiguousarray(d), X, R, t


@njit(cache=True)
def _loop_gp3p(kinds, o, d, X, Rs, ts, ws):
    total = 0
    for i in range(o.shape[0]):
        total += generalized_p3p_kernel(kinds, o[i], d[i], X[i], Rs, ts, ws)
    return total


@njit(cache=True)
def _loop_minimal_kernel(side, b, X, Rs, ts, rg):
    total = 0
    for i in range(b.shape[0]):
        total += solve_minimal_kernel(side, b[i], X[i], Rs, ts, rg)
    return total


@njit(cache=True)
def _loop_minimal_ws(side, b, X, Rs, ts, rg, ws, iws):
    total = 0
    for i in range(b.shape[0]):
        total += solve_minimal_ws(side, b[i], X[i], Rs, ts, rg, ws, iws)
    return total


def per_call_us(fn, n: int, runs: int) -> float:
    fn()  # compile / load the cache
    times = []
    for _ in range(runs):
        t0 = time.thread_time()  # CPU time of this thread: one core, whatever else the machine does
        fn()
        times.append(time.thread_time() - t0)
    return 1e6 * float(np.median(times)) / n


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20000, help="problems per split (one call each per run)")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--wrapper-n", type=int, default=2000, help="problems for the NumPy wrapper's figure")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=result_file("gp3p_results.json"))
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    Rs, ts, rg = np.empty((GP3P_MAX_SOLUTIONS, 3, 3)), np.empty((GP3P_MAX_SOLUTIONS, 3)), np.empty((8, 3))
    ws, mws, iws = np.empty(GP3P_WORK_SIZE), np.empty(MINIMAL_WORK_SIZE), np.empty(6, dtype=np.int64)
    res: dict = {"machine": machine(), "command": " ".join(["python"] + sys.argv), "n": args.n, "runs": args.runs,
                 "unit": "us per call, median of runs", "splits": {}}
    print(f"{'split':6} {'gp3p kernel':>12} {'sols/call':>10} {'minimal_kernel':>15} {'minimal_ws':>11} "
          f"{'sols/call':>10} {'ratio':>6} {'gp3p wrapper':>13}")
    for name, k in SPLITS.items():
        kinds, o, d, X, _, _ = generalized_problems(rng, args.n, k)
        R, t, mp, mq = batch_scenes(rng, args.n, "random", 3, 3, distance=(1.0, 5.0))
        side, b, Xm = batch_minimal_problems(R, t, mp, mq, k)
        g_us = per_call_us(lambda: _loop_gp3p(kinds, o, d, X, Rs, ts, ws), args.n, args.runs)
        mk_us = per_call_us(lambda: _loop_minimal_kernel(side, b, Xm, Rs, ts, rg), args.n, args.runs)
        mw_us = per_call_us(lambda: _loop_minimal_ws(side, b, Xm, Rs, ts, rg, mws, iws), args.n, args.runs)
        g_sols = _loop_gp3p(kinds, o, d, X, Rs, ts, ws) / args.n
        m_sols = _loop_minimal_ws(side, b, Xm, Rs, ts, rg, mws, iws) / args.n
        m = min(args.wrapper_n, args.n)

        def wrapper():
            for i in range(m):
                generalized_p3p(kinds, o[i], d[i], X[i])

        w_us = per_call_us(wrapper, m, args.runs)
        res["splits"][name] = {"gp3p_kernel_us": g_us, "gp3p_solutions_per_call": g_sols,
                               "solve_minimal_kernel_us": mk_us, "solve_minimal_ws_us": mw_us,
                               "minimal_solutions_per_call": m_sols, "ratio_gp3p_to_minimal_kernel": g_us / mk_us,
                               "gp3p_numpy_wrapper_us": w_us}
        print(f"{name:6} {g_us:12.3f} {g_sols:10.2f} {mk_us:15.3f} {mw_us:11.3f} {m_sols:10.2f} {g_us / mk_us:6.2f} "
              f"{w_us:13.2f}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=1))
    print(f"machine: {res['machine']['cpu']}, {res['machine']['cores']} cores, "
          f"load {res['machine']['load_average_at_start']}; written {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
