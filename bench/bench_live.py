#!/usr/bin/env python
"""Live operation benchmark (issue 25): the node, and two nodes with a localizer end to end.

    python bench/bench_live.py            # 4 s replays (120 rendered frames per marker kind and robot)
    python bench/bench_live.py --quick    # 2 s replays (60 frames)
    python bench/bench_live.py --kinds tags lights --parts e2e --work /tmp/benchlive

Measured:

* **detection alone**, per marker kind, on one core (NUMBA_NUM_THREADS=1,
  cv2.setNumThreads(1)): the node's detector (:class:`~mutloc.track.tracker.ObserverDetector`,
  what ``mutloc node`` runs: every marker kind of the rig, blinking-light
  trackers fed every frame) over a rendered 960x540 sequence held in
  memory; frames/s (wall and CPU) beside the camera's 30 frames/s;
* **node capture -> publish latency** on a replayed 30 fps stream (q's
  camera, released at its own rate by
  :class:`~mutloc.live.cameras.ReplaySource`, the node in this process on
  DDS loopback): p50/p99 of capture -> publish (the node's own figure) and
  capture -> received by a subscriber of this process, and frames dropped.

The nodes replay the rendered images as BMP (``--replay-format``, default
``bmp``: a replayed frame then costs its node a copy, as a camera driver's
frame does, not a PNG decoding of 9-12 ms that would be counted as the
node's; ``png`` replays the rendered PNGs).

* **end to end**, per marker kind: two ``mutloc node`` processes replaying
  each robot's camera at 30 fps in step and a ``mutloc localizer`` process,
  DDS over loopback (:func:`mutloc.live.demo.run_live_pair`); a subscriber
  in this process: poses received per second and capture -> pose received
  latency p50/p99 (the pose's stamp is its frame's capture time), split
  into capture -> the observation messages received here (the nodes) and
  -> the pose received here (the localizer); the time from the first frame
  to the first pose (blinking lights are named only after 0.7 s of blink
  history) and poses/s from then on; each node's own stage times (its log).
  The sequence is rendered as long as the replay (a sequence played again
  from its start would make the robots jump back: the track restarts, and
  the blinking lights' identities with it, every pass).

* **under load** (``--load idle hog``, ``--runs 3``): the end-to-end run
  again, idle and beside a CPU hog (another process keeping one core busy
  for the whole run, :class:`_machine.cpu_hog`), each ``--runs`` times:
  capture -> pose p50/p99 over the whole run and over its second half (a
  growing backlog shows there), poses received per frame captured (both
  cameras), error against the rendered truth (median, p90), frames the
  nodes dropped and records the localizer shed; medians over the runs, the
  load average (``uptime``) before and after each.

The machine and its load average are recorded beside the figures (the
machine is shared: other work running changes them).  The functions
(:func:`render_sequences`, :func:`detection_rate`, :func:`node_latency`)
are reused by the end-to-end part.  Writes bench/results/live_results.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from mutloc.api import load_rig  # noqa: E402
from mutloc.live.cameras import ReplaySource  # noqa: E402
from mutloc.live.dds import Bus  # noqa: E402
from mutloc.live.messages import observations_topic, ros_types, stamp_of  # noqa: E402
from mutloc.live.node import Node, percentile_ms  # noqa: E402
from mutloc.sim.scenario import write_simulation  # noqa: E402
from mutloc.track.frames import expanded_rig  # noqa: E402
from mutloc.track.sources import folder_frames  # noqa: E402
from mutloc.track.tracker import ObserverDetector  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import cpu_hog, dds_domain, load_now, machine, result_file  # noqa: E402

cv2.setNumThreads(1)

KINDS = ("balls", "tags", "lights", "cylinders")
PARTS = ("detection", "node", "e2e")
CAMERA_FPS = 30.0
SIZE = (960, 540)
OBSERVER = "q"  # q's camera, looking for p's markers


def render_sequences(root: Path, kinds=KINDS, frames: int = 60, size=SIZE, fps: float = CAMERA_FPS) -> dict:
    """``{kind: folder}`` of a rendered two-robot sequence per marker kind (rig.yaml, p/, q/)."""
    out = {}
    for kind in kinds:
        folder = root / f"{kind}_{frames}"
        if not (folder / "rig.yaml").exists():
            write_simulation(folder, markers=kind, frames=frames, size=size, fps=fps)
        out[kind] = folder
    return out


def detection_rate(folder: Path, observer: str = OBSERVER, repeats: int = 3) -> dict:
    """Frames/s of the node's detector over ``observer``'s frames of a sequence
    (held in memory; a fresh detector per repeat, every frame fed in order)."""
    rig = expanded_rig(load_rig(folder / "rig.yaml"))
    others = [r for r in rig.robots if r != observer]
    frames = list(folder_frames(folder / observer))
    walls, cpus, seen = [], [], []
    for _ in range(repeats + 1):  # the first is a warm-up (kernels loaded)
        det = ObserverDetector(rig, observer, others, CAMERA_FPS)
        t0, c0 = time.perf_counter(), time.process_time()
        n = 0
        for f in frames:
            det.feed(f)
            n += len(det.detect(f).observations(observer))
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
        seen.append(n / len(frames))
    walls, cpus = walls[1:], cpus[1:]
    return {"frames": len(frames), "fps_wall": len(frames) / float(np.median(walls)),
            "fps_cpu": len(frames) / float(np.median(cpus)), "markers_per_frame": seen[-1],
            "camera_fps": CAMERA_FPS}


def raw_copy(folder: Path, out: Path) -> Path:
    """``folder``'s images (and frames.csv) as BMP in ``out``: a replayed frame
    then costs its node a copy (1.5 ms per 960x540 frame here), as a camera
    driver's frame does, not a PNG decoding (9-12 ms, more than most
    detectors: it would be measured as the node's)."""
    out.mkdir(parents=True, exist_ok=True)
    for png in sorted(folder.glob("*.png")):
        bmp = out / (png.stem + ".bmp")
        if not bmp.exists():
            cv2.imwrite(str(bmp), cv2.imread(str(png), cv2.IMREAD_COLOR))
    if (folder / "frames.csv").exists():
        (out / "frames.csv").write_text((folder / "frames.csv").read_text())
    return out


def replay_folders(folder: Path, fmt: str) -> Path:
    """The sequence ``folder`` with its robots' images in ``fmt`` (``png``: as rendered; ``bmp``: :func:`raw_copy`)."""
    if fmt == "png":
        return folder
    out = folder.parent / f"{folder.name}_{fmt}"
    for r in ("p", "q"):
        raw_copy(folder / r, out / r)
    for name in ("rig.yaml", "frames.csv", "truth.tum"):
        if (folder / name).exists():
            (out / name).write_bytes((folder / name).read_bytes())
    return out


def node_latency(rig_path: Path, robot: str, folder: Path, domain: int, speed: float = 1.0) -> dict:
    """Run a node (this process, DDS loopback) over ``folder`` replayed at
    ``speed`` times its rate; p50/p99 of capture -> publish and capture ->
    received by a subscriber, frames captured/processed/dropped."""
    T = ros_types()
    bus = Bus(domain, loopback=True)
    received: list[float] = []
    stop = threading.Event()
    try:
        reader = bus.reader(observations_topic(robot), T.Observations)

        def listen():
            while not stop.is_set():
                for m in reader.take():
                    received.append(time.time() - stamp_of(m.header))
                time.sleep(0.0005)

        listener = threading.Thread(target=listen, daemon=True)
        listener.start()
        node = Node(rig_path, robot, ReplaySource(folder, speed=speed), bus)
        stats = node.run(status_every=None)
        time.sleep(0.2)
        stop.set()
        listener.join(timeout=2)
    finally:
        bus.close()
    return {"captured": stats.captured, "processed": stats.processed, "dropped": stats.dropped,
            "publish_p50_ms": percentile_ms(stats.latencies, 50), "publish_p99_ms": percentile_ms(stats.latencies, 99),
            "received": len(received), "receive_p50_ms": percentile_ms(received, 50),
            "receive_p99_ms": percentile_ms(received, 99)}


def end_to_end(folder: Path, root: Path, seconds: float, domain: int) -> dict:
    """Two node processes (each robot's camera looped to ``seconds``) and a
    localizer process; what a subscriber here receives (see the module docstring)."""
    from mutloc.live.demo import run_live_pair

    loops = {r: folder / r for r in ("p", "q")}
    # a generous lead-in: a node loads its detectors (the blinking lights' take longest) before the first frame
    s = run_live_pair(folder / "rig.yaml", loops, root / f"{folder.name}_e2e", seconds=seconds, domain=domain,
                      lead_in=12.0)
    logs = {r: (root / f"{folder.name}_e2e" / f"{r}.log").read_text(encoding="utf-8") for r in ("p", "q", "localizer")}
    return {"poses_received": s["poses_received"], "poses_per_second": s["poses_per_second"],
            "observation_messages": s["observation_messages"], "latency_p50_ms": s["latency_ms"]["p50"],
            "latency_p99_ms": s["latency_ms"]["p99"], "latency_max_ms": s["latency_ms"]["max"],
            # (absent from an older mutloc's run_live_pair: the benchmark can measure an older node)
            "stages_ms": s.get("stages_ms", {"nodes": {"p50": None, "p99": None},
                                             "localizer": {"p50": None, "p99": None}}),
            "first_pose_s": s.get("first_pose_s"),
            "poses_per_second_once_tracked": s.get("poses_per_second_once_tracked"),
            "pose_stamps_per_second": s.get("pose_stamps", 0) / seconds,
            "node_logs": {r: [ln for ln in text.splitlines() if ln.startswith(("node ", "interrupted"))]
                          for r, text in logs.items() if r != "localizer"},
            "localizer_log": logs["localizer"].strip().splitlines()[-1:]}


def _truth(folder: Path):
    """Time in the recording -> the true T_qp (the sequence's truth.tum, nearest instant)."""
    from mutloc.core.pose import Pose

    rows = np.array([[float(x) for x in ln.split()] for ln in (folder / "truth.tum").read_text().splitlines()
                     if ln.strip() and not ln.startswith("#")])

    def at(t: float):
        r = rows[int(np.argmin(np.abs(rows[:, 0] - t)))]
        return Pose.from_quaternion_xyzw(r[4:8], r[1:4])
    return at


def _count(pattern: str, lines: list[str]) -> int:
    import re

    return sum(int(m.group(1)) for ln in lines for m in [re.search(pattern, ln)] if m)


def under_load(folder: Path, root: Path, seconds: float, load: str, run: int) -> dict:
    """One end-to-end run (two node processes, a localizer) idle or beside a CPU hog (see the module docstring)."""
    from mutloc.live.demo import run_live_pair

    before = load_now()
    with cpu_hog(load == "hog"), dds_domain() as lease:
        out = root / f"{folder.name}_{load}_{run}"
        s = run_live_pair(folder / "rig.yaml", {r: folder / r for r in ("p", "q")}, out, seconds=seconds,
                          domain=lease.domain, lead_in=12.0, truth=_truth(folder))
    after = load_now()
    logs = {r: (out / f"{r}.log").read_text(encoding="utf-8").splitlines() for r in ("p", "q", "localizer")}
    nodes = [ln for r in ("p", "q") for ln in logs[r] if ln.startswith("node ") and "frames captured" in ln]
    captured = _count(r"(\d+) frames captured", nodes)
    return {"load": load, "load_average_before": before, "load_average_after": after,
            "latency_p50_ms": s["latency_ms"]["p50"], "latency_p99_ms": s["latency_ms"]["p99"],
            "latency_second_half_p50_ms": s["latency_ms_second_half"]["p50"],
            "latency_second_half_p99_ms": s["latency_ms_second_half"]["p99"],
            "frames_captured": captured, "poses_received": s["poses_received"],
            "poses_per_captured_frame": s["poses_received"] / captured if captured else None,
            "error_cm_median": s["translation_error_cm"]["median"], "error_cm_p90": s["translation_error_cm"]["p90"],
            "frames_dropped_by_nodes": _count(r"(\d+) dropped", nodes),
            "shed_by_localizer": _count(r"shed (\d+)", logs["localizer"][-1:]),
            "node_warnings": [ln for r in ("p", "q") for ln in logs[r] if "falling behind" in ln][:4],
            "localizer_said": logs["localizer"][-1:]}


def _median(runs: list[dict], key: str):
    v = [r[key] for r in runs if r[key] is not None]
    return float(np.median(v)) if v else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="2 s replays (60 frames per kind) instead of 4 s")
    ap.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    ap.add_argument("--parts", nargs="+", default=list(PARTS), choices=PARTS,
                    help="what to measure (default all): detection alone, the node alone, end to end")
    ap.add_argument("--replay-format", choices=("bmp", "png"), default="bmp",
                    help="the images the nodes replay: bmp (default: a frame costs a copy, as a camera's) or the "
                         "rendered png (a 960x540 PNG costs 9-12 ms to decode, counted as the node's)")
    ap.add_argument("--load", nargs="+", choices=("idle", "hog"), default=[],
                    help="measure end to end under each load (idle; hog: another process keeping one core busy), "
                         "--runs times each, instead of the other parts")
    ap.add_argument("--runs", type=int, default=3, help="runs per load (--load), medians reported")
    ap.add_argument("--work", help="keep the rendered sequences here (reused when present)")
    ap.add_argument("--out", default=result_file("live_results.json"))
    args = ap.parse_args()
    seconds = 2.0 if args.quick else 4.0
    frames = int(round(seconds * CAMERA_FPS))
    info = machine()
    print(f"machine: {info['cpu']}, {info['cores']} cores, load average {info['load_average_at_start']}")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.work) if args.work else Path(tmp)
        seqs = render_sequences(root, args.kinds, frames)
        replays = {kind: replay_folders(folder, args.replay_format) for kind, folder in seqs.items()} \
            if {"node", "e2e"} & set(args.parts) else {}
        detection, latency, e2e = {}, {}, {}
        if args.load:
            loaded: dict = {}
            keys = ("latency_p50_ms", "latency_p99_ms", "latency_second_half_p50_ms", "latency_second_half_p99_ms",
                    "poses_per_captured_frame", "error_cm_median", "error_cm_p90", "frames_dropped_by_nodes",
                    "shed_by_localizer")
            for kind, folder in replays.items():
                for load in args.load:
                    runs = []
                    for k in range(args.runs):
                        runs.append(under_load(folder, root, seconds, load, k))
                        print(json.dumps({"kind": kind, **runs[-1]}), flush=True)
                    med = {key: _median(runs, key) for key in keys}
                    loaded.setdefault(kind, {})[load] = {"runs": runs, "median": med}
                    print(f"{kind:<6} {load:<4} median of {args.runs}: " + ", ".join(
                        f"{key} {'n/a' if v is None else round(v, 2)}" for key, v in med.items()), flush=True)
            info["load_average_at_end"] = list(os.getloadavg())
            Path(args.out).write_text(json.dumps({"machine": info, "command": " ".join(["python", *sys.argv]),
                                                  "camera_fps": CAMERA_FPS, "replay_seconds": seconds,
                                                  "replay_format": args.replay_format, "under_load": loaded},
                                                 indent=1) + "\n")
            print(f"\nload average at end {info['load_average_at_end']}; wrote {args.out}")
            return
        if "detection" in args.parts:
            print(f"\ndetection alone, one core, {SIZE[0]}x{SIZE[1]} (camera: {CAMERA_FPS:g} frames/s)")
            print(f"{'kind':<10} {'frames/s wall':>14} {'frames/s cpu':>13} {'markers/frame':>14}")
            for kind, folder in seqs.items():
                r = detection[kind] = detection_rate(folder)
                print(f"{kind:<10} {r['fps_wall']:>14.1f} {r['fps_cpu']:>13.1f} {r['markers_per_frame']:>14.2f}")
        if "node" in args.parts:
            print(f"\nnode capture -> publish, {CAMERA_FPS:g} fps replayed for {seconds:g} s (DDS loopback)")
            print(f"{'kind':<10} {'captured':>8} {'processed':>9} {'dropped':>7} {'publish p50/p99 ms':>19} "
                  f"{'received p50/p99 ms':>20}")
            for kind, folder in replays.items():
                with dds_domain() as lease:
                    r = latency[kind] = node_latency(folder / "rig.yaml", OBSERVER, folder / OBSERVER, lease.domain)
                print(f"{kind:<10} {r['captured']:>8} {r['processed']:>9} {r['dropped']:>7} "
                      f"{r['publish_p50_ms']:>9.1f}/{r['publish_p99_ms']:<9.1f} {r['receive_p50_ms']:>10.1f}/"
                      f"{r['receive_p99_ms']:<9.1f}")
        if "e2e" in args.parts:
            print(f"\nend to end: two nodes + localizer (processes, DDS loopback), {CAMERA_FPS:g} fps for {seconds:g} s")
            print(f"{'kind':<10} {'poses/s':>8} {'messages':>9} {'capture->pose p50/p99/max ms':>29}")
            for kind, folder in replays.items():
                if kind == "cylinders":
                    continue  # slower than the camera on one core (see detection above)
                with dds_domain() as lease:
                    r = e2e[kind] = end_to_end(folder, root, seconds, lease.domain)
                lat = "/".join("n/a" if r[k] is None else f"{r[k]:.1f}"
                               for k in ("latency_p50_ms", "latency_p99_ms", "latency_max_ms"))
                print(f"{kind:<10} {r['poses_per_second']:>8.1f} {r['observation_messages']:>9} {lat:>29}")
                if r["first_pose_s"] is not None:
                    print(f"{'':<10} first pose {r['first_pose_s']:.2f} s after the first frame; from then on "
                          f"{r['poses_per_second_once_tracked']:.1f} poses/s; {r['pose_stamps_per_second']:.1f} "
                          "distinct pose stamps/s over the run")
                st = r["stages_ms"]
                f = lambda v: "n/a" if v is None else f"{v:.1f}"  # noqa: E731
                print(f"{'':<10} capture -> observations here p50/p99 {f(st['nodes']['p50'])}/"
                      f"{f(st['nodes']['p99'])} ms, -> pose here {f(st['localizer']['p50'])}/"
                      f"{f(st['localizer']['p99'])} ms")
                for lines in r["node_logs"].values():
                    for ln in lines:
                        print(f"{'':<10} {ln}")
                for ln in r["localizer_log"]:
                    print(f"{'':<10} {ln}")
    info["load_average_at_end"] = list(os.getloadavg())
    result = {"machine": info, "size": list(SIZE), "camera_fps": CAMERA_FPS, "frames_per_kind": frames,
              "replay_format": args.replay_format,
              "replay_seconds": seconds, "detection": detection, "node_latency": latency, "end_to_end": e2e}
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    print(f"\nload average at end {info['load_average_at_end']}; wrote {args.out}")


if __name__ == "__main__":
    main()
