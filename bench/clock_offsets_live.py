"""A robot's clock 40 ms off, live: the localizer's ``--clock-offsets estimate`` (mutloc issue 37, "Clock
offsets"; :mod:`mutloc.live.clocks`) -- the online estimate's accuracy over time, and what it costs per
record beside the same localizer without it.

Scene as bench/clock_offsets.py (:func:`mutloc.sim.scenario.write_team_simulation`): two robots, r0 the
reference, ``speed`` 0.7 m/s, both cameras at 30 fps, 1 px noise, ``--seconds`` long (a new scene per
seed); r1's clock ``--offset`` s behind r0's.  Each frame's observations are the message its robot's node
would publish (stamped on its clock), fed in-process to :class:`mutloc.live.localizer.Localizer` (no DDS)
arriving 8 ms after the true capture time; the estimate's work is done after every message (as the wire
loop does it in its slack), with its default windows (4 s of stamps every 10 s; ``--window``, ``--period``).  Three localizers on the
same messages, in the same run: with the estimate, without it, and without it on the synchronized
messages (every robot on the true time).  Per seed: the estimate after each window against the truth;
CPU seconds (``time.process_time``) per message of each, the estimate's work apart; the longest single
step of that work (CPU and wall: what a slice of slack can overrun by); r1's published poses' translation error
(median / p90, cm; the truth interpolated at each pose's stamp) after the first estimate, and how many of
r1's messages were fused.

    .venv/bin/python bench/clock_offsets_live.py [--seeds N] [--seconds S] [--offset S] [--window S] [--period S]

Writes bench/results/clock_offsets_live.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _machine import machine, result_file

from mutloc.api import load_rig
from mutloc.live import messages as M
from mutloc.live.localizer import Localizer
from mutloc.sim.scenario import write_team_simulation
from mutloc.sim.truth_log import truth_log
from mutloc.track.clocks_online import PERIOD, WINDOW
from mutloc.track.frames import expanded_rig

FPS = 30.0
T0 = 1_800_000_000.0
LATENCY = 0.008


def messages(rig_path, truth, seed, clocks=True):
    rid, rig = M.rig_id(rig_path), expanded_rig(load_rig(rig_path))
    offsets = truth.get("clock_offsets", {}) if clocks else {}
    out, frames = [], {}
    for t, obs in truth_log(truth, seed=seed, clocks=clocks):
        for robot in dict.fromkeys(rig.observer(o)[0] for o in obs.observer):
            frames[robot] = frames.get(robot, 0) + 1
            out.append((T0 + t + offsets.get(robot, 0.0) + LATENCY,
                        M.observations_message(robot, rid, frames[robot], T0 + t, obs), robot))
    return sorted(out, key=lambda m: m[0])


def drive(loc, msgs):
    """Feed the messages; returns CPU seconds of the localizer and of the estimate's work, the longest
    step, and the estimate after each window: ``(stamp, offset, sigma)``."""
    cpu_loc = cpu_clock = 0.0
    longest = longest_cpu = 0.0
    history = []
    for now, msg, robot in msgs:
        c0 = time.process_time()
        while loc.next_due() is not None and loc.next_due() <= now:
            loc.poll(loc.next_due())
        loc.feed(msg, now, robot)
        c1 = time.process_time()
        cpu_loc += c1 - c0
        if loc.clock_pending():
            while loc.clock_pending():
                s0, p0 = time.perf_counter(), time.process_time()
                _one_step(loc)
                longest = max(longest, time.perf_counter() - s0)
                longest_cpu = max(longest_cpu, time.process_time() - p0)
            e = loc.clocks.estimate("r1")
            history.append((round(now - T0, 2), e.offset_s, e.sigma_s, e.reason))
        cpu_clock += time.process_time() - c1
    c0 = time.process_time()
    loc.finish()
    cpu_loc += time.process_time() - c0
    return cpu_loc, cpu_clock, (longest, longest_cpu), history


def _one_step(loc):
    """One step of the estimate's work (a clock that says 'time is up' after the first)."""
    calls = [0]

    def clock() -> float:
        calls[0] += 1
        return 0.0 if calls[0] == 1 else 1.0

    loc.clock_work(clock, 0.5)


def errors_cm(poses, truth):
    ts = np.array([f["timestamp"] for f in truth["frames"]])
    xyz = np.array([f["robots"]["r1"]["t"] for f in truth["frames"]])
    e = []
    for p in poses:
        t = p.t - T0
        if p.robot == "r1" and ts[0] <= t <= ts[-1]:
            true = np.array([np.interp(t, ts, xyz[:, i]) for i in range(3)])
            e.append(100 * float(np.linalg.norm(p.estimate.pose.t - true)))
    if not e:
        return {"poses": 0}
    return {"poses": len(e), "median_cm": round(float(np.median(e)), 2), "p90_cm": round(float(np.percentile(e, 90)), 2)}


def run(seed: int, seconds: float, offset: float, settings: dict) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        write_team_simulation(tmp, robots=2, frames=int(seconds * FPS), fps=FPS, seed=seed, images=False,
                              room=False, speed=0.7, clock_offset={"r1": offset})
        truth = json.loads((Path(tmp) / "truth.json").read_text())
        rig_path = Path(tmp) / "rig.yaml"
        out = {"true_offset_s": offset}
        runs = {"estimated": (True, True), "without": (False, True), "synchronized": (False, False)}
        first = None
        for label, (estimate, clocks) in runs.items():
            msgs = messages(rig_path, truth, seed, clocks)
            loc = Localizer(rig_path, reference="r0", clock_offsets=settings if estimate else False)
            loc.warm_up()
            poses = []
            orig_feed, orig_poll = loc.feed, loc.poll

            def feed(msg, now, topic, _f=orig_feed, poses=poses):
                got = _f(msg, now, topic)
                poses.extend(got)
                return got

            def poll(now, clock=None, _p=orig_poll, poses=poses):
                got = _p(now, clock)
                poses.extend(got)
                return got

            loc.feed, loc.poll = feed, poll
            cpu_loc, cpu_clock, longest, history = drive(loc, msgs)
            n = len(msgs)
            r = {"messages": n, "records": loc.records, "r1_fused": loc.counts["r1"].fused,
                 "r1_received": loc.counts["r1"].received,
                 "cpu_ms_per_message": round(1000 * cpu_loc / n, 3)}
            if estimate:
                first = history[0][0] if history else None
                e = loc.clocks.estimate("r1")
                r.update(clock_cpu_ms_per_message=round(1000 * cpu_clock / n, 3),
                         longest_step_ms=round(1000 * longest[0], 1), longest_step_cpu_ms=round(1000 * longest[1], 1),
                         windows=history,
                         steps=loc.clocks.estimator.steps, offset_s=e.offset_s, sigma_s=e.sigma_s, reason=e.reason)
                if e.offset_s is not None:
                    r["error_ms"] = round(1000 * (e.offset_s - offset), 2)
                    r["error_over_sigma"] = round((e.offset_s - offset) / e.sigma_s, 2)
            after = [p for p in poses if first is not None and p.t - T0 > first]
            r["r1_error_after_first_estimate"] = errors_cm(after, truth)
            out[label] = r
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=32.0)
    ap.add_argument("--offset", type=float, default=0.04)
    ap.add_argument("--window", type=float, default=WINDOW, help="seconds of stamps per window")
    ap.add_argument("--period", type=float, default=PERIOD, help="seconds from one window's start to the next's")
    args = ap.parse_args()
    settings = {"window": args.window, "period": args.period}
    out = {"machine": machine(), "seconds": args.seconds, "offset_s": args.offset, **settings, "runs": {}}
    for seed in range(args.seeds):
        r = out["runs"][seed] = run(seed, args.seconds, args.offset, settings)
        e = r["estimated"]
        est = (f"{1000 * e['offset_s']:.1f} ms +- {1000 * e['sigma_s']:.1f} (error {e['error_ms']:+.1f} ms, "
               f"{e['error_over_sigma']:+.1f} sigma)" if e["offset_s"] is not None else f"undetermined: {e['reason']}")
        wins = ", ".join(f"{t:.0f} s: " + (f"{1000 * o:.1f}" if o is not None else f"- ({why})")
                         for t, o, _, why in e["windows"])
        print(f"seed {seed}: offset {est}; after each window (ms) {wins}", flush=True)
        print("  cpu ms/message: " + "; ".join(f"{k} {r[k]['cpu_ms_per_message']}" for k in
                                                ("estimated", "without", "synchronized"))
              + f"; the estimate's work {e['clock_cpu_ms_per_message']} (longest step {e['longest_step_cpu_ms']} ms CPU, "
              f"{e['longest_step_ms']} ms wall)",
              flush=True)
        print("  r1 fused/received: " + "; ".join(f"{k} {r[k]['r1_fused']}/{r[k]['r1_received']}" for k in
                                                  ("estimated", "without", "synchronized"))
              + "; r1 median / p90 cm after the first estimate: "
              + "; ".join(f"{k} {r[k]['r1_error_after_first_estimate'].get('median_cm')} / "
                          f"{r[k]['r1_error_after_first_estimate'].get('p90_cm')}"
                          for k in ("estimated", "without", "synchronized")), flush=True)
    path = Path(result_file("clock_offsets_live.json" if settings == {"window": WINDOW, "period": PERIOD}
                            else f"clock_offsets_live_w{args.window:g}_p{args.period:g}.json"))
    path.write_text(json.dumps(out, indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
