#!/usr/bin/env python
"""The rig check's window test (mutloc.track.rig_check, issue 38) as the
team tracker runs it -- ``track`` for a pair and for a team, and the live
localizer: how often it raises on a correct rig with honest noise (false
alarms), how soon it raises on a rig whose markers are 1-2 cm off
(detection), and what feeding it costs.

The tracker feeds the test each record's observations fitted on their own:
its joint solve's chi-square when the record had one (a robot started), else
the sum of its filter updates' own residuals (``TeamUpdate.own``, accepted
or rejected by the gate).  The baseline, measured in the same run on the
same logs: each record refitted on its own by ``localize`` (what the pair
tracker's hook did before, ``baseline_record_chi2`` below), fed to a test at
the same defaults.

Logs (a new seed per run):

- ``pair``: ``observation_sequence`` of the tests' ball pair
  (``standard_rig("balls")``), 10 s at 30 records/s along the filter tests'
  path, 1 px noise stated and true, 20 % of records with a marker missing, a
  blind second per camera, 2 % of records with a detection 30-60 px off (and,
  a case of its own, correct logs without those stray detections);
- ``team``: three robots (``random_team``, some pairs seen one way), every
  camera at 30 fps at its own phase (``team_camera_records``: a record is one
  camera's frame, as the localizer gets them), 10 s, 1 px noise.

Wrong rigs: every marker moved 1-2 cm in a random direction
(``perturb_rig``).  Per case: logs flagged, full windows that disagreed,
the largest window over its threshold, the first flagged record (median,
and in seconds of the log), and the share of full windows above the 1 % and
0.1 % quantiles (the values the tracker fed recorded and tested again at
those levels: on correct logs it should be at most the level).  Cost: the
track's CPU time per record (medians of the timed runs) beside the
baseline's refit per record.

    python bench/rig_check.py [--runs 20] [--team-runs 10]

Writes bench/results/rig_check.json.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402

from mutloc.api import load_rig, localize  # noqa: E402
from mutloc.errors import MutlocError  # noqa: E402
from mutloc.sim.calibration import perturb_rig  # noqa: E402
from mutloc.sim.render import default_path  # noqa: E402
from mutloc.sim.team import random_team, team_camera_records  # noqa: E402
from mutloc.sim.tracking import observation_sequence  # noqa: E402
from mutloc.sim.world import standard_rig  # noqa: E402
from mutloc.track import rig_check as rc  # noqa: E402
from mutloc.track.frames import expanded_rig  # noqa: E402
from mutloc.track.team import track_team_log  # noqa: E402
from mutloc.track.tracker import track_log  # noqa: E402

LEVELS = (1e-2, 1e-3)


def baseline_record_chi2(rig, observations, source, target, pixel_sigma):
    """A pair's record refitted on its own by ``localize`` (every observation kept): ``(chi2, dof)``."""
    obs = observations.best() if observations.has_alternatives else observations
    if len(obs) < 4:
        return math.nan, 0
    try:
        est = localize(rig, obs, source=source, target=target, pixel_sigma=pixel_sigma, confidence=1.0)
    except MutlocError:
        return math.nan, 0
    c = est.consistency
    return (float(c.chi2), int(c.dof)) if c is not None else (math.nan, 0)


class Recorded(rc.RigCheck):
    """The tracker's RigCheck, recording what it is fed (to test it again at other levels)."""

    fed: list = []

    def add(self, chi2, dof):
        Recorded.fed.append((chi2, dof))
        return super().add(chi2, dof)


def _scored(values, times):
    """The window test at the default level and at LEVELS over ``values`` (per record ``(chi2, dof)``)."""
    checks = {"default": rc.RigCheck(), **{str(a): rc.RigCheck(false_alarm=a) for a in LEVELS}}
    first, ratio = None, 0.0
    for k, (c, d) in enumerate(values):
        for name, chk in checks.items():
            t = chk.add(c, d)
            if name == "default" and t is not None and t.full and d > 0:
                ratio = max(ratio, t.chi2 / t.threshold)
                if first is None and t.disagrees:
                    first = k
    out = {"first_flag_record": first, "first_flag_s": None if first is None else float(times[first] - times[0]),
           "largest_window_over_threshold": ratio}
    for name, chk in checks.items():
        out[name] = {"flagged": chk.flagged, "full_windows": max(chk.records - chk.window + 1, 0)}
    return out


def pair_log(seed: int, wrong: bool, strays: float):
    rig = standard_rig("balls")
    seq = observation_sequence(rig, default_path(2.0, 12.0, 0.3), duration=10.0, fps=30.0, pixel_sigma=1.0,
                               seed=seed, outliers=strays)
    use = expanded_rig(load_rig(perturb_rig(rig.to_dict(), np.random.default_rng([seed, 99])))) if wrong else rig
    return use, list(zip(seq.times, seq.frames))


def team_log(seed: int, wrong: bool):
    scene = random_team(3, np.random.default_rng([seed, 7]), one_way=0.3)
    recs = team_camera_records(scene, 10.0, sigma=1.0, seed=seed)
    use = load_rig(perturb_rig(scene.rig.to_dict(), np.random.default_rng([seed, 99]))) if wrong else scene.rig
    return use, [(t, o) for t, _, _, o in recs]


def one(kind: str, seed: int, wrong: bool, strays: float = 0.02) -> dict:
    rig, records = pair_log(seed, wrong, strays) if kind == "pair" else team_log(seed, wrong)
    times = np.array([t for t, _ in records])
    Recorded.fed = []
    t0 = time.process_time()
    if kind == "pair":
        traj = track_log(rig, records, progress=False)
        rows = traj.rows
    else:
        traj = track_team_log(rig, records, progress=False)
        rows = [row for tr in traj.tracks.values() for row in tr.rows]
    t_track = (time.process_time() - t0) / len(records)
    fed = list(Recorded.fed)  # (one per record; records filtered again after an undo fed again)
    out = {"records": len(records), "track_ms_per_record": 1000 * t_track,
           "rows_flagged": sum(rc.RIG_HINT in r.reason for r in rows), "rows": len(rows),
           "hint": bool(traj.notes), "team": _scored(fed, times)}
    if kind == "pair":
        src, tgt = rig.default_pair(None, None)
        t0 = time.process_time()
        base = [baseline_record_chi2(rig, obs, src, tgt, 1.0) for _, obs in records]
        out["baseline_ms_per_record"] = 1000 * (time.process_time() - t0) / len(records)
        out["baseline"] = _scored(base, times)
    return out


def summary(runs: list[dict], key: str) -> dict:
    rs = [r[key] for r in runs]
    firsts = [r["first_flag_record"] for r in rs if r["first_flag_record"] is not None]
    secs = [r["first_flag_s"] for r in rs if r["first_flag_s"] is not None]
    s = {"logs_flagged": sum(r["default"]["flagged"] > 0 for r in rs),
         "full_windows": sum(r["default"]["full_windows"] for r in rs),
         "windows_flagged": sum(r["default"]["flagged"] for r in rs),
         "first_flag_record_median": float(np.median(firsts)) if firsts else None,
         "first_flag_record_max": int(max(firsts)) if firsts else None,
         "first_flag_s_median": float(np.median(secs)) if secs else None,
         "first_flag_s_max": float(max(secs)) if secs else None,
         "largest_window_over_threshold": max(r["largest_window_over_threshold"] for r in rs)}
    for a in LEVELS:
        s[f"share_of_windows_above_{a:g}"] = (sum(r[str(a)]["flagged"] for r in rs)
                                              / max(1, sum(r[str(a)]["full_windows"] for r in rs)))
    return s


def line(label: str, s: dict) -> str:
    return (f"{label}: {s['logs_flagged']} logs flagged, {s['windows_flagged']} of {s['full_windows']} full windows "
            f"(largest {s['largest_window_over_threshold']:.2f} x its threshold); first flag at record "
            f"{s['first_flag_record_median']} (median; max {s['first_flag_record_max']}) = "
            f"{s['first_flag_s_median']} s (max {s['first_flag_s_max']}); "
            + ", ".join(f"above the {a:g} level {s[f'share_of_windows_above_{a:g}']:.4f}" for a in LEVELS))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20, help="pair logs per case")
    ap.add_argument("--team-runs", type=int, default=10, help="team logs per case")
    ap.add_argument("--out", default=result_file("rig_check.json"))
    args = ap.parse_args(argv)
    rc_original = rc.RigCheck
    import mutloc.track.team_tracker as tt

    tt.RigCheck = Recorded  # the tracker's check records what it is fed
    try:
        one("pair", 1000, False)  # compile outside the figures
        one("team", 1000, False)
        results: dict = {"machine": machine(), "runs": args.runs, "team_runs": args.team_runs}
        cases = [("pair_correct", "pair", False, 0.02), ("pair_correct_no_strays", "pair", False, 0.0),
                 ("pair_markers_1_2_cm_off", "pair", True, 0.02), ("team_correct", "team", False, 0.0),
                 ("team_markers_1_2_cm_off", "team", True, 0.0)]
        for label, kind, wrong, strays in cases:
            n = args.runs if kind == "pair" else args.team_runs
            runs = [one(kind, seed, wrong, strays) for seed in range(n)]
            s = {"records": sum(r["records"] for r in runs), "team_path": summary(runs, "team"),
                 "logs_with_the_hint": sum(r["hint"] for r in runs),
                 "rows_flagged": sum(r["rows_flagged"] for r in runs), "rows": sum(r["rows"] for r in runs),
                 "track_ms_per_record_median": float(np.median([r["track_ms_per_record"] for r in runs]))}
            print(line(f"{label} (team path)", s["team_path"]), f"; hint in {s['logs_with_the_hint']} of {n} logs, "
                  f"{s['rows_flagged']} of {s['rows']} rows flagged; track {s['track_ms_per_record_median']:.2f} "
                  "ms/record", flush=True)
            if kind == "pair":
                s["baseline"] = summary(runs, "baseline")
                s["baseline_ms_per_record_median"] = float(np.median([r["baseline_ms_per_record"] for r in runs]))
                print(line(f"{label} (baseline: each record refitted)", s["baseline"]),
                      f"; {s['baseline_ms_per_record_median']:.2f} ms/record", flush=True)
            results[label] = s
    finally:
        tt.RigCheck = rc_original
    results["load_average_at_end"] = list(__import__("os").getloadavg())
    Path(args.out).write_text(json.dumps(results, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
