"""The built-in end-to-end job behind ``mutloc demo`` / ``make demo``.

Everything runs on images rendered here by mutloc's own ray caster (no
downloads), through the same code as ``mutloc localize-images`` and
``mutloc track``:

1. **Scene pair.**  The standard ball rig (:func:`mutloc.sim.world.standard_rig`:
   robots ``p`` with balls M3, M4 and ``q`` with M1, M2; 960x540 cameras,
   f = 800 px) in a textured room, p about 2 m in front of q and turned
   towards it.  Both views are rendered with sensor noise and a JPEG round
   trip, written as ``p.png`` / ``q.png``, read back, the balls detected and
   the pose solved (:func:`mutloc.track.frames.localize_images`).
2. **Short sequence.**  p drives a smooth path in front of q
   (:func:`mutloc.sim.render.moving_world`) while q pans; ``frames`` frames at
   ``fps`` are rendered (noise, JPEG, slight motion blur) into two image
   folders and tracked from those folders (:func:`mutloc.track.tracker.track`).
3. **Report.**  Estimates against the rendered truth
   (:func:`mutloc.sim.render.relative_pose`), a plot, annotated images.

Files in ``out_dir`` (see :data:`FILES`): ``rig.yaml``, ``p.png``, ``q.png``,
``truth.json``, ``result.json`` (SPEC result), ``detections.json``,
``annotated.png``, ``sequence/{p,q}/NNNNNN.png`` with ``sequence/frames.csv``,
``sequence_annotated.mp4``, ``trajectory.tum``, ``trajectory.csv``,
``truth.tum``, ``trajectory.png`` and ``report.md``.
"""

from __future__ import annotations

import math
import os
import platform
import re
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .._extras import require
from ..core.geometry import so3_log
from ..core.pose import Pose
from ..errors import InputError, NoSolutionError
from ..io import load_rig, save_rig, write_json
from ..io.trajectory import write_tum
from .render import moving_world, project_markers, relative_pose, render, two_robot_world
from .synthetic import facing_pose
from .world import standard_rig

__all__ = ["FILES", "PAIR_RENDER", "SEQUENCE_RENDER", "format_summary", "pair_pose", "run_demo"]

SOURCE, TARGET = "p", "q"
# Image degradations of the two parts (arguments of mutloc.sim.render.render).
PAIR_RENDER: dict[str, Any] = {"noise_sigma": 2.0, "jpeg_quality": 90}
SEQUENCE_RENDER: dict[str, Any] = {"noise_sigma": 2.0, "jpeg_quality": 90, "blur_px": 1.5}
DEFAULT_FRAMES = 30
DEFAULT_FPS = 10.0

FILES = {
    "rig.yaml": "the rig (SPEC rig file): cameras and marker positions",
    "p.png, q.png": "the scene pair as each robot's camera sees it",
    "truth.json": "the true pose T_qp of the scene pair",
    "result.json": "the estimate from the two images (SPEC result JSON)",
    "detections.json": "the marker centres detected in each image",
    "annotated.png": "both views with the detections and the estimated pose",
    "sequence/": "the sequence: p/ and q/ image folders and frames.csv (timestamps)",
    "sequence_annotated.mp4": "the sequence, annotated as by `mutloc track --annotate`",
    "trajectory.tum": "the tracked pose of p in q's frame, solved frames (TUM)",
    "trajectory.csv": "every frame with its status and pose",
    "truth.tum": "the true pose of p in q's frame per frame (TUM)",
    "trajectory.png": "estimated vs true position over time, and the errors",
    "fisheye/": "two robots with back-to-back fisheyes turned away from each other: rig.yaml (cameras:), "
                "p_front.png, p_back.png, q_front.png, q_back.png, truth.json, result.json",
    "report.md": "this run's report",
}

_FRAME_NAME = re.compile(r"^\d{6}\.png$")


def pair_pose() -> Pose:
    """T_qp of the scene pair: p 2 m in front of q, turned 10 degrees, slightly off-axis."""
    return facing_pose(2.0, yaw_p=np.radians(10.0), yaw_q=np.radians(-5.0), lateral=0.15,
                       tilt=np.radians([2.0, 0.0, 1.0]))


def _imwrite(path: Path, image: np.ndarray) -> None:
    if not cv2.imwrite(str(path), image):
        raise OSError(f"{path}: cannot write image")


def _pose_dict(T: Pose) -> dict[str, Any]:
    return {"from": SOURCE, "to": TARGET, **T.to_dict()}


def _errors(estimate: Any, truth: Pose) -> tuple[float, float]:
    """(translation error m, rotation error deg), as SPEC defines them."""
    return estimate.pose.translation_error(truth), estimate.pose.rotation_error_deg(truth)


def _annotate(path: Path, images: dict[str, np.ndarray], estimate: Any, detections: dict[str, Any]) -> None:
    """Both views side by side with detections and the pose, drawn exactly as
    ``mutloc track --annotate`` draws a video frame, kept as one image."""
    from ..track.annotate import draw_pair
    from ..track.status import FrameStatus
    from ..track.tracker import TrackRow

    row = TrackRow(0.0, 0.0, 0.0, FrameStatus.SOLVED, estimate=estimate, detections=detections)
    _imwrite(path, draw_pair(images[SOURCE], images[TARGET], row, SOURCE, TARGET))


def _check_args(out: Path, seed: Any, frames: Any, fps: Any) -> None:
    if out.exists() and not out.is_dir():
        raise InputError(f"output folder {str(out)!r} exists and is not a folder")
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool):
        raise InputError(f"seed must be an integer, got {seed!r}")
    if not isinstance(frames, (int, np.integer)) or isinstance(frames, bool) or frames < 1:
        raise InputError(f"frames must be an integer >= 1, got {frames!r}")
    if not (isinstance(fps, (int, float, np.integer, np.floating)) and math.isfinite(fps) and fps > 0):
        raise InputError(f"fps must be a finite number > 0, got {fps!r}")


def _run_pair(out: Path, rig_file: Path, rig: Any, seed: int) -> dict[str, Any]:
    from ..track.frames import localize_images

    world = two_robot_world(rig, pair_pose(), seed=seed, source=SOURCE, target=TARGET)
    truth = relative_pose(world, SOURCE, TARGET)
    t0 = time.perf_counter()
    images = {r: render(world, r, seed=seed, **PAIR_RENDER) for r in (SOURCE, TARGET)}
    t_render = time.perf_counter() - t0
    for r, img in images.items():
        _imwrite(out / f"{r}.png", img)
    write_json(_pose_dict(truth), out / "truth.json")
    # Localize from the files just written, with the rig file read back:
    # the demo goes through the same inputs a user would give.
    t0 = time.perf_counter()
    res = localize_images(load_rig(rig_file), {r: out / f"{r}.png" for r in (SOURCE, TARGET)}, SOURCE, TARGET)
    t_solve = time.perf_counter() - t0
    est = res.estimate
    write_json(est.to_dict(), out / "result.json")
    write_json(res.detections_dict(), out / "detections.json")
    _annotate(out / "annotated.png", images, est, res.detections)

    # Detected centres against the exact projections of the marker centres.
    det_err = []
    for r, det in res.detections.items():
        exact = project_markers(world, r)
        det_err += [float(np.hypot(*(np.asarray(d.uv) - exact[n]))) for n, d in det.detections.items() if n in exact]
    err_t, err_r = _errors(est, truth)
    # Error in the covariance's own parametrization: R_true = exp(dtheta) R, t_true = t + dt.
    delta = np.concatenate([so3_log(truth.R @ est.R.T), truth.t - est.t])
    sd = np.sqrt(np.diag(est.covariance))
    return {
        "truth": _pose_dict(truth),
        "estimate": est.to_dict(),
        "translation_error_m": err_t,
        "rotation_error_deg": err_r,
        "sigma_t_m": sd[3:].tolist(),
        "sigma_rot_deg": np.degrees(sd[:3]).tolist(),
        "mahalanobis": float(math.sqrt(max(0.0, delta @ np.linalg.solve(est.covariance, delta)))),
        "detected": {r: sorted(d.detections) for r, d in res.detections.items()},
        "missing": {r: list(d.missing) for r, d in res.detections.items()},
        "detection_error_px_max": max(det_err) if det_err else float("nan"),
        "seconds": {"render": t_render, "localize": t_solve},
    }


def _run_fisheye(out: Path, seed: int) -> dict[str, Any]:
    """Two robots, each with back-to-back fisheyes (about 200 degrees), turned away from each other: only the
    back cameras see the other robot.  Rendered, detected through the lenses and localized from the files."""
    import json

    from ..errors import MutlocError
    from ..track.frames import localize_images
    from .body_scenes import write_cameras_simulation

    t0 = time.perf_counter()
    write_cameras_simulation(out, facing="away", seed=seed)
    t_render = time.perf_counter() - t0
    rig = load_rig(out / "rig.yaml")
    T = json.loads((out / "truth.json").read_text())["frames"][0]["T_qp"]
    truth = Pose(T["R"], T["t"])
    t0 = time.perf_counter()
    try:
        res = localize_images(rig, {k: out / f"{k.replace('/', '_')}.png" for k in rig.observer_keys()}, SOURCE,
                              TARGET)
    except MutlocError as exc:  # reported, not raised: the rest of the demo stands
        return {"error": str(exc), "truth": _pose_dict(truth), "seconds": {"render": t_render}}
    est = res.estimate
    write_json(est.to_dict(), out / "result.json")
    err_t, err_r = _errors(est, truth)
    return {"estimate": est.to_dict(), "truth": _pose_dict(truth), "translation_error_m": err_t,
            "rotation_error_deg": err_r, "status": est.status,
            "detected": {k: sorted(d.detections) for k, d in res.detections.items()},
            "seconds": {"render": t_render, "localize": time.perf_counter() - t0}}


def _clear_frames(folder: Path) -> None:
    """Remove frames of an earlier run (only files named like the demo's)."""
    folder.mkdir(parents=True, exist_ok=True)
    for p in folder.iterdir():
        if p.is_file() and _FRAME_NAME.match(p.name):
            p.unlink()


def _run_sequence(out: Path, rig_file: Path, rig: Any, seed: int, frames: int, fps: float,
                  progress: bool) -> dict[str, Any]:
    from tqdm import tqdm

    from ..track.sources import folder_frames
    from ..track.tracker import track

    world = moving_world(rig, seed=seed, source=SOURCE, target=TARGET)
    seq = out / "sequence"
    for r in (SOURCE, TARGET):
        _clear_frames(seq / r)
    times = [i / fps for i in range(frames)]
    t0 = time.perf_counter()
    for i, t in enumerate(tqdm(times, desc="render", unit="frame", disable=not progress)):
        for r in (SOURCE, TARGET):
            _imwrite(seq / r / f"{i:06d}.png", render(world, r, t, seed=seed, **SEQUENCE_RENDER))
    t_render = time.perf_counter() - t0
    (seq / "frames.csv").write_text("frame,timestamp\n" + "".join(f"{i},{t:.9f}\n" for i, t in enumerate(times)),
                                    encoding="utf-8")
    truth = [relative_pose(world, SOURCE, TARGET, t) for t in times]
    write_tum(out / "truth.tum", times, Pose.concatenate(truth),
              comment=f"mutloc demo: true pose of {SOURCE} in {TARGET}'s camera frame (T_qp); "
                      "timestamp tx ty tz qx qy qz qw")

    # Track from the folders just written, as `mutloc track --stream p=DIR ...` does.
    t0 = time.perf_counter()
    streams = {r: folder_frames(seq / r, fps=None) for r in (SOURCE, TARGET)}
    traj = track(load_rig(rig_file), streams, SOURCE, TARGET, fps=fps, progress=progress, total=frames,
                 annotate=out / "sequence_annotated.mp4")
    t_track = time.perf_counter() - t0
    traj.write_tum(out / "trajectory.tum")
    traj.write_csv(out / "trajectory.csv")

    per_frame = []
    for row in traj.rows:
        T = relative_pose(world, SOURCE, TARGET, row.t)
        entry: dict[str, Any] = {"t": row.t, "status": str(row.status), "true_t": T.t.tolist()}
        if row.estimate is not None:
            e_t, e_r = _errors(row.estimate, T)
            entry.update(est_t=row.estimate.t.tolist(), translation_error_m=e_t, rotation_error_deg=e_r)
        per_frame.append(entry)
    solved = [f for f in per_frame if "est_t" in f]
    et = np.array([f["translation_error_m"] for f in solved])
    er = np.array([f["rotation_error_deg"] for f in solved])
    unsolved: dict[str, int] = {}
    for f in per_frame:
        if "est_t" not in f:
            unsolved[f["status"]] = unsolved.get(f["status"], 0) + 1
    return {
        "frames": frames, "fps": fps, "duration_s": frames / fps, "rows": len(traj.rows),
        "solved": len(solved), "unsolved": unsolved,
        "translation_error_m": {"median": _stat(et, np.median), "max": _stat(et, np.max)},
        "rotation_error_deg": {"median": _stat(er, np.median), "max": _stat(er, np.max)},
        "per_frame": per_frame,
        "seconds": {"render": t_render, "track": t_track},
    }


def _plot(seq: dict[str, Any], path: Path) -> None:
    matplotlib = require("matplotlib", "the demo's plot")

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    rows = seq["per_frame"]
    t = np.array([f["t"] for f in rows])
    true = np.array([f["true_t"] for f in rows])
    solved = [f for f in rows if "est_t" in f]
    ts = np.array([f["t"] for f in solved])
    est = np.array([f["est_t"] for f in solved]).reshape(-1, 3)
    fig, axes = plt.subplots(3, 1, figsize=(7.0, 7.5), sharex=True)
    for ax, k, name in ((axes[0], 0, "x (sideways)"), (axes[1], 2, "z (ahead)")):
        ax.plot(t, true[:, k], "-", color="0.3", lw=1.5, label="truth")
        ax.plot(ts, est[:, k], "o", ms=4, color="C0", label="estimate (from images)")
        ax.set_ylabel(f"p's {name} [m]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    axes[0].set_title(f"p's position in q's camera frame: {seq['solved']} of {seq['frames']} frames solved")
    ax = axes[2]
    ax.plot(ts, 100 * np.array([f["translation_error_m"] for f in solved]), "o-", ms=3, color="C1",
            label="translation [cm]")
    ax.set_ylabel("translation error [cm]", color="C1")
    ax.set_xlabel("time [s]")
    ax.grid(True, alpha=0.3)
    ax2 = ax.twinx()
    ax2.plot(ts, [f["rotation_error_deg"] for f in solved], "s--", ms=3, color="C2", label="rotation [deg]")
    ax2.set_ylabel("rotation error [deg]", color="C2")
    ax.set_ylim(bottom=0)
    ax2.set_ylim(bottom=0)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _stat(a: np.ndarray, fn: Any) -> float:
    return float(fn(a)) if a.size else float("nan")


def _num(x: float, scale: float, digits: int) -> str:
    return "n/a" if not math.isfinite(x) else f"{scale * x:.{digits}f}"


def _rotvec_deg(R: Any) -> np.ndarray:
    return np.degrees(so3_log(np.array(R)))


def _vec(v: Any, scale: float = 1.0, digits: int = 4) -> str:
    return "(" + ", ".join(f"{scale * x:+.{digits}f}" for x in v) + ")"


def _ncpu() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _report(s: dict[str, Any]) -> str:
    pair, seq = s["pair"], s["sequence"]
    est, truth = pair["estimate"], pair["truth"]
    te, re_ = seq["translation_error_m"], seq["rotation_error_deg"]
    lines = [
        "# mutloc demo",
        "",
        "Two robots, each a 960x540 camera (f = 800 px) with two coloured balls left and right of it "
        "(the standard ball rig, `rig.yaml`), in a textured room rendered by mutloc's ray caster. "
        "Every pose below is estimated from the rendered images only — ball detection, then mutual "
        "localization — and compared with the rendered truth. Pose = T_qp, p's camera in q's camera frame "
        "(x right, y down, z forward).",
        "",
        f"## Scene pair (seed {s['seed']})",
        "",
        f"Images: [`p.png`](p.png), [`q.png`](q.png) (sensor noise {PAIR_RENDER['noise_sigma']:g} grey levels, "
        f"JPEG quality {PAIR_RENDER['jpeg_quality']}). Detected: "
        + "; ".join(f"{r} sees {', '.join(v) or 'nothing'}" for r, v in pair["detected"].items())
        + f" (largest detection error {_num(pair['detection_error_px_max'], 1, 3)} px against the exact "
        "projection of the ball centres).",
        "",
        "| | estimate | truth |",
        "|---|---|---|",
        f"| t [m] | {_vec(est['t'])} | {_vec(truth['t'])} |",
        f"| rotation vector [deg] | {_vec(_rotvec_deg(est['R']), 1, 3)} | {_vec(_rotvec_deg(truth['R']), 1, 3)} |",
        "",
        f"- translation error **{100 * pair['translation_error_m']:.2f} cm**, rotation error "
        f"**{pair['rotation_error_deg']:.3f} deg**",
        f"- 1-sigma from the covariance (1 px detection noise): t {_vec(pair['sigma_t_m'], 100, 2)} cm, "
        f"rotation {_vec(pair['sigma_rot_deg'], 1, 3)} deg; the error is {pair['mahalanobis']:.2f} sigma "
        "(Mahalanobis, 6 DOF)",
        f"- reprojection RMS {est['reprojection_rms_px']:.3f} px over {', '.join(est['markers_used'])}",
        "- files: [`result.json`](result.json) (SPEC result), [`detections.json`](detections.json), "
        "[`truth.json`](truth.json)",
        "",
        "![both views with detections and the estimated pose](annotated.png)",
        "",
        "## Robots with several cameras, turned away from each other",
        "",
        "Each robot carries two fisheyes of about 200 degrees back to back (1280x800, `fisheye/rig.yaml`: "
        "`cameras:`, poses in the robot's base_link frame); the robots stand back to back, so only the back "
        "cameras see the other robot, its balls up to 90 degrees off their axes. The four images "
        "(`fisheye/p_front.png`, ...) are detected through the lens model and the pose between the robot "
        "frames is solved from all of them. "
        + (f"Failed: {s['fisheye']['error']}" if "error" in s["fisheye"] else
           f"Detected: " + "; ".join(f"{k} sees {', '.join(v) or 'nothing'}"
                                     for k, v in s["fisheye"]["detected"].items())
           + f". Status {s['fisheye']['status']}; translation error "
           f"**{100 * s['fisheye']['translation_error_m']:.2f} cm**, rotation error "
           f"**{s['fisheye']['rotation_error_deg']:.3f} deg** (t estimate {_vec(s['fisheye']['estimate']['t'])} m, "
           f"truth {_vec(s['fisheye']['truth']['t'])} m)."),
        "",
        "## Sequence",
        "",
        f"p drives in front of q while q pans: {seq['frames']} frames at {seq['fps']:g} fps "
        f"({seq['duration_s']:g} s), noise {SEQUENCE_RENDER['noise_sigma']:g} grey levels, JPEG "
        f"{SEQUENCE_RENDER['jpeg_quality']}, motion blur {SEQUENCE_RENDER['blur_px']:g} px; written to "
        "`sequence/p/`, `sequence/q/` (+ `frames.csv`) and tracked from those folders.",
        "",
        f"- frames solved: **{seq['solved']} of {seq['rows']}**"
        + ("" if not seq["unsolved"] else " (unsolved: " + "; ".join(f"{n}x {k}" for k, n in seq["unsolved"].items())
           + ")"),
        f"- translation error median **{_num(te['median'], 100, 2)} cm**, max {_num(te['max'], 100, 2)} cm",
        f"- rotation error median **{_num(re_['median'], 1, 3)} deg**, max {_num(re_['max'], 1, 3)} deg",
        "- files: [`trajectory.tum`](trajectory.tum) (estimate, TUM), "
        "[`truth.tum`](truth.tum) (truth, TUM), [`trajectory.csv`](trajectory.csv) (every frame "
        "with its status), [`sequence_annotated.mp4`](sequence_annotated.mp4)",
        "",
        "![estimated vs true position, and the errors](trajectory.png)",
        "",
        "## Run",
        "",
        f"Total {s['seconds']['total']:.1f} s on {s['machine']} — pair: render "
        f"{pair['seconds']['render']:.1f} s, detect + localize {pair['seconds']['localize']:.1f} s; sequence: "
        f"render {seq['seconds']['render']:.1f} s, track {seq['seconds']['track']:.1f} s. The first run after "
        "installing (or changing) mutloc also compiles its Numba kernels, about 45 s mostly in the first "
        "render and the first localization; they are cached on disk for the next runs.",
        "",
        f"Reproduce: `mutloc demo --out {s['out_dir']} --seed {s['seed']}"
        + (f" --frames {seq['frames']}" if seq["frames"] != DEFAULT_FRAMES else "")
        + (f" --fps {seq['fps']:g}" if seq["fps"] != DEFAULT_FPS else "") + "`.",
        "",
    ]
    return "\n".join(lines)


def run_demo(out_dir: str | Path = "demo-out", seed: int = 0, *, frames: int = DEFAULT_FRAMES,
             fps: float = DEFAULT_FPS, progress: bool = False) -> dict[str, Any]:
    """Render, detect, localize and track; write :data:`FILES` into ``out_dir``.

    ``seed`` varies the room and the sensor noise; ``frames`` at ``fps`` set
    the sequence.  Returns the summary that :func:`format_summary` prints
    (``pair`` and ``sequence`` errors against the truth, timings).  Raises
    InputError for bad arguments, OSError when a file cannot be written, the
    library's errors if the scene pair cannot be localized, and
    NoSolutionError (after writing the report) if no frame of the sequence is.
    """
    start = time.perf_counter()
    out = Path(out_dir).expanduser()
    _check_args(out, seed, frames, fps)
    seed, frames, fps = int(seed), int(frames), float(fps)
    out.mkdir(parents=True, exist_ok=True)
    rig = standard_rig("balls")
    rig_file = out / "rig.yaml"
    save_rig(rig, rig_file)
    pair = _run_pair(out, rig_file, rig, seed)
    fisheye = _run_fisheye(out / "fisheye", seed)
    seq = _run_sequence(out, rig_file, rig, seed, frames, fps, progress)
    _plot(seq, out / "trajectory.png")
    summary = {
        "out_dir": str(out), "seed": seed, "pair": pair, "sequence": seq, "fisheye": fisheye,
        "machine": f"{_cpu_model()}, {_ncpu()} cores, Python {platform.python_version()}",
        "files": list(FILES),
    }
    summary["seconds"] = {"total": time.perf_counter() - start}
    (out / "report.md").write_text(_report(summary), encoding="utf-8")
    summary["seconds"]["total"] = time.perf_counter() - start
    if seq["solved"] == 0:
        why = "; ".join(f"{n}x {k}" for k, n in seq["unsolved"].items())
        raise NoSolutionError(f"demo: no frame of the sequence was localized ({why}); see {out / 'report.md'}")
    return summary


def format_summary(s: dict[str, Any]) -> str:
    """The console summary of :func:`run_demo`."""
    pair, seq, fe = s["pair"], s["sequence"], s["fisheye"]
    est, truth = pair["estimate"], pair["truth"]
    te, re_ = seq["translation_error_m"], seq["rotation_error_deg"]
    sig_t = 100 * float(np.linalg.norm(pair["sigma_t_m"]))
    sig_r = float(np.linalg.norm(pair["sigma_rot_deg"]))
    n_det = sum(len(v) for v in pair["detected"].values())
    lines = [
        "mutloc demo: two robots with coloured balls, rendered, detected and localized from the images",
        f"  scene pair   {n_det} markers detected, reprojection RMS {est['reprojection_rms_px']:.2f} px",
        f"               t estimate {_vec(est['t'], 1, 3)} m   truth {_vec(truth['t'], 1, 3)} m",
        f"               error {100 * pair['translation_error_m']:.2f} cm, {pair['rotation_error_deg']:.3f} deg"
        f"   (1-sigma {sig_t:.2f} cm, {sig_r:.3f} deg)",
        ("  fisheyes     robots turned away, back cameras only: " + (
            f"failed ({fe['error']})" if "error" in fe else
            f"error {100 * fe['translation_error_m']:.2f} cm, {fe['rotation_error_deg']:.3f} deg ({fe['status']})")),
        f"  sequence     {seq['solved']} of {seq['rows']} frames solved ({seq['duration_s']:g} s at "
        f"{seq['fps']:g} fps); error median {_num(te['median'], 100, 2)} cm / {_num(re_['median'], 1, 3)} deg,"
        f" max {_num(te['max'], 100, 2)} cm / {_num(re_['max'], 1, 3)} deg",
        f"  report       {Path(s['out_dir']) / 'report.md'} (plot trajectory.png, annotated.png, "
        "result.json, trajectory.tum, ...)",
        f"  time         {s['seconds']['total']:.1f} s",
    ]
    return "\n".join(lines)
