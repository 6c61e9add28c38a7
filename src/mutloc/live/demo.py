"""``mutloc demo --live``: two nodes and a localizer on this machine, for real.

Renders a two-robot sequence (the demo's scene, p moving in front of q),
then starts, as separate processes on DDS over the loopback interface, a
``mutloc localizer`` and one ``mutloc node`` per robot replaying its camera
(``--realtime``, both released in step with ``--start-at``).  This process
listens like any ROS 2 subscriber would -- the pose topic and both
observation topics -- and reports the poses received, their error against
the rendered truth and the latency from capture to the pose's arrival.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..errors import InputError, positive_number
from ..io import save_rig
from ..signals import stop_process_group
from .messages import observations_topic, pose_topic, ros_types, stamp_of

__all__ = ["run_live_demo", "run_live_pair", "format_live_summary"]

SOURCE, TARGET = "p", "q"
#: Seconds between starting the nodes and their first frame (DDS discovery, loading the detectors).
LEAD_IN = 4.0
#: A node's lead-in is at least this many times the time the localizer took to start (a loaded machine).
NODE_START_FACTOR = 2.5
#: Seconds the localizer may take to start listening.
READY_TIMEOUT = 60.0


def _render_frame(args: tuple) -> tuple[str, int]:
    import cv2

    from ..sim.demo import SEQUENCE_RENDER
    from ..sim.render import moving_world, render
    from ..sim.world import standard_rig

    folder, robot, i, t, seed = args
    world = moving_world(standard_rig("balls"), seed=seed, source=SOURCE, target=TARGET)
    path = Path(folder) / robot / f"{i:06d}.png"
    if not cv2.imwrite(str(path), render(world, robot, t, seed=seed, **SEQUENCE_RENDER)):
        raise OSError(f"{path}: cannot write image")
    return robot, i


def _render(folder: Path, seconds: float, fps: float, seed: int, progress: bool) -> list[float]:
    from tqdm import tqdm

    times = [i / fps for i in range(int(round(seconds * fps)))]
    for r in (SOURCE, TARGET):
        (folder / r).mkdir(parents=True, exist_ok=True)
        for old in (folder / r).glob("*.png"):
            old.unlink()
        (folder / r / "frames.csv").write_text(
            "frame,timestamp\n" + "".join(f"{i},{t:.9f}\n" for i, t in enumerate(times)), encoding="utf-8")
    jobs = [(str(folder), r, i, t, seed) for i, t in enumerate(times) for r in (SOURCE, TARGET)]
    with ProcessPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1))) as pool:
        for _ in tqdm(pool.map(_render_frame, jobs, chunksize=8), total=len(jobs), desc="render", unit="image",
                      disable=not progress):
            pass
    return times


def warm_up_kernels(rig: Any, folders: dict[str, Path], fps: float, progress: bool = False) -> None:
    """Compile (on a cold cache: a fresh install) or load the numerical
    kernels the nodes and the localizer will use, here, before they start:
    each robot's detector on drawn markers
    (:func:`~mutloc.live.node.warm_up_detector`) and the team tracker on the
    first frames of ``folders``.  The processes then load them from the
    cache within their lead-in instead of compiling them while the replays
    run (and a stop during a compilation is never what ends them)."""
    from itertools import islice

    from ..track.frames import expanded_rig
    from ..track.sources import folder_frames
    from ..track.team import track_team
    from .node import warm_up_detector

    rig = expanded_rig(rig)
    if progress:
        print("loading the numerical kernels (compiled once on a fresh install: up to a few minutes)", flush=True)
    for r in folders:
        warm_up_detector(rig, r, [o for o in folders if o != r], fps)
    track_team(rig, {r: islice(folder_frames(f), 6) for r, f in folders.items()}, progress=False)


def run_live_demo(out_dir: str | Path = "demo-out", *, seconds: float = 10.0, fps: float = 10.0, seed: int = 0,
                  domain: int | None = None, progress: bool = False, odometry: bool = False) -> dict[str, Any]:
    """Render ``seconds`` of the demo sequence at ``fps``, run two nodes and a
    localizer on it in real time (DDS on the loopback interface, domain
    ``domain``, default one chosen from this process's id) and return what a
    subscriber received: poses, error against the truth, latency.  Writes
    ``out_dir/live/`` (the images, the localizer's ``--out`` files, each
    process's log, ``live_summary.json``).  ``odometry``: each moving robot's
    odometry too, simulated with drift (:func:`mutloc.sim.odometry.write_odometry`,
    ``out_dir/live/odometry/``) and published by a separate process as a
    robot's driver would (:mod:`mutloc.live.odometry_replay`); the localizer
    subscribes to it (``--odometry NAME=ros:/NAME/odom``)."""
    from ..sim.render import moving_world, relative_pose
    from ..sim.world import standard_rig

    seconds = positive_number(seconds, "seconds")
    fps = positive_number(fps, "fps")
    if seconds * fps < 10:
        raise InputError(f"--seconds x --fps must give at least 10 frames, got {seconds * fps:g}")
    from .dds import check_domain

    if domain is not None:
        domain = check_domain(domain)  # before the rendering, not after
    out = Path(out_dir).expanduser() / "live"
    out.mkdir(parents=True, exist_ok=True)
    rig = standard_rig("balls")
    rig_file = out / "rig.yaml"
    save_rig(rig, rig_file)
    t0 = time.perf_counter()
    times = _render(out / "cameras", seconds, fps, seed, progress)
    render_s = time.perf_counter() - t0
    world = moving_world(rig, seed=seed, source=SOURCE, target=TARGET)
    t0 = time.perf_counter()
    warm_up_kernels(rig, {r: out / "cameras" / r for r in (SOURCE, TARGET)}, fps, progress)
    warm_s = time.perf_counter() - t0
    odo_files = _simulated_odometry(out / "odometry", world, seconds, seed) if odometry else None
    summary = run_live_pair(rig_file, {r: out / "cameras" / r for r in (SOURCE, TARGET)}, out, seconds=seconds,
                            truth=lambda t: relative_pose(world, SOURCE, TARGET, t), domain=domain,
                            odometry=odo_files)
    summary.update(fps=fps, frames_per_camera=len(times), render_seconds=render_s, warm_up_seconds=warm_s)
    (out / "live_summary.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    return summary


def _simulated_odometry(folder: Path, world: Any, seconds: float, seed: int) -> dict[str, Path]:
    """Each moving robot's drifting odometry (the simulator's default drift and rate) as a TUM file of ``folder``."""
    from ..sim.odometry import DEFAULT_DRIFT, DEFAULT_RATE, write_odometry

    folder.mkdir(parents=True, exist_ok=True)
    names = write_odometry(folder, {r: (lambda t, r=r: world.pose(r, t)) for r in (SOURCE, TARGET)}, seconds,
                           rate=DEFAULT_RATE, drift=DEFAULT_DRIFT, seed=seed, clock_offset={})
    return {n[len("odometry_"):-len(".tum")]: folder / n for n in names}


def run_live_pair(rig_file: Path, folders: dict[str, Path], out: Path, *, seconds: float,
                  truth: Callable[[float], Any] | None = None, domain: int | None = None,
                  lead_in: float = LEAD_IN, odometry: dict[str, Path] | None = None) -> dict[str, Any]:
    """Run a ``mutloc localizer`` and one ``mutloc node`` per robot of
    ``folders`` (replaying that recording in real time, all released in step
    ``lead_in`` s from now) as separate processes on loopback DDS for
    ``seconds``; listen to the pose of the rig's first robot in its second's
    frame like any subscriber.  Returns the poses received, their latency
    (capture -> arrival here) and, with ``truth`` (time in the recording ->
    the true pose), their error.  Each process's output goes to
    ``out/NAME.log``, the localizer's files to ``out/localizer``.  ``odometry``:
    ``{robot: TUM file}``, published in step with the cameras by a separate
    process (:mod:`mutloc.live.odometry_replay`, ``out/odometry.log``) and
    subscribed to by the localizer."""
    from ..io import load_rig
    from .dds import Bus, check_domain

    domain = check_domain(domain if domain is not None else 100 + os.getpid() % 100)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = list(load_rig(rig_file).robots)
    source, target = names[0], names[1]
    T = ros_types()
    bus = Bus(domain, loopback=True)
    readers = {"pose": bus.reader(pose_topic(source, target), T.PoseWithCovarianceStamped, depth=100),
               **{r: bus.reader(observations_topic(r), T.Observations) for r in folders}}
    exe = [sys.executable, "-m", "mutloc.cli.main"]
    common = ["--rig", str(rig_file), "--domain", str(domain), "--loopback"]
    run_for = lead_in + seconds + 2.0
    procs: list[subprocess.Popen] = []
    logs = []
    received: list[tuple[float, float, Any]] = []  # (arrival wall time, stamp, message)
    source_time: dict[int, float] = {}  # stamp ns -> time in the recording
    arrived: dict[int, float] = {}  # stamp ns -> arrival here of the last observation message of that stamp
    messages = 0
    labels = ["localizer", *folders, *(["odometry"] if odometry else [])]
    from .odometry_replay import odometry_topic

    odo_args = [a for r in (odometry or {}) for a in ("--odometry", f"{r}=ros:{odometry_topic(r)}")]
    def launch(name: str, cmd: list[str]) -> None:
        log = open(out / f"{name}.log", "w", encoding="utf-8")
        logs.append(log)
        procs.append(subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True))

    try:
        launch("localizer", exe + ["localizer", *common, *odo_args, "--out", str(out / "localizer"), "--duration",
                                   f"{run_for + (1 + NODE_START_FACTOR) * READY_TIMEOUT:g}"])
        # the nodes' replays start once the localizer listens (it says so when ready)
        launched = time.monotonic()
        deadline = launched + READY_TIMEOUT
        while "localizer: rig_id" not in (out / "localizer.log").read_text(encoding="utf-8"):
            if procs[0].poll() is not None or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        # a node takes as long to start as the localizer did (the same imports and DDS on this machine at its
        # present load), then loads its detectors: its replay starts after that, not while it is still starting
        ready_s = time.monotonic() - launched
        lead_in = max(lead_in, NODE_START_FACTOR * ready_s + 1.0)
        start_at = time.time() + lead_in
        run_for = lead_in + seconds + 2.0
        for r, f in folders.items():
            launch(r, exe + ["node", *common, "--robot", r, "--camera", str(f), "--realtime", "--start-at",
                             f"{start_at:.6f}", "--duration", f"{run_for:g}", "--no-progress"])
        if odometry:
            launch("odometry", [sys.executable, "-m", "mutloc.live.odometry_replay", "--domain", str(domain),
                                "--loopback", "--start-at", f"{start_at:.6f}", "--duration", f"{seconds:g}",
                                *(a for r, f in odometry.items() for a in ("--odometry", f"{r}={f}"))])
        end = start_at + seconds + 1.5
        while time.time() < end:
            if any(p.poll() not in (None, 0) for p in procs):
                break
            now = time.time()
            for m in readers["pose"].take():
                received.append((now, stamp_of(m.header), m))
            for r in folders:
                for m in readers[r].take():
                    ns = _ns(stamp_of(m.header))
                    source_time[ns] = float(m.source_time)
                    arrived[ns] = now
                    messages += 1
            time.sleep(0.002)
    finally:
        stop_process_group(procs)
        for log in logs:
            log.close()
        bus.close()
    failed = [(n, p.returncode) for n, p in zip(labels, procs) if p.returncode not in (0, 130, -signal.SIGTERM)]
    if failed:
        name = failed[0][0]
        tail = (out / f"{name}.log").read_text(encoding="utf-8").strip().splitlines()[-1:] or ["(no output)"]
        raise InputError(f"the {name} process stopped (exit {failed[0][1]}): {tail[0]}")
    summary = _summary(out, received, source_time, truth, seconds, domain)
    summary.update(_process_counts(out, [*folders]))
    summary["observation_messages"] = messages
    summary["stages_ms"] = _stages(received, arrived)
    summary["start_at"] = start_at  # the wall-clock time of every recording's first frame
    summary["localizer_start_s"], summary["lead_in_s"] = ready_s, lead_in
    # the first pose's capture time after the first frame, and the rate of poses from then on
    first = min((stamp for _, stamp, _ in received), default=None)
    summary["first_pose_s"] = None if first is None else first - start_at
    summary["poses_per_second_once_tracked"] = (None if first is None or start_at + seconds <= first
                                                else len(received) / (start_at + seconds - first))
    # a record of one robot's message fused before the other's came gives a pose each: stamps counted once
    summary["pose_stamps"] = len({_ns(stamp) for _, stamp, _ in received})
    # capture -> pose received over the second half of the run only (a backlog growing shows there)
    half = [arrival - stamp for arrival, stamp, _ in received if stamp >= start_at + seconds / 2]
    summary["latency_ms_second_half"] = {q: float(np.percentile(half, int(q[1:])) * 1e3) if half else None
                                         for q in ("p50", "p99")}
    return summary


def _process_counts(out: Path, robots: list[str]) -> dict[str, Any]:
    """What the processes' last lines say they did: the localizer's records
    fused, poses published and messages shed; each node's frames captured and
    dropped (None where a log has no such line: a process that did not finish)."""
    import re

    def last(name: str, pattern: str) -> tuple[int, ...] | None:
        path = out / f"{name}.log"
        text = path.read_text(encoding="utf-8") if path.exists() else ""
        found = re.findall(pattern, text)
        return tuple(int(x) for x in found[-1] if x.isdigit()) if found else None

    loc = last("localizer", r"(\d+) records fused; (\d+) poses published;.*?, shed (\d+)")
    path = out / "localizer.log"
    odo = re.findall(r"odometry (\w+) (\d+) used(?: \(([^)]*)\))?", path.read_text(encoding="utf-8")
                     if path.exists() else "")
    # (the poses not published before the rig check's first window agreed: mutloc.live.rig_gate)
    waiting = last("localizer", r"poses not published: (\d+) waiting for the rig check(,?)")
    withheld = last("localizer", r"poses not published: .*?(\d+) while the rig disagreed(;?)")
    nodes = {r: last(r, r"(\d+) frames captured from .*?, (\d+) processed .*?, (\d+) dropped") for r in robots}
    return {"localizer": None if loc is None else {"records_fused": loc[0], "poses_published": loc[1],
                                                   "shed": loc[2], "rig_waiting": waiting[0] if waiting else 0,
                                                   "rig_withheld": withheld[0] if withheld else 0},
            "nodes": {r: None if n is None else {"captured": n[0], "processed": n[1], "dropped": n[2]}
                      for r, n in nodes.items()},
            "odometry": {r: {"used": int(n), "note": note} for r, n, note in odo}}


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def _stages(received: list, arrived: dict) -> dict[str, dict[str, float | None]]:
    """Where capture -> pose received went, p50/p99 ms: ``nodes`` (capture ->
    the last observation message of the pose's stamp received here: the
    nodes' detection and DDS) and ``localizer`` (that -> the pose received:
    the localizer's reorder wait, fusion, publishing and DDS)."""
    nodes, loc = [], []
    for arrival, stamp, _ in received:
        last = arrived.get(_ns(stamp))
        if last is not None:
            nodes.append(last - stamp)
            loc.append(max(0.0, arrival - last))

    def pct(v: list[float]) -> dict[str, float | None]:
        return {q: float(np.percentile(v, int(q[1:])) * 1e3) if v else None for q in ("p50", "p99")}

    return {"nodes": pct(nodes), "localizer": pct(loc)}


def _summary(out: Path, received: list, source_time: dict, truth: Callable[[float], Any] | None, seconds: float,
             domain: int) -> dict[str, Any]:
    from ..core.geometry import matrix_from_quaternion_xyzw, rotation_error_deg

    err_t, err_r, latency = [], [], []
    unmatched = 0
    for arrival, stamp, m in received:
        latency.append(arrival - stamp)
        st = source_time.get(_ns(stamp))
        if truth is None:
            continue
        if st is None:
            unmatched += 1
            continue
        true = truth(st)
        p = m.pose.pose
        est_t = np.array([p.position.x, p.position.y, p.position.z])
        R = matrix_from_quaternion_xyzw(np.array([p.orientation.x, p.orientation.y, p.orientation.z,
                                                  p.orientation.w]))
        err_t.append(float(np.linalg.norm(est_t - true.t)))
        err_r.append(float(rotation_error_deg(R, true.R)))

    def pct(v: list[float], q: float, scale: float = 1.0) -> float | None:
        return float(np.percentile(v, q) * scale) if v else None

    return {
        "seconds": seconds, "dds_domain": domain, "observation_messages": len(source_time),
        "poses_received": len(received), "poses_per_second": len(received) / seconds,
        "translation_error_cm": {"median": pct(err_t, 50, 100), "p90": pct(err_t, 90, 100),
                                 "max": pct(err_t, 100, 100)},
        "rotation_error_deg": {"median": pct(err_r, 50), "max": pct(err_r, 100)},
        "latency_ms": {"p50": pct(latency, 50, 1e3), "p99": pct(latency, 99, 1e3), "max": pct(latency, 100, 1e3)},
        "poses_without_a_known_frame": unmatched, "folder": str(out),
    }


def format_live_summary(s: dict[str, Any]) -> str:
    """The lines ``mutloc demo --live`` prints."""
    def f(v: float | None, spec: str) -> str:
        return "n/a" if v is None else format(v, spec)

    return "\n".join([
        f"live: two nodes (p, q) replaying {s['seconds']:g} s of camera at {s['fps']:g} fps and a localizer, "
        f"DDS domain {s['dds_domain']} on the loopback interface",
        f"  observation messages received: {s['observation_messages']}; poses of p in q received: "
        f"{s['poses_received']} ({s['poses_per_second']:.1f}/s)",
        f"  error against the truth: median {f(s['translation_error_cm']['median'], '.2f')} cm, "
        f"p90 {f(s['translation_error_cm']['p90'], '.2f')} cm, max {f(s['translation_error_cm']['max'], '.2f')} cm; "
        f"rotation median {f(s['rotation_error_deg']['median'], '.2f')} deg",
        f"  latency capture -> pose received: p50 {f(s['latency_ms']['p50'], '.1f')} ms, "
        f"p99 {f(s['latency_ms']['p99'], '.1f')} ms",
        *([f"  odometry fused: " + ", ".join(f"{r} {o['used']} samples" + (f" ({o['note']})" if o["note"] else "")
                                             for r, o in s["odometry"].items())] if s.get("odometry") else []),
        f"  files: {s['folder']} (localizer/ holds the trajectory and the received log; *.log each process's output)",
    ])
