"""What the live localizer's odometry costs (``localizer --odometry``, mutloc
issue 37): per odometry message taken (:meth:`Localizer.receive_odometry`:
checked, rounded as its TUM line, added to the robot's stream) beside an
observation message taken (:meth:`Localizer.receive`: decoded, checked,
held), and the CPU time of a whole run per record with both robots'
odometry beside the same run without it.

Scene: the tests' (tests/test_live_odometry.py): two robots of
:func:`mutloc.sim.team.random_team` moving at up to 0.72 m/s, both cameras
at 30 fps with 1 px noise, 6 s, nothing seen for 2 s; each robot's odometry
at 50 Hz with 1 % / 0.3 deg/m drift.  Each run a new seed (new messages);
the median over ``--runs``.  A first run (not counted) compiles the kernels.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/live_odometry.py [--runs 5]

Writes bench/results/live_odometry.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from _machine import machine, result_file  # noqa: E402

from mutloc.core.pose import Pose  # noqa: E402
from mutloc.io import save_rig  # noqa: E402
from mutloc.live import messages as M  # noqa: E402
from mutloc.live.localizer import Localizer  # noqa: E402
from mutloc.live.odometry import LiveOdometry  # noqa: E402
from mutloc.sim.odometry import drifting_odometry, odometry_times  # noqa: E402
from mutloc.sim.team import TeamScene, random_team, team_motion  # noqa: E402

T0 = 1_800_000_000.0
DURATION, FPS, RATE, GAP, LATENCY = 6.0, 30.0, 50.0, (2.5, 4.5), 0.006
TOPICS = {"r0": "/r0/odom", "r1": "/r1/odom"}


def messages(seed: int, folder: Path):
    team = random_team(2, np.random.default_rng(seed), one_way=0.0)
    at = team_motion(team, seed=seed, amplitude=0.3, speed=0.6, yaw_deg=8.0)
    path = folder / f"rig{seed}.yaml"
    save_rig(team.rig, path)
    rid = M.rig_id(path)
    rng = np.random.default_rng([seed, 77])
    obs_msgs, odo_msgs = [], []
    for k in range(int(DURATION * FPS)):
        t = k / FPS
        obs = TeamScene(team.rig, at(t), team.links, team.max_range).observations(1.0, rng)
        if GAP[0] <= t < GAP[1]:
            obs = obs.take(np.empty(0, np.int64))
        for r in team.names:
            obs_msgs.append((T0 + t + LATENCY, r, M.observations_message(r, rid, k + 1, T0 + t, obs)))
    times = odometry_times(0.0, DURATION, RATE)
    for j, r in enumerate(team.names):
        odo = drifting_odometry(lambda t, r=r: at(t)[r], times, drift_pct=1.0, deg_per_m=0.3, seed=seed, stream=j)
        for t, R, tv in zip(times, odo.R, odo.t):
            odo_msgs.append((T0 + t + LATENCY, r, M.odometry_message(T0 + t, Pose(R, tv), None, r)))
    return path, obs_msgs, odo_msgs


def run(path: Path, obs_msgs, odo_msgs, odometry: bool) -> dict:
    """CPU seconds: the whole run; the messages' receive calls of each kind."""
    loc = Localizer(path, max_coast=3.0, odometry=LiveOdometry(TOPICS) if odometry else None)
    tagged = [(a, "obs", r, m) for a, r, m in obs_msgs] + ([(a, "odo", r, m) for a, r, m in odo_msgs]
                                                          if odometry else [])
    tagged.sort(key=lambda x: x[0])
    spent = {"obs": 0.0, "odo": 0.0}
    start = time.process_time()
    for now, kind, r, msg in tagged:
        while loc.next_due() is not None and loc.next_due() <= now:
            loc.poll(loc.next_due())
        c0 = time.process_time()
        if kind == "odo":
            loc.receive_odometry(r, msg, now)
        else:
            loc.receive(msg, now, r)
        spent[kind] += time.process_time() - c0
        loc.poll(now)
    loc.finish()
    total = time.process_time() - start
    return {"cpu_s": total, "records": loc.records, "receive_obs_us": 1e6 * spent["obs"] / len(obs_msgs),
            "receive_odo_us": 1e6 * spent["odo"] / len(odo_msgs) if odometry else None}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--out", default=result_file("live_odometry.json"))
    args = ap.parse_args()
    info = machine()
    folder = Path(tempfile.mkdtemp())
    path, o, d = messages(1000, folder)
    run(path, o, d, True)  # compiles the kernels
    rows = []
    for k in range(args.runs):
        path, o, d = messages(k + 1, folder)
        with_, without = run(path, o, d, True), run(path, o, d, False)
        rows.append({"seed": k + 1, "with": with_, "without": without})
        print(f"seed {k + 1}: per record {1e3 * with_['cpu_s'] / with_['records']:.2f} ms with odometry, "
              f"{1e3 * without['cpu_s'] / without['records']:.2f} ms without; receive: odometry message "
              f"{with_['receive_odo_us']:.0f} us, observation message {with_['receive_obs_us']:.0f} us", flush=True)

    def med(f):
        return float(np.median([f(r) for r in rows]))

    summary = {
        "per_record_ms_with_odometry": med(lambda r: 1e3 * r["with"]["cpu_s"] / r["with"]["records"]),
        "per_record_ms_without": med(lambda r: 1e3 * r["without"]["cpu_s"] / r["without"]["records"]),
        "receive_odometry_message_us": med(lambda r: r["with"]["receive_odo_us"]),
        "receive_observation_message_us": med(lambda r: r["with"]["receive_obs_us"]),
    }
    info["load_average_at_end"] = list(os.getloadavg())
    print("median over %d runs: per record %.2f ms with odometry (both robots', 50 Hz), %.2f ms without; "
          "taking an odometry message %.0f us, an observation message %.0f us; load %s -> %s"
          % (args.runs, summary["per_record_ms_with_odometry"], summary["per_record_ms_without"],
             summary["receive_odometry_message_us"], summary["receive_observation_message_us"],
             info["load_average_at_start"], info["load_average_at_end"]))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"machine": info, "summary": summary, "runs": rows}, indent=2))


if __name__ == "__main__":
    main()
