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
the MCAP container is written with the ``mcap`` package, the bag with
rosbags' writer.  Both are written as the poses come
(:class:`Ros2BagWriter`, :class:`McapPoseWriter`; see
:mod:`mutloc.io.streaming`): a killed run leaves a bag folder and an MCAP
file that rosbags and the ``mcap`` readers open, with every pose written.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .._extras import require
from ..core.geometry import matrix_from_quaternion_xyzw
from ..core.pose import Pose
from ..errors import FileFormatError, InputError
from ._files import PathLike
from .streaming import RollingFile, StreamWriter, deferred_interrupt

__all__ = ["ros_covariance", "spec_covariance", "pose_topic", "write_ros2_bag", "write_mcap", "POSE_TYPE", "TF_TYPE",
           "TF_TOPIC", "Ros2BagWriter", "McapPoseWriter", "BAG_STORAGES", "ODOMETRY_TYPE", "odometry_sample"]

POSE_TYPE = "geometry_msgs/msg/PoseWithCovarianceStamped"
TF_TYPE = "tf2_msgs/msg/TFMessage"
TF_TOPIC = "/tf"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
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


def odometry_sample(msg: Any) -> tuple[float, Pose, np.ndarray, str]:
    """``(stamp s, pose, covariance, child_frame_id)`` of a ``nav_msgs/msg/Odometry``
    message (ROS 1 or ROS 2, from a bag or over DDS): the pose of the child
    frame in ``header.frame_id``, its covariance in SPEC order (all zeros:
    none given).  A quaternion of zero norm gives a non-finite pose (the
    caller rejects it); nothing here raises for the values."""
    h = msg.header.stamp
    t = float(h.sec) + float(h.nanosec) * 1e-9
    p, o = msg.pose.pose.position, msg.pose.pose.orientation
    q = np.array([o.x, o.y, o.z, o.w], dtype=float)
    n = float(np.linalg.norm(q))
    R = matrix_from_quaternion_xyzw(q) if n > 0 and math.isfinite(n) else np.full((3, 3), np.nan)
    return t, Pose(R, [p.x, p.y, p.z]), spec_covariance(msg.pose.covariance), str(msg.child_frame_id)


def pose_topic(source: str, target: str) -> str:
    """The pose topic of ``source`` in ``target``'s frame."""
    return f"/mutloc/{source}_in_{target}"


def _store() -> Any:
    require("rosbags", "ROS messages")
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)



class _Messages:
    """A pose's two messages, serialised (CDR): the pose topic's and ``/tf``'s."""

    def __init__(self, store: Any) -> None:
        T = store.types
        self.store = store
        self.Header, self.Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
        self.Point, self.Quat = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]
        self.PoseMsg, self.PWC, self.PWCS = (T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/PoseWithCovariance"],
                                             T[POSE_TYPE])
        self.Vec, self.Tf, self.TfS, self.TFM = (T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Transform"],
                                                 T["geometry_msgs/msg/TransformStamped"], T[TF_TYPE])

    def __call__(self, t: float, pose: Pose | None, cov: np.ndarray | None, source: str,
                 target: str) -> tuple[int, bytes, bytes] | None:
        """(time ns, pose message, tf message), or None for a missing or non-finite pose."""
        if pose is None or not (pose.isfinite() and math.isfinite(float(t))):
            return None
        ns = int(round(float(t) * 1e9))
        stamp = self.Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        q = pose.quaternion_xyzw
        x, y, z = (float(v) for v in pose.t)
        c = ros_covariance(cov if cov is not None else np.full((6, 6), np.nan)).reshape(-1)
        pmsg = self.PWCS(header=self.Header(stamp=stamp, frame_id=target),
                         pose=self.PWC(pose=self.PoseMsg(position=self.Point(x=x, y=y, z=z),
                                                         orientation=self.Quat(x=q[0], y=q[1], z=q[2], w=q[3])),
                                       covariance=np.ascontiguousarray(c)))
        tf = self.TFM(transforms=[self.TfS(header=self.Header(stamp=stamp, frame_id=target), child_frame_id=source,
                                           transform=self.Tf(translation=self.Vec(x=x, y=y, z=z),
                                                             rotation=self.Quat(x=q[0], y=q[1], z=q[2], w=q[3])))])
        return ns, bytes(self.store.serialize_cdr(pmsg, POSE_TYPE)), bytes(self.store.serialize_cdr(tf, TF_TYPE))


def _fresh(path: PathLike, what: str) -> Path:
    p = Path(path).expanduser()
    if p.exists():
        raise FileFormatError(f"{p}: already exists (a {what} is written to a new path)")
    p.parent.mkdir(parents=True, exist_ok=True)
    return p


#: The robots of a writer's pose topics: one (source, target) per track.
Names = Sequence[tuple[str, str]]


class _PoseWriter(StreamWriter):
    """What the bag and MCAP writers share: tracks, messages, ``write``."""

    def __init__(self, names: Names) -> None:
        self.names = [(str(s), str(t)) for s, t in names]
        if not self.names:
            raise InputError("no track to write (names: one (source, target) per track)")
        self._store = _store()
        self._messages = _Messages(self._store)

    def _track(self, track: int | str) -> int:
        if isinstance(track, str):
            for k, (s, _) in enumerate(self.names):
                if s == track:
                    return k
            raise InputError(f"no track of robot {track!r} (tracks: {[s for s, _ in self.names]})")
        if not 0 <= int(track) < len(self.names):
            raise InputError(f"no track {track} ({len(self.names)} tracks)")
        return int(track)

    def write(self, t: float, pose: Pose | None, covariance: np.ndarray | None = None,
              track: int | str = 0) -> bool:
        """The pose (and its covariance, SPEC order) of track ``track`` (index
        or source robot) at time ``t``: one message on its pose topic, one on
        ``/tf``.  A missing or non-finite pose is skipped (False)."""
        k = self._track(track)
        m = self._messages(t, pose, covariance, *self.names[k])
        if m is None:
            return False
        with deferred_interrupt():
            self._put(k, *m)
            self.rows += 1
        return True

    def _put(self, k: int, ns: int, pose: bytes, tf: bytes) -> None:  # pragma: no cover - abstract
        raise NotImplementedError


class _McapStorage:
    """rosbags' storage-writer interface (``Writer.STORAGE_PLUGINS``) for a
    rosbag2 MCAP file that is a complete MCAP after each :meth:`commit`
    (unchunked, :class:`~mutloc.io.streaming.RollingFile`); the records are
    those of rosbags' own MCAP storage: schemas, channels with their
    ``offered_qos_profiles``, messages, and the ``rosbag2`` metadata record
    at close."""

    def __init__(self, path: Path, compression: Any) -> None:
        require("mcap", "a rosbag2 bag with MCAP storage")
        from mcap.writer import CompressionType, Writer

        self.path = path / f"{path.name}.mcap"
        self._file = RollingFile.mcap(self.path)
        self._w = Writer(self._file, use_chunking=False, compression=CompressionType.NONE)
        self._w.start(profile="ros2", library="mutloc")
        self._schemas: dict[str, int] = {}
        self._channels: dict[int, int] = {}

    def add_msgtype(self, connection: Any) -> None:
        from rosbags.interfaces import MessageDefinitionFormat

        fmt = "ros2msg" if connection.msgdef.format == MessageDefinitionFormat.MSG else "ros2idl"
        self._schemas[connection.msgtype] = self._w.register_schema(name=connection.msgtype, encoding=fmt,
                                                                    data=connection.msgdef.data.encode())

    def add_connection(self, connection: Any, offered_qos_profiles: str) -> None:
        self._channels[connection.id] = self._w.register_channel(
            topic=connection.topic, message_encoding=connection.ext.serialization_format,
            schema_id=self._schemas[connection.msgtype], metadata={"offered_qos_profiles": offered_qos_profiles})

    def write(self, connection: Any, timestamp: int, data: bytes) -> None:
        self._w.add_message(self._channels[connection.id], log_time=timestamp, publish_time=timestamp, data=bytes(data))

    def commit(self) -> None:
        self._file.commit()

    def close(self, version: int, metadata: str) -> None:
        self._w.add_metadata("rosbag2", {"serialized_metadata": metadata})
        self._w.finish()
        self._file.finish()

    def abort(self) -> None:
        self._file.abandon()


#: The rosbag2 storages :class:`Ros2BagWriter` writes.
BAG_STORAGES = ("sqlite3", "mcap")


class Ros2BagWriter(_PoseWriter):
    """Streams a rosbag2 folder (version 8, rosbags' writer), each
    :meth:`write` made durable before it returns; ``metadata.yaml`` is written
    at open, refreshed at most every ``metadata_every`` seconds and at
    :meth:`close` (see :mod:`mutloc.io.streaming`).

    ``storage``: ``"sqlite3"`` (ROS 2 Humble's default; one committed
    transaction per pose) or ``"mcap"`` (Iron and later's default; one
    unchunked MCAP file, complete after each pose)."""

    def __init__(self, path: PathLike, names: Names, *, storage: str = "sqlite3",
                 metadata_every: float = 1.0) -> None:
        require("rosbags", "a ROS 2 bag")
        from rosbags.rosbag2 import StoragePlugin, Writer

        if storage not in BAG_STORAGES:
            raise InputError(f"bag storage {storage!r}: expected one of {', '.join(BAG_STORAGES)}")

        class _Writer(Writer):
            STORAGE_PLUGINS = {**Writer.STORAGE_PLUGINS, StoragePlugin.MCAP: _McapStorage}

        super().__init__(names)
        p = _fresh(path, "ROS 2 bag folder")
        self.paths = (p,)
        self.storage = storage
        self.metadata_every = float(metadata_every)
        self._w = _Writer(p, version=8, storage_plugin=StoragePlugin[storage.upper()])
        self._w.open()
        try:
            if storage == "sqlite3":
                db = self._w.storage.conn  # type: ignore[union-attr]
                db.commit()
                # Durable against a killed process (the OS has every committed page); no fsync per row.
                db.execute("PRAGMA synchronous=OFF")
                self._commit = db.commit
            else:
                self._commit = self._w.storage.commit  # type: ignore[union-attr]
            self._pose_conns = [self._w.add_connection(pose_topic(s, t), POSE_TYPE, typestore=self._store)
                                for s, t in self.names]
            self._tf_conn = self._w.add_connection(TF_TOPIC, TF_TYPE, typestore=self._store)
            self._commit()
            self._refresh()
        except BaseException:
            self._w.close()
            raise

    def _put(self, k: int, ns: int, pose: bytes, tf: bytes) -> None:
        self._w.write(self._pose_conns[k], ns, pose)
        self._w.write(self._tf_conn, ns, tf)
        self._commit()
        if time.monotonic() - self._refreshed >= self.metadata_every:
            self._refresh()

    def _refresh(self) -> None:
        """Write ``metadata.yaml`` as of now: rosbags' ``Writer.close`` with
        its storage set aside (only its path is read), the storage left open."""

        class _Open:
            def __init__(self, path: Path) -> None:
                self.path = path

            def close(self, version: int, metadata: str) -> None:
                pass

        storage = self._w.storage
        self._w.storage = _Open(storage.path)  # type: ignore[assignment,union-attr]
        try:
            self._w.close()
        finally:
            self._w.storage = storage
        self._refreshed = time.monotonic()

    def _close(self) -> None:
        self._w.close()


class McapPoseWriter(_PoseWriter):
    """Streams an MCAP file (profile ``ros2``, CDR messages with their
    ``ros2msg`` schemas), unchunked: after each :meth:`write` the file is a
    complete MCAP without summary; :meth:`close` adds the summary (see
    :class:`mutloc.io.streaming.RollingFile`)."""

    def __init__(self, path: PathLike, names: Names) -> None:
        require("mcap", "an MCAP file")
        require("rosbags", "an MCAP file of ROS messages")
        from mcap.writer import CompressionType, Writer

        super().__init__(names)
        p = _fresh(path, "MCAP file")
        self.paths = (p,)
        self._file = RollingFile.mcap(p)
        try:
            w = self._w = Writer(self._file, use_chunking=False, compression=CompressionType.NONE)
            w.start(profile="ros2", library="mutloc")
            schemas = {}
            for typ in (POSE_TYPE, TF_TYPE):
                text, _ = self._store.generate_msgdef(typ, ros_version=2)
                schemas[typ] = w.register_schema(name=typ, encoding="ros2msg", data=text.encode())
            self._pose_chans = [w.register_channel(topic=pose_topic(s, t), message_encoding="cdr",
                                                   schema_id=schemas[POSE_TYPE]) for s, t in self.names]
            self._tf_chan = w.register_channel(topic=TF_TOPIC, message_encoding="cdr", schema_id=schemas[TF_TYPE])
            self._file.commit()
        except BaseException:
            self._file.abandon()
            raise

    def _put(self, k: int, ns: int, pose: bytes, tf: bytes) -> None:
        seq = self.rows
        self._w.add_message(self._pose_chans[k], log_time=ns, publish_time=ns, sequence=seq, data=pose)
        self._w.add_message(self._tf_chan, log_time=ns, publish_time=ns, sequence=seq, data=tf)
        self._file.commit()

    def _close(self) -> None:
        self._w.finish()
        self._file.finish()


#: One track's messages: (times, poses, covariances, source, target).
Track = tuple[Sequence[float], Pose, Sequence[np.ndarray], str, str]


def _all_tracks(times: Sequence[float] | None, poses: Pose | None, covariances: Sequence[np.ndarray] | None,
                source: str | None, target: str | None, tracks: Sequence[Track] | None) -> list[Track]:
    out = list(tracks or [])
    if poses is not None:
        out.insert(0, (times, poses, covariances, source, target))  # type: ignore[arg-type]
    return out


def _write_tracks(writer: _PoseWriter, tracks: Sequence[Track]) -> None:
    """Every track's poses, in time order (ties: in track order)."""
    rows = [(float(t), k, pose, cov) for k, (times, poses, covs, _, _) in enumerate(tracks)
            for t, pose, cov in zip(times, poses, covs)]
    rows.sort(key=lambda r: (int(round(r[0] * 1e9)) if math.isfinite(r[0]) else 0, r[1]))
    with writer:
        for t, k, pose, cov in rows:
            writer.write(t, pose, cov, track=k)


def write_ros2_bag(path: PathLike, times: Sequence[float] | None = None, poses: Pose | None = None,
                   covariances: Sequence[np.ndarray] | None = None, source: str | None = None,
                   target: str | None = None, *, tracks: Sequence[Track] | None = None,
                   storage: str = "sqlite3") -> None:
    """A rosbag2 folder (SQLite storage, or ``storage="mcap"``) with the pose
    and ``/tf`` topics (``tracks``: several robots' tracks, one pose topic
    each, one ``/tf``)."""
    tracks = _all_tracks(times, poses, covariances, source, target, tracks)
    _write_tracks(Ros2BagWriter(path, [(tr[3], tr[4]) for tr in tracks], storage=storage), tracks)


def write_mcap(path: PathLike, times: Sequence[float] | None = None, poses: Pose | None = None,
               covariances: Sequence[np.ndarray] | None = None, source: str | None = None,
               target: str | None = None, *, tracks: Sequence[Track] | None = None) -> None:
    """An MCAP file (ROS 2 CDR messages with their ``ros2msg`` schemas); ``tracks`` as :func:`write_ros2_bag`."""
    tracks = _all_tracks(times, poses, covariances, source, target, tracks)
    _write_tracks(McapPoseWriter(path, [(tr[3], tr[4]) for tr in tracks]), tracks)
