#!/usr/bin/env python
"""Speed of marker calibration (``mutloc.calibrate_markers``) on one core:
40 and 1,000 frames of two robots (1-3.5 m, yaw +-30 deg, roll +-15 deg,
0.5 px), end to end (every frame localized with the measured rig, then the
bundle adjustment) and the bundle adjustment alone (its first fit: every combination held near the
given rig, which the weakly determined ones then stay near); beside it,
SciPy's ``least_squares`` (trf, sparse finite-difference Jacobian, Huber
loss, the scale held by a stiff residual, the prior as residuals) on the
same problem from the same start.

    python bench/bench_calibrate.py [--runs 5] [--frames 40 1000]

Writes bench/results/calibrate_results.json.  Targets (issue 14): 40 frames <= 1 s,
1,000 frames <= 10 s.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")  # one core

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402

import mutloc.calibration as mc  # noqa: E402
from mutloc.core import calibration as cc  # noqa: E402
from mutloc.sim.calibration import ball_rig, pair_sequence, perturb_rig, true_positions  # noqa: E402

SIGMA = 0.5
SCALE = ("M3", "M4", 0.30)


def best_of(fn, runs: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(runs):
        t0 = time.process_time()
        out = fn()
        times.append(time.process_time() - t0)
    return min(times), out


def captured_problem(measured, frames):
    """The BundleProblem and start calibrate_markers builds (captured from its call to adjust)."""
    seen = {}
    real = mc.adjust

    def spy(problem, markers0, R0, t0, **kw):
        seen.setdefault("args", (problem, np.array(markers0), R0.copy(), t0.copy(), kw))
        return real(problem, markers0, R0, t0, **kw)

    mc.adjust = spy
    try:
        mc.calibrate_markers(measured, frames, scale=SCALE, pixel_sigma=SIGMA)
    finally:
        mc.adjust = real
    return seen["args"]


def scipy_adjust(problem, M0, R0, t0):
    """The same robust problem with scipy.optimize.least_squares."""
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    G, S = problem.n_groups, problem.n_slots
    npose = G * 6 * S
    n = len(problem.group)
    res = np.zeros((n, 2))
    wts = np.ones(n)
    system = cc._System(problem)
    Rn, tn, Mn = np.empty_like(R0), np.empty_like(t0), np.empty_like(M0)
    (i, j, D), = problem.constraints

    # the prior (the given rig; calibrate_markers' first fit holds every combination near it)
    W = problem.prior_matrix()
    if W is None:
        L = np.zeros((0, M0.size))
    else:
        lw, U = np.linalg.eigh(W)
        L = (np.sqrt(np.clip(lw, 0.0, None)) * U).T[lw > 1e-12 * max(lw.max(), 1e-300)]

    def fun(x):
        cc._apply_step(R0, t0, M0, problem.slot_used, x[:npose].reshape(G, 6 * S), x[npose:], Rn, tn, Mn)
        system.cost(problem, Mn, Rn, tn, SIGMA, 1e12, res, wts)
        stiff = 1e4 * (np.linalg.norm(Mn[i] - Mn[j]) - D)  # metres -> 0.1 mm per sigma
        prior = L @ (Mn - problem.prior).ravel() / SIGMA if len(L) else np.zeros(0)
        return np.concatenate([res.ravel() / SIGMA, [stiff], prior])

    A = lil_matrix((2 * n + 1 + len(L), npose + M0.size), dtype=int)
    A[2 * n + 1:, npose:] = 1
    for k in range(n):
        g, m = problem.group[k], problem.marker[k]
        A[2 * k:2 * k + 2, g * 6 * S:(g + 1) * 6 * S] = 1
        A[2 * k:2 * k + 2, npose + 3 * m:npose + 3 * m + 3] = 1
    A[2 * n, npose + 3 * i:npose + 3 * i + 3] = 1
    A[2 * n, npose + 3 * j:npose + 3 * j + 3] = 1
    out = least_squares(fun, np.zeros(npose + M0.size), jac_sparsity=A, method="trf", loss="huber",
                        f_scale=cc.HUBER_K, x_scale="jac", xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=500)
    cc._apply_step(R0, t0, M0, problem.slot_used, out.x[:npose].reshape(G, 6 * S), out.x[npose:], Rn, tn, Mn)
    return Mn.copy(), out.nfev, int(out.status)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--frames", type=int, nargs="+", default=[40, 1000])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-scipy", dest="scipy", action="store_false")
    ap.add_argument("--out", default=result_file("calibrate_results.json"))
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    truth = ball_rig(2)
    measured = perturb_rig(truth, rng)
    tp = true_positions(truth)
    # Compile and warm up outside the timing.
    mc.calibrate_markers(measured, pair_sequence(truth, 20, rng, pixel_sigma=SIGMA).frames, scale=SCALE,
                         pixel_sigma=SIGMA)
    results = {"machine": machine(), "runs": args.runs, "pixel_sigma": SIGMA, "cases": {}}
    for n in args.frames:
        frames = pair_sequence(truth, n, rng, pixel_sigma=SIGMA).frames
        runs = args.runs if n <= 100 else max(1, args.runs // 2)
        t_all, res = best_of(lambda: mc.calibrate_markers(measured, frames, scale=SCALE, pixel_sigma=SIGMA), runs)
        problem, M0, R0, t0, kw = captured_problem(measured, frames)
        t_ba, adj = best_of(lambda: cc.adjust(problem, M0, R0, t0, **kw), runs)
        names = res.covariance_markers
        case = {"frames": n, "observations": len(problem.group), "end_to_end_s": t_all,
                "bundle_adjustment_s": t_ba, "iterations": adj.iterations,
                "marker_rms_error_mm": 1000 * float(np.sqrt(np.mean([np.sum((res.markers[k].new - tp[k]) ** 2)
                                                                      for k in names])))}
        line = (f"{n:5d} frames ({len(problem.group)} observations): end to end {t_all:.3f} s, bundle adjustment "
                f"{t_ba:.3f} s ({adj.iterations} iterations)")
        if args.scipy:
            sc_runs = 1 if n > 100 else runs
            print(line, flush=True)
            t_sc, (M_sc, nfev, status) = best_of(lambda: scipy_adjust(problem, M0, R0, t0), sc_runs)
            diff = float(np.abs(M_sc - adj.markers).max())
            case.update({"scipy_least_squares_s": t_sc, "scipy_nfev": nfev, "scipy_status": status,
                         "scipy_ratio": t_sc / t_ba,
                         "scipy_max_marker_difference_mm": 1000 * diff})
            line = (f"      scipy least_squares on the same problem: {t_sc:.3f} s ({t_sc / t_ba:.0f}x the bundle "
                    f"adjustment; {nfev} evaluations, status {status}), markers agree to {1000 * diff:.3f} mm")
        print(line)
        results["cases"][str(n)] = case
    Path(args.out).write_text(json.dumps(results, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
