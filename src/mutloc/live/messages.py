"""ROS 2 messages on the DDS wire, without ROS.

A ROS 2 node is a DDS participant: a ROS 2 message ``pkg/msg/Name`` travels
as DDS type ``pkg::msg::dds_::Name_`` on topic ``rt/<ros topic>``, serialised
as CDR (little endian, XCDR1).  The types here follow the ROS 2 (Humble and
later) definitions field by field, so the bytes are the ones ``rmw_cyclonedds``
puts on the wire and rosbags writes in a bag (``tests/test_live_messages.py``
checks every type against rosbags' serialisation).  mutloc's own types,
``mutloc_msgs/msg/Observations`` and ``Observation``, are defined by the
``.msg`` files shipped in :data:`MSG_PACKAGE` (a ROS 2 package ROS users can
build with colcon).

The types need ``cyclonedds`` (the ``live`` extra); they are built on the
first call of :func:`ros_types`.  Converting to and from mutloc's objects:
:func:`observations_message` / :func:`observations_from_message`,
:func:`pose_messages`, :func:`diagnostics_message`.
"""

# No "from __future__ import annotations": cyclonedds reads the field types of the classes in ros_types().
import hashlib
import math
import struct
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Iterable, Sequence

import numpy as np

from .._extras import require
from ..core.observations import ObservationSet
from ..core.pose import Pose
from ..errors import InputError
from ..io.ros import TF_TOPIC, pose_topic, ros_covariance

__all__ = ["ros_types", "MSG_PACKAGE", "rig_id", "observations_topic", "dds_topic", "OBSERVATIONS_TYPE",
           "observations_message", "observations_from_message", "observations_from_cdr", "observations_peek", "pose_messages", "pose_cdr",
           "pose_cdr_body", "raw_sample", "diagnostics_message", "odometry_message",
           "stamp_of", "stamp", "MessageError", "RobotStatus", "DIAGNOSTICS_TOPIC", "TF_TOPIC", "TF_STATIC_TOPIC",
           "pose_topic", "static_transforms_message", "observer_frame_ids",
           "OK", "WARN", "ERROR", "STALE"]

#: The ROS 2 package of mutloc's message definitions (``package.xml``, ``msg/*.msg``).
MSG_PACKAGE = Path(__file__).resolve().parent / "msg" / "mutloc_msgs"
OBSERVATIONS_TYPE = "mutloc_msgs/msg/Observations"
DIAGNOSTICS_TOPIC = "/diagnostics"
#: Where tf2's static broadcasters publish (transient-local, keep-last 1: late joiners get the last message).
TF_STATIC_TOPIC = "/tf_static"
#: ``diagnostic_msgs/msg/DiagnosticStatus`` levels.
OK, WARN, ERROR, STALE = 0, 1, 2, 3


class MessageError(InputError):
    """A message that cannot be taken: malformed content, another rig, a wrong robot."""


def rig_id(data: bytes | str | Path) -> str:
    """The SPEC's ``rig_id`` of a rig file (its bytes, or its path): the first
    16 hex digits of the SHA-256 of the file's bytes."""
    if not isinstance(data, bytes):
        data = Path(data).expanduser().read_bytes()
    return hashlib.sha256(data).hexdigest()[:16]


def observations_topic(robot: str) -> str:
    """``/mutloc/NAME/observations``: where robot NAME's node publishes."""
    return f"/mutloc/{robot}/observations"


def dds_topic(ros_topic: str) -> str:
    """The DDS topic name of a ROS 2 topic (``/tf`` -> ``rt/tf``)."""
    return "rt/" + ros_topic.lstrip("/")


@cache
def ros_types() -> SimpleNamespace:
    """The message types (cyclonedds ``IdlStruct`` dataclasses), by ROS name's
    last part: ``Time``, ``Header``, ``Observation``, ``Observations``, ``Point``,
    ``Quaternion``, ``Pose``, ``PoseWithCovariance``, ``PoseWithCovarianceStamped``,
    ``Vector3``, ``Transform``, ``TransformStamped``, ``TFMessage``, ``Twist``,
    ``TwistWithCovariance``, ``Odometry`` (``nav_msgs/msg/Odometry``), ``KeyValue``,
    ``DiagnosticStatus``, ``DiagnosticArray``, ``RegionOfInterest``, ``Image``,
    ``CompressedImage``, ``CameraInfo``; ``ros_name[cls]`` is each one's
    ``pkg/msg/Name``."""
    require("cyclonedds", "ROS 2 messages over DDS")
    from dataclasses import dataclass as idl, field

    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl.types import array, byte, float32, float64, int32, sequence, uint8, uint32

    def name(ros: str) -> str:
        pkg, _, msg = ros.split("/")
        return f"{pkg}::msg::dds_::{msg}_"

    @idl
    class Time(IdlStruct, typename=name("builtin_interfaces/msg/Time")):
        sec: int32 = 0
        nanosec: uint32 = 0

    @idl
    class Header(IdlStruct, typename=name("std_msgs/msg/Header")):
        stamp: Time = field(default_factory=Time)
        frame_id: str = ""

    @idl
    class Observation(IdlStruct, typename=name("mutloc_msgs/msg/Observation")):
        marker: str = ""
        u: float64 = 0.0
        v: float64 = 0.0
        score: float32 = 0.0

    @idl
    class Observations(IdlStruct, typename=name(OBSERVATIONS_TYPE)):
        header: Header = field(default_factory=Header)
        robot: str = ""
        rig_id: str = ""
        frame: uint32 = 0
        source_time: float64 = 0.0
        observations: sequence[Observation] = field(default_factory=list)

    @idl
    class Point(IdlStruct, typename=name("geometry_msgs/msg/Point")):
        x: float64 = 0.0
        y: float64 = 0.0
        z: float64 = 0.0

    @idl
    class Vector3(IdlStruct, typename=name("geometry_msgs/msg/Vector3")):
        x: float64 = 0.0
        y: float64 = 0.0
        z: float64 = 0.0

    @idl
    class Quaternion(IdlStruct, typename=name("geometry_msgs/msg/Quaternion")):
        x: float64 = 0.0
        y: float64 = 0.0
        z: float64 = 0.0
        w: float64 = 1.0

    @idl
    class PoseMsg(IdlStruct, typename=name("geometry_msgs/msg/Pose")):
        position: Point = field(default_factory=Point)
        orientation: Quaternion = field(default_factory=Quaternion)

    @idl
    class PoseWithCovariance(IdlStruct, typename=name("geometry_msgs/msg/PoseWithCovariance")):
        pose: PoseMsg = field(default_factory=PoseMsg)
        covariance: array[float64, 36] = field(default_factory=lambda: [0.0] * 36)

    @idl
    class PoseWithCovarianceStamped(IdlStruct, typename=name("geometry_msgs/msg/PoseWithCovarianceStamped")):
        header: Header = field(default_factory=Header)
        pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)

    @idl
    class Transform(IdlStruct, typename=name("geometry_msgs/msg/Transform")):
        translation: Vector3 = field(default_factory=Vector3)
        rotation: Quaternion = field(default_factory=Quaternion)

    @idl
    class TransformStamped(IdlStruct, typename=name("geometry_msgs/msg/TransformStamped")):
        header: Header = field(default_factory=Header)
        child_frame_id: str = ""
        transform: Transform = field(default_factory=Transform)

    @idl
    class TFMessage(IdlStruct, typename=name("tf2_msgs/msg/TFMessage")):
        transforms: sequence[TransformStamped] = field(default_factory=list)

    @idl
    class Twist(IdlStruct, typename=name("geometry_msgs/msg/Twist")):
        linear: Vector3 = field(default_factory=Vector3)
        angular: Vector3 = field(default_factory=Vector3)

    @idl
    class TwistWithCovariance(IdlStruct, typename=name("geometry_msgs/msg/TwistWithCovariance")):
        twist: Twist = field(default_factory=Twist)
        covariance: array[float64, 36] = field(default_factory=lambda: [0.0] * 36)

    @idl
    class Odometry(IdlStruct, typename=name("nav_msgs/msg/Odometry")):
        header: Header = field(default_factory=Header)
        child_frame_id: str = ""
        pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
        twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)

    @idl
    class KeyValue(IdlStruct, typename=name("diagnostic_msgs/msg/KeyValue")):
        key: str = ""
        value: str = ""

    @idl
    class DiagnosticStatus(IdlStruct, typename=name("diagnostic_msgs/msg/DiagnosticStatus")):
        level: byte = 0  # ROS 2 "byte": IDL octet
        name: str = ""
        message: str = ""
        hardware_id: str = ""
        values: sequence[KeyValue] = field(default_factory=list)

    @idl
    class DiagnosticArray(IdlStruct, typename=name("diagnostic_msgs/msg/DiagnosticArray")):
        header: Header = field(default_factory=Header)
        status: sequence[DiagnosticStatus] = field(default_factory=list)

    @idl
    class RegionOfInterest(IdlStruct, typename=name("sensor_msgs/msg/RegionOfInterest")):
        x_offset: uint32 = 0
        y_offset: uint32 = 0
        height: uint32 = 0
        width: uint32 = 0
        do_rectify: bool = False

    @idl
    class Image(IdlStruct, typename=name("sensor_msgs/msg/Image")):
        header: Header = field(default_factory=Header)
        height: uint32 = 0
        width: uint32 = 0
        encoding: str = ""
        is_bigendian: uint8 = 0
        step: uint32 = 0
        data: sequence[uint8] = field(default_factory=list)

    @idl
    class CompressedImage(IdlStruct, typename=name("sensor_msgs/msg/CompressedImage")):
        header: Header = field(default_factory=Header)
        format: str = ""
        data: sequence[uint8] = field(default_factory=list)

    @idl
    class CameraInfo(IdlStruct, typename=name("sensor_msgs/msg/CameraInfo")):
        header: Header = field(default_factory=Header)
        height: uint32 = 0
        width: uint32 = 0
        distortion_model: str = ""
        d: sequence[float64] = field(default_factory=list)
        k: array[float64, 9] = field(default_factory=lambda: [0.0] * 9)
        r: array[float64, 9] = field(default_factory=lambda: [0.0] * 9)
        p: array[float64, 12] = field(default_factory=lambda: [0.0] * 12)
        binning_x: uint32 = 0
        binning_y: uint32 = 0
        roi: RegionOfInterest = field(default_factory=RegionOfInterest)

    classes = dict(Time=Time, Header=Header, Observation=Observation, Observations=Observations, Point=Point,
                   Vector3=Vector3, Quaternion=Quaternion, Pose=PoseMsg, PoseWithCovariance=PoseWithCovariance,
                   PoseWithCovarianceStamped=PoseWithCovarianceStamped, Transform=Transform,
                   TransformStamped=TransformStamped, TFMessage=TFMessage, Twist=Twist,
                   TwistWithCovariance=TwistWithCovariance, Odometry=Odometry, KeyValue=KeyValue,
                   DiagnosticStatus=DiagnosticStatus, DiagnosticArray=DiagnosticArray,
                   RegionOfInterest=RegionOfInterest, Image=Image, CompressedImage=CompressedImage,
                   CameraInfo=CameraInfo)
    ros_name = {cls: cls.__idl_typename__.replace("::msg::dds_::", "/msg/").rstrip("_") for cls in classes.values()}
    return SimpleNamespace(**classes, ros_name=ros_name)


def stamp(t: float) -> Any:
    """A ``builtin_interfaces/msg/Time`` for ``t`` seconds (rounded to the nanosecond)."""
    ns = int(round(float(t) * 1e9))
    return ros_types().Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def stamp_of(header: Any) -> float:
    """A header's stamp in seconds."""
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def observations_message(robot: str, rig: str, frame: int, time: float, observations: ObservationSet | None,
                         source_time: float = 0.0, frame_id: str | None = None) -> Any:
    """The ``Observations`` message of one processed frame of ``robot``'s camera
    (``observations``: what it saw, possibly nothing; only the observations of
    ``frame_id`` -- default ``robot`` -- are taken), stamped with the frame's
    capture ``time``; ``rig``: the rig's :func:`rig_id`; ``frame_id``: the
    camera's observation key, ``ROBOT/CAMERA`` for a robot with several
    cameras (SPEC "Robots with several cameras, any lens")."""
    T = ros_types()
    key = robot if frame_id is None else frame_id
    entries = []
    if observations is not None:
        for o in observations:
            if o.observer == key:
                entries.append(T.Observation(marker=o.marker or "", u=float(o.uv[0]), v=float(o.uv[1]),
                                             score=float(o.score)))
    return T.Observations(header=T.Header(stamp=stamp(time), frame_id=key), robot=robot, rig_id=rig,
                          frame=int(frame) % 2**32, source_time=float(source_time), observations=entries)


def observations_from_cdr(data: bytes) -> Any:
    """An ``Observations`` message from its CDR bytes (with the 4-byte
    encapsulation header), as ``ros_types().Observations.deserialize(data)``
    gives it, decoded in one pass: the localizer's hot path, in a fifth of
    the time of the binding's generic decoder.  Plain CDR (XCDR1, either byte order: what ROS 2
    middlewares write) is decoded here; another encapsulation goes to the
    binding.  :class:`MessageError` for bytes that are not a whole message
    (truncated, a length past the end, a string without its terminating NUL or
    not UTF-8): stricter than the binding, which lets some of those through;
    what both decode is the same message (``tests/test_live_messages.py``)."""
    T = ros_types()
    data = bytes(data)
    if len(data) < 4:
        raise MessageError(f"observations message of {len(data)} bytes")
    if data[0] != 0 or data[1] > 1:
        try:
            return T.Observations.deserialize(data)
        except Exception as exc:  # noqa: BLE001 -- whatever the binding raises for bytes it cannot decode
            raise MessageError(f"observations message: {type(exc).__name__}: {exc}") from None
    e = "<" if data[1] == 1 else ">"
    u32, i32u32, f64, ddf = _STRUCTS[e]
    n = len(data)
    Obs = T.Observation

    def string(p: int) -> tuple[str, int]:
        p += -(p - 4) % 4
        (k,) = u32.unpack_from(data, p)
        p += 4
        if k < 1 or p + k > n or data[p + k - 1] != 0:
            raise MessageError("observations message: a string past the end or without its NUL")
        return data[p:p + k - 1].decode("utf-8"), p + k

    try:
        sec, nanosec = i32u32.unpack_from(data, 4)
        frame_id, p = string(12)
        robot, p = string(p)
        rig, p = string(p)
        p += -(p - 4) % 4
        (frame,) = u32.unpack_from(data, p)
        p += 4
        p += -(p - 4) % 8
        (source_time,) = f64.unpack_from(data, p)
        p += 8
        (count,) = u32.unpack_from(data, p)
        p += 4
        if count > (n - p) // 24:  # each entry takes 24 bytes at least (an empty marker, u, v, score)
            raise MessageError(f"observations message: {count} observations in {n} bytes")
        entries = []
        for _ in range(count):
            marker, p = string(p)
            p += -(p - 4) % 8
            u, v, score = ddf.unpack_from(data, p)
            p += 20
            entries.append(Obs(marker=marker, u=u, v=v, score=score))
    except (struct.error, UnicodeDecodeError) as exc:
        raise MessageError(f"observations message: {exc}") from None
    return T.Observations(header=T.Header(stamp=T.Time(sec=sec, nanosec=nanosec), frame_id=frame_id), robot=robot,
                          rig_id=rig, frame=frame, source_time=source_time, observations=entries)


def observations_peek(data: bytes) -> tuple[str, int, int] | None:
    """``(header.frame_id, stamp in ns, frame number)`` of an ``Observations``
    message's CDR bytes, read without decoding the rest (what the localizer
    needs to tell which camera's newest message a sample is before it decodes
    any, and which frame numbers never came); None for bytes it cannot read
    so (another encapsulation, too short, a bad string): those are decoded,
    and refused if they are not a message."""
    if len(data) < 16 or data[0] != 0 or data[1] > 1:
        return None
    u32, i32u32 = _STRUCTS["<" if data[1] == 1 else ">"][:2]
    sec, nanosec = i32u32.unpack_from(data, 4)
    (k,) = u32.unpack_from(data, 12)
    if k < 1 or 16 + k > len(data) or data[15 + k] != 0 or sec < 0 or nanosec >= 1_000_000_000:
        return None
    try:
        frame_id = bytes(data[16:15 + k]).decode("utf-8")
    except UnicodeDecodeError:
        return None
    p = 16 + k
    for _ in range(2):  # robot, rig_id: skipped
        p += -(p - 4) % 4
        if p + 4 > len(data):
            return None
        (k,) = u32.unpack_from(data, p)
        p += 4 + k
        if k < 1 or p > len(data):
            return None
    p += -(p - 4) % 4
    if p + 4 > len(data):
        return None
    (frame,) = u32.unpack_from(data, p)
    return frame_id, sec * 1_000_000_000 + nanosec, frame


_STRUCTS = {e: (struct.Struct(e + "I"), struct.Struct(e + "iI"), struct.Struct(e + "d"), struct.Struct(e + "ddf"))
            for e in "<>"}


@dataclass(frozen=True)
class ReceivedObservations:
    """An ``Observations`` message taken apart and checked."""

    robot: str
    rig_id: str
    frame: int
    time: float
    source_time: float
    observations: ObservationSet
    #: The observing camera's key (``ROBOT``, or ``ROBOT/CAMERA``): the observer of :attr:`observations`.
    key: str = ""


def observer_frame_ids(rig: Any) -> dict[str, dict[str, str]]:
    """``{robot: {frame_id: observation key}}``: the ``header.frame_id`` values
    a node of each robot of ``rig`` sends and the camera each names -- ``ROBOT``
    (or empty) for a robot given with one ``camera``, ``ROBOT/CAMERA`` for each
    camera of a robot with ``cameras`` (also ``ROBOT`` and empty when it has
    only one)."""
    out: dict[str, dict[str, str]] = {}
    for name, robot in rig.robots.items():
        keys = {robot.observer_key(c): robot.observer_key(c) for c in robot.mounts}
        if len(keys) == 1:
            (key,) = keys.values()
            keys.update({"": key, name: key})
        out[name] = keys
    return out


def observations_from_message(msg: Any, robots: Sequence[str] | None = None,
                              frame_ids: dict[str, dict[str, str]] | None = None) -> ReceivedObservations:
    """Check an ``Observations`` message and take it apart; :class:`MessageError`
    (one line) for anything a node of mutloc would not send: an unknown robot
    (``robots``: the rig's), a header naming another robot or camera, a
    non-finite or negative stamp, a non-finite pixel or score.  ``frame_ids``
    (:func:`observer_frame_ids` of the rig): the frame_ids each robot may send,
    and the observation key each names (default: ``ROBOT`` or empty, the key
    ``ROBOT``); the observations are the key's."""
    robot = getattr(msg, "robot", None)
    if not isinstance(robot, str) or not robot:
        raise MessageError("observations message without a robot name")
    if robots is not None and robot not in robots:
        raise MessageError(f"observations message from robot {robot!r}, not in the rig")
    header = msg.header
    known = frame_ids.get(robot) if frame_ids is not None else None
    if known is None:
        known = {"": robot, robot: robot}
    key = known.get(header.frame_id)
    if key is None:
        names = ", ".join(sorted(k for k in known if k))
        raise MessageError(f"observations message of robot {robot!r} with frame_id {header.frame_id!r} "
                           f"(its cameras: {names})")
    t = stamp_of(header)
    if not math.isfinite(t) or header.stamp.sec < 0 or header.stamp.nanosec >= 1_000_000_000:
        raise MessageError(f"observations message of robot {robot!r} with an invalid stamp")
    markers, uv, score = [], [], []
    for o in msg.observations:
        if not (math.isfinite(o.u) and math.isfinite(o.v) and math.isfinite(o.score)):
            raise MessageError(f"observations message of robot {robot!r} with a non-finite pixel or score")
        markers.append(o.marker or None)
        uv.append((o.u, o.v))
        score.append(o.score)
    obs = ObservationSet.trusted([key] * len(markers), markers, np.asarray(uv, dtype=float).reshape(-1, 2),
                                 time=t, score=np.asarray(score, dtype=float))
    source_time = float(msg.source_time)
    return ReceivedObservations(robot, str(msg.rig_id), int(msg.frame), t,
                                source_time if math.isfinite(source_time) else 0.0, obs, key)


def static_transforms_message(rig: Any, t: float) -> Any:
    """The ``TFMessage`` of every camera's pose on its robot, for ``/tf_static``
    (:data:`TF_STATIC_TOPIC`): one transform per camera of each robot given
    with ``cameras``, ``header.frame_id`` the robot's frame (its name, as the
    poses on ``/tf`` name it), ``child_frame_id`` the camera's observation key
    ``ROBOT/CAMERA`` (its optical frame: the frame_id of that camera's
    observations), the transform ``T_robot_camera`` (the rig's ``pose``),
    stamped ``t``.  Robots given with one ``camera`` have none (their frame is
    the camera's).  Empty when no robot has ``cameras``."""
    T = ros_types()
    st = stamp(t)
    out = []
    for name, robot in rig.robots.items():
        if not robot.is_body:
            continue
        for cname, mount in robot.mounts.items():
            q = [float(v) for v in mount.pose.quaternion_xyzw]
            x, y, z = (float(v) for v in mount.pose.t)
            out.append(T.TransformStamped(
                header=T.Header(stamp=st, frame_id=name), child_frame_id=robot.observer_key(cname),
                transform=T.Transform(translation=T.Vector3(x=x, y=y, z=z),
                                      rotation=T.Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]))))
    return T.TFMessage(transforms=out)


def odometry_message(t: float, pose: Pose, covariance: np.ndarray | None, robot: str, frame: str = "odom") -> Any:
    """A ``nav_msgs/msg/Odometry`` of ``robot``'s frame (``child_frame_id``) in its
    odometry frame ``frame`` at ``t``, ``covariance`` 6x6 in SPEC order (None:
    all zeros, none given); the twist is left zero (mutloc uses the poses)."""
    T = ros_types()
    q = pose.quaternion_xyzw
    cov = [0.0] * 36 if covariance is None else [float(x) for x in ros_covariance(covariance).reshape(-1)]
    return T.Odometry(header=T.Header(stamp=stamp(t), frame_id=frame), child_frame_id=robot,
                      pose=T.PoseWithCovariance(pose=T.Pose(position=T.Point(*map(float, pose.t)),
                                                            orientation=T.Quaternion(*map(float, q))),
                                                covariance=cov))


def pose_messages(t: float, pose: Pose, covariance: np.ndarray | None, source: str, target: str) -> tuple[Any, Any]:
    """``(PoseWithCovarianceStamped, TFMessage)`` of ``source``'s pose in
    ``target``'s frame at time ``t``, exactly as ``track --bag`` writes them
    (covariance in ROS order; see :mod:`mutloc.io.ros`)."""
    T = ros_types()
    st = stamp(t)
    q = [float(v) for v in pose.quaternion_xyzw]
    x, y, z = (float(v) for v in pose.t)
    cov = ros_covariance(covariance if covariance is not None else np.full((6, 6), np.nan)).reshape(-1)
    quat = T.Quaternion(x=q[0], y=q[1], z=q[2], w=q[3])
    pmsg = T.PoseWithCovarianceStamped(
        header=T.Header(stamp=st, frame_id=target),
        pose=T.PoseWithCovariance(pose=T.Pose(position=T.Point(x=x, y=y, z=z), orientation=quat),
                                  covariance=[float(c) for c in cov]))
    tf = T.TFMessage(transforms=[T.TransformStamped(header=T.Header(stamp=st, frame_id=target), child_frame_id=source,
                                                    transform=T.Transform(translation=T.Vector3(x=x, y=y, z=z),
                                                                          rotation=quat))])
    return pmsg, tf


_CDR_LE = b"\x00\x01\x00\x00"  # the encapsulation header: plain CDR (XCDR1), little endian


def _align(buf: bytearray, n: int) -> None:
    buf += b"\0" * (-(len(buf) - 4) % n)  # (offsets count from after the encapsulation header)


def _cdr_string(buf: bytearray, text: str) -> None:
    data = text.encode() + b"\0"
    _align(buf, 4)
    buf += struct.pack("<I", len(data)) + data


def pose_cdr(stamp_ns: int, pose: Pose, covariance: np.ndarray | None, source: str, target: str,
             body: tuple[bytes, bytes] | None = None) -> tuple[bytes, bytes]:
    """The CDR bytes of :func:`pose_messages` stamped ``stamp_ns`` nanoseconds
    (byte-identical; ``tests/test_live_messages.py``), packed directly: the
    localizer's hot path, a tenth of building and serialising the messages.
    ``body``: :func:`pose_cdr_body` of the same pose, covariance and names,
    made once for several stamps (only the stamp differs)."""
    pm, tf = body if body is not None else pose_cdr_body(pose, covariance, source, target)
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    st = _STAMP.pack(sec, nanosec)
    return _CDR_LE + st + pm, _CDR_LE + _ONE + st + tf


def pose_cdr_body(pose: Pose, covariance: np.ndarray | None, source: str, target: str) -> tuple[bytes, bytes]:
    """What follows the stamp in :func:`pose_cdr`'s two messages (the stamp
    is the first field, fixed size: the alignment after it does not depend on it)."""
    q = np.asarray(pose.quaternion_xyzw, dtype="<f8")
    t = np.asarray(pose.t, dtype="<f8")
    cov = (np.asarray(covariance, dtype="<f8").reshape(36)[_ROS_ORDER] if covariance is not None
           else np.full(36, np.nan))  # (ros_covariance's order, as a flat gather)
    pm = bytearray(_CDR_LE) + bytes(8)  # (the stamp's place: the offsets count from the encapsulation header)
    _cdr_string(pm, target)
    _align(pm, 8)
    pm += t.tobytes() + q.tobytes() + cov.tobytes()
    tf = bytearray(_CDR_LE) + bytes(12)
    _cdr_string(tf, target)
    _cdr_string(tf, source)
    _align(tf, 8)
    tf += t.tobytes() + q.tobytes()
    return bytes(pm[12:]), bytes(tf[16:])


_STAMP = struct.Struct("<iI")
#: Where each entry of a ROS covariance comes from in the flattened SPEC one.
_ROS_ORDER = ros_covariance(np.arange(36.0).reshape(6, 6)).reshape(36).astype(np.intp)
_ONE = struct.pack("<I", 1)  # TFMessage: one transform


def raw_sample(cls: type, data: bytes) -> Any:
    """A sample of ``cls`` (a type of :func:`ros_types`) that a DataWriter
    writes as the CDR bytes ``data`` as they are (made by :func:`pose_cdr`)."""
    sample = _raw_class(cls).__new__(_raw_class(cls))
    sample._cdr = data
    return sample


@cache
def _raw_class(cls: type) -> type:
    class Raw(cls):  # type: ignore[valid-type,misc]
        def serialize(self, use_version_2: bool = False, **_: Any) -> bytes:
            return self._cdr

    return Raw


@dataclass
class RobotStatus:
    """One robot's line in ``/diagnostics``."""

    robot: str
    level: int
    message: str
    values: dict[str, Any]


def diagnostics_message(t: float, statuses: Iterable[RobotStatus], name: str = "mutloc localizer") -> Any:
    """A ``DiagnosticArray`` stamped ``t``: one ``DiagnosticStatus`` per robot
    (``name`` "NAME: ROBOT", ``hardware_id`` the robot's name)."""
    T = ros_types()
    return T.DiagnosticArray(header=T.Header(stamp=stamp(t), frame_id=""), status=[
        T.DiagnosticStatus(level=int(s.level), name=f"{name}: {s.robot}", message=s.message, hardware_id=s.robot,
                           values=[T.KeyValue(key=str(k), value=str(v)) for k, v in s.values.items()])
        for s in statuses])
