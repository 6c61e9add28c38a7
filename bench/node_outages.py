#!/usr/bin/env python
"""A node killed and restarted 20 times during a run (issue 38): what the
localizer publishes while one robot's camera is gone, and whether any of it
is a confident wrong pose.

The localizer (:class:`mutloc.live.localizer.Localizer`, the class ``mutloc
localizer`` runs) is fed in this process, without DDS, the observation
messages two nodes would send: both robots' cameras at 30 fps (q's half a
frame after p's), 1 px noise, p driving the default figure in front of q
(``mutloc.sim.tracking.camera_records``), each message arriving 8 ms after
its capture.  Twenty times during the run q's node is "killed": its messages
stop for 0.5-4 s (uniform; a restarted node takes seconds to start) and then
resume, as a restarted node's would.  The rig: ``mutloc simulate``'s, two
balls per robot (one camera's frame alone never fixes the pose: every record
is ``partial``, the two cameras' records together fix it); with the rig file
right, and with every marker of the rig file 1-2 cm off the true positions
(as measured by hand; the pixels are those of the true markers).

Counted over every pose the localizer returns for publishing: poses beyond
5 sigma of their own published covariance (NEES above chi2_6's two-sided
5-sigma quantile, 39.5), by status; the error and sigma of the poses published
while q's node is down; what ``/diagnostics`` said for q then (OK / WARN /
STALE), and for the wrong rig, whether anything said so (a status, a
diagnostics message); the rows held back waiting for the rig check's first
window (mutloc.live.rig_gate) and when the first pose was published.  A new log (seed) per run.  Beside it, in the same run,
the rule switched off (every measured row published, as before the rule:
``TieWindow.tied`` made to tie every robot).

    python bench/node_outages.py [--runs 5] [--seconds 90]

Writes bench/results/node_outages.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402

from mutloc.core.geometry import so3_log  # noqa: E402
from mutloc.io import load_rig, save_rig  # noqa: E402
from mutloc.live import messages as M  # noqa: E402
from mutloc.live.localizer import Localizer  # noqa: E402
from mutloc.sim.calibration import perturb_rig  # noqa: E402
from mutloc.sim.tracking import camera_records  # noqa: E402
from mutloc.sim.world import standard_rig  # noqa: E402

T0 = 1_800_000_000.0
LATENCY = 0.008
FIVE_SIGMA_NEES = 39.5  # chi2_6 at the two-sided 5-sigma tail (5.7e-7)
OUTAGES = 20
LEVELS = {M.OK: "OK", M.WARN: "WARN", M.ERROR: "ERROR", M.STALE: "STALE"}


def outages(seconds: float, rng: np.random.Generator) -> list[tuple[float, float]]:
    """``OUTAGES`` stretches (start, end) spread over the run, 0.5-4 s each, after a 3 s start."""
    slot = (seconds - 3.0) / OUTAGES
    out = []
    for k in range(OUTAGES):
        length = rng.uniform(0.5, min(4.0, 0.8 * slot))
        start = 3.0 + k * slot + rng.uniform(0.0, slot - length)
        out.append((start, start + length))
    return out


def nees(est, truth) -> float:
    """The pose error's NEES against its covariance (SPEC perturbation: rotation first, then translation)."""
    e = np.concatenate([so3_log(est.R @ truth.R.T), est.t - truth.t])
    return float(e @ np.linalg.solve(est.covariance, e))


def one(wrong: bool, seed: int, seconds: float, folder: Path, rule: bool = True) -> dict:
    rig = standard_rig("balls")
    recs = camera_records(rig, duration=seconds, offsets={"q": 1 / 60}, pixel_sigma=1.0, seed=seed)
    rng = np.random.default_rng([seed, 7])
    path = folder / f"rig-{seed}-{int(wrong)}.yaml"
    if wrong:
        save_rig(load_rig(perturb_rig(rig.to_dict(), np.random.default_rng([seed, 99]))), path)
    else:
        save_rig(rig, path)
    rid = M.rig_id(path)
    down = outages(seconds, rng)

    def is_down(t: float) -> bool:
        return any(a <= t < b for a, b in down)

    msgs, frames = [], Counter()
    for t, obs, cams in zip(recs.times, recs.frames, recs.cameras):
        for c in cams:
            frames[c] += 1
            if c == "q" and is_down(t):
                continue
            msgs.append((T0 + t + LATENCY, M.observations_message(c, rid, frames[c], T0 + t, obs), c))
    loc = Localizer(path)
    if not rule:
        loc.ties.tied = lambda t, counts=None: set(loc.tracked)
    poses = []
    q_levels, p_levels = Counter(), Counter()
    next_diag = T0
    for now, msg, topic in msgs:
        while loc.next_due() is not None and loc.next_due() <= now:
            poses += loc.poll(loc.next_due())
        poses += loc.feed(msg, now, topic)
        if now >= next_diag:  # /diagnostics once a second, as the localizer publishes it
            level = {s.robot: s.level for s in loc.diagnostics(now)}.get("q")
            q_levels[("down" if is_down(now - T0) else "up", int(level))] += 1
            p_levels[("down" if is_down(now - T0) else "up", int({s.robot: s.level for s in loc.diagnostics(now)}["p"]))] += 1
            next_diag = now + 1.0
    poses += loc.finish()
    truth_of = {round(float(t), 6): T for t, T in zip(recs.times, recs.truth)}
    rows = []
    for p in poses:
        t = round(p.t - T0, 6)
        T = truth_of.get(t)
        if T is None:
            continue
        err = float(np.linalg.norm(p.estimate.t - T.t))
        rows.append({"t": t, "status": str(p.status), "nees": nees(p.estimate, T), "err_m": err,
                     "sigma_m": float(np.sqrt(np.trace(p.estimate.covariance[3:, 3:]))), "down": is_down(t)})
    beyond = [r for r in rows if r["nees"] > FIVE_SIGMA_NEES]
    gate = loc.rig_gate
    # the wait for the rig check (mutloc.live.rig_gate): from the first pose it held back to the first published
    first_held = None if gate.first_held is None else gate.first_held - T0
    first_pose = min((r["t"] for r in rows), default=None)
    during = [r for r in rows if r["down"]]
    statuses = Counter(r["status"] for r in rows)
    return {"poses": len(rows), "statuses": dict(statuses), "beyond_5_sigma": len(beyond),
            "beyond_by_status": dict(Counter(r["status"] for r in beyond)),
            "beyond_worst_err_m": max((r["err_m"] for r in beyond), default=None),
            "down_poses": len(during),
            "down_err_m_median": float(np.median([r["err_m"] for r in during])) if during else None,
            "down_err_m_max": max((r["err_m"] for r in during), default=None),
            "down_sigma_m_median": float(np.median([r["sigma_m"] for r in during])) if during else None,
            "up_err_m_median": float(np.median([r["err_m"] for r in rows if not r["down"]]))
            if any(not r["down"] for r in rows) else None,
            "q_diagnostics": {f"{k[0]}:{LEVELS[k[1]]}": v for k, v in sorted(q_levels.items())},
            "p_diagnostics": {f"{k[0]}:{LEVELS[k[1]]}": v for k, v in sorted(p_levels.items())},
            "outage_seconds": float(sum(b - a for a, b in down)),
            "rig_waiting": sum(c.rig_waiting for c in loc.counts.values()), "rig_state": gate.state,
            "first_held_s": first_held, "first_pose_s": first_pose,
            "wait_s": None if first_held is None or first_pose is None else first_pose - first_held}


def _cm_median(values: list) -> float:
    """The median of the values given (metres) in centimetres (nan: none given: no pose published)."""
    values = [v for v in values if v is not None]
    return 100 * float(np.median(values)) if values else float("nan")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=90.0)
    ap.add_argument("--out", default=result_file("node_outages.json"))
    args = ap.parse_args(argv)
    results: dict = {"machine": machine(), "runs": args.runs, "seconds": args.seconds, "outages_per_run": OUTAGES}
    with tempfile.TemporaryDirectory() as d:
        for wrong, rule in ((False, True), (False, False), (True, True), (True, False)):
            label = f"rig {'1-2 cm off' if wrong else 'right'}, {'tie rule' if rule else 'rule off (before)'}"
            runs = [one(wrong, seed, args.seconds, Path(d), rule) for seed in range(args.runs)]
            s = {"poses": sum(r["poses"] for r in runs),
                 "beyond_5_sigma": sum(r["beyond_5_sigma"] for r in runs),
                 "beyond_by_status": dict(sum((Counter(r["beyond_by_status"]) for r in runs), Counter())),
                 "statuses": dict(sum((Counter(r["statuses"]) for r in runs), Counter())),
                 "down_poses": sum(r["down_poses"] for r in runs),
                 "down_err_cm_median": _cm_median([r["down_err_m_median"] for r in runs]),
                 "down_err_cm_max": 100 * max(r["down_err_m_max"] or 0.0 for r in runs),
                 "down_sigma_cm_median": _cm_median([r["down_sigma_m_median"] for r in runs]),
                 "up_err_cm_median": _cm_median([r["up_err_m_median"] for r in runs]),
                 "q_diagnostics": dict(sum((Counter(r["q_diagnostics"]) for r in runs), Counter())),
                 "p_diagnostics": dict(sum((Counter(r["p_diagnostics"]) for r in runs), Counter())),
                 "rig_waiting": sum(r["rig_waiting"] for r in runs),
                 "first_pose_s": [r["first_pose_s"] for r in runs], "wait_s": [r["wait_s"] for r in runs],
                 "per_run": runs}
            results[label] = s
            print(f"{label}: {s['beyond_5_sigma']} of {s['poses']} published poses beyond 5 sigma "
                  f"{s['beyond_by_status']}; statuses {s['statuses']}; while q's node is down: "
                  f"{s['down_poses']} poses, error median {s['down_err_cm_median']:.2f} cm (max "
                  f"{s['down_err_cm_max']:.1f} cm), sigma median {s['down_sigma_cm_median']:.2f} cm; "
                  f"diagnostics once a second: q {s['q_diagnostics']}, p {s['p_diagnostics']}; waiting for the "
                  f"rig check: {s['rig_waiting']} rows held back, first pose at "
                  f"{[None if x is None else round(x, 2) for x in s['first_pose_s']]} s "
                  f"(waited {[None if x is None else round(x, 2) for x in s['wait_s']]} s)", flush=True)
    Path(args.out).write_text(json.dumps(results, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
