"""Reading odometry: TUM files and nav_msgs/Odometry topics of ROS 1 and ROS 2
bags (written here with rosbags) give back the poses, stamps and covariances
written; what cannot be used is refused in one line naming the file or topic."""

import math

import numpy as np
import pytest

from mutloc.core.geometry import so3_exp
from mutloc.core.pose import Pose
from mutloc.errors import OdometryError
from mutloc.io.ros import ros_covariance
from mutloc.io.trajectory import write_tum
from mutloc.track.odometry import load_odometry, read_bag_odometry, read_tum_odometry


def _truth(n=40, dt=0.02):
    times = 100.0 + dt * np.arange(n)
    R = np.array([so3_exp([0.0, 0.8 * t, 0.1 * math.sin(t)]) for t in times - 100])
    tt = np.stack([np.cos(times - 100), 0.01 * (times - 100), np.sin(times - 100)], 1)
    return times, Pose(R, tt)


def write_odometry_bag(path, version, topic, times, poses, covs=None, child="p", other_topic=None):
    """A ROS 1 (version 1) or ROS 2 bag with nav_msgs/Odometry on ``topic``."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE if version == 2 else Stores.ROS1_NOETIC)
    ty = store.types
    Odo = ty["nav_msgs/msg/Odometry"]
    if version == 2:
        from rosbags.rosbag2 import Writer

        writer, ser = Writer(path, version=8), store.serialize_cdr
    else:
        from rosbags.rosbag1 import Writer

        writer, ser = Writer(path), store.serialize_ros1
    with writer:
        conn = writer.add_connection(topic, Odo.__msgtype__, typestore=store)
        if other_topic:
            writer.add_connection(other_topic, "std_msgs/msg/String", typestore=store)
        for i, (t, pose) in enumerate(zip(times, poses)):
            sec = int(t)
            hk = dict(stamp=ty["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9))),
                      frame_id="odom")
            if version == 1:
                hk["seq"] = i
            q = pose.quaternion_xyzw
            cov = np.zeros(36) if covs is None else ros_covariance(covs[i]).reshape(-1)
            msg = Odo(header=ty["std_msgs/msg/Header"](**hk), child_frame_id=child,
                      pose=ty["geometry_msgs/msg/PoseWithCovariance"](
                          pose=ty["geometry_msgs/msg/Pose"](position=ty["geometry_msgs/msg/Point"](*pose.t),
                                                            orientation=ty["geometry_msgs/msg/Quaternion"](*q)),
                          covariance=cov),
                      twist=ty["geometry_msgs/msg/TwistWithCovariance"](
                          twist=ty["geometry_msgs/msg/Twist"](linear=ty["geometry_msgs/msg/Vector3"](0, 0, 0),
                                                              angular=ty["geometry_msgs/msg/Vector3"](0, 0, 0)),
                          covariance=np.zeros(36)))
            writer.write(conn, int(t * 1e9) + 5_000_000, ser(msg, Odo.__msgtype__))


def test_tum_round_trip(tmp_path):
    times, poses = _truth()
    write_tum(tmp_path / "p.tum", times, poses)
    odo = read_tum_odometry(tmp_path / "p.tum")
    np.testing.assert_allclose(odo.times, times, atol=1e-9)
    inc = odo.increment(times[3], times[30])
    want = poses[3].inverse() @ poses[30]
    assert inc.pose.translation_error(want) < 1e-7 and np.abs(inc.pose.R - want.R).max() < 1e-7


def test_a_tum_line_cut_inside_a_number_is_refused_not_read(tmp_path):
    times, poses = _truth()
    write_tum(tmp_path / "p.tum", times, poses)
    text = (tmp_path / "p.tum").read_text()
    # a kill cut the last write inside its last number: the line is dropped (with a warning), not read
    (tmp_path / "cut.tum").write_text(text[:-4])
    with pytest.warns(UserWarning, match=r"cut\.tum:40: .*dropped"):
        odo = read_tum_odometry(tmp_path / "cut.tum")
    assert len(odo) == 39 and odo.end == pytest.approx(times[38])
    # a line cut in the middle of the file is refused with its line number
    lines = text.splitlines(keepends=True)
    lines[10] = lines[10][:30] + "\n"
    (tmp_path / "mid.tum").write_text("".join(lines))
    with pytest.raises(OdometryError, match=r"^\S*mid\.tum:11: not 8 finite numbers"):
        read_tum_odometry(tmp_path / "mid.tum")
    with pytest.raises(OdometryError, match="cannot read"):
        read_tum_odometry(tmp_path / "none.tum")


@pytest.mark.parametrize("version", [1, 2])
def test_bag_round_trip_with_covariances(tmp_path, version):
    times, poses = _truth()
    C = np.diag([1e-5, 2e-5, 3e-5, 1e-4, 2e-4, 3e-4]) + 1e-6
    covs = [k * C for k in range(len(times))]
    path = tmp_path / ("o.bag" if version == 1 else "o2")
    write_odometry_bag(path, version, "/p/odom", times, poses, covs, child="/p")
    odo = load_odometry("bag:/p/odom", "p", bag=path)
    np.testing.assert_allclose(odo.times, times, atol=1e-9)  # the header's stamps, not the record times
    assert odo.source == f"{path}:/p/odom"
    want = poses[3].inverse() @ poses[4]
    inc = odo.increment(times[3], times[4])
    assert inc.pose.translation_error(want) < 1e-12 and np.abs(inc.pose.R - want.R).max() < 1e-12
    # one interval's covariance is the growth C, rotated into the robot frame at its start
    J = np.kron(np.eye(2), poses.R[3].T)
    np.testing.assert_allclose(inc.covariance, J @ C @ J.T, rtol=1e-6, atol=1e-15)


@pytest.mark.parametrize("version", [1, 2])
def test_bag_odometry_refusals(tmp_path, version):
    times, poses = _truth()
    path = tmp_path / ("o.bag" if version == 1 else "o2")
    write_odometry_bag(path, version, "/p/odom", times, poses, child="base_link", other_topic="/p/chatter")
    with pytest.raises(OdometryError, match=r"/p/odom: child_frame_id 'base_link' at stamp 100\.000000000 is not "
                                            r"robot 'p'"):
        read_bag_odometry(path, "/p/odom", "p")
    with pytest.raises(OdometryError, match=r"no topic '/q/odom' \(odometry topics: /p/odom\)$"):
        read_bag_odometry(path, "/q/odom", "p")
    with pytest.raises(OdometryError, match=r"/p/chatter: a std_msgs/msg/String topic, not nav_msgs/msg/Odometry"):
        read_bag_odometry(path, "/p/chatter", "p")
    with pytest.raises(OdometryError, match="has none"):
        load_odometry("bag:/p/odom", "p", bag=None)
    with pytest.raises(OdometryError, match=r"a bag topic is bag:/TOPIC"):
        load_odometry("bag:p/odom", "p", bag=path)


def test_an_unset_child_frame_is_taken_and_a_nan_message_rejected(tmp_path):
    times, poses = _truth()
    t = poses.t.copy()
    t[7] = np.nan
    write_odometry_bag(tmp_path / "o2", 2, "/odom", times, Pose(poses.R, t), child="")
    odo = read_bag_odometry(tmp_path / "o2", "/odom", "p")
    assert odo.counts["invalid"] == 1 and len(odo) == len(times) - 1
