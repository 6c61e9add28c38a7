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
    # a robot with several cameras: a camera's observations (frame_id ROBOT/CAMERA), the mounts for /tf_static
    body = ObservationSet.from_dict({"p/front": {"M1": [100.5, 20.25]}, "p/back": {"M2": [3.0, 4.0]}})
    yield M.observations_message("p", "0123456789abcdef", 8, 12.5, body, source_time=0.5, frame_id="p/back")
    from mutloc.sim.body_scenes import fisheye_pair_rig

    yield M.static_transforms_message(fisheye_pair_rig("balls"), 5.125)
    odo = M.odometry_message(7.5, pose, A @ A.T, "p", "p_odom")
    odo.twist = T.TwistWithCovariance(twist=T.Twist(linear=T.Vector3(0.5, -0.25, 0.125), angular=T.Vector3(0, 0, 1.5)),
                                      covariance=[float(i) / 7 for i in range(36)])
    yield odo


@pytest.mark.parametrize("index", range(11))
def test_each_type_serialises_byte_identical_to_rosbags(store, index):
    msg = list(_samples())[index]
    T = M.ros_types()
    ours = bytes(msg.serialize())
    theirs = bytes(store.serialize_cdr(_to_rosbags(store, msg), T.ros_name[type(msg)]))
    assert ours == theirs
    assert type(msg).deserialize(ours) == msg


def test_odometry_message_carries_the_pose_and_spec_covariance_back():
    from mutloc.io.ros import odometry_sample

    pose = Pose.from_rotvec([0.1, -0.2, 0.3], [1.0, 2.0, 3.0])
    A = RNG.normal(size=(6, 6))
    msg = M.ros_types().Odometry.deserialize(M.odometry_message(12.25, pose, A @ A.T, "p").serialize())
    assert M.ros_types().Odometry.__idl_typename__ == "nav_msgs::msg::dds_::Odometry_"
    t, back, cov, child = odometry_sample(msg)
    assert t == 12.25 and child == "p" and msg.header.frame_id == "odom"
    np.testing.assert_allclose(back.R, pose.R, atol=1e-12)
    np.testing.assert_allclose(back.t, pose.t)
    np.testing.assert_allclose(cov, A @ A.T)


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


def _observation_messages():
    obs = ObservationSet.from_dict({"p": {"M1": [612.25, 281.5], "M2": [701.0, 280.4], "é": [1.5, -2.0]}})
    yield M.observations_message("p", "0123456789abcdef", 7, 12.345678901, obs, source_time=0.4)
    yield M.observations_message("robot_one", "ab", 2**32 - 1, 1.5, None)  # nothing seen
    cands = ObservationSet(["q", "q", "q"], ["M1", "M1", None], [[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]],
                           score=[0.75, 0.25, 0.125])
    yield M.observations_message("q", "", 0, 0.0, cands)  # candidates, an unnamed detection, empty strings


@pytest.mark.parametrize("index", range(3))
def test_observations_from_cdr_decodes_what_the_binding_decodes(index):
    """The localizer's decoder gives the binding's message from the same
    bytes, in either byte order, and refuses every truncation of them."""
    from cyclonedds.idl._support import Endianness

    T = M.ros_types()
    msg = list(_observation_messages())[index]
    for order in (Endianness.Little, Endianness.Big):
        data = bytes(msg.serialize(endianness=order))
        assert data[1] == (1 if order == Endianness.Little else 0)
        got = M.observations_from_cdr(data)
        assert got == T.Observations.deserialize(data) == msg
        for cut in range(len(data)):  # (the last field ends the message: no padding after it)
            with pytest.raises(M.MessageError):
                M.observations_from_cdr(data[:cut])


def test_observations_from_cdr_never_accepts_what_the_binding_refuses():
    """Fuzzed bytes: what the decoder takes, the binding decodes to the same
    message (the decoder is the stricter of the two), and it refuses with a
    MessageError only."""
    T = M.ros_types()
    template = bytes(next(_observation_messages()).serialize())
    rng = np.random.default_rng(11)
    taken = 0
    for i in range(3000):
        b = bytearray(template)
        if i % 3 == 0:
            for k in rng.integers(0, len(b), size=rng.integers(1, 6)):
                b[k] = rng.integers(256)
        elif i % 3 == 1:
            b = b[:rng.integers(0, len(b))] + bytes(rng.integers(0, 4))  # truncated, maybe padded
        else:
            b = bytearray(rng.integers(0, 256, rng.integers(4, 200), dtype=np.uint8).tobytes())
            b[0], b[1] = 0, i % 2  # a plain CDR header
        try:
            got = M.observations_from_cdr(bytes(b))
        except M.MessageError:
            continue
        taken += 1
        assert got == T.Observations.deserialize(bytes(b))
    assert taken > 100  # (byte flips in the numbers still decode)


def test_pose_cdr_from_a_shared_body_is_the_same_bytes():
    pose = Pose.from_rotvec(RNG.normal(size=3), RNG.normal(size=3))
    A = RNG.normal(size=(6, 6))
    body = M.pose_cdr_body(pose, A @ A.T, "robot_one", "q")
    for ns in (0, 1, 1_800_000_000_123_456_789, 2**31 * 10**9 - 1):
        assert M.pose_cdr(ns, None, None, "robot_one", "q", body) == M.pose_cdr(ns, pose, A @ A.T, "robot_one", "q")


def test_a_cameras_message_holds_that_cameras_observations_keyed_by_it():
    """A robot with several cameras: the message of camera p/back holds p/back's observations only, with
    frame_id p/back, and taken apart with the rig's frame_ids they are p/back's again; a frame_id naming no
    camera of the robot is refused."""
    from mutloc.sim.body_scenes import fisheye_pair_rig

    rig = fisheye_pair_rig("balls")
    obs = ObservationSet.from_dict({"p/front": {"M1": [100.5, 20.25]}, "p/back": {"M2": [3.0, 4.0]}})
    msg = M.observations_message("p", "0123456789abcdef", 8, 12.5, obs, frame_id="p/back")
    assert (msg.robot, msg.header.frame_id) == ("p", "p/back")
    assert [(o.marker, o.u, o.v) for o in msg.observations] == [("M2", 3.0, 4.0)]
    got = M.observations_from_message(type(msg).deserialize(msg.serialize()), list(rig.robots),
                                      M.observer_frame_ids(rig))
    assert got.key == "p/back" and got.observations.to_dict() == {"p/back": {"M2": (3.0, 4.0)}}
    for frame_id in ("p", "", "p/side", "q/back"):
        msg.header.frame_id = frame_id
        with pytest.raises(M.MessageError, match="frame_id"):
            M.observations_from_message(msg, list(rig.robots), M.observer_frame_ids(rig))
