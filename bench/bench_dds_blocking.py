#!/usr/bin/env python
"""Does a reliable DDS writer wait for a stalled reader?  (Cyclone DDS, the
binding mutloc uses; the answer behind the live guide's QoS section.)

    python bench/bench_dds_blocking.py            # keep-last 10 (mutloc's writers), then keep-all

A subscriber process (bench/_stalled_subscriber.py: ROS 2's default QoS)
matches a pose writer in this process and stops itself (SIGSTOP), so it
never acknowledges a sample; this process then writes a pose every
millisecond for 5 s and times each ``write``.  With keep-last history the
writer keeps the last samples and goes on; with keep-all it must keep every
unacknowledged sample, and ``write`` blocks up to the writer's
``max_blocking_time`` (here 100 ms) and then fails.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from mutloc.core.pose import Pose
from mutloc.live import messages as M


def run(keep_all: bool, domain: int, seconds: float = 5.0) -> dict:
    from cyclonedds.core import Policy, Qos
    from cyclonedds.pub import DataWriter

    from mutloc.live.dds import Bus

    bus = Bus(domain, loopback=True)
    T = M.ros_types()
    history = Policy.History.KeepAll if keep_all else Policy.History.KeepLast(10)
    qos = Qos(Policy.Reliability.Reliable(max_blocking_time=100_000_000), Policy.Durability.Volatile, history)
    writer = DataWriter(bus.participant, bus._topic("/mutloc/p_in_q", T.PoseWithCovarianceStamped), qos=qos)
    sub = subprocess.Popen([sys.executable, str(Path(__file__).resolve().parent / "_stalled_subscriber.py"),
                            str(domain), "stop", "/mutloc/p_in_q"], stdout=subprocess.PIPE, text=True,
                           start_new_session=True)
    try:
        if sub.stdout.readline().strip() != "matched":
            raise RuntimeError("the subscriber did not match")
        while not writer.get_matched_subscriptions():
            time.sleep(0.05)
        pm, _ = M.pose_cdr(0, Pose(np.eye(3), np.zeros(3)), None, "p", "q")
        sample = M.raw_sample(T.PoseWithCovarianceStamped, pm)
        took, failed = [], 0
        end = time.time() + seconds
        while time.time() < end:
            t = time.perf_counter()
            try:
                writer.write(sample)
            except Exception:  # noqa: BLE001 -- DDS_RETCODE_TIMEOUT: the sample is not written
                failed += 1
            took.append(time.perf_counter() - t)
            time.sleep(0.001)
    finally:
        os.killpg(sub.pid, 9)
        sub.wait()
        bus.close()
    ms = np.array(took) * 1000
    return {"history": "keep-all" if keep_all else "keep-last 10", "writes": len(ms), "failed": failed,
            "write_ms_p50": round(float(np.median(ms)), 3), "write_ms_p99": round(float(np.percentile(ms, 99)), 3),
            "write_ms_max": round(float(ms.max()), 1)}


def main() -> int:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _machine import dds_domain

    with dds_domain() as lease:
        for keep_all in (False, True):
            print(json.dumps({**run(keep_all, lease.domain), "load_average": os.getloadavg()}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
