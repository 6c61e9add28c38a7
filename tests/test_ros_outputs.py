"""The trajectory as ROS 2 messages (rosbag2 folder, MCAP file), read back
with rosbags and mcap-ros2-support and compared with trajectory.csv."""

import numpy as np
import pytest

from mutloc.cli.main import main
from mutloc.core.geometry import so3_exp
from mutloc.io import save_rig
from mutloc.io.logs import write_observation_log
from mutloc.io.ros import ros_covariance, spec_covariance
from mutloc.io.trajectory import read_trajectory_csv
from mutloc.sim.render import default_path
from mutloc.sim.tracking import observation_sequence
from mutloc.sim.world import standard_rig


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ros")
    rig = standard_rig("balls")
    seq = observation_sequence(rig, default_path(2.0, 12.0, 0.3), duration=2.0, fps=30.0, pixel_sigma=1.0, seed=2,
                               blind=((0.8, 1.2, "p"),))
    save_rig(rig, tmp / "rig.yaml")
    write_observation_log(tmp / "log.jsonl", seq.frames)
    assert main(["track", "--rig", str(tmp / "rig.yaml"), "--observations", str(tmp / "log.jsonl"), "--out",
                 str(tmp / "out"), "--bag", str(tmp / "out" / "bag"), "--mcap", str(tmp / "out" / "traj.mcap"),
                 "--no-progress"]) == 0
    rows = [r for r in read_trajectory_csv(tmp / "out" / "trajectory.csv") if r["pose"] is not None]
    assert len(rows) >= 55
    return tmp, rows


def _check(messages, rows):
    """messages: (topic, time ns, msg) from a reader; checked against the CSV rows."""
    poses = [(t, m) for topic, t, m in messages if topic == "/mutloc/p_in_q"]
    tfs = [(t, m) for topic, t, m in messages if topic == "/tf"]
    assert len(poses) == len(tfs) == len(rows)
    for (t, m), (t2, tf), row in zip(poses, tfs, rows):
        stamp = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
        assert stamp == pytest.approx(row["t"], abs=1e-9) and t == t2 == int(round(row["t"] * 1e9))
        assert m.header.frame_id == "q"
        p = m.pose.pose
        np.testing.assert_allclose([p.position.x, p.position.y, p.position.z], row["pose"].t, atol=1e-9)
        q = np.array([p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w])
        np.testing.assert_allclose(q, row["pose"].quaternion_xyzw, atol=1e-9)
        cov = np.asarray(m.pose.covariance, float).reshape(6, 6)
        # ROS order: x, y, z, then rotation; the CSV's sigmas are SPEC order (rotation first).
        np.testing.assert_allclose(np.sqrt(np.diag(cov)), np.r_[row["sigma"][3:], row["sigma"][:3]], rtol=1e-6)
        np.testing.assert_allclose(cov, cov.T)
        (ts,) = tf.transforms
        assert ts.header.frame_id == "q" and ts.child_frame_id == "p"
        tr = ts.transform
        np.testing.assert_allclose([tr.translation.x, tr.translation.y, tr.translation.z], row["pose"].t, atol=1e-9)
        np.testing.assert_allclose([tr.rotation.x, tr.rotation.y, tr.rotation.z, tr.rotation.w], q, atol=1e-12)


def test_ros2_bag_reads_back(tracked):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    tmp, rows = tracked
    store = get_typestore(Stores.ROS2_HUMBLE)
    with Reader(tmp / "out" / "bag") as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types == {"/mutloc/p_in_q": "geometry_msgs/msg/PoseWithCovarianceStamped",
                         "/tf": "tf2_msgs/msg/TFMessage"}
        msgs = [(c.topic, t, store.deserialize_cdr(raw, c.msgtype)) for c, t, raw in reader.messages()]
    _check(msgs, rows)


def test_mcap_reads_back(tracked):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    tmp, rows = tracked
    with open(tmp / "out" / "traj.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        decoded = list(reader.iter_decoded_messages())
    assert {s.name for s, _, _, _ in decoded} == {"geometry_msgs/msg/PoseWithCovarianceStamped",
                                                   "tf2_msgs/msg/TFMessage"}
    assert {c.message_encoding for _, c, _, _ in decoded} == {"cdr"}
    _check([(c.topic, m.log_time, msg) for _, c, m, msg in decoded], rows)


def test_covariance_order_is_ros_order():
    """A covariance with only the x-translation variance set lands at ROS index 0."""
    c = np.zeros((6, 6))
    c[3, 3] = 4.0  # SPEC: sigma_tx
    c[0, 4] = c[4, 0] = 0.5  # rx-ty
    r = ros_covariance(c)
    assert r[0, 0] == 4.0 and r[3, 1] == r[1, 3] == 0.5 and np.count_nonzero(r) == 3
    np.testing.assert_array_equal(spec_covariance(r.reshape(-1)), c)
    # A rotation perturbation about the parent's x axis moves a point on the parent's y axis along z,
    # whichever order: the ROS rotation block is the SPEC's left rotation vector.
    R = so3_exp([1e-6, 0, 0])
    assert (R @ [0, 1, 0])[2] > 0


def test_existing_output_is_refused(tracked, capsys):
    tmp, _ = tracked
    assert main(["track", "--rig", str(tmp / "rig.yaml"), "--observations", str(tmp / "log.jsonl"), "--out",
                 str(tmp / "out2"), "--bag", str(tmp / "out" / "bag"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mutloc: error:") and "already exists" in err and err.count("\n") == 1
