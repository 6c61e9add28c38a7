"""A trajectory as ROS 2 messages, in a rosbag2 folder or an MCAP file.

Per pose: ``geometry_msgs/msg/PoseWithCovarianceStamped`` (frame
``target``, the pose of ``source`` in it) on ``/mutloc/SOURCE_in_TARGET``
and the same transform as ``tf2_msgs/msg/TFMessage`` on ``/tf``
(``frame_id`` target, ``child_frame_id`` source), stamped with the frame's
time.  ROS orders a pose covariance translation first (x, y, z, then
rotation about x, y, z of the parent frame); mutloc's SPEC order is rotation
first, so the blocks are swapped here -- the perturbations are the same (a
rotation vector on the left, i.e. about the parent frame's axes, and a
translation in the parent frame).

Serialisation is rosbags' (CDR, the message definitions of ROS 2 Humble);
the MCAP container is written with the ``mcap`` package.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..core.pose import Pose
from ..errors import FileFormatError
from ._files import PathLike

__all__ = ["ros_covariance", "spec_covariance", "pose_topic", "write_ros2_bag", "write_mcap", "POSE_TYPE", "TF_TYPE",
           "TF_TOPIC"]

POSE_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
TF_TYPE = "tf2_msgs/msg/TFMessage"
TF_TOPIC = "/tf"
# SPEC (rx, ry, rz, tx, ty, tz) -> ROS (x, y, z, rx, ry, rz)
_TO_ROS = np.array([3, 4, 5, 0, 1, 2])


def ros_covariance(cov: np.ndarray) -> np.ndarray:
    """A 6x6 covariance in SPEC order (rotation, translation) as ROS orders it (translation, rotation)."""
    c = np.asarray(cov, dtype=float)
    return c[np.ix_(_TO_ROS, _TO_ROS)]


def spec_covariance(ros: Any) -> np.ndarray:
    """The inverse of :func:`ros_covariance` (a ROS ``covariance``, 36 numbers, back to SPEC order)."""
    c = np.asarray(ros, dtype=float).reshape(6, 6)
    inv = np.argsort(_TO_ROS)
    return c[np.ix_(inv, inv)]


def pose_topic(source: str, target: str) -> str:
    """The pose topic of ``source`` in ``target``'s frame."""
    return f"/mutloc/{source}_in_{target}"


def _store() -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def _messages(store: Any, times: Sequence[float], poses: Pose, covariances: Sequence[np.ndarray], source: str,
              target: str):
    """(time ns, pose message, tf message) per finite pose."""
    T = store.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Point, Quat = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]
    PoseMsg, PWC, PWCS = T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/PoseWithCovariance"], T[POSE_TYPE]
    Vec, Tf, TfS, TFM = (T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Transform"],
                         T["geometry_msgs/msg/TransformStamped"], T[TF_TYPE])
    for t, pose, cov in zip(times, poses, covariances):
        if not (pose.isfinite() and math.isfinite(t)):
            continue
        ns = int(round(float(t) * 1e9))
        stamp = Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        q = pose.quaternion_xyzw
        x, y, z = (float(v) for v in pose.t)
        c = ros_covariance(cov if cov is not None else np.full((6, 6), np.nan)).reshape(-1)
        pmsg = PWCS(header=Header(stamp=stamp, frame_id=target),
                    pose=PWC(pose=PoseMsg(position=Point(x=x, y=y, z=z),
                                          orientation=Quat(x=q[0], y=q[1], z=q[2], w=q[3])),
                             covariance=np.ascontiguousarray(c)))
        tf = TFM(transforms=[TfS(header=Header(stamp=stamp, frame_id=target), child_frame_id=source,
                                 transform=Tf(translation=Vec(x=x, y=y, z=z),
                                              rotation=Quat(x=q[0], y=q[1], z=q[2], w=q[3])))])
        yield ns, pmsg, tf


def _fresh(path: PathLike, what: str) -> Path:
    p = Path(path).expanduser()
    if p.exists():
        raise FileFormatError(f"{p}: already exists (a {what} is written to a new path)")
    p.parent.mkdir(parents=True, exist_ok=True)
    return p


#: One track's messages: (times, poses, covariances, source, target).
Track = tuple[Sequence[float], Pose, Sequence[np.ndarray], str, str]


def _all_tracks(times: Sequence[float] | None, poses: Pose | None, covariances: Sequence[np.ndarray] | None,
                source: str | None, target: str | None, tracks: Sequence[Track] | None) -> list[Track]:
    out = list(tracks or [])
    if poses is not None:
        out.insert(0, (times, poses, covariances, source, target))  # type: ignore[arg-type]
    return out


def _time_ordered(store: Any, tracks: Sequence[Track]) -> list[tuple[int, int, Any, Any]]:
    """(time ns, track index, pose message, tf message) of every track, in time order."""
    msgs = [(ns, k, pm, tf) for k, tr in enumerate(tracks) for ns, pm, tf in _messages(store, *tr)]
    msgs.sort(key=lambda m: (m[0], m[1]))
    return msgs


def write_ros2_bag(path: PathLike, times: Sequence[float] | None = None, poses: Pose | None = None,
                   covariances: Sequence[np.ndarray] | None = None, source: str | None = None,
                   target: str | None = None, *, tracks: Sequence[Track] | None = None) -> None:
    """A rosbag2 folder (SQLite storage) with the pose and ``/tf`` topics
    (``tracks``: several robots' tracks, one pose topic each, one ``/tf``)."""
    from rosbags.rosbag2 import Writer

    tracks = _all_tracks(times, poses, covariances, source, target, tracks)
    p = _fresh(path, "ROS 2 bag folder")
    store = _store()
    with Writer(p, version=8) as w:
        cps = [w.add_connection(pose_topic(tr[3], tr[4]), POSE_TYPE, typestore=store) for tr in tracks]
        ct = w.add_connection(TF_TOPIC, TF_TYPE, typestore=store)
        for ns, k, pmsg, tf in _time_ordered(store, tracks):
            w.write(cps[k], ns, store.serialize_cdr(pmsg, POSE_TYPE))
            w.write(ct, ns, store.serialize_cdr(tf, TF_TYPE))


def write_mcap(path: PathLike, times: Sequence[float] | None = None, poses: Pose | None = None,
               covariances: Sequence[np.ndarray] | None = None, source: str | None = None,
               target: str | None = None, *, tracks: Sequence[Track] | None = None) -> None:
    """An MCAP file (ROS 2 CDR messages with their ``ros2msg`` schemas); ``tracks`` as :func:`write_ros2_bag`."""
    from mcap.writer import Writer

    tracks = _all_tracks(times, poses, covariances, source, target, tracks)
    p = _fresh(path, "MCAP file")
    store = _store()
    with open(p, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="mutloc")
        schemas = {}
        for typ in (POSE_TYPE, TF_TYPE):
            text, _ = store.generate_msgdef(typ, ros_version=2)
            schemas[typ] = w.register_schema(name=typ, encoding="ros2msg", data=text.encode())
        pose_chans = [w.register_channel(topic=pose_topic(tr[3], tr[4]), message_encoding="cdr",
                                         schema_id=schemas[POSE_TYPE]) for tr in tracks]
        tf_chan = w.register_channel(topic=TF_TOPIC, message_encoding="cdr", schema_id=schemas[TF_TYPE])
        for seq, (ns, k, pmsg, tf) in enumerate(_time_ordered(store, tracks)):
            for chan, typ, msg in ((pose_chans[k], POSE_TYPE, pmsg), (tf_chan, TF_TYPE, tf)):
                w.add_message(chan, log_time=ns, publish_time=ns, sequence=seq,
                              data=bytes(store.serialize_cdr(msg, typ)))
        w.finish()
