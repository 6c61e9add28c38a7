#!/usr/bin/env python
"""Solver benchmark: latency, throughput and correctness per configuration,
next to OpenCV's P3P measured in the same run.

    python bench/bench_solvers.py            # full run (10^6 problems per configuration)
    python bench/bench_solvers.py --n 100000 # quicker

Prints a table and writes bench/results/solvers_results.json.  Everything runs on one core
(NUMBA_NUM_THREADS=1; the kernels are serial anyway); batched throughput is
measured in CPU time of the solving thread; latencies in wall-clock time, each
window of calls its best of a few passes, the median over windows (the same
for cv2.solveP3P and localize, so their ratio compares like with like).
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

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

import mutloc  # noqa: E402
from mutloc.core.batch import iter_solve_minimal  # noqa: E402
from mutloc.core.camera import Camera  # noqa: E402
from mutloc.core.minimal import solve_minimal  # noqa: E402
from mutloc.core.rig import Marker, Rig, Robot  # noqa: E402
from mutloc.sim.synthetic import batch_minimal_problems, batch_scenes  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402

CONFIGS = {"3-0": 3, "2-1": 2, "1-2": 1, "0-3": 0}
KINDS = ("usual", "facing", "random")


def per_call_us(fn, args_list, repeat: int = 5, window: int = 20) -> float:
    """Time per call: args_list is cut into windows of ``window`` calls; each
    window's time is its best of ``repeat`` passes, and the figure is the
    median over windows.  On a shared machine a pass the scheduler
    interrupted is an outlier the best-of ignores; localize is timed the
    same way (one scene's calls per window), so the ratios compare like with
    like."""
    n_win = max(len(args_list) // window, 1)
    best = np.full(n_win, np.inf)
    for _ in range(repeat):
        for w in range(n_win):
            part = args_list[w * window:(w + 1) * window]
            t0 = time.perf_counter()
            for a in part:
                fn(*a)
            best[w] = min(best[w], (time.perf_counter() - t0) / len(part))
    return 1e6 * float(np.median(best))


def cv2_problems(bearings: np.ndarray, points: np.ndarray, k: int) -> list[tuple]:
    """Equivalent P3P calls for OpenCV: 3 object points, 3 normalised image points."""
    K = np.eye(3)
    out = []
    for b, p in zip(bearings, points):
        img = np.ascontiguousarray(b[:, :2] / b[:, 2:3])
        out.append((np.ascontiguousarray(p), img, K, None, cv2.SOLVEPNP_P3P))
    return out


def found_rate(side, bearings, points, R, t) -> tuple[int, int]:
    """(#problems whose true pose is among the candidates, #problems)."""
    ok = 0
    for ch in iter_solve_minimal(side, bearings, points):
        sl = slice(ch.start, ch.start + len(ch))
        et = np.linalg.norm(ch.t - t[sl][:, None, :], axis=2)
        c = (np.einsum("nkij,nij->nk", ch.R, R[sl]) - 1.0) / 2.0
        er = np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))
        ok += int(np.sum(np.any((et < 1e-6) & (er < 1e-5), axis=1)))
    return ok, len(bearings)


def bench_minimal(n_correct: int, n_latency: int, n_batch: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    res: dict = {}
    # cv2.solveP3P on usual-mounting P3P problems: the peer figure.
    R, t, mp, mq = batch_scenes(rng, n_latency, "random", 3, 3)
    side, b, X = batch_minimal_problems(R, t, mp, mq, 3)
    cv_args = cv2_problems(b, X, 3)
    for a in cv_args[:10]:
        cv2.solveP3P(*a)
    cv_us = per_call_us(cv2.solveP3P, cv_args)
    res["cv2_solveP3P_us"] = cv_us
    res["cv2_args"] = cv_args
    for name, k in tqdm(CONFIGS.items(), desc="configurations"):
        R, t, mp, mq = batch_scenes(rng, max(n_latency, n_batch), "usual", 3, 3)
        side, b, X = batch_minimal_problems(R, t, mp, mq, k)
        solve_minimal(side, b[0], X[0])  # compile / load cache
        args = [(side, b[i], X[i]) for i in range(n_latency)]
        single = per_call_us(solve_minimal, args)
        bb, XX = b[:n_batch], X[:n_batch]
        list(iter_solve_minimal(side, bb[:10], XX[:10]))
        # CPU time of this thread: one core's throughput, whatever else the
        # (shared) machine is doing.  Best of three.
        best = np.inf
        for _ in range(3):
            t0 = time.thread_time()
            for _ in iter_solve_minimal(side, bb, XX):
                pass
            best = min(best, time.thread_time() - t0)
        rate = n_batch / best
        entry = {"single_call_us": single, "ratio_to_cv2_P3P": single / cv_us, "batch_solves_per_s": rate,
                 "found": {}}
        for kind in KINDS:
            ok = tot = 0
            chunk = 200_000
            for start in range(0, n_correct, chunk):
                m = min(chunk, n_correct - start)
                R, t, mp, mq = batch_scenes(rng, m, kind, 3, 3)
                s, b2, X2 = batch_minimal_problems(R, t, mp, mq, k)
                o, n = found_rate(s, b2, X2, R, t)
                ok += o
                tot += n
            entry["found"][kind] = {"rate": ok / tot, "missed": tot - ok, "problems": tot}
        res[name] = entry
    return res


def _rig_for(mp: np.ndarray, mq: np.ndarray, cam: Camera) -> Rig:
    return Rig({
        "p": Robot("p", cam, {f"P{i}": Marker(f"P{i}", "p", x) for i, x in enumerate(mp)}),
        "q": Robot("q", cam, {f"Q{i}": Marker(f"Q{i}", "q", x) for i, x in enumerate(mq)}),
    })


def _observations(R, t, mp, mq, cam, rng, sigma):
    up = cam.project((mq - t) @ R) + rng.normal(scale=sigma, size=(len(mq), 2))
    uq = cam.project(mp @ R.T + t) + rng.normal(scale=sigma, size=(len(mp), 2))
    return {"p": {f"Q{i}": up[i] for i in range(len(mq))}, "q": {f"P{i}": uq[i] for i in range(len(mp))}}


def _passes(rig, obs) -> bool:
    try:
        mutloc.localize(rig, obs)
        return True
    except mutloc.errors.InconsistentObservationsError:
        return False


def _columns(obs: dict) -> tuple[list, list, np.ndarray]:
    """(observer, marker, uv) columns of an observation dict: what a detector hands over per frame."""
    observer = [r for r, ms in obs.items() for _ in ms]
    marker = [m for ms in obs.values() for m in ms]
    uv = np.array([u for ms in obs.values() for u in ms.values()], float)
    return observer, marker, uv


def bench_localize(n_scenes: int, seed: int, cv_args: list[tuple]) -> dict:
    """Full 2-2 localize (validation, candidates, refinement, covariance,
    consistency test) latency as a user's call costs it: every frame is new,
    so every call gets a new ObservationSet (built from the frame's columns
    inside the timed call: the headline) or the SPEC's dict (converted inside
    localize).  For the record, the same set localized again (what the set's
    memo saves; not a user's cost) and a new set with the consistency test
    disabled (what the checks cost); per frame in one localize_batch call, new
    sets and dicts.  The peer, ``cv2.solveP3P``, is timed again just before
    and after (the machine's load changes over a run)."""
    ObservationSet = mutloc.ObservationSet
    p3p_before = per_call_us(cv2.solveP3P, cv_args)
    rng = np.random.default_rng(seed)
    cam = Camera(np.array([[800.0, 0, 479.5], [0, 800.0, 269.5], [0, 0, 1]]), None, (960, 540))
    R, t, mp, mq = batch_scenes(rng, n_scenes, "usual", 2, 2, distance=(1.0, 3.0))
    cases = [(_rig_for(mp[i], mq[i], cam), _observations(R[i], t[i], mp[i], mq[i], cam, rng, 1.0))
             for i in range(n_scenes)]
    # The ~1% of noise draws the consistency test rejects (at its 99%) would
    # time the error path; a clean localize is what is measured.
    cases = [(rig, obs) for rig, obs in cases if _passes(rig, obs)]
    cols = [(rig, _columns(obs)) for rig, obs in cases]
    reused = [(rig, ObservationSet(*c)) for rig, c in cols]
    no_checks = {"confidence": 1.0, "reject_outliers": False}
    variants = {
        "new_set": lambda rig, c: (lambda: mutloc.localize(rig, ObservationSet(*c))),
        "dict": lambda rig, obs: (lambda: mutloc.localize(rig, obs)),
        "new_set_no_checks": lambda rig, c: (lambda: mutloc.localize(rig, ObservationSet(*c), **no_checks)),
        "reused_set": lambda rig, o: (lambda: mutloc.localize(rig, o)),
    }
    data = {"new_set": cols, "dict": cases, "new_set_no_checks": cols, "reused_set": reused}
    for name, make in variants.items():
        make(*data[name][0])()
    out: dict = {"scenes": len(cases), "headline": "new_set",
                 "note": "new_set: an ObservationSet built from the frame's columns inside each timed call; "
                         "dict: the SPEC dict; reused_set: one set localized again (its memo), not a user's cost"}
    timings = {}
    for name, make in variants.items():
        # per scene: its best of 3 windows of 20 calls, as per_call_us
        timings[name] = np.array([per_call_us(make(*d), [()] * 20, repeat=3) for d in data[name]])
    p3p_us = 0.5 * (p3p_before + per_call_us(cv2.solveP3P, cv_args))
    out["cv2_solveP3P_us"] = p3p_us
    for name, per in timings.items():
        out[name] = {"median_us": float(np.median(per)), "p90_us": float(np.percentile(per, 90)),
                     "ratio_to_cv2_P3P": float(np.median(per) / p3p_us)}
    rig0 = cols[0][0]
    frame_cols = [c for rig, c in cols if rig is rig0] * 20
    frame_dicts = [obs for rig, obs in cases if rig is rig0] * 20
    out["batch_per_frame_us"] = {
        "new_set": per_call_us(lambda: mutloc.localize_batch(rig0, [ObservationSet(*c) for c in frame_cols]),
                               [()] * 50, repeat=3, window=1) / len(frame_cols),
        "dict": per_call_us(lambda: mutloc.localize_batch(rig0, frame_dicts), [()] * 50, repeat=3,
                            window=1) / len(frame_dicts),
    }
    out["checks_overhead"] = out["new_set"]["median_us"] / out["new_set_no_checks"]["median_us"] - 1.0
    return out


def bench_initializers(n_scenes: int, seed: int) -> dict:
    """Minimal-subset candidates versus the essential-matrix initializer, 3-3 markers."""
    rng = np.random.default_rng(seed)
    cam = Camera(np.array([[800.0, 0, 479.5], [0, 800.0, 269.5], [0, 0, 1]]), None, (960, 540))
    R, t, mp, mq = batch_scenes(rng, n_scenes, "random", 3, 3, distance=(1.0, 3.0))
    out = {}
    for init in ("minimal", "essential", "both"):
        errs, times, fails = [], [], 0
        rng2 = np.random.default_rng(seed + 1)
        for i in range(n_scenes):
            rig = _rig_for(mp[i], mq[i], Camera(cam.K, None, None))
            obs = _observations(R[i], t[i], mp[i], mq[i], cam, rng2, 1.0)
            t0 = time.perf_counter()
            try:
                est = mutloc.localize(rig, obs, initializer=init)
            except mutloc.errors.MutlocError:
                fails += 1
                continue
            times.append(time.perf_counter() - t0)
            errs.append((np.linalg.norm(est.t - t[i]), mutloc.rotation_error_deg(est.R, R[i])))
        e = np.array(errs) if errs else np.full((1, 2), np.nan)
        out[init] = {"median_translation_m": float(np.median(e[:, 0])), "median_rotation_deg": float(np.median(e[:, 1])),
                     "median_time_us": float(np.median(times) * 1e6) if times else None, "failures": fails}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1_000_000, help="problems per configuration and scene kind for the correctness rate")
    ap.add_argument("--latency-n", type=int, default=2000)
    ap.add_argument("--batch-n", type=int, default=200_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=result_file("solvers_results.json"))
    args = ap.parse_args(argv)
    result = {"machine": machine(), "command": " ".join(["python"] + sys.argv)}
    result["minimal"] = bench_minimal(args.n, args.latency_n, args.batch_n, args.seed)
    result["localize_2_2"] = bench_localize(200, args.seed, result["minimal"].pop("cv2_args"))
    try:
        result["initializers_3_3"] = bench_initializers(300, args.seed)
    except ImportError as exc:  # essential initializer not available
        result["initializers_3_3"] = {"error": str(exc)}
    m = result["minimal"]
    print(f"machine: {result['machine']['cpu']} ({result['machine']['cores']} cores), one core used")
    print(f"cv2.solveP3P (Ding et al.) per call: {m['cv2_solveP3P_us']:.2f} us")
    print(f"{'config':6} {'single us':>10} {'x cv2':>7} {'batch /s':>11}   true pose found (usual / facing / random)")
    for name in CONFIGS:
        e = m[name]
        f = e["found"]
        rates = " / ".join(f"{100 * f[k]['rate']:.4f}% ({f[k]['missed']} missed)" for k in KINDS)
        print(f"{name:6} {e['single_call_us']:10.2f} {e['ratio_to_cv2_P3P']:7.2f} {e['batch_solves_per_s']:11,.0f}   {rates}")
    loc = result["localize_2_2"]
    print(f"cv2.solveP3P per call, timed again around the localize runs: {loc['cv2_solveP3P_us']:.2f} us")
    labels = {"new_set": "new ObservationSet per call (headline)", "dict": "SPEC dict per call",
              "new_set_no_checks": "new set, consistency test off", "reused_set": "same set again (its memo; not a user's cost)"}
    for k, label in labels.items():
        v = loc[k]
        print(f"localize 2-2, {label:45}: median {v['median_us']:.1f} us, p90 {v['p90_us']:.1f} us, "
              f"{v['ratio_to_cv2_P3P']:.2f} x cv2.solveP3P")
    b = loc["batch_per_frame_us"]
    print(f"localize_batch per frame: {b['new_set']:.1f} us with new sets (headline), {b['dict']:.1f} us with dicts; "
          f"consistency checks add {100 * loc['checks_overhead']:.1f}%")
    ini = result["initializers_3_3"]
    for k, v in ini.items():
        if isinstance(v, dict):
            print(f"initializer {k:9}: median {100 * v['median_translation_m']:.2f} cm / {v['median_rotation_deg']:.3f} deg, "
                  f"{v['median_time_us']:.0f} us, failures {v['failures']}")
    Path(args.out).write_text(json.dumps(result, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
