"""Live, end to end (issue 25's acceptance): two ``mutloc node`` processes
replaying rendered cameras in real time and a ``mutloc localizer`` process,
on DDS over the loopback interface.  A subscriber written here with
cyclonedds and its OWN type definitions (not mutloc's) receives the poses:
at least 90% of those expected, with errors against the rendered truth
those of offline ``track`` on the same images (the filter without the
smoother's lag, as a live pose is published at once)."""

import os
import shutil
import threading
import time
from dataclasses import dataclass, field

import numpy as np
import pytest
from _shared_inputs import clock_offset_pair

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float64, int32, uint32
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from mutloc.core.geometry import matrix_from_quaternion_xyzw, rotation_error_deg
from mutloc.live.dds import LOOPBACK_CONFIG
from mutloc.live.demo import run_live_pair
from mutloc.track.filtering import FilterOptions
from mutloc.track.sources import open_streams
from mutloc.track.tracker import track

FPS = 30.0
FRAMES = 60  # 2 s (tests/_shared_inputs.py's clock_offset_pair)


# The subscriber's own definitions of the ROS 2 types it listens to.
@dataclass
class Stamp(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Head(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Stamp = field(default_factory=Stamp)
    frame_id: str = ""


@dataclass
class P3(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Q4(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class PoseM(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: P3 = field(default_factory=P3)
    orientation: Q4 = field(default_factory=Q4)


@dataclass
class PoseCov(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: PoseM = field(default_factory=PoseM)
    covariance: array[float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class PoseCovStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovarianceStamped_"):
    header: Head = field(default_factory=Head)
    pose: PoseCov = field(default_factory=PoseCov)


def _listen(domain, stop, got):
    dp = DomainParticipant(domain)
    qos = Qos(Policy.Reliability.Reliable(max_blocking_time=100_000_000), Policy.Durability.Volatile,
              Policy.History.KeepLast(10))
    reader = DataReader(dp, Topic(dp, "rt/mutloc/p_in_q", PoseCovStamped, qos=qos), qos=qos)
    while not stop.is_set():
        for m in reader.take(N=64):
            if isinstance(m, PoseCovStamped):
                got.append(m)
        time.sleep(0.005)


def test_two_nodes_and_a_localizer_deliver_the_poses_to_any_subscriber(tmp_path, tmp_path_factory, dds_domain):
    # The rendered pair of tests/test_track_stream_clocks.py (rendered once per run), both cameras on the
    # true clock here: q's frames.csv (the reference's, the true times) for both.
    sim = tmp_path / "sim"
    shutil.copytree(clock_offset_pair(tmp_path_factory), sim)
    assert len(list((sim / "p").glob("*.png"))) == len(list((sim / "q").glob("*.png"))) == FRAMES
    (sim / "p" / "frames.csv").write_text((sim / "q" / "frames.csv").read_text())
    times = [float(line.split(",")[1]) for line in (sim / "q" / "frames.csv").read_text().splitlines()[1:]]
    truth = _truth(sim / "truth.tum")

    # offline, the same images
    offline = track(sim / "rig.yaml", open_streams({"p": sim / "p", "q": sim / "q"}), progress=False,
                    filter=FilterOptions(smooth_lag=0))
    off_err = [np.linalg.norm(r.estimate.t - truth[round(r.t * FPS)][1]) for r in offline.rows
               if r.estimate is not None]

    domain = dds_domain
    loopback = Domain(domain, LOOPBACK_CONFIG)  # noqa: F841 -- this process's domain: on the loopback interface
    stop, got = threading.Event(), []
    listener = threading.Thread(target=_listen, args=(domain, stop, got), daemon=True)
    listener.start()
    try:
        summary = run_live_pair(sim / "rig.yaml", {"p": sim / "p", "q": sim / "q"}, tmp_path / "live",
                                seconds=FRAMES / FPS, domain=domain, lead_in=5.0)
    finally:
        stop.set()
        listener.join(5.0)
    # both cameras' messages arrive; the simulated cameras are synchronized, so the
    # localizer fuses the two of each frame time as one record (as track pairs them): one pose each
    _accounted(summary, len(got), len(times))
    # each pose against the truth of its capture: frame k was released at start_at + k / FPS
    errs = []
    for m in got:
        k = round((_ns(m.header.stamp) * 1e-9 - summary["start_at"]) * FPS)
        assert 0 <= k < len(truth)
        q, pos = m.pose.pose.orientation, m.pose.pose.position
        R = matrix_from_quaternion_xyzw(np.array([q.x, q.y, q.z, q.w]))
        errs.append(np.linalg.norm(np.array([pos.x, pos.y, pos.z]) - truth[k][1]))
        assert rotation_error_deg(R, truth[k][0]) < 2.0
    # the same as offline causal tracking of the same images (measured: equal to 1e-6 m)
    assert np.median(errs) <= 1.25 * np.median(off_err) + 0.0002, (np.median(errs), np.median(off_err))
    assert max(errs) < 0.05


def _ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _truth(path):
    out = []
    for line in path.read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        v = [float(x) for x in line.split()]
        out.append((matrix_from_quaternion_xyzw(np.array(v[4:8])), np.array(v[1:4])))
    return out


pytestmark = pytest.mark.slow


def _accounted(summary, received, frames):
    """Every frame of the run is accounted for and every pose delivered: the
    nodes published what they did not drop (counted), this process received
    it; each record (a frame time, both cameras) was fused or its messages
    shed by the localizer (counted: a loaded machine sheds, it does not fall
    behind); the localizer published a pose for the records it fused (after
    the first, which starts the track, and those before the rig check's first
    window agreed, counted) and this process received them."""
    loc, nodes = summary["localizer"], summary["nodes"]
    assert loc is not None and all(n is not None for n in nodes.values()), summary
    assert all(n["captured"] == frames for n in nodes.values()), nodes
    published = sum(n["processed"] for n in nodes.values())
    dropped = sum(n["dropped"] for n in nodes.values())
    assert published + dropped >= sum(n["captured"] for n in nodes.values()), nodes
    assert summary["observation_messages"] >= 0.9 * published
    assert loc["records_fused"] + (loc["shed"] + dropped) / 2 >= 0.9 * frames, (loc, nodes)
    assert loc["poses_published"] + loc["rig_waiting"] + loc["rig_withheld"] >= loc["records_fused"] - 2, loc
    assert loc["rig_waiting"] > 0  # (no pose before the rig check's window, 30 records, was full and agreed)
    assert received >= 0.9 * loc["poses_published"] and received >= 1, (received, loc)


def test_demo_live_prints_what_a_subscriber_received(tmp_path, capsys, dds_domain):
    """``mutloc demo --live`` (5 s at 10 frames/s: the rig check's first window, 30 records, has agreed
    before the end): poses received,
    their error against the rendered truth and the latency, in its summary
    and live_summary.json."""
    import json

    from mutloc.cli.main import main

    assert main(["demo", "--live", "--seconds", "5", "--fps", "10", "--out", str(tmp_path),
                 "--domain", str(dds_domain), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    summary = json.loads((tmp_path / "live" / "live_summary.json").read_text())
    _accounted(summary, summary["poses_received"], 50)
    assert summary["translation_error_cm"]["median"] < 0.5
    assert f"poses of p in q received: {summary['poses_received']}" in printed
    assert "latency capture -> pose received" in printed
