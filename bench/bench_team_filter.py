#!/usr/bin/env python
"""Team filter: cameras at their own times (issue 24 item 5).  mutloc's
joint team filter (``core.team_filter.TeamFilter``) and GTSAM's
``IncrementalFixedLagSmoother`` on the same simulated records, in the same
run: every camera of a team at 30 fps, unsynchronized (the cameras spread
evenly over a frame, so each record is one camera's frame: 300 records a
second for 10 robots, 1500 for 50), 1 px noise.

    OPENBLAS_NUM_THREADS=1 taskset -c 1 python bench/bench_team_filter.py [--robots 10 50] [--durations 2 0.2]
        [--gtsam-durations 1 0.2] [--lags 0.02 0.1] [--gtsam-budget 120] [--detection-sigma 1]
        [--no-measure-noise] [--speed 1 --turn-rate 30]

``--detection-sigma``: the simulated detections' noise (px; the filter's
stated noise stays 1 px): below it, e.g. 0.05 px as in rendered images,
the filter's gain weighs the detections by the noise it measures
(``--no-measure-noise``: by the stated 1 px, as GTSAM's factors do).
``--speed``/``--turn-rate``: the robots drive circles at about that speed
(m/s) and turn at that peak rate (deg/s) instead of swaying slowly
(:func:`mutloc.sim.team.team_motion`).

Per record, timed alike (wall clock and the process's CPU time, all threads; median over
the records after a warm-up, a new ``ObservationSet`` every call):

- mutloc: ``team_problem`` (names to solver form) + ``predict`` to the
  record's time + ``update``;
- GTSAM: building the record's factors and values, ``update`` (one iSAM2
  step, relinearising above 1e-3) and reading the new poses.

The factor graph: per robot (not the reference, whose pose is the identity:
one key under a 1e-6 prior) a ``Pose3`` and a ``Vector6`` velocity at every
record the robot is in (observer or observed), chained by the same
constant-velocity model and noise as mutloc's filter (a ``CustomFactor``:
GTSAM has no built-in one for a pose with angular velocity, so these are
Python callbacks -- their share of the time is reported); each observation
with built-in factors only: a ``Point3`` for the marker in the reference's
frame, tied to its owner's pose and the marker's position on it by a
``ReferenceFrameFactorPoint3Pose3`` (sigma 0.1 mm: a constraint, against a
pixel's ~6 mm at 3 m) and seen by the observer through a
``GenericProjectionFactorCal3_S2`` (1 px).  Marker positions are keys under
1e-6 m priors.  Start: the same joint solution at t=0 for both, GTSAM's
priors per robot (marginals; mutloc gets the joint covariance).  Keys older
than ``--lag`` leave the window (each robot's newest keys are kept in it).

Accuracy on the same records, outside the timing: for each record, the
robots in it at the record's time (after ``--settle`` seconds): median
translation error and mean NEES/6 of the 6-DOF pose (GTSAM's marginal
covariance turned into the SPEC's convention).

Writes bench/results/team_filter.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402

from mutloc.core.filter import MotionNoise  # noqa: E402
from mutloc.core.geometry import so3_exp, so3_log  # noqa: E402
from mutloc.core.pose import Pose  # noqa: E402
from mutloc.core.team_filter import TeamFilter  # noqa: E402
from mutloc.sim.team import TeamScene, random_team, team_camera_records, team_motion  # noqa: E402
from mutloc.team import localize_team, team_problem  # noqa: E402

try:
    import gtsam
    from bench_filter_gtsam import COUNTS, from_pose3, gtsam_covariance, motion_factor, pose3, spec_covariance
except ImportError:  # the bench extra: pip install "mutloc[bench]"
    gtsam = None

NOISE = MotionNoise()  # the filter's default, and bench_filter_gtsam's process noise
SIGMA = 1.0
WARMUP = 30


def setup(n: int, seed: int, duration: float, detection_sigma: float = SIGMA, **motion):
    rng = np.random.default_rng(seed)
    scene = random_team(n, rng, one_way=0.0)
    recs = team_camera_records(scene, duration, sigma=detection_sigma, seed=seed, **motion)
    snap = TeamScene(scene.rig, team_motion(scene, seed=seed, **motion)(0.0), scene.links)
    team = localize_team(scene.rig, snap.observations(detection_sigma, rng), scene.names[0], pixel_sigma=SIGMA)
    return scene, recs, team


def involved(scene, prob, ref: int) -> list[int]:
    return sorted({int(i) for i in np.r_[prob.cam, prob.own]} - {ref})


def score(errors: list) -> dict:
    """errors: (translation error m, NEES/6) per robot and record."""
    if not errors:
        return {"evaluated": 0}
    e = np.array(errors)
    return {"evaluated": len(e), "median_error_m": float(np.median(e[:, 0])), "nees_over_6_mean": float(np.mean(e[:, 1])),
            "nees_over_6_median": float(np.median(e[:, 1])), "nees_above_chi2_999": float(np.mean(e[:, 1] > 20.5 / 6))}


def pose_error(world, ref: str, name: str, pose: Pose, cov: np.ndarray) -> tuple[float, float]:
    T = world[ref].inverse() @ world[name]
    e = np.r_[so3_log(T.R @ pose.R.T), T.t - pose.t]
    return float(np.linalg.norm(e[3:])), float(e @ np.linalg.solve(cov, e) / 6)


def timings(wall: list, cpu: list) -> dict:
    w, c = np.array(wall[WARMUP:]), np.array(cpu[WARMUP:])
    return {"records_timed": len(w), "median_wall_s": float(np.median(w)), "mean_wall_s": float(np.mean(w)),
            "p90_wall_s": float(np.percentile(w, 90)), "median_cpu_s": float(np.median(c)),
            "mean_cpu_s": float(np.mean(c)), "records_per_second_median_wall": float(1.0 / np.median(w)),
            "records_per_second_mean_cpu": float(1.0 / np.mean(c))}


def run_mutloc(scene, recs, team, settle: float, measure_noise: bool = True) -> dict:
    names = scene.names
    ref = names[0]
    f = TeamFilter(names, ref, NOISE, pixel_sigma=SIGMA, measure_noise=measure_noise)
    f.reset(0.0, {r: team.poses[r] for r in team.robots}, team.joint_covariance)
    wall, cpu, errors, accepted, obs_count = [], [], [], 0, []
    for t, _, world, obs in recs:
        w0, c0 = time.perf_counter(), time.process_time()
        prob = team_problem(scene.rig, obs)[0]
        f.predict(t)
        upd = f.update(prob) if len(prob.cam) else None
        c1, w1 = time.process_time(), time.perf_counter()
        wall.append(w1 - w0)
        cpu.append(c1 - c0)
        obs_count.append(len(prob.cam))
        accepted += bool(upd is not None and upd.accepted)
        errors.append([pose_error(world, ref, names[i], f.pose(names[i]), f.covariance(names[i]))
                       for i in involved(scene, prob, 0)])
    late = [e for (t, *_), e in zip(recs, errors) if t >= settle]
    return {"time_per_record": timings(wall, cpu), "accuracy": score(sum(late, [])), "accepted": accepted,
            "detection_sigma_measured": f.detection_sigma, "gain_sigma": f.gain_sigma,
            "records": len(recs), "observations_per_record_median": float(np.median(obs_count)),
            "errors_per_record": errors}


def run_gtsam(scene, recs, team, settle: float, lag: float, relinearize: float, budget: float) -> dict:
    """GTSAM's fixed-lag smoother over the same records (see the module docstring)."""
    from bench_filter_gtsam import process_noise

    names = scene.names
    ref = names[0]
    rig = scene.rig
    marker_index = {m: k for k, m in enumerate(m for r in names for m in rig.robots[r].markers)}
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(relinearize)
    params.relinearizeSkip = 1
    smoother = gtsam.IncrementalFixedLagSmoother(lag, params)
    pixel = gtsam.noiseModel.Isotropic.Sigma(2, SIGMA)
    tie = gtsam.noiseModel.Isotropic.Sigma(3, 1e-4)
    fixed3 = gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)
    RKEY = gtsam.symbol("r", 0)
    cal = {r: gtsam.Cal3_S2(*(lambda K: (K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2]))(rig.robots[r].camera.K))
           for r in names}

    def xkey(i, k):
        return 1_000_000 * i + k

    graph, values, stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), {}
    values.insert(RKEY, gtsam.Pose3())
    graph.add(gtsam.PriorFactorPose3(RKEY, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    stamps[RKEY] = 0.0
    for r in names:
        for m, marker in rig.robots[r].markers.items():
            key = gtsam.symbol("m", marker_index[m])
            values.insert(key, np.asarray(marker.position, float))
            graph.add(gtsam.PriorFactorPoint3(key, np.asarray(marker.position, float), fixed3))
            stamps[key] = 0.0
    fixed_keys = list(stamps)
    latest = {}  # robot index -> (count, time, Pose3, velocity)
    from gtsam.symbol_shorthand import V, X

    for r in team.robots:
        i = names.index(r)
        T = pose3(team.poses[r])
        values.insert(X(xkey(i, 0)), T)
        values.insert(V(xkey(i, 0)), np.zeros(6))
        graph.add(gtsam.PriorFactorPose3(X(xkey(i, 0)), T, gtsam.noiseModel.Gaussian.Covariance(
            gtsam_covariance(team.covariance(r), team.poses[r].R))))
        graph.add(gtsam.PriorFactorVector(V(xkey(i, 0)), np.zeros(6), gtsam.noiseModel.Diagonal.Sigmas(
            np.r_[[NOISE.initial_angular] * 3, [NOISE.initial_linear] * 3])))
        stamps[X(xkey(i, 0))] = stamps[V(xkey(i, 0))] = 0.0
        latest[i] = (0, 0.0, T, np.zeros(6))
    smoother.update(graph, values, stamps)
    COUNTS.update(behind_camera=0, factor_calls=0, factor_seconds=0.0)
    wall, cpu, errs, landmark, failed = [], [], [], 0, None
    python_seconds = []
    start = time.perf_counter()
    for t, _, world, obs in recs:
        if time.perf_counter() - start > budget and len(wall) >= 2 * WARMUP:
            break  # the records so far are reported (all of them in mutloc's figures beside)
        w0, c0 = time.perf_counter(), time.process_time()
        s0 = COUNTS["factor_seconds"]
        prob, _, marker_names = team_problem(rig, obs)
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        stamps = dict.fromkeys(fixed_keys, t)  # the reference and the markers stay
        inv = [i for i in involved(scene, prob, 0) if i in latest]
        keys = {}
        for i in inv:
            k, t_prev, T_prev, vel = latest[i]
            dt = t - t_prev
            if dt <= 0.0:  # a key at this time already (the start)
                keys[i] = (X(xkey(i, k)), T_prev)
                stamps[X(xkey(i, k))] = stamps[V(xkey(i, k))] = t
                continue
            R = so3_exp(vel[:3] * dt) @ T_prev.rotation().matrix()
            T = gtsam.Pose3(gtsam.Rot3(R), T_prev.translation() + vel[3:] * dt)
            values.insert(X(xkey(i, k + 1)), T)
            values.insert(V(xkey(i, k + 1)), vel)
            graph.add(motion_factor(xkey(i, k), xkey(i, k + 1), dt, gtsam.noiseModel.Gaussian.Covariance(process_noise(dt))))
            stamps[X(xkey(i, k + 1))] = stamps[V(xkey(i, k + 1))] = t
            keys[i] = (X(xkey(i, k + 1)), T)
        for j in range(len(prob.cam)):
            a, b = int(prob.cam[j]), int(prob.own[j])
            if (a != 0 and a not in keys) or (b != 0 and b not in keys):
                continue
            lkey = gtsam.symbol("l", landmark)
            landmark += 1
            Tb = keys[b][1] if b != 0 else gtsam.Pose3()
            values.insert(lkey, Tb.transformFrom(prob.points[j]))
            stamps[lkey] = t
            mkey = gtsam.symbol("m", marker_index[marker_names[j]])
            graph.add(gtsam.ReferenceFrameFactorPoint3Pose3(mkey, keys[b][0] if b != 0 else RKEY, lkey, tie))
            graph.add(gtsam.GenericProjectionFactorCal3_S2(prob.uv[j], pixel, keys[a][0] if a != 0 else RKEY, lkey,
                                                           cal[names[a]]))
        for i, (k, *_rest) in latest.items():  # every robot's newest keys stay in the window
            if i not in keys:
                stamps[X(xkey(i, k))] = stamps[V(xkey(i, k))] = t
        try:
            smoother.update(graph, values, stamps)
            for i in inv:
                k = latest[i][0] + int(values.exists(X(xkey(i, latest[i][0] + 1))))
                latest[i] = (k, t, smoother.calculateEstimatePose3(X(xkey(i, k))),
                             smoother.calculateEstimateVector(V(xkey(i, k))))
        except (RuntimeError, ValueError) as exc:  # GTSAM gave up: reported, the figures stop there
            failed = (float(t), " ".join(str(exc).split())[:200])
            break
        c1, w1 = time.process_time(), time.perf_counter()
        wall.append(w1 - w0)
        cpu.append(c1 - c0)
        python_seconds.append(COUNTS["factor_seconds"] - s0)
        if t >= settle:
            for i in inv:
                T = latest[i][2]
                R = np.ascontiguousarray(T.rotation().matrix())
                cov = spec_covariance(smoother.marginalCovariance(X(xkey(i, latest[i][0]))), R)
                errs.append(pose_error(world, ref, names[i], from_pose3(T), cov))
    out = {"time_per_record": timings(wall, cpu) if len(wall) > WARMUP else None, "accuracy": score(errs),
           "records": len(wall), "failed": failed, "lag_s": lag, "relinearize_threshold": relinearize,
           "python_motion_factor_share_of_wall": float(np.sum(python_seconds[WARMUP:]) / np.sum(wall[WARMUP:]))
           if len(wall) > WARMUP else None,
           "python_factor_calls_per_record": COUNTS["factor_calls"] / max(len(wall), 1)}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, nargs="+", default=[10, 50])
    ap.add_argument("--durations", type=float, nargs="+", default=[2.0, 0.2],
                    help="seconds of records per team size (mutloc)")
    ap.add_argument("--gtsam-durations", type=float, nargs="+", default=[1.0, 0.2],
                    help="seconds of records per team size for GTSAM (0: skip); the first of mutloc's records")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--settle", type=float, default=0.5, help="accuracy from this time on (capped at a quarter)")
    ap.add_argument("--lags", type=float, nargs="+", default=[0.02, 0.1], help="GTSAM's windows (s), a run each")
    ap.add_argument("--relinearize", type=float, default=1e-3)
    ap.add_argument("--gtsam-budget", type=float, default=120.0,
                    help="seconds per GTSAM run; it stops there (after at least 60 records) and reports those")
    ap.add_argument("--detection-sigma", type=float, default=SIGMA,
                    help="the simulated detections' noise (px); the stated noise stays 1 px")
    ap.add_argument("--no-measure-noise", action="store_true",
                    help="the filter's gain weighs the detections by the stated noise only")
    ap.add_argument("--speed", type=float, default=None, help="the robots drive circles at about this speed (m/s)")
    ap.add_argument("--turn-rate", type=float, default=None, help="and turn at this peak rate (deg/s)")
    ap.add_argument("--out", default=result_file("team_filter.json"))
    args = ap.parse_args(argv)
    import os
    from importlib.metadata import version

    res = {"machine": machine(), "args": {k: v for k, v in vars(args).items() if k != "out"},
           "env": {k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS", "OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE",
                                                  "OMP_NUM_THREADS", "NUMBA_NUM_THREADS")},
           "gtsam": version("gtsam") if gtsam is not None else None, "teams": {}}
    for n, dur, gdur in zip(args.robots, args.durations, args.gtsam_durations):
        t0 = time.perf_counter()
        scene, recs, team = setup(n, args.seed, dur, args.detection_sigma, speed=args.speed, turn_rate=args.turn_rate)
        settle = min(args.settle, (gdur if gdur > 0 else dur) / 4)  # one window for both
        entry = {"records": len(recs), "duration_s": dur, "records_per_second_simulated": len(recs) / dur,
                 "simulation_s": time.perf_counter() - t0,
                 "mutloc": run_mutloc(scene, recs, team, settle, not args.no_measure_noise)}
        m = entry["mutloc"]
        print(f"{n} robots, {len(recs)} records ({len(recs) / dur:.0f}/s), {m['observations_per_record_median']:.0f} "
              f"observations per record; mutloc per record median {1e6 * m['time_per_record']['median_wall_s']:.0f} us "
              f"wall, {1e6 * m['time_per_record']['median_cpu_s']:.0f} us CPU; accepted {m['accepted']}; gain sigma "
              f"{m['gain_sigma']:.3g} px (measured {m['detection_sigma_measured'] or float('nan'):.3g}); "
              f"{m['accuracy']}", flush=True)
        if gtsam is not None and gdur > 0:
            cut = [r for r in recs if r[0] <= gdur]
            for lag in args.lags:
                g = run_gtsam(scene, cut, team, settle, lag, args.relinearize, args.gtsam_budget)
                # mutloc on the same records (its run above), for the same accuracy window
                g["mutloc_on_the_same_records"] = score(sum((e for (t, *_), e in zip(cut[:g["records"]], m["errors_per_record"])
                                                             if t >= settle), []))
                entry[f"gtsam_lag_{lag:g}"] = g
                tp = g["time_per_record"] or {}
                share = g["python_motion_factor_share_of_wall"]
                print(f"  GTSAM lag {lag:g} s on the first {g['records']} records: per record median "
                      f"{1e6 * tp.get('median_wall_s', np.nan):.0f} us wall, "
                      f"{1e6 * tp.get('median_cpu_s', np.nan):.0f} us CPU (Python motion factors "
                      f"{100 * (share if share is not None else np.nan):.0f}% of wall); failed: {g['failed']}; "
                      f"{g['accuracy']}; mutloc on them: {g['mutloc_on_the_same_records']}", flush=True)
        times = np.array([r[0] for r in recs])
        edges = np.linspace(0.0, dur, 9)  # mutloc's accuracy over time: the start's transient
        m["accuracy_by_time"] = [{"from_s": float(lo), "to_s": float(hi), **score(sum(
            (m["errors_per_record"][k] if m["errors_per_record"][k] else []
             for k in np.flatnonzero((times >= lo) & (times < hi))), []))} for lo, hi in zip(edges[:-1], edges[1:])]
        del m["errors_per_record"]
        res["teams"][str(n)] = entry
    Path(args.out).write_text(json.dumps(res, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
