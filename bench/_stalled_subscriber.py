"""A subscriber that matches ROS 2's default QoS on every pose topic and /tf, then stops (SIGSTOP itself) or never takes."""
import os, signal, sys, time
from mutloc.live.dds import Bus
from mutloc.live import messages as M
domain, mode, topics = int(sys.argv[1]), sys.argv[2], sys.argv[3:]
bus = Bus(domain, loopback=True)
T = M.ros_types()
readers = [bus.reader(t, T.TFMessage if t == "/tf" else T.PoseWithCovarianceStamped) for t in topics]
deadline = time.time() + 20
while time.time() < deadline and not all(r.native.get_matched_publications() for r in readers):
    time.sleep(0.05)
print("matched", flush=True)
if mode == "stop":
    os.kill(os.getpid(), signal.SIGSTOP)
while True:
    time.sleep(1 if mode == "idle" else 0.5)
    if mode == "slow":
        for r in readers:
            r.take(1)
