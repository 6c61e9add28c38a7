#!/usr/bin/env python
"""Team tracking (``mutloc track`` with more than two robots): accuracy
against the truth and cost per frame, with ``mutloc.localize_team`` on the
same frames in the same run as the peer.

    python bench/bench_team_track.py [--seeds 3] [--frames 90] [--render-frames 20] [--fast-frames 60]

- synthetic logs: random teams of four robots (30% of mutual pairs seen one
  way), each robot swaying on its own loop (mutloc.sim.team.team_sequence),
  30 fps, sigma = 1 px: per robot and frame, the causal filter's pose
  (``--filter cv --smooth-lag 0``), the fixed-lag smoothed one (``--filter
  cv``, the default lag) and the per-frame joint estimate (``--filter
  none``) against the truth; mean NEES / 6 of each covariance; CPU time of
  TeamTracker.step per frame next to a cold localize_team per frame, and of
  a whole smoothed track per frame.
- rendered: ``mutloc simulate --robots 3 --markers tags --frames N`` (640x360,
  f = 530 px, seed 2) tracked from the three image folders with
  ``--pixel-sigma 0.3``, smoothed (default) and ``--smooth-lag 0``; errors
  per robot against truth_NAME.tum.
- fast team (tests/test_team_unsync.py): cameras at 30/20/15 fps, robots at
  1.25 m/s turning at 75 deg/s, 2 s, every frame a record of its own
  (``--tolerance 0.001``), 0.3 px noise added to the detections (seed 7);
  filtered and smoothed error and NEES / 6 of the solved and partial rows.

Writes bench/results/team_track_results.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

# One BLAS thread: on a loaded 2-core machine OpenBLAS's threads turn the
# joint covariance's small triangular solves into milliseconds each.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from _machine import machine, result_file  # noqa: E402

from mutloc import localize_team  # noqa: E402
from mutloc.cli.main import main  # noqa: E402
from mutloc.core.geometry import so3_log  # noqa: E402
from mutloc.errors import MutlocError  # noqa: E402
from mutloc.io.trajectory import read_trajectory_csv, read_tum  # noqa: E402
from mutloc.sim.team import random_team, team_sequence  # noqa: E402
from mutloc.track.filtering import DEFAULT_SMOOTH_LAG, FilterOptions  # noqa: E402
from mutloc.track.team import TeamTracker, track_team_log  # noqa: E402


def synthetic(seed: int, frames: int) -> dict:
    scene = random_team(4, np.random.default_rng(seed), one_way=0.3)
    seq = team_sequence(scene, frames, 30.0, sigma=1.0, seed=seed)
    log = [(t, o) for t, _, o in seq]
    out = {}
    track_team_log(scene.rig, log[:3], progress=False)  # compile the kernels before any timing
    for kind in ("cv", "cv_smoothed", "none"):
        opts = FilterOptions(smooth_lag=0) if kind == "cv" else FilterOptions(kind="cv" if kind == "cv_smoothed" else kind)
        t0 = time.process_time()
        traj = track_team_log(scene.rig, log, progress=False, filter=opts)
        cpu = time.process_time() - t0
        err, nees, status = [], [], {}
        for r, tr in traj.tracks.items():
            for (t, snap, _), row in zip(seq, tr.rows):
                status[row.status.value] = status.get(row.status.value, 0) + 1
                if row.estimate is None:
                    continue
                T = snap.truth()[r]
                e = np.r_[so3_log(T.R @ row.estimate.pose.R.T), T.t - row.estimate.pose.t]
                err.append(float(np.linalg.norm(e[3:])))
                nees.append(float(e @ np.linalg.solve(row.estimate.covariance, e)))
        out[kind] = {"median_translation_m": float(np.median(err)), "mean_nees_over_6": float(np.mean(nees) / 6),
                     "statuses": status, "track_ms_per_frame": 1e3 * cpu / len(log)}
    # cost: the tracker's step against a cold localize_team, same frames, CPU time
    TeamTracker(scene.rig).step(0.0, log[0][1])  # compile
    t0 = time.process_time()
    tracker = TeamTracker(scene.rig)
    for t, o in log:
        tracker.step(t, o)
    step = (time.process_time() - t0) / len(log)
    t0 = time.process_time()
    for _, o in log:
        try:
            localize_team(scene.rig, o)
        except MutlocError:
            pass  # a frame nothing ties to the reference: the tracker's rows say so
    cold = (time.process_time() - t0) / len(log)
    out["step_ms"] = 1e3 * step
    out["cold_localize_team_ms"] = 1e3 * cold
    out["joint_solves"] = tracker.joint_solves  # records solved on their own to start a robot
    out["ratio_filtered_over_per_frame"] = out["cv"]["median_translation_m"] / out["none"]["median_translation_m"]
    out["ratio_smoothed_over_filtered"] = (out["cv_smoothed"]["median_translation_m"]
                                           / out["cv"]["median_translation_m"])
    return out


def rendered(frames: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        sim = Path(tmp) / "sim"
        t0 = time.time()
        assert main(["simulate", "--robots", "3", "--markers", "tags", "--frames", str(frames), "--fps", "10",
                     "--size", "640x360", "--focal", "530", "--seed", "2", "--out", str(sim), "--no-progress"]) == 0
        render_s = time.time() - t0
        res = {"render_s": render_s, "frames": frames}
        for lag in ("0", "default"):
            res[f"smooth_lag_{lag}"] = _rendered_track(sim, Path(tmp) / f"out_{lag}", lag)
        return res


def _rendered_track(sim: Path, out: Path, lag: str) -> dict:
    t0 = time.process_time()
    assert main(["track", "--rig", str(sim / "rig.yaml"), *[a for i in range(3) for a in
                 ("--stream", f"r{i}={sim / f'r{i}'}")], "--pixel-sigma", "0.3", "--out", str(out),
                 *(["--smooth-lag", lag] if lag != "default" else []), "--no-progress"]) == 0
    res = {"track_cpu_s": time.process_time() - t0}
    for r in ("r1", "r2"):
        _, truth = read_tum(sim / f"truth_{r}.tum")
        rows = read_trajectory_csv(out / f"trajectory_{r}.csv")
        e = [float(np.linalg.norm(row["pose"].t - truth[k].t)) for k, row in enumerate(rows) if row["pose"] is not None]
        a = [float(row["pose"].rotation_error_deg(truth[k])) for k, row in enumerate(rows) if row["pose"] is not None]
        st = {}
        for row in rows:
            st[row["status"]] = st.get(row["status"], 0) + 1
        res[r] = {"median_translation_m": float(np.median(e)), "max_translation_m": float(np.max(e)),
                  "median_rotation_deg": float(np.median(a)), "statuses": st}
    return res


def fast_team(frames: int) -> dict:
    """The fast team of tests/test_team_unsync.py: filtered against smoothed."""
    # the test's scene, truth interpolation and tracking
    from test_team_unsync import ROBOTS, _nees, _truth, filtered_and_smoothed

    with tempfile.TemporaryDirectory() as tmp:
        sim, apart = Path(tmp) / "sim", Path(tmp) / "apart"
        assert main(["simulate", "--robots", "3", "--markers", "tags", "--frames", str(frames), "--fps", "30",
                     "--camera-fps", "r1=20", "--camera-fps", "r2=15", "--camera-offset", "r1=0.011",
                     "--camera-offset", "r2=0.023", "--speed", "1.25", "--turn-rate", "75", "--size", "480x270",
                     "--focal", "400", "--seed", "2", "--out", str(sim), "--no-progress"]) == 0
        assert main(["track", "--rig", str(sim / "rig.yaml"), *[a for r in ROBOTS for a in
                     ("--stream", f"{r}={sim / r}")], "--pixel-sigma", "0.3", "--angular-noise", "2",
                     "--linear-noise", "2", "--tolerance", "0.001", "--observations-out", str(apart / "log.jsonl"),
                     "--out", str(apart), "--no-progress"]) == 0
        truth = _truth(sim)
        records, rows, _ = filtered_and_smoothed(sim, apart / "log.jsonl")
    res = {"records": len(records)}
    for r in ("r1", "r2"):
        keep = [k for k in range(len(records)) if rows[0][k][r].status.value in ("solved", "partial")]
        res[r] = {"rows": len(keep)}
        for lag, name in ((0, "filtered"), (DEFAULT_SMOOTH_LAG, "smoothed")):
            ests = [(rows[lag][k][r].estimate, truth(r, records[k][0])) for k in keep]
            res[r][name] = {"median_translation_m": float(np.median([np.linalg.norm(e.pose.t - T.t) for e, T in ests])),
                            "mean_nees_over_6": float(np.mean([_nees(e, T) for e, T in ests]))}
    return res


def run() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--render-frames", type=int, default=20)
    ap.add_argument("--fast-frames", type=int, default=60)
    args = ap.parse_args()
    res = {"machine": machine(), "synthetic": {}}
    for seed in range(args.seeds):
        res["synthetic"][str(seed)] = synthetic(seed, args.frames)
        print(f"seed {seed}:", json.dumps(res["synthetic"][str(seed)]))
    res["rendered"] = rendered(args.render_frames)
    print("rendered:", json.dumps(res["rendered"]))
    res["fast_team"] = fast_team(args.fast_frames)
    print("fast team:", json.dumps(res["fast_team"]))
    path = Path(result_file("team_track_results.json"))
    path.write_text(json.dumps(res, indent=1) + "\n")
    print(f"wrote {path}")


if __name__ == "__main__":
    run()
