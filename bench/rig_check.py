#!/usr/bin/env python
"""The rig check's window test (mutloc.track.rig_check, issue 38): how often
it raises on a correct rig with honest noise (false alarms), how soon it
raises on a rig whose markers are 1-2 cm off (detection), and what it costs
per record beside the tracker's own step.

Logs: ``observation_sequence`` of the tests' ball pair (``standard_rig``),
10 s at 30 records/s along the filter tests' path, 1 px noise stated and
true, 20 % of records with a marker missing, a blind second per camera, 2 %
of records with a detection 30-60 px off (and, a third case, correct logs
without those stray detections).  A new log (seed) per run.  Per
record, the pair's own chi-square (``record_chi2``) fed to ``RigCheck`` at
the default level and, to check that the level is honest, at 1 % and 0.1 %
(the share of full windows above those quantiles on correct logs should be
at most the level).  Cost: ``record_chi2`` per record against
``track_log``'s time per record (which includes it), medians over runs.

    python bench/rig_check.py [--runs 20]

Writes bench/results/rig_check.json.
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

from mutloc.api import load_rig  # noqa: E402
from mutloc.sim.calibration import perturb_rig  # noqa: E402
from mutloc.sim.render import default_path  # noqa: E402
from mutloc.sim.tracking import observation_sequence  # noqa: E402
from mutloc.sim.world import standard_rig  # noqa: E402
from mutloc.track.frames import expanded_rig  # noqa: E402
from mutloc.track.rig_check import RigCheck, record_chi2  # noqa: E402
from mutloc.track.tracker import track_log  # noqa: E402

LEVELS = (1e-2, 1e-3)


def one(seed: int, wrong: bool, timed: bool, strays: float = 0.02) -> dict:
    rig = standard_rig("balls")
    src, tgt = rig.default_pair(None, None)
    seq = observation_sequence(rig, default_path(2.0, 12.0, 0.3), duration=10.0, fps=30.0, pixel_sigma=1.0,
                               seed=seed, outliers=strays)
    use = expanded_rig(load_rig(perturb_rig(rig.to_dict(), np.random.default_rng([seed, 99])))) if wrong else rig
    checks = {"default": RigCheck(), **{str(a): RigCheck(false_alarm=a) for a in LEVELS}}
    first, ratio = None, 0.0
    t0 = time.process_time()
    values = [record_chi2(use, fr, src, tgt, 1.0) for fr in seq.frames]
    t_check = (time.process_time() - t0) / len(seq.frames)
    for k, (c, d) in enumerate(values):
        for name, chk in checks.items():
            t = chk.add(c, d)
            if name == "default" and t is not None and t.full:
                ratio = max(ratio, t.chi2 / t.threshold)
                if first is None and t.disagrees:
                    first = k
    out = {"records": len(seq.frames), "first_flag_record": first, "record_chi2_ms": 1000 * t_check,
           "largest_window_over_threshold": ratio}
    for name, chk in checks.items():
        full = max(chk.records - chk.window + 1, 0)
        out[name] = {"flagged": chk.flagged, "full_windows": full}
    if timed:
        t0 = time.process_time()
        track_log(use, list(zip(seq.times, seq.frames)), progress=False)
        out["track_log_ms_per_record"] = 1000 * (time.process_time() - t0) / len(seq.frames)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--timed-runs", type=int, default=3)
    ap.add_argument("--out", default=result_file("rig_check.json"))
    args = ap.parse_args(argv)
    one(1000, False, True)  # compile outside the figures
    results: dict = {"machine": machine(), "runs": args.runs}
    for label, wrong, strays in (("correct", False, 0.02), ("correct_no_strays", False, 0.0),
                                 ("markers_1_2_cm_off", True, 0.02)):
        runs = [one(seed, wrong, seed < args.timed_runs, strays) for seed in range(args.runs)]
        s = {"records": sum(r["records"] for r in runs),
             "logs_flagged": sum(r["default"]["flagged"] > 0 for r in runs),
             "full_windows": sum(r["default"]["full_windows"] for r in runs),
             "windows_flagged": sum(r["default"]["flagged"] for r in runs),
             "first_flag_record_median": (float(np.median([r["first_flag_record"] for r in runs
                                                           if r["first_flag_record"] is not None]))
                                          if any(r["first_flag_record"] is not None for r in runs) else None),
             "largest_window_over_threshold": max(r["largest_window_over_threshold"] for r in runs),
             "record_chi2_ms_median": float(np.median([r["record_chi2_ms"] for r in runs])),
             "track_log_ms_per_record_median": float(np.median([r["track_log_ms_per_record"] for r in runs
                                                                 if "track_log_ms_per_record" in r]))}
        for a in LEVELS:
            s[f"share_of_windows_above_{a:g}"] = (sum(r[str(a)]["flagged"] for r in runs)
                                                  / max(1, sum(r[str(a)]["full_windows"] for r in runs)))
        results[label] = s
        print(f"{label}: {s['logs_flagged']} of {args.runs} logs flagged, {s['windows_flagged']} of "
              f"{s['full_windows']} full windows (largest window {s['largest_window_over_threshold']:.2f} x its "
              f"threshold); first flag at record {s['first_flag_record_median']} (median); "
              + ", ".join(f"share above the {a:g} level {s[f'share_of_windows_above_{a:g}']:.4f}" for a in LEVELS)
              + f"; record_chi2 {s['record_chi2_ms_median']:.2f} ms/record beside track_log "
              f"{s['track_log_ms_per_record_median']:.2f} ms/record", flush=True)
    Path(args.out).write_text(json.dumps(results, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
