"""The paper's simulation experiment with noise (Sec. V-B).

Two cameras (960x540, f = 800 px, the standard ball rig) about 1 m apart
(and 2 m, 3 m), rotated and translated over a wide range.  Each scene is
rendered for both cameras and the coloured balls are found once with the
real detector (:func:`mutloc.track.frames.detect_markers`).  Zero-mean
Gaussian noise of sigma pixels is then added to the detected centres and the
pose is solved with the paper's best algebraic root (``refine=False``) and
with the refined maximum-likelihood pose (the default).  Errors are measured
against the rendered truth.  The Cramer-Rao bound sigma^2 (J^T J)^-1 at the
true pose gives the error a efficient estimator would make: its medians are
estimated by sampling N(0, CRB).

Output in ``OUT/noise/``: ``results.json`` (SPEC "Experiment results"),
``report.md``, ``translation_vs_sigma.png`` and ``rotation_vs_sigma.png``.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ._common import (StageTimer, fmt, median, pose_errors, pyplot, reproduce_lines, save_figure, versions,
                      write_results)

__all__ = ["run_noise", "PAPER_TRANSLATION_M", "PAPER_ROTATION_DEG", "METHODS", "QUICK"]

NAME = "noise"
METHODS = ("best_root", "refined", "crlb")
# Paper, Sec. V-B: "deviates only by 5cm and 2.5 deg ... noise of up to 10 pixels".
PAPER_SIGMA_PX = 10.0
PAPER_TRANSLATION_M = 0.05
PAPER_ROTATION_DEG = 2.5
# Parameters of ``mutloc experiment noise --quick``.
QUICK = dict(sigmas=(0.0, 10.0), distances=(1.0, 2.0), poses_per_distance=3, trials_per_pose=40)

# Random relative poses: wide but with every ball visible to both cameras.
MAX_YAW_DEG = 25.0
MAX_TILT_DEG = 5.0
MAX_LATERAL_FRACTION = 0.3  # of the distance
DISTANCE_SPREAD = 0.1  # +-10 % around the nominal distance
# A scene is used only if the detector finds every ball within this of its
# true projection (a ball cut by the image border or hidden would bias it).
MAX_DETECTION_ERROR_PX = 1.0
CRB_SAMPLES_PER_SCENE = 400
MAX_POSE_ATTEMPTS = 200


class _Scene:
    """One rendered scene: truth, detected centres, and the CRB shape."""

    def __init__(self, rig, T_qp, detected: dict[str, dict[str, np.ndarray]], info_inv: np.ndarray):
        self.rig = rig
        self.T = T_qp
        self.detected = detected
        self.info_inv = info_inv  # CRB = sigma^2 * info_inv


def _sample_pose(rng: np.random.Generator, distance: float):
    from ..sim.synthetic import facing_pose

    d = distance * rng.uniform(1 - DISTANCE_SPREAD, 1 + DISTANCE_SPREAD)
    yaw_p, yaw_q = np.radians(rng.uniform(-MAX_YAW_DEG, MAX_YAW_DEG, 2))
    tilt = np.radians(rng.uniform(-MAX_TILT_DEG, MAX_TILT_DEG, 3)) * np.array([1.0, 0.0, 1.0])
    lateral = rng.uniform(-MAX_LATERAL_FRACTION, MAX_LATERAL_FRACTION) * d
    return facing_pose(d, yaw_p, yaw_q, lateral, tilt=tilt)


def _information_inverse(rig, T_qp, truth_px: dict[str, dict[str, np.ndarray]]) -> np.ndarray:
    """(J^T J)^-1 of the pixel model at the true pose, for the four balls."""
    from ..core.estimate import PairProblem
    from ..core.refine import information

    cam_p, cam_q = rig.robot("p").camera, rig.robot("q").camera
    names_p = sorted(truth_px["p"])  # q's markers, seen by p (side 0)
    names_q = sorted(truth_px["q"])  # p's markers, seen by q (side 1)
    up = np.array([truth_px["p"][n] for n in names_p], float)
    uq = np.array([truth_px["q"][n] for n in names_q], float)
    obs = PairProblem(
        side=np.array([0] * len(names_p) + [1] * len(names_q)),
        points=np.vstack([[rig.robot("q").markers[n].position for n in names_p],
                          [rig.robot("p").markers[n].position for n in names_q]]),
        bearings=np.vstack([cam_p.pixels_to_bearings(up), cam_q.pixels_to_bearings(uq)]),
        pixels=np.vstack([up, uq]),
        K=(cam_p.K, cam_q.K),
        dist=(cam_p.dist, cam_q.dist),
    )
    H = np.empty((6, 6))
    if not information(*obs.kernel_args(), T_qp.R.copy(), T_qp.t.copy(), H):
        raise RuntimeError("a marker is behind a camera at the true pose")
    return np.linalg.inv(H)


def _make_scene(rng: np.random.Generator, rig, distance: float) -> tuple[_Scene, int]:
    """Render and detect a random visible scene; returns it and the attempts used."""
    from ..sim.render import project_markers, relative_pose, render, two_robot_world
    from ..track.frames import detect_markers

    n_markers = {"p": len(rig.robot("q").markers), "q": len(rig.robot("p").markers)}
    for attempt in range(1, MAX_POSE_ATTEMPTS + 1):
        T = _sample_pose(rng, distance)
        room_seed = int(rng.integers(0, 2**31 - 1))
        world = two_robot_world(rig, T, seed=room_seed)
        truth = {obs: project_markers(world, obs, check_occlusion=True) for obs in ("p", "q")}
        if any(len(truth[o]) != n_markers[o] for o in truth):
            continue
        detected: dict[str, dict[str, np.ndarray]] = {}
        ok = True
        for obs in ("p", "q"):
            det = detect_markers(rig, obs, render(world, obs, seed=room_seed))
            found = {n: np.asarray(d.uv, float) for n, d in det.detections.items()}
            if set(found) != set(truth[obs]) or any(
                    np.linalg.norm(found[n] - np.asarray(truth[obs][n])) > MAX_DETECTION_ERROR_PX for n in found):
                ok = False
                break
            detected[obs] = found
        if not ok:
            continue
        T_true = relative_pose(world, "p", "q")
        return _Scene(rig, T_true, detected, _information_inverse(rig, T_true, truth)), attempt
    raise RuntimeError(f"no scene at {distance:g} m with every ball detected in {MAX_POSE_ATTEMPTS} attempts")


def _solve_errors(scene: _Scene, noisy: dict[str, dict[str, np.ndarray]], sigma: float
                  ) -> dict[str, tuple[float, float] | None]:
    import mutloc
    from ..errors import MutlocError

    obs = {o: {n: (float(uv[0]), float(uv[1])) for n, uv in d.items()} for o, d in noisy.items()}
    out: dict[str, tuple[float, float] | None] = {}
    for method, refine in (("best_root", False), ("refined", True)):
        try:
            est = mutloc.localize(scene.rig, obs, "p", "q", pixel_sigma=max(sigma, 1.0), refine=refine,
                                     confidence=1.0)  # a study of the estimator: keep every draw
        except MutlocError:
            out[method] = None
            continue
        out[method] = pose_errors(est, scene.T)
    return out


def _distance_key(d: float) -> str:
    return f"{float(d):.1f}"


def run_noise(out_dir: str | Path, *, seed: int = 0, sigmas: Sequence[float] = (0, 1, 2, 4, 6, 8, 10),
              distances: Sequence[float] = (1.0, 2.0, 3.0), poses_per_distance: int = 12,
              trials_per_pose: int = 20, progress: bool = True, command: str | None = None) -> dict[str, Any]:
    """Run the noise experiment; write ``out_dir/noise/{results.json, report.md, *.png}``.

    Returns the results dict (also written as ``results.json``).  The first
    distance is the paper's setting and fills the top-level ``methods``; every
    distance is under ``by_distance_m``.  Deterministic for a ``seed``.
    """
    from tqdm import tqdm

    from ..sim.world import standard_rig

    sigmas = [float(s) for s in sigmas]
    distances = [float(d) for d in distances]
    if not sigmas or any(not (math.isfinite(s) and s >= 0) for s in sigmas):
        raise ValueError(f"sigmas must be finite and >= 0, got {sigmas}")
    if not distances or any(not (math.isfinite(d) and d > 0) for d in distances):
        raise ValueError(f"distances must be finite and > 0, got {distances}")
    if poses_per_distance < 1 or trials_per_pose < 1:
        raise ValueError("poses_per_distance and trials_per_pose must be >= 1")
    out = Path(out_dir) / NAME
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    timer = StageTimer()
    rng = np.random.default_rng(seed)
    rig = standard_rig("balls")

    by_distance: dict[str, Any] = {}
    failures: dict[str, dict[str, int]] = {}
    attempts_used: dict[str, int] = {}
    total = len(distances) * poses_per_distance
    bar = tqdm(total=total, desc="noise experiment (scenes)", unit="scene", disable=not progress, leave=False)
    for d in distances:
        key = _distance_key(d)
        errs = {m: {s: ([], []) for s in sigmas} for m in METHODS}
        fails = {m: 0 for m in ("best_root", "refined")}
        attempts = 0
        for _ in range(poses_per_distance):
            bar.set_postfix(distance_m=d)
            with timer("render and detect scenes"):
                scene, n_att = _make_scene(rng, rig, d)
            attempts += n_att
            # The CRB shape: sigma scales it, so one set of unit draws per scene.
            z = rng.multivariate_normal(np.zeros(6), scene.info_inv, size=CRB_SAMPLES_PER_SCENE)
            unit_t = np.linalg.norm(z[:, 3:], axis=1)
            unit_r = np.degrees(np.linalg.norm(z[:, :3], axis=1))
            with timer("solve (best root, refined)"):
                for s in sigmas:
                    errs["crlb"][s][0].extend((s * unit_t).tolist())
                    errs["crlb"][s][1].extend((s * unit_r).tolist())
                    for _trial in range(trials_per_pose if s > 0 else 1):
                        noisy = {o: {n: uv + rng.normal(scale=s, size=2) if s > 0 else uv.copy()
                                     for n, uv in det.items()} for o, det in scene.detected.items()}
                        for method, e in _solve_errors(scene, noisy, s).items():
                            if e is None:
                                fails[method] += 1
                                continue
                            errs[method][s][0].append(e[0])
                            errs[method][s][1].append(e[1])
            bar.update(1)
        by_distance[key] = {
            "distance_m": d,
            "scenes": poses_per_distance,
            "methods": {m: {"median_translation_m": [median(errs[m][s][0]) for s in sigmas],
                            "median_rotation_deg": [median(errs[m][s][1]) for s in sigmas],
                            "samples": [len(errs[m][s][0]) for s in sigmas]} for m in METHODS},
        }
        failures[key] = fails
        attempts_used[key] = attempts
    bar.close()
    elapsed = time.perf_counter() - started

    main_key = _distance_key(distances[0])
    results: dict[str, Any] = {
        "experiment": NAME,
        "seed": int(seed),
        "sigma_px": sigmas,
        "distance_m": distances[0],
        "methods": by_distance[main_key]["methods"],
        "by_distance_m": by_distance,
        "paper": {"sigma_px": PAPER_SIGMA_PX, "median_translation_m": PAPER_TRANSLATION_M,
                  "median_rotation_deg": PAPER_ROTATION_DEG, "distance_m": 1.0},
        "setup": {
            "rig": "standard_rig('balls')", "image_size": [960, 540], "focal_px": 800.0,
            "poses_per_distance": int(poses_per_distance), "trials_per_pose": int(trials_per_pose),
            "max_yaw_deg": MAX_YAW_DEG, "max_tilt_deg": MAX_TILT_DEG,
            "max_lateral_fraction": MAX_LATERAL_FRACTION, "distance_spread": DISTANCE_SPREAD,
            "max_detection_error_px": MAX_DETECTION_ERROR_PX, "crb_samples_per_scene": CRB_SAMPLES_PER_SCENE,
            "pose_attempts": attempts_used,
        },
        "solver_failures": failures,
        "command": command or f"mutloc.experiments.noise.run_noise(seed={seed})",
        "versions": versions(),
        "elapsed_s": round(elapsed, 2),
    }
    with timer("plots and files"):
        _plots(results, out)
    results["timing"] = timer.as_dict()
    write_results(results, out)
    (out / "report.md").write_text(_report(results), encoding="utf-8")
    return results


def _plots(results: dict[str, Any], out: Path) -> None:
    plt = pyplot()
    sig = results["sigma_px"]
    styles = {"best_root": ("-", "o", "best root (paper)"), "refined": ("--", "s", "refined (ML)"),
              "crlb": (":", None, "CRB-implied")}
    for quantity, scale, ylabel, fname, paper in (
            ("median_translation_m", 100.0, "median translation error [cm]", "translation_vs_sigma.png",
             PAPER_TRANSLATION_M * 100),
            ("median_rotation_deg", 1.0, "median rotation error [deg]", "rotation_vs_sigma.png",
             PAPER_ROTATION_DEG)):
        fig, ax = plt.subplots(figsize=(6.4, 4.4))
        for i, (key, block) in enumerate(results["by_distance_m"].items()):
            color = f"C{i}"
            for m in METHODS:
                ls, mk, label = styles[m]
                ax.plot(sig, np.array(block["methods"][m][quantity], float) * scale, ls=ls, marker=mk,
                        color=color, label=f"{label}, {float(key):g} m")
        ax.plot([PAPER_SIGMA_PX], [paper], "k*", ms=12, label="paper (10 px, ~1 m)")
        ax.set_xlabel("pixel noise sigma [px]")
        ax.set_ylabel(ylabel)
        ax.set_title(f"Noise experiment (seed {results['seed']})")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
        save_figure(fig, out / fname, 120)


def _report(results: dict[str, Any]) -> str:
    sig = results["sigma_px"]
    setup = results["setup"]
    lines = [
        "# Simulation experiment with noise (paper Sec. V-B)",
        "",
        "Two cameras (960x540, f = 800 px, standard ball rig) rendered at random relative poses "
        f"(yaw of each camera within +-{setup['max_yaw_deg']:g} deg, tilt within +-{setup['max_tilt_deg']:g} deg, "
        f"lateral offset up to {setup['max_lateral_fraction']:g} x the distance, distance +-"
        f"{setup['distance_spread'] * 100:g} %); balls detected once per scene by hue with the real detector; "
        f"zero-mean Gaussian noise added to the detected centres ({setup['trials_per_pose']} draws per scene "
        f"and sigma, {setup['poses_per_distance']} scenes per distance). Errors against the rendered truth: "
        "translation = |t_est - t_true|, rotation = the paper's angle. Medians. "
        "*best root* = the paper's method (best algebraic root, `refine=False`); *refined* = mutloc's "
        "maximum-likelihood pose; *CRB-implied* = medians of samples from N(0, sigma^2 (J^T J)^-1) at the true pose.",
        "",
    ]
    i10 = None
    if PAPER_SIGMA_PX in sig:
        i10 = sig.index(PAPER_SIGMA_PX)
    m1 = results["methods"]
    if i10 is not None and float(results["distance_m"]) == 1.0:
        lines += ["## At 10 px, cameras ~1 m apart, beside the paper", "",
                  "| method | median translation | median rotation |", "|---|---|---|",
                  f"| paper (reported) | {PAPER_TRANSLATION_M * 100:.1f} cm (at most) | "
                  f"{PAPER_ROTATION_DEG:.1f} deg (at most) |"]
        for m, label in (("best_root", "best root (paper's method)"), ("refined", "refined (mutloc)"),
                         ("crlb", "CRB-implied")):
            lines.append(f"| {label} | {fmt(m1[m]['median_translation_m'][i10], 100, 2)} cm | "
                         f"{fmt(m1[m]['median_rotation_deg'][i10], 1, 2)} deg |")
        lines.append("")
    for key, block in results["by_distance_m"].items():
        ms = block["methods"]
        lines += [f"## Cameras ~{float(key):g} m apart", "",
                  "| sigma [px] | best root [cm] | refined [cm] | CRB [cm] | best root [deg] | refined [deg] | "
                  "CRB [deg] |", "|---|---|---|---|---|---|---|"]
        for j, s in enumerate(sig):
            lines.append(
                f"| {s:g} | " + " | ".join(fmt(ms[m]["median_translation_m"][j], 100, 2) for m in METHODS) + " | "
                + " | ".join(fmt(ms[m]["median_rotation_deg"][j], 1, 3) for m in METHODS) + " |")
        fails = results["solver_failures"][key]
        lines += ["", f"Solver failures (excluded): best root {fails['best_root']}, refined {fails['refined']}.", ""]
    lines += ["Plots: `translation_vs_sigma.png`, `rotation_vs_sigma.png`.", ""] + reproduce_lines(results)
    return "\n".join(lines)
