"""The live messages are ROS 2's on the wire: every type serialises to the
same CDR bytes as rosbags' ROS 2 serialisation of the same content (the
standard types from rosbags' Humble store, mutloc_msgs from the shipped
``.msg`` files), and a message survives the round trip."""

import math

import numpy as np
import pytest


from rosbags.typesys import Stores, get_typestore, get_types_from_msg  # noqa: E402

from mutloc.core.observations import ObservationSet  # noqa: E402
from mutloc.core.pose import Pose  # noqa: E402
from mutloc.errors import InputError  # noqa: E402
from mutloc.io.ros import spec_covariance  # noqa: E402
from mutloc.live import messages as M  # noqa: E402

RNG = np.random.default_rng(3)


@pytest.fixture(scope="module")
def store():
    ts = get_typestore(Stores.ROS2_HUMBLE)
    add = {}
    for name in ("Observation", "Observations"):
        text = (M.MSG_PACKAGE / "msg" / f"{name}.msg").read_text()
        add.update(get_types_from_msg(text, f"mutloc_msgs/msg/{name}"))
    ts.register(add)
    return ts


def _to_rosbags(ts, obj):
    """The same content as a rosbags message (built field by field from the dataclass)."""
    T = M.ros_types()
    cls = ts.types[T.ros_name[type(obj)]]
    kwargs = {}
    for f in obj.__dataclass_fields__:
        v = getattr(obj, f)
        if hasattr(v, "__idl_typename__"):
            v = _to_rosbags(ts, v)
        elif isinstance(v, list) and v and hasattr(v[0], "__idl_typename__"):
            v = [_to_rosbags(ts, x) for x in v]
        elif isinstance(v, list) and f in ("observations", "transforms", "status", "values"):
            v = [_to_rosbags(ts, x) for x in v]
        elif isinstance(v, list):
            kind = {"covariance": np.float64, "k": np.float64, "r": np.float64, "p": np.float64, "d": np.float64,
                    "data": np.uint8}[f]
            v = np.asarray(v, dtype=kind)
        kwargs[f] = v
    return cls(**kwargs)


def _samples():
    T = M.ros_types()
    obs = ObservationSet.from_dict({"p": {"M1": [612.25, 281.5], "M2": [701.0, 280.4]}, "q": {"M3": [1.0, 2.0]}})
    yield M.observations_message("p", "0123456789abcdef", 7, 12.345678901, obs, source_time=0.4)
    yield M.observations_message("q", "0123456789abcdef", 2**32 + 3, 1.5, None)
    pose = Pose.from_rotvec(RNG.normal(size=3), RNG.normal(size=3))
    A = RNG.normal(size=(6, 6))
    pm, tf = M.pose_messages(3.25, pose, A @ A.T, "p", "q")
    yield pm
    yield tf
    yield M.diagnostics_message(4.0, [M.RobotStatus("p", M.OK, "tracked", {"status": "solved", "received": 12}),
                                      M.RobotStatus("q", M.STALE, "dropped", {})])
    yield T.Image(header=T.Header(stamp=M.stamp(1.25), frame_id="q_camera"), height=2, width=3, encoding="rgb8",
                  step=9, data=list(range(18)))
    yield T.CompressedImage(header=T.Header(stamp=M.stamp(2.0), frame_id="q"), format="jpeg", data=[255, 216, 0])
    yield T.CameraInfo(header=T.Header(stamp=M.stamp(2.0), frame_id="q"), height=540, width=960,
                       distortion_model="plumb_bob", d=[0.1, -0.2, 0.0, 0.0, 0.0],
                       k=[800.0, 0, 479.5, 0, 800.0, 269.5, 0, 0, 1.0], r=[1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0],
                       p=[800.0, 0, 479.5, 0, 0, 800.0, 269.5, 0, 0, 0, 1.0, 0], binning_x=1, binning_y=2,
                       roi=T.RegionOfInterest(x_offset=1, y_offset=2, height=3, width=4, do_rectify=True))


@pytest.mark.parametrize("index", range(8))
def test_each_type_serialises_byte_identical_to_rosbags(store, index):
    msg = list(_samples())[index]
    T = M.ros_types()
    ours = bytes(msg.serialize())
    theirs = bytes(store.serialize_cdr(_to_rosbags(store, msg), T.ros_name[type(msg)]))
    assert ours == theirs
    assert type(msg).deserialize(ours) == msg


def test_dds_type_names_follow_ros2():
    T = M.ros_types()
    assert T.Observations.__idl_typename__ == "mutloc_msgs::msg::dds_::Observations_"
    assert T.PoseWithCovarianceStamped.__idl_typename__ == "geometry_msgs::msg::dds_::PoseWithCovarianceStamped_"
    assert M.dds_topic(M.observations_topic("p")) == "rt/mutloc/p/observations"
    assert M.dds_topic(M.TF_TOPIC) == "rt/tf"


def test_observations_round_trip_and_refusals():
    obs = ObservationSet.from_dict({"p": {"M1": [612.25, 281.5], "M2": [701.0, 280.4]}})
    msg = M.observations_message("p", "abc", 9, 100.000000123, obs)
    got = M.observations_from_message(type(msg).deserialize(msg.serialize()), robots=["p", "q"])
    assert got.robot == "p" and got.frame == 9 and got.rig_id == "abc"
    assert math.isclose(got.time, 100.000000123, abs_tol=1e-9)
    assert got.observations.marker == ("M1", "M2")
    np.testing.assert_array_equal(got.observations.uv, obs.uv)
    with pytest.raises(M.MessageError, match="not in the rig"):
        M.observations_from_message(msg, robots=["q", "r"])
    msg.observations[0].u = float("nan")
    with pytest.raises(M.MessageError, match="non-finite"):
        M.observations_from_message(msg)
    assert issubclass(M.MessageError, InputError)


def test_pose_message_carries_the_spec_pose_and_covariance():
    pose = Pose.from_rotvec([0.1, -0.2, 0.3], [1.0, 2.0, 3.0])
    A = RNG.normal(size=(6, 6))
    cov = A @ A.T
    pm, tf = M.pose_messages(1.0, pose, cov, "p", "q")
    assert pm.header.frame_id == "q" and tf.transforms[0].child_frame_id == "p"
    np.testing.assert_allclose(spec_covariance(pm.pose.covariance), cov)
    q = pm.pose.pose.orientation
    back = Pose.from_quaternion_xyzw([q.x, q.y, q.z, q.w], [pm.pose.pose.position.x, pm.pose.pose.position.y,
                                                            pm.pose.pose.position.z])
    np.testing.assert_allclose(back.R, pose.R, atol=1e-12)


def test_rig_id_is_the_first_16_hex_digits_of_the_files_sha256(tmp_path):
    import hashlib

    f = tmp_path / "rig.yaml"
    f.write_bytes(b"robots: {}\n")
    assert M.rig_id(f) == hashlib.sha256(b"robots: {}\n").hexdigest()[:16] == M.rig_id(b"robots: {}\n")


def test_the_ros_package_is_shipped():
    assert (M.MSG_PACKAGE / "package.xml").is_file() and (M.MSG_PACKAGE / "CMakeLists.txt").is_file()
    text = (M.MSG_PACKAGE / "msg" / "Observations.msg").read_text()
    assert "mutloc_msgs/Observation[] observations" in text


@pytest.mark.parametrize("names", [("p", "q"), ("robot_one", "r"), ("ab", "abcdefg"), ("x" * 9, "y" * 3)])
def test_pose_cdr_is_the_serialised_pose_messages(names):
    """The localizer's packed poses are byte for byte the messages' CDR, whatever the names' lengths (padding)."""
    source, target = names
    for k in range(5):
        pose = Pose.from_rotvec(RNG.normal(size=3), RNG.normal(size=3))
        A = RNG.normal(size=(6, 6))
        ns = int(RNG.integers(0, 2**31 * 10**9))
        pm, tf = M.pose_messages(0.0, pose, A @ A.T if k else None, source, target)
        st = M.ros_types().Time(sec=ns // 10**9, nanosec=ns % 10**9)
        pm.header.stamp = tf.transforms[0].header.stamp = st
        assert M.pose_cdr(ns, pose, A @ A.T if k else None, source, target) == (bytes(pm.serialize()),
                                                                                  bytes(tf.serialize()))
