#!/usr/bin/env python
"""The live localizer's cost and latency over DDS (issue 25: ten robots'
observations at 30 Hz each, the localizer <= 30% of one core).

    python bench/bench_localizer.py                        # 10 robots, then 2, 30 Hz, 10 s each
    python bench/bench_localizer.py --robots 10 --seconds 5
    python bench/bench_localizer.py --robots 10 --stalled stop idle  # also with a stalled subscriber

For each team size: ``mutloc localizer --loopback`` runs as its own process
on a DDS domain of this run; this process publishes every robot's
``Observations`` as its node would (simulated free-running cameras at
``--rate`` frames/s, each camera at its own phase; stamps are the wall-clock
time of capture, each message published at its stamp) and subscribes to
every pose topic.  Measured:

- the localizer's CPU time (user + system, /proc) over the streaming window,
  as a share of one core;
- message-in -> pose-out latency: a pose's arrival here minus the
  publication of the message it was fused from (same stamp): DDS both ways,
  the reorder buffer's wait, the fusion and the publication; and, with
  ``--load``, the same to the pose's writing by the localizer (its DDS
  source timestamp: the localizer's own latency, without this process's
  delay in taking the poses when it is itself behind);
- poses received against the poses expected (one per message per tracked
  robot it is about: its observer, the robots it saw), and whether a
  backlog grew (latency over the last second);
- in-process, without DDS: CPU per message of the tracker and of the rest
  of the localizer (decode, checks, pose messages);
- with ``--stalled stop idle``: the same again with another process
  subscribed to every pose topic and /tf with ROS 2's default QoS that stops
  (SIGSTOP) once matched (``stop``), or that never takes a sample
  (``idle``: its DDS threads still receive and acknowledge), and that
  process's own CPU.

With ``--load idle hog`` (``--runs 3``): the run over DDS idle and beside
a CPU hog (another process keeping one core busy for the whole run), each
``--runs`` times, reporting also p99 over the whole run and its second
half, poses received per message sent, error against the simulator's
truth (median, p90) and the messages the localizer shed; medians over the
runs and the load average before and after each.

Writes bench/results/localizer_results.json (with the machine and its load).
Functions :func:`over_dds` and :func:`in_process` are what bench_live.py may call.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mutloc.io import save_rig
from mutloc.live import messages as M

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import cpu_hog, dds_domain, load_now, machine, result_file  # noqa: E402


def streams(robots: int, seconds: float, rate: float, seed: int = 0, truth: bool = False):
    """``(rig, [(time, robot, ObservationSet)])``: every camera at ``rate`` at its own phase (``truth``: also
    ``{robot: f(time) -> its true pose in the reference's frame}``)."""
    if truth:
        return _streams_with_truth(robots, seconds, rate, seed)
    if robots == 2:
        from mutloc.sim.tracking import camera_records
        from mutloc.sim.world import standard_rig

        rig = standard_rig()
        recs = camera_records(rig, duration=seconds, rates={"p": rate, "q": rate}, offsets={"q": 0.5 / rate},
                              pixel_sigma=1.0, seed=seed)
        return rig, [(float(t), c[0], obs) for t, obs, c in zip(recs.times, recs.frames, recs.cameras)]
    from mutloc.sim.team import random_team, team_camera_records

    scene = random_team(robots, np.random.default_rng(seed), one_way=0.0)
    recs = team_camera_records(scene, seconds, fps=rate, sigma=1.0, seed=seed)
    return scene.rig, [(float(t), a, obs) for t, a, _, obs in recs]


def _streams_with_truth(robots: int, seconds: float, rate: float, seed: int):
    if robots == 2:
        from mutloc.sim.tracking import camera_records
        from mutloc.sim.world import standard_rig

        rig = standard_rig()
        recs = camera_records(rig, duration=seconds, rates={"p": rate, "q": rate}, offsets={"q": 0.5 / rate},
                              pixel_sigma=1.0, seed=seed)
        times = np.asarray(recs.times)

        def p_in_q(t):
            return recs.truth[int(np.argmin(np.abs(times - t)))]
        return rig, [(float(t), c[0], obs) for t, obs, c in zip(recs.times, recs.frames, recs.cameras)], {"p": p_in_q}
    from mutloc.sim.team import random_team, team_camera_records

    scene = random_team(robots, np.random.default_rng(seed), one_way=0.0)
    recs = team_camera_records(scene, seconds, fps=rate, sigma=1.0, seed=seed)
    names = list(scene.rig.robots)
    times = np.array([float(t) for t, _, _, _ in recs])

    def in_ref(r, t):
        world = recs[int(np.argmin(np.abs(times - t)))][2]
        return world[names[0]].inverse() @ world[r]
    truth = {r: (lambda t, r=r: in_ref(r, t)) for r in names[1:]}
    return scene.rig, [(float(t), a, obs) for t, a, _, obs in recs], truth


def _grouped(published: dict, key: int, tolerance_us: int = 5000) -> float:
    """A pose of a record of several messages (stamps within the localizer's
    --tolerance, the record at their mean): the latest publication of those
    messages (the record is fused once the last arrived)."""
    near = [p for k, p in published.items() if abs(k - key) <= tolerance_us]
    return max(near) if near else np.nan


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def over_dds(robots: int = 10, rate: float = 30.0, seconds: float = 10.0, seed: int = 0, stalled: str = "",
             written: bool = False) -> dict:
    """One run of ``mutloc localizer`` over DDS loopback (see the module docstring).  ``stalled``
    "stop": with another process subscribed to every pose topic and /tf (ROS 2's default QoS) that
    stops (SIGSTOP) once matched; "idle": one that never takes a sample.  ``written``: the localizer
    writes its files (``--out``), so its smoother runs."""
    from cyclonedds.core import Policy, Qos
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from mutloc.live.dds import Bus

    rig, frames, truth = streams(robots, seconds + 1.0, rate, seed, truth=True)
    tmp = Path(tempfile.mkdtemp(prefix="bench_localizer_"))
    path = tmp / "rig.yaml"
    save_rig(rig, path)
    rid = M.rig_id(path)
    names = list(rig.robots)
    reference = names[1] if robots == 2 else names[0]
    tracked = [n for n in names if n != reference]
    lease = dds_domain()  # held until this run ends (its localizer and subscribers on it)
    domain = lease.domain
    cmd = [sys.executable, "-m", "mutloc", "localizer", "--rig", str(path), "--domain", str(domain), "--loopback",
           "--duration", str(seconds + 30), *(["--out", str(tmp / "out")] if written else [])]
    child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    children: list = []
    try:
        line = child.stderr.readline()
        if not line.startswith("localizer:"):
            raise RuntimeError(line + child.stderr.read())
        if stalled:
            topics = [M.pose_topic(r, reference) for r in tracked] + [M.TF_TOPIC]
            slow = subprocess.Popen([sys.executable, str(Path(__file__).resolve().parent / "_stalled_subscriber.py"),
                                     str(domain), stalled, *topics], stdout=subprocess.PIPE, text=True,
                                    start_new_session=True)
            children.append(slow)
            if slow.stdout.readline().strip() != "matched":
                raise RuntimeError("the stalled subscriber did not match the localizer's writers")
        bus = Bus(domain, loopback=True)
        T = M.ros_types()
        writers = {r: bus.writer(M.observations_topic(r), T.Observations) for r in names}

        qos = Qos(Policy.Reliability.Reliable(max_blocking_time=100_000_000), Policy.Durability.Volatile,
                  Policy.History.KeepLast(10000))
        readers = {r: DataReader(bus.participant, Topic(bus.participant, f"rt/mutloc/{r}_in_{reference}",
                                                        T.PoseWithCovarianceStamped), qos=qos) for r in tracked}
        deadline = time.time() + 20
        while time.time() < deadline and not all(w.get_matched_subscriptions() for w in writers.values()):
            time.sleep(0.05)
        time.sleep(0.5)
        published: dict[tuple[str, int], float] = {}
        arrivals: list[tuple[float, float]] = []  # (pose arrival, its message's publication)
        writes: list[tuple[float, float]] = []  # (pose written by the localizer: its source timestamp, publication)
        errors: list[float] = []  # translation error (m) of each pose against the truth at its stamp

        def take() -> None:
            now = time.time()
            for r, rd in readers.items():
                for s in rd.take(N=1000):
                    if hasattr(s, "header"):
                        key = round(M.stamp_of(s.header) * 1e6)
                        pub = published.get(key, np.nan) if key in published else _grouped(published, key)
                        arrivals.append((now, pub))
                        info = getattr(s, "sample_info", None)
                        if info is not None and getattr(info, "source_timestamp", 0) > 0:
                            writes.append((info.source_timestamp * 1e-9, pub))
                        x = s.pose.pose.position
                        true = truth[r](M.stamp_of(s.header) - start)
                        errors.append(float(np.linalg.norm(np.array([x.x, x.y, x.z]) - true.t)))

        start = time.time() + 0.3
        warm = 1.0  # the first second: the tracks start; not measured
        cpu0 = wall0 = None
        sent = expected = 0
        for k, (t, robot, obs) in enumerate(frames):
            while time.time() < start + t:
                take()
                time.sleep(0.0005)
            if cpu0 is None and t >= warm:
                cpu0, wall0 = _cpu_seconds(child.pid), time.time()
                slow_cpu0 = _cpu_seconds(children[0].pid) if stalled else 0.0
            stamp = start + t
            msg = M.observations_message(robot, rid, k, stamp, obs)
            published[round(M.stamp_of(msg.header) * 1e6)] = time.time()
            writers[robot].write(msg)
            if t >= warm:
                sent += 1
                expected += 1 if robots == 2 else len({robot, *(rig.owner(m) for m in obs.marker)} - {reference})
        cpu1, wall1 = _cpu_seconds(child.pid), time.time()
        slow_cpu = _cpu_seconds(children[0].pid) - slow_cpu0 if stalled else None
        end = time.time()
        while time.time() < end + 1.0:
            take()
            time.sleep(0.005)
    finally:
        for c in children:
            os.killpg(c.pid, 9)
            c.wait()
        if child.poll() is None:
            os.killpg(child.pid, 2)
            try:
                child.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(child.pid, 9)
                child.wait()
        lease.release()
    summary = (child.stderr.read() or "").strip().splitlines()[-1:]
    measured = [(a, p) for a, p in arrivals if p >= wall0 and np.isfinite(p)]
    lat = np.array([a - p for a, p in measured]) * 1000
    last = np.array([a - p for a, p in measured if p > wall1 - 1.0]) * 1000
    half = np.array([a - p for a, p in measured if p > (wall0 + wall1) / 2]) * 1000
    out = [(a, p) for a, p in writes if p >= wall0 and np.isfinite(p)]
    wlat = np.array([a - p for a, p in out]) * 1000
    whalf = np.array([a - p for a, p in out if p > (wall0 + wall1) / 2]) * 1000
    said = summary[0] if summary else ""
    import re

    shed = re.search(r"shed (\d+)", said)
    unsmoothed = re.search(r"(\d+) records? written unsmoothed", said)
    err = np.array(errors[len(errors) // 10:]) * 100  # (the tracks' start left out)
    return {"robots": robots, "rate_hz": rate, "seconds": round(wall1 - wall0, 2), "messages": sent,
            "cpu_share_of_one_core": round((cpu1 - cpu0) / (wall1 - wall0), 3),
            "latency_ms_p50": round(float(np.percentile(lat, 50)), 1) if len(lat) else None,
            "latency_ms_p99": round(float(np.percentile(lat, 99)), 1) if len(lat) else None,
            "latency_ms_p50_last_second": round(float(np.percentile(last, 50)), 1) if len(last) else None,
            "latency_ms_p99_second_half": round(float(np.percentile(half, 99)), 1) if len(half) else None,
            "latency_ms_p50_second_half": round(float(np.percentile(half, 50)), 1) if len(half) else None,
            # message published -> its pose written by the localizer (the pose's DDS source timestamp, same
            # clock): the localizer's own latency, without this process's delay in taking the poses
            "written_ms_p50": round(float(np.percentile(wlat, 50)), 1) if len(wlat) else None,
            "written_ms_p99": round(float(np.percentile(wlat, 99)), 1) if len(wlat) else None,
            "written_ms_p99_second_half": round(float(np.percentile(whalf, 99)), 1) if len(whalf) else None,
            "bench_send_seconds": round(wall1 - wall0, 2),
            "poses_per_expected": round(len(measured) / expected, 3) if expected else None,
            "error_cm_median": round(float(np.median(err)), 2) if len(err) else None,
            "error_cm_p90": round(float(np.percentile(err, 90)), 2) if len(err) else None,
            "shed": int(shed.group(1)) if shed else None, "files_written": written,
            "records_unsmoothed": int(unsmoothed.group(1)) if unsmoothed else (0 if written else None),
            "poses_received": len(measured), "poses_expected": expected,
            **({"stalled_subscriber": stalled, "its_cpu_share_of_one_core": round(slow_cpu / (wall1 - wall0), 3)}
               if stalled else {}),
            "localizer_said": summary[0] if summary else ""}


def in_process(robots: int = 10, rate: float = 30.0, seconds: float = 5.0, seed: int = 0,
               smoother: bool = False) -> dict:
    """CPU per message without DDS: the tracker's and the rest of the localizer's (decode, checks, the poses' CDR).
    ``smoother``: with a sink for the rows (as ``--out`` gives it), so the smoother runs too."""
    from mutloc.live.localizer import Localizer

    rig, frames = streams(robots, seconds, rate, seed)
    tmp = Path(tempfile.mkdtemp(prefix="bench_localizer_"))
    path = tmp / "rig.yaml"
    save_rig(rig, path)
    rid = M.rig_id(path)
    loc = Localizer(path, sink=(lambda row, robot: None) if smoother else None)
    loc.warm_up()
    step = loc.engine.step
    spent = [0.0]

    def timed(t, obs):
        c = time.process_time()
        try:
            return step(t, obs)
        finally:
            spent[0] += time.process_time() - c

    loc.engine.step = timed
    raw = [(t, r, bytes(M.observations_message(r, rid, k, 1000.0 + t, obs).serialize()))
           for k, (t, r, obs) in enumerate(frames)]
    poses = 0
    c0 = time.process_time()
    for t, r, b in raw:
        for p in loc.feed(M.observations_from_cdr(b), 1000.0 + t + 0.005, r):  # (as dds.Reader decodes them)
            p.cdr()
            poses += 1
    total = time.process_time() - c0
    n = len(raw)
    return {"robots": robots, "messages": n, "poses": poses, "cpu_ms_per_message": round(1000 * total / n, 3),
            "tracker_ms_per_message": round(1000 * spent[0] / n, 3),
            "rest_ms_per_message": round(1000 * (total - spent[0]) / n, 3),
            "cpu_share_at_rate": round(total / n * robots * rate, 3), "smoother": smoother}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", type=int, nargs="*", default=[10, 2])
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--stalled", choices=["stop", "idle"], nargs="*", default=[],
                    help="also run with a stalled subscriber to every pose topic and /tf (ROS 2's default QoS): "
                         "a process stopped (SIGSTOP) once matched, or one that never takes a sample")
    ap.add_argument("--load", nargs="+", choices=("idle", "hog"), default=[],
                    help="only the run over DDS, under each load (idle; hog: another process keeping one core busy), "
                         "--runs times each, medians reported")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--smoother", action="store_true",
                    help="only the in-process cost per message without and with the smoother (what --out adds), "
                         "alternating, --runs times each: how much of a record's cost the smoother is")
    ap.add_argument("--written", action="store_true",
                    help="with --load: the localizer writes its files (--out), so its smoother runs")
    ap.add_argument("--out", default=result_file("localizer_results.json"))
    args = ap.parse_args()
    results = {"machine": machine(), "command": " ".join(["python", *sys.argv]), "runs": []}
    if args.smoother:
        for n in args.robots:
            got: dict = {False: [], True: []}
            for k in range(args.runs):
                for sm in (False, True):
                    r = in_process(n, args.rate, min(args.seconds, 5.0), seed=k, smoother=sm)
                    got[sm].append(r)
                    print(json.dumps(r), flush=True)
            med = {("with" if sm else "without") + "_smoother_" + key: float(np.median([r[key] for r in got[sm]]))
                   for sm in (False, True) for key in ("cpu_ms_per_message", "tracker_ms_per_message")}
            results["runs"].append({"robots": n, "smoother": med, "load_average_after": load_now()})
            print(f"{n} robots, median of {args.runs}: {med}", flush=True)
        Path(args.out).write_text(json.dumps(results, indent=1) + "\n")
        print(f"wrote {args.out}")
        return 0
    if args.load:
        keys = ("latency_ms_p50", "latency_ms_p99", "latency_ms_p50_second_half", "latency_ms_p99_second_half",
                "poses_per_expected", "error_cm_median", "error_cm_p90", "shed", "cpu_share_of_one_core",
                "written_ms_p50", "written_ms_p99", "written_ms_p99_second_half",
                "records_unsmoothed")
        for n in args.robots:
            for load in args.load:
                runs = []
                for k in range(args.runs):
                    before = load_now()
                    with cpu_hog(load == "hog"):
                        r = over_dds(n, args.rate, args.seconds, seed=k, written=args.written)
                    r.update(load=load, load_average_before=before, load_average_after=load_now())
                    print(json.dumps(r), flush=True)
                    runs.append(r)
                med = {key: (float(np.median([r[key] for r in runs if r[key] is not None]))
                             if any(r[key] is not None for r in runs) else None) for key in keys}
                results["runs"].append({"robots": n, "load": load, "runs": runs, "median": med})
                print(f"{n} robots, {load}, median of {args.runs}: "
                      + ", ".join(f"{key} {v if v is None else round(v, 3)}" for key, v in med.items()), flush=True)
        results["machine"]["load_average_at_end"] = load_now()
        Path(args.out).write_text(json.dumps(results, indent=1) + "\n")
        print(f"wrote {args.out}")
        return 0
    for n in args.robots:
        run = {"in_process": in_process(n, args.rate, min(args.seconds, 5.0)),
               "over_dds": over_dds(n, args.rate, args.seconds)}
        for how in args.stalled:
            run[f"over_dds_with_{how}_subscriber"] = over_dds(n, args.rate, args.seconds, stalled=how)
        run["load_average_after"] = list(os.getloadavg())
        print(json.dumps(run), flush=True)
        results["runs"].append(run)
    Path(args.out).write_text(json.dumps(results, indent=1) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
