#!/usr/bin/env python
"""The motion model at speed (issue 37 item 1): is the team tracker's
covariance honest when robots drive fast and turn fast, and a robot goes
unseen?

The scene (held out: not the tests' seed): ``mutloc simulate --robots 3
--markers tags --frames 120 --fps 30 --camera-fps r1=20 --camera-fps r2=15
--camera-offset r1=0.011 --camera-offset r2=0.023 --speed 1.25 --turn-rate 75
--size 480x270 --focal 400 --seed S`` (4 s; every robot drives a 0.3 m circle
at 1.0-1.5 m/s while its heading swings by 15 degrees at up to 70-80 deg/s;
cameras free-running at 30/20/15 fps), rendered once and detected once
(``mutloc track --tolerance 0.001 --observations-out``: every frame a record
at its own time).  The detections are then tracked in this process by
:class:`mutloc.track.team.TeamTracker` (reference r0, ``--pixel-sigma 0.3``,
0.3 px Gaussian noise added to every detection: rendered corners are more
exact than that), the causal filter (``smooth_lag 0``: what a live
localizer publishes), with each robot made dark in turn: every observation
of it and by its camera removed for 0.6 s (``--dark``), from 1.5 s (r1) and
from 2.7 s (r2) -- the robot is coasted on the motion model.

Counted against the rendered truth (every robot's pose at every capture
instant, interpolated to the record's time): poses beyond 5 sigma of their
own covariance (NEES over the 6 pose dimensions above chi2_6's two-sided
5-sigma quantile, 39.5), separately for the rows coasted in the dark
(``predicted``) and for the ``solved`` rows; solved rows off by more than
5 cm; the error and sigma (largest translation 1-sigma) of the coasted rows
at the end of the dark stretch; mean NEES / 6 of coasted and of solved and
partial rows.  ``--noise`` runs the old walking-pace defaults, the tests'
agile values (``--angular-noise 2 --linear-noise 2``), each with the
reference's turning modelled (``MotionNoise.reference_angular`` equal to
``angular``) and without it (``-old``: the default) -- all in one run.

    python bench/motion_speed.py [--seeds 5,6,7] [--dark 0.6] [--cache DIR]

Writes bench/results/motion_speed.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402

from mutloc.api import load_rig  # noqa: E402
from mutloc.cli.main import main  # noqa: E402
from mutloc.core.filter import MotionNoise  # noqa: E402
from mutloc.core.geometry import so3_log  # noqa: E402
from mutloc.core.observations import ObservationSet  # noqa: E402
from mutloc.io.logs import iter_observation_log  # noqa: E402
from mutloc.sim.truth_log import truth_pose_at  # noqa: E402
from mutloc.track.filtering import FilterOptions  # noqa: E402
from mutloc.track.frames import expanded_rig  # noqa: E402
from mutloc.track.team import TeamTracker  # noqa: E402

ROBOTS = ("r0", "r1", "r2")
NEES_5_SIGMA = 39.49
DARK_FROM = {"r1": 1.5, "r2": 2.7}


def scene(folder: Path, seed: int) -> Path:
    """Render and detect the scene once (cached in ``folder``); the observation log's path."""
    sim, det = folder / f"sim{seed}", folder / f"det{seed}"
    log, done = det / "log.jsonl", det / "done"
    if done.exists():
        return log
    assert main(["simulate", "--robots", "3", "--markers", "tags", "--frames", "120", "--fps", "30",
                 "--camera-fps", "r1=20", "--camera-fps", "r2=15", "--camera-offset", "r1=0.011",
                 "--camera-offset", "r2=0.023", "--speed", "1.25", "--turn-rate", "75", "--size", "480x270",
                 "--focal", "400", "--seed", str(seed), "--out", str(sim), "--no-progress"]) == 0
    assert main(["track", "--rig", str(sim / "rig.yaml"), *[a for r in ROBOTS for a in ("--stream", f"{r}={sim / r}")],
                 "--pixel-sigma", "0.3", "--tolerance", "0.001", "--observations-out", str(log), "--smooth-lag", "0",
                 "--out", str(det / "track"), "--no-progress"]) == 0
    done.write_text("")
    return log


def truth_at(sim: Path):
    """``T_r0_r(t)`` interpolated between the capture instants of truth.json."""
    return truth_pose_at(sim / "truth.json")


def dark(obs: ObservationSet, t: float, span: float) -> ObservationSet:
    """``obs`` without any observation of or by a robot in its dark stretch at ``t``."""
    off = [r for r, t0 in DARK_FROM.items() if t0 <= t < t0 + span]
    keep = [k for k, (o, m) in enumerate(zip(obs.observer, obs.marker))
            if not any(o == r or (m or "").startswith(f"{r}_") for r in off)]
    return obs.take(np.array(keep, dtype=np.int64))


def run(log: Path, sim: Path, noise: MotionNoise | None, span: float, seed: int) -> dict:
    rig = expanded_rig(load_rig(sim / "rig.yaml"))
    truth = truth_at(sim)
    rng = np.random.default_rng(seed + 1000)
    opts = FilterOptions(smooth_lag=0) if noise is None else FilterOptions(noise=noise, smooth_lag=0)
    tracker = TeamTracker(rig, "r0", pixel_sigma=0.3, options=opts)
    out = {"coasted": [], "solved": [], "other": [], "end_of_dark": []}
    for t, obs in iter_observation_log(log):
        obs = ObservationSet(obs.observer, obs.marker, obs.uv + rng.normal(0.0, 0.3, obs.uv.shape), t)
        rows = tracker.step(t, dark(obs, t, span))
        for r in ("r1", "r2"):
            row = rows[r]
            if row.estimate is None:
                continue
            T, e = truth(r, t), row.estimate
            d = np.r_[so3_log(T.R @ e.pose.R.T), T.t - e.pose.t]
            nees = float(d @ np.linalg.solve(e.covariance, d))
            err = float(np.linalg.norm(d[3:]))
            sig = float(np.sqrt(np.max(np.linalg.eigvalsh(e.covariance[3:, 3:]))))
            in_dark = DARK_FROM[r] <= t < DARK_FROM[r] + span
            kind = ("coasted" if in_dark and row.status.value == "predicted" else
                    "solved" if row.status.value == "solved" else "other")
            out[kind].append((t, err, sig, nees))
            if in_dark and t >= DARK_FROM[r] + span - 0.07:
                out["end_of_dark"].append((r, t, err, sig, nees))
    return out


def summary(runs: list[dict]) -> dict:
    def cat(k):
        return [x for r in runs for x in r[k]]

    co, so, ot = cat("coasted"), cat("solved"), cat("other")
    allp = co + so + ot
    end = cat("end_of_dark")
    return {
        "poses": len(allp), "beyond_5_sigma": sum(x[3] > NEES_5_SIGMA for x in allp),
        "coasted": len(co), "coasted_beyond_5_sigma": sum(x[3] > NEES_5_SIGMA for x in co),
        "coasted_mean_nees6": float(np.mean([x[3] for x in co]) / 6) if co else None,
        "solved": len(so), "solved_beyond_5_sigma": sum(x[3] > NEES_5_SIGMA for x in so),
        "solved_off_5cm": sum(x[1] > 0.05 for x in so),
        "solved_median_cm": float(100 * np.median([x[1] for x in so])) if so else None,
        "solved_mean_nees6": float(np.mean([x[3] for x in so]) / 6) if so else None,
        "other_beyond_5_sigma": sum(x[3] > NEES_5_SIGMA for x in ot),
        "end_of_dark": [{"robot": r, "t": round(t, 3), "error_cm": round(100 * e, 1), "sigma_cm": round(100 * s, 1),
                         "nees": round(n, 1)} for r, t, e, s, n in end],
    }


def main_() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="5,6,7")
    ap.add_argument("--dark", type=float, default=0.6)
    ap.add_argument("--cache", default="/tmp/mutloc-motion-speed")
    ap.add_argument("--noise", default="walking-old,walking,agile-old,agile",
                    help="comma-separated: walking (--angular-noise 0.5 --linear-noise 1, the defaults), agile "
                         "(2 / 2, the tests'), the reference's turning modelled (MotionNoise.reference_angular = "
                         "angular); '-old': not modelled (the default); default: FilterOptions()'s")
    ap.add_argument("--out", default=result_file("motion_speed.json"))
    args = ap.parse_args()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    noises = {"walking": MotionNoise(angular=0.5, linear=1.0, reference_angular=0.5),
              "agile": MotionNoise(angular=2.0, linear=2.0, reference_angular=2.0),
              "walking-old": MotionNoise(angular=0.5, linear=1.0),
              "agile-old": MotionNoise(angular=2.0, linear=2.0), "default": None}
    seeds = [int(s) for s in args.seeds.split(",")]
    res = {"machine": machine(), "seeds": seeds, "dark_s": args.dark, "noise": {}}
    logs = {}
    for s in seeds:
        t0 = time.perf_counter()
        logs[s] = scene(cache, s)
        print(f"scene {s}: {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    for name in args.noise.split(","):
        runs = [run(logs[s], cache / f"sim{s}", noises[name], args.dark, s) for s in seeds]
        res["noise"][name] = sm = summary(runs)
        print(f"{name:8s} poses {sm['poses']} beyond 5 sigma {sm['beyond_5_sigma']} | coasted {sm['coasted']} "
              f"beyond {sm['coasted_beyond_5_sigma']} NEES/6 {sm['coasted_mean_nees6']:.1f} | solved {sm['solved']} "
              f"beyond {sm['solved_beyond_5_sigma']} off>5cm {sm['solved_off_5cm']} median "
              f"{sm['solved_median_cm']:.2f} cm NEES/6 {sm['solved_mean_nees6']:.2f} | other beyond "
              f"{sm['other_beyond_5_sigma']}")
        for e in sm["end_of_dark"][::3]:
            print(f"   end of dark {e}")
    Path(args.out).write_text(json.dumps(res, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main_()
