#!/usr/bin/env python
"""Per-row cost of the streaming, crash-safe writers of mutloc.io against
batch peers that write the same content once at the end (what ``track`` did
before: buffered text files, one SQLite transaction, rosbags' chunked MCAP
storage, a chunked zstd MCAP, a Rerun stream flushed only at close, OpenCV's mp4v VideoWriter).

    python bench/bench_streaming.py            # 2000 rows
    python bench/bench_streaming.py --rows 500

Prints microseconds per row (wall clock and CPU time of the process, median
of --repeat runs) and writes bench/results/streaming_results.json.  The rows are
precomputed; the ROS writers' figures include serialising the two messages;
the video is 640x480 frames (at most 300).
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mutloc.core.geometry import so3_exp
from mutloc.core.observations import ObservationSet
from mutloc.core.pose import Pose
from mutloc.io.logs import ObservationLogWriter
from mutloc.io.ros import McapPoseWriter, Ros2BagWriter
from mutloc.io.rrd import RerunWriter
from mutloc.io.trajectory import CSV_COLUMNS, TrajectoryCsvWriter, TumWriter
from mutloc.io.video import VideoWriter

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine  # noqa: E402

EXTRA = ("reason", "markers_used")


def rows(n):
    out = []
    for i in range(n):
        t = 0.033 * i
        pose = Pose(so3_exp([0.01 * i, 0.02, -0.03]), [0.01 * i, 1.0, 2.0])
        obs = ObservationSet.from_dict({"p": {"m1": [100.0 + i, 50.5], "m2": [7.25, 3.0]}, "q": {"m3": [1.0, 2.0]}},
                                       time=t)
        out.append({"t": t, "status": "solved", "pose": pose, "covariance": np.eye(6) * 1e-4, "reason": "",
                    "markers_used": "m1 m2", "observations": obs})
    return out


# ---------------------------------------------------------------- streaming writers (one call per row)

def stream_csv(d, rs):
    with TrajectoryCsvWriter(d / "t.csv", EXTRA) as w:
        for r in rs:
            w.write(r)


def stream_tum(d, rs):
    with TumWriter(d / "t.tum", "bench") as w:
        for r in rs:
            w.write(r["t"], r["pose"])


def stream_log(d, rs):
    with ObservationLogWriter(d / "log.jsonl") as w:
        for r in rs:
            w.write(r["t"], r["observations"])


def stream_bag(d, rs):
    with Ros2BagWriter(d / "bag", [("p", "q")]) as w:
        for r in rs:
            w.write(r["t"], r["pose"], r["covariance"])


def stream_bag_mcap(d, rs):
    with Ros2BagWriter(d / "bag", [("p", "q")], storage="mcap") as w:
        for r in rs:
            w.write(r["t"], r["pose"], r["covariance"])


def stream_mcap(d, rs):
    with McapPoseWriter(d / "t.mcap", [("p", "q")]) as w:
        for r in rs:
            w.write(r["t"], r["pose"], r["covariance"])


def stream_rrd(d, rs):
    with RerunWriter(d / "t.rrd", "p", "q") as w:
        for r in rs:
            w.write(r["t"], r["status"], r["reason"], r["pose"], r["covariance"])


def _frames(rs):
    """One 640x480 frame per row (a moving gradient: something to encode)."""
    x = np.arange(640, dtype=np.uint8)[None, :, None]
    return [np.broadcast_to(x + np.uint8(i % 256), (480, 640, 3)).copy() for i in range(len(rs))]


FRAMES: list = []


def stream_video(d, rs):
    with VideoWriter(d / "v.mp4", fps=30) as w:
        for f in FRAMES[:len(rs)]:
            w.write(f)


# ---------------------------------------------------------------- batch peers (write everything at the end)

def batch_csv(d, rs):
    with open(d / "t.csv", "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow([*CSV_COLUMNS, *EXTRA])
        for r in rs:
            p = r["pose"]
            w.writerow([f"{r['t']:.9f}", r["status"], *(f"{x:.9f}" for x in (*p.t, *p.quaternion_xyzw)),
                        *(f"{x:.9f}" for x in np.sqrt(np.diag(r["covariance"]))), r["reason"], r["markers_used"]])


def batch_tum(d, rs):
    lines = ["# bench"] + [" ".join(f"{x:.9f}" for x in (r["t"], *r["pose"].t, *r["pose"].quaternion_xyzw))
                           for r in rs]
    (d / "t.tum").write_text("\n".join(lines) + "\n", encoding="utf-8")


def batch_log(d, rs):
    with open(d / "log.jsonl", "w", encoding="utf-8") as f:
        for r in rs:
            f.write(json.dumps({"time": r["t"], "observations": {o: {m: list(uv) for m, uv in e.items()}
                                                                 for o, e in r["observations"].to_dict().items()}},
                               separators=(",", ":")) + "\n")


def _serialised(rs):
    from mutloc.io.ros import POSE_TYPE, TF_TYPE, ros_covariance  # noqa: F401 (same message content as the writers)
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    for r in rs:
        ns = int(round(r["t"] * 1e9))
        stamp = T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
        q, (x, y, z) = r["pose"].quaternion_xyzw, r["pose"].t
        head = T["std_msgs/msg/Header"](stamp=stamp, frame_id="q")
        quat = T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3])
        pm = T[POSE_TYPE](header=head, pose=T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=x, y=y, z=z), orientation=quat),
            covariance=np.ascontiguousarray(ros_covariance(r["covariance"]).reshape(-1))))
        tf = T[TF_TYPE](transforms=[T["geometry_msgs/msg/TransformStamped"](
            header=head, child_frame_id="p", transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z), rotation=quat))])
        yield store, ns, bytes(store.serialize_cdr(pm, POSE_TYPE)), bytes(store.serialize_cdr(tf, TF_TYPE))


def batch_bag(d, rs, storage="sqlite3"):
    from rosbags.rosbag2 import StoragePlugin, Writer

    from mutloc.io.ros import POSE_TYPE, TF_TYPE

    with Writer(d / "bag", version=8, storage_plugin=StoragePlugin[storage.upper()]) as w:
        cp = ct = None
        for store, ns, pm, tf in _serialised(rs):
            if cp is None:
                cp = w.add_connection("/mutloc/p_in_q", POSE_TYPE, typestore=store)
                ct = w.add_connection("/tf", TF_TYPE, typestore=store)
            w.write(cp, ns, pm)
            w.write(ct, ns, tf)


def batch_bag_mcap(d, rs):
    batch_bag(d, rs, "mcap")


def batch_mcap(d, rs):
    from mcap.writer import Writer

    from mutloc.io.ros import POSE_TYPE, TF_TYPE

    with open(d / "t.mcap", "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="bench")
        cp = ct = None
        for seq, (store, ns, pm, tf) in enumerate(_serialised(rs)):
            if cp is None:
                ids = {t: w.register_schema(name=t, encoding="ros2msg",
                                            data=store.generate_msgdef(t, ros_version=2)[0].encode())
                       for t in (POSE_TYPE, TF_TYPE)}
                cp = w.register_channel("/mutloc/p_in_q", "cdr", ids[POSE_TYPE])
                ct = w.register_channel("/tf", "cdr", ids[TF_TYPE])
            w.add_message(cp, log_time=ns, publish_time=ns, sequence=seq, data=pm)
            w.add_message(ct, log_time=ns, publish_time=ns, sequence=seq, data=tf)
        w.finish()


def batch_rrd(d, rs):
    w = RerunWriter(d / "t.rrd", "p", "q")
    flush, w.rec.flush = w.rec.flush, lambda *a, **k: None  # the batching stream decides when to write
    for r in rs:
        w.write(r["t"], r["status"], r["reason"], r["pose"], r["covariance"])
    w.rec.flush = flush
    w.close()


def batch_video(d, rs):
    import cv2

    vw = cv2.VideoWriter(str(d / "v.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (640, 480))
    for f in FRAMES[:len(rs)]:
        vw.write(f)
    vw.release()


CASES = {name: (globals()[f"stream_{name}"], globals()[f"batch_{name}"])
         for name in ("csv", "tum", "log", "bag", "bag_mcap", "mcap", "rrd", "video")}


def timed(fn, rs, repeat):
    walls, cpus = [], []
    for _ in range(repeat):
        d = Path(tempfile.mkdtemp(prefix="mutloc-bench-"))
        try:
            w0, c0 = time.perf_counter(), time.process_time()
            fn(d, rs)
            walls.append(time.perf_counter() - w0)
            cpus.append(time.process_time() - c0)
        finally:
            shutil.rmtree(d)
    n = len(rs)
    return {"wall_us_per_row": 1e6 * float(np.median(walls)) / n, "cpu_us_per_row": 1e6 * float(np.median(cpus)) / n}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    rs = rows(args.rows)
    FRAMES[:] = _frames(rs[:300])  # the video: at most 300 frames (ten seconds)
    for fn in (stream_rrd, stream_bag):  # warm-up: imports, type stores
        timed(fn, rs[:10], 1)
    results = {}
    print(f"{'writer':8} {'streaming wall/cpu us/row':>28} {'batch wall/cpu us/row':>24}")
    for name, (stream, batch) in CASES.items():
        data = rs[:len(FRAMES)] if name == "video" else rs
        s, b = timed(stream, data, args.repeat), timed(batch, data, args.repeat)
        results[name] = {"streaming": s, "batch": b}
        print(f"{name:8} {s['wall_us_per_row']:16.1f} / {s['cpu_us_per_row']:7.1f} "
              f"{b['wall_us_per_row']:14.1f} / {b['cpu_us_per_row']:7.1f}")
    out = Path(__file__).resolve().parent / "results" / "streaming_results.json"
    out.write_text(json.dumps({"rows": args.rows, "repeat": args.repeat, "results": results,
                               "machine": machine()}, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
