#!/usr/bin/env python
"""Team benchmark: joint solve rate of a 50-robot team from a warm start,
cold-start latency of 10-robot teams, and the same problems solved by
scipy.optimize.least_squares (method='trf', given the analytic
Jacobian) and, when it is installed (the ``bench`` extra), GTSAM
(Levenberg-Marquardt on a factor graph) in the same run.

    python bench/bench_team.py            # full run
    python bench/bench_team.py --quick    # fewer repetitions

Prints the figures and writes bench/results/team_results.json.  One core
(NUMBA_NUM_THREADS=1, BLAS single-threaded); times are medians over the
repetitions after one warm-up call (Numba compiled and cached) for mutloc
and both peers alike, both
wall-clock and CPU time of the calling thread (on a shared, loaded machine
the wall clock also counts the time other processes held the core; the
ratios against the peers are taken on CPU time, measured in the same run).
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
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import mutloc  # noqa: E402
from mutloc.core.geometry import so3_exp  # noqa: E402
from mutloc.core.team import TeamProblem, solve_team, team_residuals  # noqa: E402
from mutloc.sim.team import random_team  # noqa: E402
from mutloc.team import team_problem  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402


def big_team(n: int, seen: int, rng: np.random.Generator):
    """``n`` robots in a disc sized for the team, each observing its ``seen``
    nearest robots among those in its field of view."""
    scene = random_team(n, rng, radius=1.1 * np.sqrt(n), one_way=0.0)
    scene.links = None
    vis = scene.visible()
    pos = {r: T.t for r, T in scene.world.items()}
    by_obs: dict[str, set[str]] = {}
    for a, m, _ in vis:
        by_obs.setdefault(a, set()).add(m.rsplit("_m", 1)[0])
    links = set()
    for a, bs in by_obs.items():
        near = sorted(bs, key=lambda b: np.linalg.norm(pos[a] - pos[b]))[:seen]
        links |= {(a, b) for b in near}
    scene.links = links
    return scene


def perturbed(truth: dict, rng: np.random.Generator, rot_deg: float, trans_m: float) -> dict:
    """The truth moved by about ``rot_deg`` and ``trans_m`` per robot (a previous frame's solution)."""
    out = {}
    for r, T in truth.items():
        w = rng.normal(0.0, np.radians(rot_deg) / np.sqrt(3), 3)
        out[r] = mutloc.Pose(so3_exp(w) @ T.R, T.t + rng.normal(0.0, trans_m / np.sqrt(3), 3))
    return out


def timed(fn, reps: int) -> tuple[float, object]:
    """Median wall-clock seconds of ``reps`` calls after one warm-up call
    (the CPU seconds of the same calls in :data:`CPU`)."""
    fn()
    times, cpu = [], []
    out = None
    for _ in range(reps):
        c0 = time.thread_time()
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
        cpu.append(time.thread_time() - c0)
    CPU.append(float(np.median(cpu)))
    return float(np.median(times)), out


def fresh(obs: mutloc.ObservationSet) -> mutloc.ObservationSet:
    """A new set of the same observations, built in the timed call: every frame is new (a set keeps
    what it derived, so timing the same set again would time that memo)."""
    return mutloc.ObservationSet(obs.observer, obs.marker, obs.uv, obs.time, obs.score)


#: CPU seconds (this thread) of the last :func:`timed` measurements: on a
#: loaded machine the wall clock also counts the time other processes had
#: the core.
CPU: list[float] = []


# -- scipy ---------------------------------------------------------------------


def _left_jacobian(phi: np.ndarray) -> np.ndarray:
    """SO(3) left Jacobian: exp(phi + d) = exp(J_l(phi) d) exp(phi) to first order."""
    th = float(np.linalg.norm(phi))
    W = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    if th < 1e-8:
        return np.eye(3) + 0.5 * W
    return np.eye(3) + (1 - np.cos(th)) / th**2 * W + (th - np.sin(th)) / th**3 * (W @ W)


def scipy_solve(problem: TeamProblem, ref: int, Rs0: np.ndarray, ts0: np.ndarray):
    """The same maximum-likelihood problem with scipy.optimize.least_squares
    (method='trf'): left rotation vectors and translations relative to the
    start, the residuals and the analytic Jacobian from mutloc's own
    kernel (``team_residuals``; its left-perturbation Jacobians times the SO(3)
    left Jacobian of the parameters), so scipy is timed on its solver, not on
    finite differencing."""
    from scipy.optimize import least_squares

    N = problem.n_robots
    var = [i for i in range(N) if i != ref]
    col = {i: k for k, i in enumerate(var)}
    n = len(problem.cam)
    cam, own = np.asarray(problem.cam), np.asarray(problem.own)
    r = np.empty(2 * n)
    Ja = np.empty((n, 2, 6))
    Jb = np.empty((n, 2, 6))
    # the Jacobian's non-zeros: per observation, its 2 rows x 6 columns of the observer and of the owner
    rows, cols, take = [], [], []
    for j in range(n):
        for which, i in ((0, int(cam[j])), (1, int(own[j]))):
            if i == ref:
                continue
            for k in range(2):
                for c in range(6):
                    rows.append(2 * j + k)
                    cols.append(6 * col[i] + c)
                    take.append((which, j, k, c))
    rows, cols = np.array(rows), np.array(cols)
    take = np.array(take)
    shape = (2 * n, 6 * len(var))

    def poses(x):
        Rs, ts = Rs0.copy(), ts0.copy()
        for k, i in enumerate(var):
            Rs[i] = so3_exp(x[6 * k:6 * k + 3]) @ Rs0[i]
            ts[i] = ts0[i] + x[6 * k + 3:6 * k + 6]
        return Rs, ts

    def fun(x):
        Rs, ts = poses(x)
        team_residuals(problem.cam, problem.own, problem.points, problem.uv, problem.wt, problem.K, problem.dist, Rs, ts,
                       r, Ja,
                       Jb, False)
        return r.copy()

    def jac(x):
        Rs, ts = poses(x)
        team_residuals(problem.cam, problem.own, problem.points, problem.uv, problem.wt, problem.K, problem.dist, Rs, ts,
                       r, Ja,
                       Jb, True)
        for k, i in enumerate(var):  # d/dx of the rotation part: left perturbation times J_l(x)
            Jl = _left_jacobian(x[6 * k:6 * k + 3])
            m = cam == i
            Ja[m, :, :3] = Ja[m, :, :3] @ Jl
            m = own == i
            Jb[m, :, :3] = Jb[m, :, :3] @ Jl
        J = np.stack([Ja, Jb])
        out = np.zeros(shape)
        out[rows, cols] = J[take[:, 0], take[:, 1], take[:, 2], take[:, 3]]
        return out

    # Dense Jacobian, tr_solver='exact': the fastest set-up of least_squares
    # measured here (50 robots, warm start: CPU 169 ms, 5 evaluations, our
    # optimum to 1e-8 m; sparse with lsmr 619 ms and 137 evaluations, stopping
    # 3 mm short; 'lm' 222 ms; 'dogbox' 996 ms).  Default tolerances (1e-8).
    res = least_squares(fun, np.zeros(6 * len(var)), jac=jac, method="trf", tr_solver="exact")
    Rs, ts = poses(res.x)
    return Rs, ts, float(2 * res.cost), int(res.nfev)


# -- GTSAM ---------------------------------------------------------------------


def gtsam_solve(problem: TeamProblem, ref: int, Rs0: np.ndarray, ts0: np.ndarray):
    """The same problem as a GTSAM factor graph in the usual landmark form,
    without Python callbacks: a Pose3 per robot (the reference held by
    NonlinearEquality), a world Point3 per marker and a
    GenericProjectionFactorCal3_S2 (1 px) per observation.  A marker is tied
    to its robot by ReferenceFrameFactorPoint3Pose3 (world =
    pose.transformFrom(local), the local point held by NonlinearEquality)
    with sigma 1e-4 m, GTSAM's default Levenberg-Marquardt parameters: the
    fastest set-up found that reaches our optimum (within what the 0.1 mm
    tie allows: cost within 1e-6 relative, poses within about 0.1 mm, far
    below the noise).  Stiffer ties make it slower: at 1e-5 m it needs
    diagonal damping or a higher lambda bound and 2-10x the iterations from
    cold starts, at 1e-6 m it cannot take a step.  Undistorted pinhole: the
    benchmark cameras have no distortion.  Returns the poses, the graph
    building and optimising times (wall, CPU) and the iterations."""
    import gtsam
    from gtsam.symbol_shorthand import L, M, X

    c0, t0 = time.thread_time(), time.perf_counter()
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for i in range(problem.n_robots):
        values.insert(X(i), gtsam.Pose3(gtsam.Rot3(Rs0[i]), np.asarray(ts0[i], float)))
    graph.add(gtsam.NonlinearEqualityPose3(X(ref), gtsam.Pose3()))
    pix = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    tie = gtsam.noiseModel.Isotropic.Sigma(3, 1e-4)
    marker_key: dict[tuple, int] = {}
    cals = {}
    for j in range(len(problem.cam)):
        a, b = int(problem.cam[j]), int(problem.own[j])
        P = np.asarray(problem.points[j], float)
        key = (b, tuple(np.round(P, 9)))
        if key not in marker_key:
            k = len(marker_key)
            marker_key[key] = k
            values.insert(L(k), Rs0[b] @ P + ts0[b])
            values.insert(M(k), P)
            graph.add(gtsam.NonlinearEqualityPoint3(M(k), P))
            # the factor reads local = trans.transformFrom(global): with trans the
            # robot's pose, "global" is the point in the robot's frame
            graph.add(gtsam.ReferenceFrameFactorPoint3Pose3(M(k), X(b), L(k), tie))
        if a not in cals:
            K = problem.K[a]
            cals[a] = gtsam.Cal3_S2(K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2])
        graph.add(gtsam.GenericProjectionFactorCal3_S2(np.asarray(problem.uv[j], float), pix, X(a),
                                                        L(marker_key[key]), cals[a]))
    c1, t1 = time.thread_time(), time.perf_counter()
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams())
    result = optimizer.optimize()
    c2, t2 = time.thread_time(), time.perf_counter()
    Rs = np.array([result.atPose3(X(i)).rotation().matrix() for i in range(problem.n_robots)])
    ts = np.array([result.atPose3(X(i)).translation() for i in range(problem.n_robots)])
    return Rs, ts, {"build_s": t1 - t0, "optimize_s": t2 - t1, "build_cpu_s": c1 - c0, "optimize_cpu_s": c2 - c1,
                    "iterations": int(optimizer.iterations())}


def gtsam_timed(problem: TeamProblem, ref: int, Rs0: np.ndarray, ts0: np.ndarray, reps: int):
    """:func:`gtsam_solve` timed as mutloc is (:func:`timed`): one warm-up call, then the
    median of each time over ``reps`` calls."""
    gtsam_solve(problem, ref, Rs0, ts0)
    runs = [gtsam_solve(problem, ref, Rs0, ts0) for _ in range(reps)]
    Rs, ts, _ = runs[-1]
    info = {k: float(np.median([r[2][k] for r in runs])) for k in runs[0][2]}
    info["iterations"] = int(runs[-1][2]["iterations"])
    return Rs, ts, info


def cost_of(problem: TeamProblem, Rs: np.ndarray, ts: np.ndarray) -> float:
    from mutloc.core.team import team_cost

    return float(team_cost(problem.cam, problem.own, problem.points, problem.uv, problem.wt, problem.K, problem.dist, Rs, ts))


def max_pose_diff(Rs1, ts1, Rs2, ts2) -> tuple[float, float]:
    dt = float(np.max(np.linalg.norm(ts1 - ts2, axis=1)))
    c = (np.einsum("nij,nij->n", Rs1, Rs2) - 1) / 2
    return dt, float(np.degrees(np.max(np.arccos(np.clip(c, -1, 1)))))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repetitions")
    ap.add_argument("--out", default=result_file("team_results.json"))
    args = ap.parse_args()
    reps = 5 if args.quick else 20
    n_teams = 5 if args.quick else 20
    rng = np.random.default_rng(0)
    try:
        import gtsam  # noqa: F401

        have_gtsam = True
    except ImportError:
        have_gtsam = False
    results: dict = {"machine": machine(), "command": "python bench/bench_team.py" + (" --quick" if args.quick else "")}
    from mutloc.core.team import initial_poses

    # -- 50 robots, warm start ------------------------------------------------
    warm: dict[str, list] = {k: [] for k in (
        "core_solve_s", "core_solve_cpu_s", "localize_team_s", "localize_team_cpu_s", "iterations", "observations",
        "scipy_s", "scipy_cpu_s", "scipy_cost_ratio", "scipy_pose_diff",
        "gtsam_optimize_s", "gtsam_optimize_cpu_s", "gtsam_build_cpu_s", "gtsam_iterations", "gtsam_cost_ratio",
        "gtsam_pose_diff")}
    for k in range(n_teams):
        scene = big_team(50, 4, rng)
        obs = scene.observations(1.0, rng)
        truth = scene.truth()
        problem, names, _ = team_problem(scene.rig, obs)
        start = perturbed(truth, rng, 0.5, 0.02)
        Rs0 = np.array([start[n].R for n in names])
        ts0 = np.array([start[n].t for n in names])
        Rs0[0], ts0[0] = np.eye(3), np.zeros(3)
        loc = np.ones(len(names), bool)
        t_core, sol = timed(lambda: solve_team(problem, 0, initial=(Rs0, ts0, loc)), reps)
        warm["core_solve_cpu_s"].append(CPU[-1])
        if not np.all(sol.localized):
            raise SystemExit("a robot of the benchmark team is not tied to the reference; change the seed")
        t_api, team = timed(lambda: mutloc.localize_team(scene.rig, fresh(obs), initial=start, confidence=1.0), reps)
        warm["localize_team_cpu_s"].append(CPU[-1])
        warm["core_solve_s"].append(t_core)
        warm["localize_team_s"].append(t_api)
        warm["iterations"].append(sol.iterations)
        warm["observations"].append(len(problem.cam))
        t_sp, (Rsp, tsp, csp, nfev) = timed(lambda: scipy_solve(problem, 0, Rs0, ts0), reps)
        warm["scipy_s"].append(t_sp)
        warm["scipy_cpu_s"].append(CPU[-1])
        warm["scipy_cost_ratio"].append(csp / sol.cost)
        warm["scipy_pose_diff"].append(max_pose_diff(sol.Rs, sol.ts, Rsp, tsp))
        line = (f"50 robots #{k}: {len(problem.cam)} observations, core {1e3 * t_core:.2f} ms "
                f"(CPU {1e3 * warm['core_solve_cpu_s'][-1]:.2f} ms, {sol.iterations} iterations), localize_team "
                f"{1e3 * t_api:.2f} ms (CPU {1e3 * warm['localize_team_cpu_s'][-1]:.2f}), scipy {1e3 * t_sp:.0f} ms "
                f"(CPU {1e3 * CPU[-1]:.0f}, cost ratio {csp / sol.cost:.9f})")
        if have_gtsam:
            Rg, tg, info = gtsam_timed(problem, 0, Rs0, ts0, reps)
            warm["gtsam_optimize_s"].append(info["optimize_s"])
            warm["gtsam_optimize_cpu_s"].append(info["optimize_cpu_s"])
            warm["gtsam_build_cpu_s"].append(info["build_cpu_s"])
            warm["gtsam_iterations"].append(info["iterations"])
            warm["gtsam_pose_diff"].append(max_pose_diff(sol.Rs, sol.ts, Rg, tg))
            warm["gtsam_cost_ratio"].append(cost_of(problem, Rg, tg) / sol.cost)
            line += (f", gtsam optimize {1e3 * info['optimize_s']:.1f} ms (CPU {1e3 * info['optimize_cpu_s']:.1f}, "
                     f"{info['iterations']} iterations, graph built in CPU {1e3 * info['build_cpu_s']:.1f} ms; max pose "
                     f"diff {warm['gtsam_pose_diff'][-1][0]:.2e} m, cost ratio {warm['gtsam_cost_ratio'][-1]:.9f})")
        print(line, flush=True)

    # -- 10 robots, cold start --------------------------------------------------
    cold: dict[str, list] = {k: [] for k in (
        "localize_team_s", "localize_team_cpu_s", "observations", "refine_s", "refine_cpu_s",
        "scipy_s", "scipy_cpu_s", "scipy_pose_diff", "scipy_cost_ratio",
        "gtsam_optimize_s", "gtsam_optimize_cpu_s", "gtsam_pose_diff", "gtsam_cost_ratio")}
    for k in range(n_teams):
        scene = random_team(10, rng, one_way=0.3)
        obs = scene.observations(1.0, rng)
        problem, names, _ = team_problem(scene.rig, obs)
        t_api, team = timed(lambda: mutloc.localize_team(scene.rig, fresh(obs), confidence=1.0), reps)
        cold["localize_team_s"].append(t_api)
        cold["localize_team_cpu_s"].append(CPU[-1])
        cold["observations"].append(len(problem.cam))
        Rs = np.array([team.poses[n].R if n in team.poses else np.eye(3) for n in names])
        ts = np.array([team.poses[n].t if n in team.poses else np.zeros(3) for n in names])
        # the peers refine our initialisation (they have none of their own):
        # compared with our refinement from the same start
        Rs0, ts0, placed = initial_poses(problem, 0)
        if not np.all(placed):
            continue
        t_ref, _ = timed(lambda: solve_team(problem, 0, initial=(Rs0, ts0, placed)), reps)
        cold["refine_s"].append(t_ref)
        cold["refine_cpu_s"].append(CPU[-1])
        c_ours = cost_of(problem, Rs, ts)
        t_sp, (Rsp, tsp, csp, _) = timed(lambda: scipy_solve(problem, 0, Rs0, ts0), reps)
        cold["scipy_s"].append(t_sp)
        cold["scipy_cpu_s"].append(CPU[-1])
        cold["scipy_pose_diff"].append(max_pose_diff(Rs, ts, Rsp, tsp))
        cold["scipy_cost_ratio"].append(csp / c_ours)
        if have_gtsam:
            Rg, tg, info = gtsam_timed(problem, 0, Rs0, ts0, reps)
            cold["gtsam_optimize_s"].append(info["optimize_s"])
            cold["gtsam_optimize_cpu_s"].append(info["optimize_cpu_s"])
            cold["gtsam_pose_diff"].append(max_pose_diff(Rs, ts, Rg, tg))
            cold["gtsam_cost_ratio"].append(cost_of(problem, Rg, tg) / c_ours)
    print(f"10 robots cold: localize_team median {1e3 * np.median(cold['localize_team_s']):.2f} ms "
          f"(CPU {1e3 * np.median(cold['localize_team_cpu_s']):.2f} ms)")

    def med(x):
        return float(np.median(x)) if len(x) else None

    def ms(x):
        return 1e3 * float(np.median(x)) if len(x) else None

    def ratio(a, b):
        return float(np.median(np.asarray(a) / np.asarray(b))) if len(a) and len(a) == len(b) else None

    def worst(diffs):
        return float(np.max([d[0] for d in diffs])) if diffs else None

    summary = {
        "warm_50": {
            "observations_median": med(warm["observations"]),
            "core_solve_ms": ms(warm["core_solve_s"]),
            "core_solve_cpu_ms": ms(warm["core_solve_cpu_s"]),
            "core_solve_hz": 1.0 / med(warm["core_solve_s"]),
            "localize_team_ms": ms(warm["localize_team_s"]),
            "localize_team_cpu_ms": ms(warm["localize_team_cpu_s"]),
            "localize_team_hz": 1.0 / med(warm["localize_team_s"]),
            "localize_team_cpu_hz": 1.0 / med(warm["localize_team_cpu_s"]),
            "iterations_median": med(warm["iterations"]),
            "scipy_trf_ms": ms(warm["scipy_s"]),
            "scipy_trf_cpu_ms": ms(warm["scipy_cpu_s"]),
            "scipy_over_core_cpu": ratio(warm["scipy_cpu_s"], warm["core_solve_cpu_s"]),
            "scipy_cost_ratio_max": float(np.max(warm["scipy_cost_ratio"])),
            "scipy_cost_ratio_min": float(np.min(warm["scipy_cost_ratio"])),
            "scipy_max_pose_diff_m": worst(warm["scipy_pose_diff"]),
            "gtsam_optimize_ms": ms(warm["gtsam_optimize_s"]),
            "gtsam_optimize_cpu_ms": ms(warm["gtsam_optimize_cpu_s"]),
            "gtsam_build_cpu_ms": ms(warm["gtsam_build_cpu_s"]),
            "gtsam_iterations_median": med(warm["gtsam_iterations"]),
            "gtsam_optimize_over_core_cpu": ratio(warm["gtsam_optimize_cpu_s"], warm["core_solve_cpu_s"]),
            "gtsam_cost_ratio_max": float(np.max(warm["gtsam_cost_ratio"])) if have_gtsam else None,
            "gtsam_cost_ratio_min": float(np.min(warm["gtsam_cost_ratio"])) if have_gtsam else None,
            "gtsam_max_pose_diff_m": worst(warm["gtsam_pose_diff"]),
        },
        "cold_10": {
            "observations_median": med(cold["observations"]),
            "localize_team_ms": ms(cold["localize_team_s"]),
            "localize_team_p90_ms": 1e3 * float(np.percentile(cold["localize_team_s"], 90)),
            "localize_team_cpu_ms": ms(cold["localize_team_cpu_s"]),
            "localize_team_cpu_p90_ms": 1e3 * float(np.percentile(cold["localize_team_cpu_s"], 90)),
            "refine_from_init_cpu_ms": ms(cold["refine_cpu_s"]),
            "scipy_trf_refine_cpu_ms": ms(cold["scipy_cpu_s"]),
            "scipy_over_refine_cpu": ratio(cold["scipy_cpu_s"], cold["refine_cpu_s"]),
            "scipy_max_pose_diff_m": worst(cold["scipy_pose_diff"]),
            "gtsam_optimize_cpu_ms": ms(cold["gtsam_optimize_cpu_s"]),
            "gtsam_optimize_over_refine_cpu": ratio(cold["gtsam_optimize_cpu_s"], cold["refine_cpu_s"]),
            "gtsam_max_pose_diff_m": worst(cold["gtsam_pose_diff"]),
            "gtsam_cost_ratio_max": float(np.max(cold["gtsam_cost_ratio"])) if cold["gtsam_cost_ratio"] else None,
        },
    }
    results["machine"]["load_average_at_end"] = list(os.getloadavg())
    results.update(summary=summary, warm_50=warm, cold_10=cold)
    print(json.dumps(summary, indent=2))
    Path(args.out).write_text(json.dumps(results, indent=1, default=float))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
