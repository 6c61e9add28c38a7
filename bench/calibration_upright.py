#!/usr/bin/env python
"""Marker calibration of two upright robots (issue 38): what judging the held
combinations at the residuals' noise gives against judging them at the
stated ``--pixel-sigma``, in one run on the same logs.

Each run: the two-ball-per-robot rig of the tests (``ball_rig(2)``), every
marker moved 1-2 cm (the given rig), a log of 60 frames of two robots that
only yaw (no roll: the weakly determined case), detections good to 0.1 px
while the stated noise is the default 1 px, the true distance between p's
balls held; then 30 held-out frames localized with the given and the
calibrated rigs.  "before": the combinations held at the given rig judged at
the stated noise (the previous behaviour, by replacing
``mutloc.calibration._hold_noise``); "after": at the residuals' noise (now).
A new log (seed) every run; medians over the runs of each run's median.

    python bench/calibration_upright.py [--runs 9]

Writes bench/results/calibration_upright.json.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402

import mutloc.calibration as mc  # noqa: E402
from mutloc.sim.calibration import ball_rig, held_out_errors, pair_sequence, perturb_rig, true_positions  # noqa: E402

TRUE_SIGMA = 0.1
SCALE = ("M3", "M4", 0.30)


def one(seed: int, frames: int) -> dict:
    rng = np.random.default_rng([seed, 3838])
    truth = ball_rig(2)
    measured = perturb_rig(truth, rng)
    seq = pair_sequence(truth, frames, rng, pixel_sigma=TRUE_SIGMA, roll_deg=0.0)
    held = pair_sequence(truth, 30, rng, pixel_sigma=TRUE_SIGMA, roll_deg=0.0)
    tp = true_positions(truth)
    out = {}
    g = held_out_errors(measured, held, "p", "q")
    out["given"] = {"held_out_rotation_deg": float(np.nanmedian(g[:, 1])),
                    "held_out_translation_mm": 1000 * float(np.nanmedian(g[:, 0])),
                    "marker_rms_mm": 1000 * float(np.sqrt(np.mean([np.sum((np.asarray(m["position"]) - tp[n]) ** 2)
                                                                   for s in measured["robots"].values()
                                                                   for n, m in s["markers"].items()])))}
    real = mc._hold_noise
    for name, judge in (("before", lambda measured_, dof, stated: stated), ("after", real)):
        mc._hold_noise = judge
        try:
            res = mc.calibrate_markers(measured, seq.frames, scale=SCALE)  # --pixel-sigma: the default 1 px
        finally:
            mc._hold_noise = real
        e = held_out_errors(res.rig, held, "p", "q")
        out[name] = {"held_out_rotation_deg": float(np.nanmedian(e[:, 1])),
                     "held_out_translation_mm": 1000 * float(np.nanmedian(e[:, 0])),
                     "marker_rms_mm": 1000 * float(np.sqrt(np.mean([np.sum((m.new - tp[n]) ** 2)
                                                                    for n, m in res.markers.items()]))),
                     "held_combinations": sum(w.held for w in res.weak_directions),
                     "measured_pixel_sigma": res.measured_pixel_sigma}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=9)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--out", default=result_file("calibration_upright.json"))
    args = ap.parse_args(argv)
    runs = []
    for seed in range(args.runs):
        runs.append(one(seed, args.frames))
        r = runs[-1]
        print(f"run {seed}: held-out rotation given {r['given']['held_out_rotation_deg']:.2f} deg, before "
              f"{r['before']['held_out_rotation_deg']:.2f}, after {r['after']['held_out_rotation_deg']:.2f}; "
              f"markers {r['given']['marker_rms_mm']:.1f} / {r['before']['marker_rms_mm']:.1f} / "
              f"{r['after']['marker_rms_mm']:.1f} mm; held {r['before']['held_combinations']} -> "
              f"{r['after']['held_combinations']}", flush=True)
    summary = {}
    for name in ("given", "before", "after"):
        summary[name] = {k: float(np.median([r[name][k] for r in runs]))
                         for k in ("held_out_rotation_deg", "held_out_translation_mm", "marker_rms_mm")}
        print(f"{name:>6}: held-out rotation {summary[name]['held_out_rotation_deg']:.2f} deg, translation "
              f"{summary[name]['held_out_translation_mm']:.1f} mm, markers {summary[name]['marker_rms_mm']:.1f} mm "
              "(medians over runs)")
    Path(args.out).write_text(json.dumps({"machine": machine(), "runs": args.runs, "frames": args.frames,
                                          "true_pixel_sigma": TRUE_SIGMA, "stated_pixel_sigma": 1.0,
                                          "summary": summary, "per_run": runs}, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
