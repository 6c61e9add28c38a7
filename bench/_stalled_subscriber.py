"""A stalled subscriber for bench_localizer.py --stalled: subscribed to the
given ROS 2 topics with ROS 2's default QoS (reliable, volatile, keep-last
10); once every one matched a writer it prints "matched" and then stops
itself (SIGSTOP: it never acknowledges a sample again) or, ``idle``, never
takes a sample.

    python bench/_stalled_subscriber.py DOMAIN stop|idle /mutloc/r1_in_r0 ... /tf
"""

import os
import signal
import sys
import time

from mutloc.live import messages as M
from mutloc.live.dds import Bus

domain, mode, topics = int(sys.argv[1]), sys.argv[2], sys.argv[3:]
bus = Bus(domain, loopback=True)
T = M.ros_types()
readers = [bus.reader(t, T.TFMessage if t == M.TF_TOPIC else T.PoseWithCovarianceStamped) for t in topics]
deadline = time.time() + 20
while time.time() < deadline and not all(r.native.get_matched_publications() for r in readers):
    time.sleep(0.05)
print("matched", flush=True)
if mode == "stop":
    os.kill(os.getpid(), signal.SIGSTOP)
while True:
    time.sleep(1.0)
