#!/usr/bin/env python
"""Filter or smoother (issue 11): GTSAM's ``IncrementalFixedLagSmoother``
against mutloc's error-state filter and its fixed-lag RTS smoother, on the
sequences of ``bench_filter.py`` and with the same noise, in the same run.

    python bench/bench_filter_gtsam.py [--seeds 6] [--lag 10] [--robust huber:1.345 ...] [--iterations 1]

The factor graph (gtsam, the ``bench`` extra): per frame ``k`` a ``Pose3``
key for ``T_qp`` and a ``Vector6`` key for its velocity ``(w, v)`` in
mutloc's convention (``core/filter.py``: ``R <- exp(w dt) R``, ``t <- t + v
dt``, both in q's frame);

- between frames a constant-velocity factor, error ``(log(R1 (exp(w0 dt)
  R0)^T), t1 - t0 - v0 dt, vel1 - vel0)`` with the covariance mutloc's
  filter adds over ``dt`` (its own prediction, ``TeamFilter.predict``'s
  kernel, from a zero covariance: the same white-acceleration prior,
  default ``MotionNoise``);
- per observation a pixel factor (q sees p's marker at ``T_qp X_p``, p sees
  q's at ``T_qp^-1 X_q``, through the camera's ``K`` and distortion) whose
  residual and Jacobian are mutloc's own (``core.refine.residuals``), at
  the 2 px mutloc's tracks are given (``--pixel-sigma 2``) under a robust
  loss (``--robust``: Huber by default, or Cauchy, or none);
- the track starts as mutloc's does, at the first frame ``localize`` solves
  on its own: a prior on that pose with its covariance and a zero velocity
  with ``MotionNoise``'s initial sigmas; frames before it report what
  ``--filter none`` does (mutloc's tracker reports frames of three markers
  before its track is confirmed on its own too).  Where GTSAM gives up (an
  indeterminate system) the track stops and the JSON says where.

Each new pose is initialised from the previous frame's estimate moved by
its velocity.  With a lag of ``--lag`` frames each frame is reported twice:
causal (the estimate when it is the newest) and ``lag`` frames later (what
mutloc's default fixed-lag smoother reports; the last ``lag`` frames as the
smoother leaves them at the end of the sequence).  Sigmas from GTSAM's marginal covariances, turned into
the SPEC's convention (GTSAM's ``Pose3`` tangent is rotation then
translation applied on the right, ``T exp(xi)``: ``dtheta = R omega``,
``dt = R nu``).

Timings (wall clock, one pass, median over frames, measured under load):
GTSAM per frame is building the frame's factors, ``update`` (and any extra
relinearising ``--iterations``), and reading the causal and lagged
estimates with their marginal covariances; mutloc per frame is
the pair's track step plus its fixed-lag smoothing spread over
the frames.

Writes bench/results/filter_gtsam_results.json.
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
from bench_filter import NOISE, SIGMA, figures, sequence, track_estimates, translation_errors  # noqa: E402

from mutloc.core.consistency import DEFAULT_CONFIDENCE  # noqa: E402
from mutloc.core.filter import STATE_DIM  # noqa: E402
from mutloc.core.geometry import so3_exp, so3_log  # noqa: E402
from mutloc.core.pose import Pose  # noqa: E402
from mutloc.core.refine import MODE_PIXEL, WS_SIZE, residuals  # noqa: E402
from mutloc.core.team_kernels import team_predict  # noqa: E402
from mutloc.sim.world import standard_rig  # noqa: E402
from mutloc.track.filtering import FilterOptions, pair_problem  # noqa: E402
from mutloc.track.solving import solve_row  # noqa: E402
from mutloc.track.status import FrameStatus  # noqa: E402
from mutloc.track.tracker import PairTrack, TrackRow  # noqa: E402

try:
    import gtsam
    from gtsam.symbol_shorthand import V, X
except ImportError:  # the bench extra: pip install "mutloc[bench]"
    gtsam = None

#: mutloc's tracks compared with GTSAM's on the same frames.
MUTLOC = {"mutloc_default": FilterOptions(), "mutloc_causal": FilterOptions(smooth_lag=0)}


# -- conventions -----------------------------------------------------------------


def _blocks(R: np.ndarray) -> np.ndarray:
    """``blockdiag(R, R)``: GTSAM's Pose3 tangent (omega, nu) to the SPEC's (dtheta, dt), to first order."""
    A = np.zeros((6, 6))
    A[:3, :3] = R
    A[3:, 3:] = R
    return A


def to_gtsam_jacobian(J: np.ndarray, R: np.ndarray) -> np.ndarray:
    """A Jacobian over the SPEC's pose perturbation (``R <- exp(dtheta) R``,
    ``t <- t + dt``) as one over GTSAM's ``T exp(xi)`` at rotation ``R``."""
    return J @ _blocks(R)


def spec_covariance(cov_gtsam: np.ndarray, R: np.ndarray) -> np.ndarray:
    """GTSAM's Pose3 marginal covariance as the SPEC's 6x6."""
    A = _blocks(R)
    return A @ cov_gtsam @ A.T


def gtsam_covariance(cov_spec: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The SPEC's 6x6 pose covariance over GTSAM's Pose3 tangent."""
    A = _blocks(R)
    return A.T @ cov_spec @ A


def pose3(pose: Pose) -> "gtsam.Pose3":
    return gtsam.Pose3(gtsam.Rot3(pose.R), np.asarray(pose.t, float))


def from_pose3(T: "gtsam.Pose3") -> Pose:
    return Pose(np.ascontiguousarray(T.rotation().matrix()), np.asarray(T.translation(), float))


def process_noise(dt: float) -> np.ndarray:
    """The 12x12 covariance mutloc's filter adds over ``dt`` (its own
    prediction, ``TeamFilter.predict``'s kernel, of one robot at rest from a
    zero covariance: the integrated white acceleration)."""
    P = np.zeros((STATE_DIM, STATE_DIM))
    team_predict(np.zeros(1, np.int64), np.eye(3)[None].copy(), np.zeros((1, 3)), np.zeros((1, 6)), P, dt,
                 NOISE.angular**2, NOISE.linear**2)
    return P


# -- factors ----------------------------------------------------------------------


def pixel_error(side: int, point: np.ndarray, uv: np.ndarray, K, dist):
    """``f(R, t, want_jac) -> (r (2,), J (2, 6) over the SPEC's perturbation)``:
    one observation's pixel residual by ``core.refine.residuals``; a marker
    behind the camera seeing it gives ``r = 2 fx`` and ``J = 0``, as GTSAM's
    own projection factors do (``throwCheirality`` off)."""
    side_a = np.array([side], np.int64)
    pts = np.ascontiguousarray(np.reshape(point, (1, 3)), float)
    meas = np.ascontiguousarray(np.reshape(uv, (1, 2)), float)
    basis = np.zeros((1, 3, 3))
    _ONE = np.ones(1)
    ws = np.empty(WS_SIZE)
    Kp, dp, Kq, dq = (np.ascontiguousarray(a, float) for a in (K[0], dist[0], K[1], dist[1]))
    behind = np.full(2, 2.0 * (Kp if side == 0 else Kq)[0, 0])

    def f(R, t, want_jac):
        r, J = np.empty(2), np.empty((2, 6))
        if not residuals(side_a, pts, meas, basis, Kp, dp, Kq, dq, MODE_PIXEL, _ONE, R, t, r, J, want_jac, ws):
            COUNTS["behind_camera"] += 1
            return behind.copy(), np.zeros((2, 6))
        return r, J

    return f


#: Per track: how often a pixel factor found its marker behind the camera,
#: how many times GTSAM called back into Python for a factor, and the wall
#: time spent in those calls.
COUNTS = {"behind_camera": 0, "factor_calls": 0, "factor_seconds": 0.0}


def pixel_factor(key: int, fn, model) -> "gtsam.CustomFactor":
    """A CustomFactor on the pose ``key`` around :func:`pixel_error`'s ``fn``."""

    def error(this, values, H):
        t0 = time.perf_counter()
        T = values.atPose3(key)
        R = np.ascontiguousarray(T.rotation().matrix())
        r, J = fn(R, np.asarray(T.translation(), float), H is not None)
        if H is not None:
            H[0] = to_gtsam_jacobian(J, R)
        COUNTS["factor_calls"] += 1
        COUNTS["factor_seconds"] += time.perf_counter() - t0
        return r

    return gtsam.CustomFactor(model, [key], error)


def motion_error(R0, t0, vel0, R1, t1, vel1, dt: float, want_jac: bool):
    """The constant-velocity residual (12,) from frame 0 to frame 1 and, with
    ``want_jac``, its Jacobians over (pose 0, velocity 0, pose 1, velocity 1),
    the poses' over the SPEC's perturbation."""
    phi = vel0[:3] * dt
    E = so3_exp(phi)
    e = so3_log(R1 @ (E @ R0).T)
    r = np.r_[e, t1 - t0 - vel0[3:] * dt, vel1 - vel0]
    if not want_jac:
        return r, None
    # GTSAM's Rot3 derivatives are the right Jacobians: J_r(x) = ExpmapDerivative(x),
    # J_r^-1(x) = LogmapDerivative(x), and J_l(x) = J_r(-x).
    Jr_inv = gtsam.Rot3.LogmapDerivative(e)
    Jl_inv = gtsam.Rot3.LogmapDerivative(-e)
    Jl_phi = gtsam.Rot3.ExpmapDerivative(-phi)
    I3 = np.eye(3)
    A0, B0, A1, B1 = (np.zeros((12, 6)) for _ in range(4))
    A0[:3, :3] = -Jr_inv @ E
    A0[3:6, 3:] = -I3
    B0[:3, :3] = -Jr_inv @ Jl_phi * dt
    B0[3:6, 3:] = -I3 * dt
    B0[6:, :] = -np.eye(6)
    A1[:3, :3] = Jl_inv
    A1[3:6, 3:] = I3
    B1[6:, :] = np.eye(6)
    return r, (A0, B0, A1, B1)


def motion_factor(k0: int, k1: int, dt: float, model) -> "gtsam.CustomFactor":
    """A CustomFactor on (X(k0), V(k0), X(k1), V(k1)) around :func:`motion_error`."""
    keys = [X(k0), V(k0), X(k1), V(k1)]

    def error(this, values, H):
        t0 = time.perf_counter()
        T0, T1 = values.atPose3(keys[0]), values.atPose3(keys[2])
        R0, R1 = T0.rotation().matrix(), T1.rotation().matrix()
        r, J = motion_error(R0, T0.translation(), values.atVector(keys[1]), R1, T1.translation(),
                            values.atVector(keys[3]), dt, H is not None)
        if H is not None:
            H[0] = to_gtsam_jacobian(J[0], R0)
            H[1] = J[1]
            H[2] = to_gtsam_jacobian(J[2], R1)
            H[3] = J[3]
        COUNTS["factor_calls"] += 1
        COUNTS["factor_seconds"] += time.perf_counter() - t0
        return r

    return gtsam.CustomFactor(model, keys, error)


def check_jacobians(rig, seq) -> dict:
    """Both factors' analytic Jacobians against central differences through
    GTSAM's own retraction, at a frame of ``seq`` with the pose perturbed;
    the largest relative difference of each."""
    rng = np.random.default_rng(0)
    T = seq.truth[5]
    vel0, vel1 = rng.normal(scale=0.3, size=6), rng.normal(scale=0.3, size=6)
    T0, T1 = pose3(T), pose3(T).retract(rng.normal(scale=0.02, size=6))
    values = gtsam.Values()
    values.insert(X(0), T0)
    values.insert(V(0), vel0)
    values.insert(X(1), T1)
    values.insert(V(1), vel1)
    model = gtsam.noiseModel.Unit.Create(12)
    factors = {"motion": motion_factor(0, 1, 1 / 30, model)}
    prob = pair_problem(seq.frames[5].pair(rig, "p", "q"))
    for i in range(len(prob.side)):
        fn = pixel_error(int(prob.side[i]), prob.points[i], prob.pixels[i], prob.K, prob.dist)
        factors[f"pixel_{i}_side_{int(prob.side[i])}"] = pixel_factor(X(1), fn, gtsam.noiseModel.Unit.Create(2))
    out = {}
    h = 1e-6
    for name, fac in factors.items():
        lin = fac.linearize(values)
        A = lin.jacobian()[0]  # whitened = raw under the unit model; columns in key order
        cols, c = [], 0
        for key in fac.keys():
            dim = 6
            for j in range(dim):
                d = np.zeros(dim)
                d[j] = h
                vp, vm = gtsam.Values(values), gtsam.Values(values)
                if gtsam.Symbol(key).chr() == ord("x"):
                    vp.update(key, values.atPose3(key).retract(d))
                    vm.update(key, values.atPose3(key).retract(-d))
                else:
                    vp.update(key, values.atVector(key) + d)
                    vm.update(key, values.atVector(key) - d)
                cols.append((fac.unwhitenedError(vp) - fac.unwhitenedError(vm)) / (2 * h))
            c += dim
        N = np.array(cols).T
        out[name] = float(np.max(np.abs(A - N)) / np.max(np.abs(N)))
    return out


# -- the smoother -----------------------------------------------------------------


def robust_model(spec: str):
    """``huber:K``, ``cauchy:K`` or ``none``: the pixel factors' noise model (2 px isotropic under it)."""
    base = gtsam.noiseModel.Isotropic.Sigma(2, SIGMA)
    kind, _, k = spec.partition(":")
    if kind == "none":
        return base
    est = {"huber": gtsam.noiseModel.mEstimator.Huber, "cauchy": gtsam.noiseModel.mEstimator.Cauchy}[kind]
    return gtsam.noiseModel.Robust.Create(est.Create(float(k)), base)


def gtsam_track(rig, seq, lag: int, robust: str, iterations: int = 1, relinearize: float = 1e-3) -> dict:
    """GTSAM's incremental fixed-lag smoother over ``seq``: per frame the
    causal and the lag-``lag`` (pose, SPEC covariance) or None, the wall
    time of each frame's work, and ``failed``: (frame, message) where GTSAM
    gave up (the track stops there), else None."""
    n = len(seq.frames)
    dt = float(seq.times[1] - seq.times[0])
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(relinearize)
    params.relinearizeSkip = 1
    # Keys newer than (newest - lag) stay: a frame leaves the window lag + 1 frames after it came.
    smoother = gtsam.IncrementalFixedLagSmoother((lag + 0.5) * dt, params)
    motion_model = gtsam.noiseModel.Gaussian.Covariance(process_noise(dt))
    pixel_model = robust_model(robust)
    causal: list = [None] * n
    lagged: list = [None] * n
    seconds = np.full(n, np.nan)

    def read(k):
        T = smoother.calculateEstimatePose3(X(k))
        R = np.ascontiguousarray(T.rotation().matrix())
        return from_pose3(T), spec_covariance(smoother.marginalCovariance(X(k)), R)

    start, failed = None, None
    COUNTS.update(behind_camera=0, factor_calls=0, factor_seconds=0.0)
    for k, (tk, frame) in enumerate(zip(seq.times, seq.frames)):
        if start is None:
            row = TrackRow(float(tk), float(tk), float(tk), FrameStatus.SOLVED, observations=frame)
            solve_row(row, rig, "p", "q", SIGMA, DEFAULT_CONFIDENCE)
            if row.status != FrameStatus.SOLVED:
                continue
        t0 = time.perf_counter()
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if start is None:
            start = k
            est = row.estimate
            values.insert(X(k), pose3(est.pose))
            values.insert(V(k), np.zeros(6))
            graph.add(gtsam.PriorFactorPose3(X(k), pose3(est.pose), gtsam.noiseModel.Gaussian.Covariance(
                gtsam_covariance(est.covariance, est.pose.R))))
            graph.add(gtsam.PriorFactorVector(V(k), np.zeros(6), gtsam.noiseModel.Diagonal.Sigmas(
                np.r_[[NOISE.initial_angular] * 3, [NOISE.initial_linear] * 3])))
        else:
            prev = smoother.calculateEstimatePose3(X(k - 1))
            vel = smoother.calculateEstimateVector(V(k - 1))
            R = so3_exp(vel[:3] * dt) @ prev.rotation().matrix()
            values.insert(X(k), gtsam.Pose3(gtsam.Rot3(R), prev.translation() + vel[3:] * dt))
            values.insert(V(k), vel)
            graph.add(motion_factor(k - 1, k, dt, motion_model))
        pair = frame.pair(rig, "p", "q")
        if len(pair.rows):
            prob = pair_problem(pair)
            for i in range(len(prob.side)):
                fn = pixel_error(int(prob.side[i]), prob.points[i], prob.pixels[i], prob.K, prob.dist)
                graph.add(pixel_factor(X(k), fn, pixel_model))
        try:
            smoother.update(graph, values, {X(k): float(tk), V(k): float(tk)})
            for _ in range(iterations - 1):
                smoother.update()
            causal[k] = read(k)
            if k - lag >= start:
                lagged[k - lag] = read(k - lag)
        except RuntimeError as exc:  # e.g. an indeterminate system once the track has diverged
            failed = (k, " ".join(str(exc).split())[:200])
            break
        seconds[k] = time.perf_counter() - t0
    if start is not None and failed is None:
        for k in range(max(start, n - lag), n):
            lagged[k] = read(k)
    return {"causal": causal, "lagged": lagged, "seconds": seconds, "start": start, **COUNTS,
            "failed": failed}


def mutloc_seconds(rig, seq, options: FilterOptions) -> np.ndarray:
    """Wall time of the pair's track step per frame, plus its final
    smoothing spread evenly over the frames."""
    tracker = PairTrack(rig, "p", "q", pixel_sigma=SIGMA, options=options)
    out = np.empty(len(seq.frames))
    for k, (t, f) in enumerate(zip(seq.times, seq.frames)):
        row = TrackRow(float(t), float(t), float(t), FrameStatus.SOLVED, observations=f)
        t0 = time.perf_counter()
        tracker.step(row)
        out[k] = time.perf_counter() - t0
    t0 = time.perf_counter()
    tracker.team.finalize(end=True)
    return out + (time.perf_counter() - t0) / len(out)


def run(rig, seeds: int, lag: int, robust: list[str], iterations: int, relinearize: float) -> dict:
    names = [*MUTLOC, *(f"gtsam_{r}_{w}" for r in robust for w in ("lag", "causal"))]
    out = {"per_frame_median_m": [], "tracks": {k: {} for k in names}, "outliers": [],
           "mutloc_outliers_rejected_or_dropped": {k: [] for k in MUTLOC},
           "seconds_per_frame_median": {k: [] for k in ["mutloc_default", "mutloc_causal", *robust]},
           "gtsam_pixel_factors_behind_camera": {r: [] for r in robust}, "gtsam_failed": {r: [] for r in robust},
           "gtsam_factor_calls_per_frame": {r: [] for r in robust},
           "gtsam_share_of_time_in_python_factors": {r: [] for r in robust},
           "seconds_per_frame_mean": {k: [] for k in ["mutloc_default", "mutloc_causal", *robust]},
           "gtsam_seconds_per_frame_mean_outside_python_factors": {r: [] for r in robust}}
    for seed in range(seeds):
        seq = sequence(rig, seed)
        alone = track_estimates(rig, seq, "none")[0]
        en = translation_errors(alone, seq.truth)
        out["per_frame_median_m"].append(float(np.nanmedian(en)))
        out["outliers"].append(int(seq.outlier.sum()))
        tracks = {}
        for name, opts in MUTLOC.items():
            estimates, rows = track_estimates(rig, seq, opts)
            tracks[name] = estimates
            out["mutloc_outliers_rejected_or_dropped"][name].append(
                sum(int(rows[i].status == "rejected" or "dropped" in rows[i].reason) for i in np.flatnonzero(seq.outlier)))
            mutloc_seconds(rig, seq, opts)  # warm: the first pass may compile
            sec = mutloc_seconds(rig, seq, opts)
            out["seconds_per_frame_median"][name].append(float(np.median(sec)))
            out["seconds_per_frame_mean"][name].append(float(np.mean(sec)))
        for r in robust:
            g = gtsam_track(rig, seq, lag, r, iterations, relinearize)
            # Before its first solved frame the track reports each frame on its own, as mutloc's does.
            head = alone[:g["start"]] if g["start"] is not None else alone
            tracks[f"gtsam_{r}_lag"] = head + g["lagged"][len(head):]
            tracks[f"gtsam_{r}_causal"] = head + g["causal"][len(head):]
            out["seconds_per_frame_median"][r].append(float(np.nanmedian(g["seconds"])))
            out["gtsam_pixel_factors_behind_camera"][r].append(g["behind_camera"])
            frames_run = int(np.sum(~np.isnan(g["seconds"])))
            out["gtsam_factor_calls_per_frame"][r].append(g["factor_calls"] / frames_run)
            out["gtsam_share_of_time_in_python_factors"][r].append(g["factor_seconds"] / np.nansum(g["seconds"]))
            out["seconds_per_frame_mean"][r].append(float(np.nanmean(g["seconds"])))
            out["gtsam_seconds_per_frame_mean_outside_python_factors"][r].append(
                float((np.nansum(g["seconds"]) - g["factor_seconds"]) / frames_run))
            out["gtsam_failed"][r].append(g["failed"])
            if g["failed"]:
                print(f"  GTSAM {r} failed at frame {g['failed'][0]}: {g['failed'][1]}")
        line = [f"seed {seed}: per frame {100 * out['per_frame_median_m'][-1]:.2f} cm"]
        for name, est in tracks.items():
            fig = figures(seq, est, en)
            for m, x in fig.items():
                out["tracks"][name].setdefault(m, []).append(x)
            line.append(f"{name} {100 * fig['filtered_median_m']:.2f} cm (x{fig['ratio_same_frames']:.2f}, "
                        f"blind {100 * fig['blind_median_m']:.2f}, NEES/6 {fig['nees_over_6']:.2f}, "
                        f"ms {fig['normalised_error_mean_square']:.2f}, outliers ok "
                        f"{fig['outliers_within_twice_median']}/{int(seq.outlier.sum())})")
        times = {k: f"{1e6 * v[-1]:.0f} us" for k, v in out["seconds_per_frame_median"].items()}
        behind = {r: v[-1] for r, v in out["gtsam_pixel_factors_behind_camera"].items()}
        print("\n  ".join(line) + f"\n  time per frame (median): {times}; GTSAM markers behind the camera: {behind}",
              flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--lag", type=int, default=10, help="frames in the smoother's window after each frame (10)")
    ap.add_argument("--robust", nargs="+", default=["huber:1.345"],
                    help="pixel factors' loss, each a GTSAM run: huber:K, cauchy:K (K in sigmas) or none")
    ap.add_argument("--iterations", type=int, default=1, help="iSAM2 updates per frame (1; more relinearise again)")
    ap.add_argument("--relinearize", type=float, default=1e-3, help="iSAM2 relinearisation threshold (1e-3)")
    ap.add_argument("--out", default=result_file("filter_gtsam_results.json"))
    args = ap.parse_args(argv)
    if gtsam is None or not hasattr(gtsam, "IncrementalFixedLagSmoother"):
        print("needs gtsam >= 4.3 (gtsam.IncrementalFixedLagSmoother): pip install 'mutloc[bench]'", file=sys.stderr)
        return 2
    rig = standard_rig("balls")
    from importlib.metadata import version

    res = {"machine": machine(), "gtsam": version("gtsam"), "args": {k: v for k, v in vars(args).items() if k != "out"},
           "jacobian_check_max_relative_difference": check_jacobians(rig, sequence(rig, 0))}
    print("Jacobians against central differences (max relative difference):",
          {k: f"{v:.1e}" for k, v in res["jacobian_check_max_relative_difference"].items()})
    res.update(run(rig, args.seeds, args.lag, args.robust, args.iterations, args.relinearize))
    sec = {k: np.array(v) for k, v in res["seconds_per_frame_median"].items()}
    res["time_ratio_gtsam_over_mutloc"] = {f"{r}/{m}": (sec[r] / sec[m]).tolist()
                                           for r in args.robust for m in MUTLOC}
    print("summary (min-max over seeds; NaN: a track failed):")
    for name, d in res["tracks"].items():
        print(f"  {name}: " + ", ".join(f"{m} {np.min(v):.3g}-{np.max(v):.3g}" for m, v in d.items()))
    for name, v in sec.items():
        mean = np.array(res["seconds_per_frame_mean"][name])
        print(f"  time per frame {name}: median {1e6 * v.min():.0f}-{1e6 * v.max():.0f} us, "
              f"mean {1e6 * mean.min():.0f}-{1e6 * mean.max():.0f} us")
    med = {k: np.array(v["filtered_median_m"]) for k, v in res["tracks"].items()}
    res["median_error_ratio_gtsam_over_mutloc"] = {
        f"gtsam_{r}_{w}/{m}": (med[f"gtsam_{r}_{w}"] / med[m]).tolist()
        for r in args.robust for w, m in (("lag", "mutloc_default"), ("causal", "mutloc_causal"))}
    for name, v in res["median_error_ratio_gtsam_over_mutloc"].items():
        print(f"  median error ratio {name}: {' '.join(f'{x:.2f}' for x in v)}")
    for name, v in res["time_ratio_gtsam_over_mutloc"].items():
        print(f"  time ratio {name}: {min(v):.1f}-{max(v):.1f}")
    for r in args.robust:
        print(f"  GTSAM {r}: {np.mean(res['gtsam_factor_calls_per_frame'][r]):.0f} Python factor calls per frame, "
              f"{100 * np.min(res['gtsam_share_of_time_in_python_factors'][r]):.0f}-"
              f"{100 * np.max(res['gtsam_share_of_time_in_python_factors'][r]):.0f}% of its time in them, "
              f"{1e6 * np.min(res['gtsam_seconds_per_frame_mean_outside_python_factors'][r]):.0f}-"
              f"{1e6 * np.max(res['gtsam_seconds_per_frame_mean_outside_python_factors'][r]):.0f} us per frame "
              "outside them (mean); failed: "
              f"{[f for f in res['gtsam_failed'][r] if f] or 'never'}")
    Path(args.out).write_text(json.dumps(res, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
