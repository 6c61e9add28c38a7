"""Timestamped image streams: image folders, video files, ROS 1 / ROS 2 bags.

Every source yields :class:`Frame` objects in time order.  A frame that
cannot be decoded is yielded with ``image=None`` and a status saying why, so
the caller records it and carries on with the rest of the file.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterator, Mapping

import cv2
import numpy as np

from ..core.camera import Camera
from ..core.rig import Rig
from ..errors import FileFormatError, InputError

__all__ = ["Frame", "Stream", "open_bag", "folder_frames", "video_frames", "bag_frames", "bag_camera", "open_source",
           "open_streams", "rig_with_bag_cameras", "IMAGE_SUFFIXES", "image_from_message", "camera_from_info"]

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"}
_NUMBER = re.compile(r"^(\d+(?:\.\d+)?)$")


@dataclass
class Frame:
    """One image of a stream; ``image`` is None when the frame is corrupt."""

    index: int
    t: float
    image: np.ndarray | None
    status: str = "ok"


class Stream:
    """A time-ordered stream of frames (iterable once) that knows its frame
    rate: ``fps`` is the container's or given rate, else the one the
    timestamps show (median interval), else None."""

    def __init__(self, frames: Iterator[Frame], fps: float | None, name: str):
        self._frames = frames
        self.fps = fps
        self.name = name

    def __iter__(self) -> Iterator[Frame]:
        return self._frames

    def __repr__(self) -> str:
        return f"Stream({self.name!r}, fps={self.fps})"


def _rate(stamps: list[float]) -> float | None:
    d = np.diff(np.asarray(stamps, dtype=float))
    d = d[d > 0]
    return float(1.0 / np.median(d)) if len(d) else None


def _stamp_from_name(stem: str) -> float | None:
    m = _NUMBER.match(stem)
    if not m:
        return None
    value = float(m.group(1))
    if "." in stem:
        return value
    # Short integers are frame numbers, not times; 16+ digits are nanoseconds
    # (ROS-style exports), 10-15 digits seconds since the epoch.
    if len(stem) < 10:
        return None
    return value * 1e-9 if len(stem) >= 16 else value


def folder_frames(folder: str | Path, fps: float | None = None) -> Iterator[Frame]:
    """Images of a folder in name order.  Timestamps come from names that are
    times (``12.345.png`` seconds, or 16+ digit integers in nanoseconds), a ``frames.csv``
    (``index,timestamp``) beside the images, or ``index / fps``."""
    files, stamps = _folder_stamps(folder, fps)
    for i, (path, t) in enumerate(zip(files, stamps)):
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        yield Frame(i, t, img, "ok" if img is not None else f"unreadable image {path.name}")


def _folder_stamps(folder: str | Path, fps: float | None) -> tuple[list[Path], list[float]]:
    root = Path(folder)
    if not root.is_dir():
        raise FileFormatError(f"{root}: not a folder of images")
    files = sorted(p for p in root.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise FileFormatError(f"{root}: no images ({', '.join(sorted(IMAGE_SUFFIXES))})")
    stamps = _csv_stamps(root / "frames.csv", len(files)) or _csv_stamps(root.parent / "frames.csv", len(files))
    named = [_stamp_from_name(p.stem) for p in files]
    if stamps is None and all(s is not None for s in named) and len(set(named)) == len(named) and fps is None:
        stamps = [float(s) for s in named]  # type: ignore[arg-type]
    if stamps is None:
        if fps is None:
            raise InputError(f"{root}: image names are not timestamps and there is no frames.csv: give --fps")
        stamps = [i / fps for i in range(len(files))]
    return files, stamps


def _csv_stamps(path: Path, n: int) -> list[float] | None:
    if not path.is_file():
        return None
    out = []
    for line in path.read_text().splitlines():
        parts = [p.strip() for p in line.split(",")]
        if len(parts) < 2:
            continue
        try:
            out.append(float(parts[1]))
        except ValueError:
            continue  # header
    return out if len(out) == n else None


def video_frames(path: str | Path, fps: float | None = None) -> Iterator[Frame]:
    """Frames of a video file (OpenCV); timestamps from the container, else
    ``index / fps``.  A frame that fails to decode mid-file ends the stream
    with a status frame rather than an exception."""
    p = Path(path)
    if not p.is_file():
        raise FileFormatError(f"{p}: no such video file")
    cap = cv2.VideoCapture(str(p))
    if not cap.isOpened():
        raise FileFormatError(f"{p}: not a readable video")
    rate = fps or cap.get(cv2.CAP_PROP_FPS) or 0.0
    total = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
    i = 0
    try:
        while True:
            ok, img = cap.read()
            if not ok:
                if total and i < total:
                    yield Frame(i, i / rate if rate else float(i), None,
                                f"video decoding stopped at frame {i} of {total}")
                break
            t = i / rate if rate else cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
            yield Frame(i, t, img)
            i += 1
    finally:
        cap.release()
    if i == 0:
        raise FileFormatError(f"{p}: the video has no decodable frame")


def image_from_message(msg) -> np.ndarray:
    """BGR image of a sensor_msgs Image or CompressedImage message (from a bag, or
    received over DDS: ``data`` bytes or a list of ints); ValueError when it cannot be decoded."""
    if hasattr(msg, "format"):  # CompressedImage
        img = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
        if img is None:
            raise ValueError("undecodable compressed image")
        return img
    enc = msg.encoding.lower()
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.frombuffer(bytes(msg.data), np.uint8)
    if data.size < h * step:
        raise ValueError(f"image message holds {data.size} bytes, expected {h * step}")
    rows = data[: h * step].reshape(h, step)
    if enc in ("bgr8", "rgb8"):
        img = rows[:, : 3 * w].reshape(h, w, 3)
        return img[:, :, ::-1].copy() if enc == "rgb8" else img.copy()
    if enc in ("bgra8", "rgba8"):
        img = rows[:, : 4 * w].reshape(h, w, 4)[:, :, :3]
        return img[:, :, ::-1].copy() if enc == "rgba8" else img.copy()
    if enc in ("mono8", "8uc1"):
        return cv2.cvtColor(rows[:, :w].copy(), cv2.COLOR_GRAY2BGR)
    if enc in ("mono16", "16uc1"):
        g = np.frombuffer(rows[:, : 2 * w].tobytes(), "<u2").reshape(h, w)
        return cv2.cvtColor((g >> 8).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    if enc.startswith("bayer_"):
        codes = {"bayer_rggb8": cv2.COLOR_BayerBG2BGR, "bayer_bggr8": cv2.COLOR_BayerRG2BGR,
                 "bayer_gbrg8": cv2.COLOR_BayerGR2BGR, "bayer_grbg8": cv2.COLOR_BayerGB2BGR}
        if enc in codes:
            return cv2.cvtColor(rows[:, :w].copy(), codes[enc])
    raise ValueError(f"unsupported image encoding {msg.encoding!r}")


def open_bag(path: str | Path):
    """An opened rosbags ``AnyReader`` of a ROS 1 or ROS 2 bag (close it when done); FileFormatError for a
    missing or unreadable bag."""
    path = Path(path)
    from .._extras import require

    require("rosbags", "reading a ROS bag")
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if not path.exists():
        raise FileFormatError(f"{path}: no such bag")
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # rosbags raises its own hierarchy for every malformed bag
        raise FileFormatError(f"{path}: not a readable ROS bag ({' '.join(str(exc).split())})") from None
    return reader


def bag_frames(path: str | Path, topic: str) -> Iterator[Frame]:
    """Images of one topic of a ROS 1 or ROS 2 bag, stamped by their header
    (or the record time when the header stamp is zero)."""
    p = Path(path)
    reader = open_bag(p)
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        if not conns:
            topics = sorted({c.topic for c in reader.connections if "Image" in c.msgtype})
            raise InputError(f"{p}: no topic {topic!r} (image topics: {', '.join(topics) or 'none'})")
        for i, (conn, stamp, raw) in enumerate(reader.messages(connections=conns)):
            t = stamp * 1e-9
            try:
                msg = reader.deserialize(raw, conn.msgtype)
                hs = msg.header.stamp
                if hs.sec or hs.nanosec:
                    t = hs.sec + hs.nanosec * 1e-9
                img = image_from_message(msg)
                yield Frame(i, t, img)
            except Exception as exc:  # a corrupt message must not end the stream
                yield Frame(i, t, None, f"corrupt message: {' '.join(str(exc).split())}")
    finally:
        reader.close()


def bag_camera(path: str | Path, topic: str) -> Camera | None:
    """The camera of the first ``sensor_msgs/CameraInfo`` message on ``topic``."""
    p = Path(path)
    reader = open_bag(p)
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        if not conns:
            raise InputError(f"{p}: no camera_info topic {topic!r}")
        for conn, _, raw in reader.messages(connections=conns):
            return camera_from_info(reader.deserialize(raw, conn.msgtype))
        return None
    finally:
        reader.close()


def camera_from_info(msg) -> Camera:
    """The camera of a ``sensor_msgs/CameraInfo`` message (ROS 1 or ROS 2, from a bag or over DDS)."""
    # ROS 1 spells the fields K and D, ROS 2 k and d.
    K = np.asarray(getattr(msg, "k", None) if hasattr(msg, "k") else msg.K, float).reshape(3, 3)
    d = np.asarray(getattr(msg, "d", None) if hasattr(msg, "d") else msg.D, float)
    size = (int(msg.width), int(msg.height)) if msg.width and msg.height else None
    return Camera(K, d if d.size else None, size)


def _video_rate(p: Path) -> float | None:
    cap = cv2.VideoCapture(str(p))
    try:
        rate = cap.get(cv2.CAP_PROP_FPS) if cap.isOpened() else 0.0
    finally:
        cap.release()
    return float(rate) if rate and np.isfinite(rate) and rate > 0 else None


def _bag_rate(p: Path, topic: str) -> float | None:
    reader = open_bag(p)
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        n = sum(int(getattr(c, "msgcount", 0) or 0) for c in conns)
        span = (reader.end_time - reader.start_time) * 1e-9
        return float((n - 1) / span) if n > 1 and span > 0 else None
    finally:
        reader.close()


def open_source(spec: str | Path, *, fps: float | None = None, topic: str | None = None) -> Stream:
    """A :class:`Stream` of a folder, a video file or (with ``topic``) a ROS bag."""
    p = Path(spec)
    if topic is not None:
        return Stream(bag_frames(p, topic), fps or _bag_rate(p, topic), f"{p}:{topic}")
    if p.is_dir() and not (p / "metadata.yaml").exists():
        files, stamps = _folder_stamps(p, fps)
        return Stream(folder_frames(p, fps), fps or _rate(stamps), str(p))
    if p.suffix == ".bag" or (p.is_dir() and (p / "metadata.yaml").exists()):
        raise InputError(f"{p}: a ROS bag needs the image topic (--topic ROBOT=TOPIC)")
    if not p.is_file():
        raise FileFormatError(f"{p}: no such video file or image folder")
    return Stream(video_frames(p, fps), fps or _video_rate(p), str(p))


def open_streams(paths: Mapping[str, str | Path], *, fps: float | None = None,
                 topics: Mapping[str, str] | None = None) -> dict[str, Stream]:
    """One :class:`Stream` per robot; the same source given for two robots is
    an error (one camera cannot be two robots' cameras)."""
    topics = topics or {}
    seen: dict[tuple[str, str | None], str] = {}
    for robot, path in paths.items():
        key = (str(Path(path).resolve()), topics.get(robot))
        if key in seen:
            raise InputError(f"robots {seen[key]!r} and {robot!r} are given the same stream {str(path)!r}"
                             + (f" topic {topics.get(robot)!r}" if topics.get(robot) else "")
                             + ": each robot's camera needs its own")
        seen[key] = robot
    return {r: open_source(p, fps=fps, topic=topics.get(r)) for r, p in paths.items()}


def rig_with_bag_cameras(rig: Rig, bags: Mapping[str, str | Path], topics: Mapping[str, str]) -> Rig:
    """``rig`` with each camera of ``topics`` (``ROBOT``, or ``ROBOT/CAMERA`` for a robot with several)
    calibrated from the first camera_info message on its topic of its bag (a body's camera keeps its pose)."""
    robots = dict(rig.robots)
    for key, topic in topics.items():
        robot, cname = rig.observer(key)
        cam = bag_camera(bags[key], topic) if key in bags else None
        if cam is None:
            raise InputError(f"no camera_info message for {'camera' if cname else 'robot'} {key!r} on {topic!r}")
        old = robots[robot]
        if old.cameras is None:
            robots[robot] = replace(old, camera=cam)
        else:
            cams = dict(old.cameras)
            cams[cname] = replace(cams[cname], camera=cam)
            robots[robot] = replace(old, cameras=cams)
    return Rig(robots)
