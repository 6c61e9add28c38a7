"""A node's camera: live sources that always hand on the newest frame.

``mutloc node --camera SOURCE`` (SPEC "Live operation") takes

- a camera device (``/dev/video0`` or ``0``: V4L2 through OpenCV),
- a GStreamer pipeline (``... ! appsink``) or a stream URL (``rtsp://...``)
  that OpenCV opens,
- a ROS 2 image topic over DDS (``ros:/p/image_raw``: ``sensor_msgs/msg/Image``;
  ``ros:/p/image_raw/compressed``: ``CompressedImage``), or
- a recording (video file, image folder, bag with ``topic``: the readers of
  :mod:`mutloc.track.sources`) replayed at its own rate (``realtime``).

Every source runs in a background thread and keeps only the newest frame
(:class:`LatestFrame`): a frame the detector had no time for is replaced by
the next one and counted as dropped, never queued, so the node's delay stays
one frame whatever the detector's speed.  Frames are stamped with the
wall-clock time at which they were captured (a ROS image: its header stamp;
a V4L2 device: the driver's buffer timestamp, :class:`DriverClock`);
a replayed frame's own time in the recording travels as ``source_time``.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import cv2
import numpy as np

from .._extras import require
from ..core.camera import Camera
from ..errors import InputError, MutlocError
from ..track.sources import Frame, image_from_message, open_source

__all__ = ["LiveFrame", "LatestFrame", "CameraSource", "CaptureSource", "ReplaySource", "RosImageSource",
           "open_camera", "camera_kind", "camera_info_topic", "compare_cameras", "camera_from_camera_info",
           "CAMERA_INFO_MODES", "DISTORTION_MODELS", "RECORDING_NEEDS_REALTIME", "DriverClock"]

#: ``--camera-info``: ``check`` a ROS camera_info against the rig's camera (warn when they differ), or ``use`` it.
CAMERA_INFO_MODES = ("check", "use")
#: The camera_info distortion models mutloc's cameras take, with their number of coefficients (``equidistant``:
#: the fisheye model, Kannala-Brandt k1..k4, as OpenCV's fisheye module and ROS's image_pipeline use it).
DISTORTION_MODELS = {"plumb_bob": 5, "rational_polynomial": 8, "equidistant": 4}

#: Seconds of frames in a row a starved replay drops at most (then one is released, however late).
MAX_DROPPED_RUN = 1.0

RECORDING_NEEDS_REALTIME = "a recording is replayed as a camera only with --realtime (frames released at their " \
                           "own rate, stamped when released)"


@dataclass
class LiveFrame(Frame):
    """A captured frame: ``t`` the wall-clock capture time (seconds since the
    epoch), ``index`` the source's own frame number (gaps: frames dropped
    before they reached the node), ``source_time`` a replayed frame's own
    time in the recording (else 0)."""

    source_time: float = 0.0
    #: Decodes ``image`` when the node takes the frame (ROS messages: only the frames processed are decoded).
    decode: Callable[[], np.ndarray] | None = None


class LatestFrame:
    """A one-frame slot between a capture thread and the node: :meth:`put`
    replaces a frame not yet taken (counted in :attr:`dropped`), :meth:`take`
    waits for the newest one."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._frame: LiveFrame | None = None
        self.captured = 0
        self.dropped = 0
        self.ended = False
        self.error: str | None = None

    def put(self, frame: LiveFrame, skipped: int = 0) -> None:
        """Hand on ``frame`` (``skipped``: frames the source itself dropped for it, counted too)."""
        with self._cond:
            self.captured += 1 + skipped
            self.dropped += skipped + (self._frame is not None)
            self._frame = frame
            self._cond.notify_all()

    def skip(self, n: int = 1) -> None:
        """``n`` frames captured that the node has no use for (counted as captured and dropped)."""
        with self._cond:
            self.captured += n
            self.dropped += n

    def end(self, error: str | None = None) -> None:
        """No frame will come after the one waiting (``error``: why, when it is a failure)."""
        with self._cond:
            self.ended = True
            self.error = self.error or error
            self._cond.notify_all()

    def take(self, timeout: float | None = None) -> LiveFrame | None:
        """The newest frame, waiting up to ``timeout`` seconds; None when there
        is none (timed out, or the source ended: see :attr:`finished`)."""
        with self._cond:
            if self._frame is None and not self.ended:
                self._cond.wait(timeout)
            frame, self._frame = self._frame, None
            return frame

    def discard(self) -> None:
        """Drop the frame waiting, if any (counted): the node stops."""
        with self._cond:
            self.dropped += self._frame is not None
            self._frame = None

    @property
    def finished(self) -> bool:
        """The source ended and its last frame was taken."""
        with self._cond:
            return self.ended and self._frame is None


class CameraSource:
    """A live source of :class:`LiveFrame`: :meth:`start` its thread,
    :meth:`take` the newest frame, :meth:`close` it.  ``fps`` is its nominal
    rate (None: unknown), ``camera`` a calibration it announces (ROS
    camera_info), ``notes`` what the node should tell its user."""

    name = "camera"
    fps: float | None = None
    #: Whether the source waits for frames forever (a ROS topic whose publisher may start later).
    patient = False

    def __init__(self) -> None:
        self.slot = LatestFrame()
        self.camera: Camera | None = None
        self.notes: list[str] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._handled = threading.Condition()
        self._handled_index = -1

    def handled(self, frame: LiveFrame) -> None:
        """The consumer is done with ``frame`` (the node published it): a
        source that has work of its own to do between frames (a replay's
        decoding) does it now rather than while the detector runs."""
        with self._handled:
            self._handled_index = max(self._handled_index, frame.index)
            self._handled.notify_all()

    def _wait_handled(self, index: int, deadline: float) -> None:
        """Wait until frame ``index`` (or a later one) was :meth:`handled`, or
        until ``deadline`` (``time.monotonic()``), or the source stops."""
        with self._handled:
            while self._handled_index < index and not self._stop.is_set():
                left = deadline - time.monotonic()
                if left <= 0:
                    return
                self._handled.wait(min(left, 0.05))

    def start(self) -> "CameraSource":
        self._thread = threading.Thread(target=self._guarded, name=f"mutloc camera {self.name}", daemon=True)
        self._thread.start()
        return self

    def _guarded(self) -> None:
        try:
            self._run()
        except Exception as exc:  # noqa: BLE001 -- the node reports it (one line) and stops
            self.slot.end(" ".join(str(exc).split()) or type(exc).__name__)
        else:
            self.slot.end()

    def _run(self) -> None:
        raise NotImplementedError

    def take(self, timeout: float | None = None) -> LiveFrame | None:
        frame = self.slot.take(timeout)
        if frame is not None and frame.decode is not None:
            try:
                frame.image = frame.decode()
            except Exception as exc:  # noqa: BLE001 -- a bad image message is a corrupt frame, not an end
                frame.image, frame.status = None, f"undecodable image: {' '.join(str(exc).split())}"
            frame.decode = None
        return frame

    @property
    def finished(self) -> bool:
        return self.slot.finished

    @property
    def error(self) -> str | None:
        return self.slot.error

    @property
    def captured(self) -> int:
        return self.slot.captured

    @property
    def dropped(self) -> int:
        return self.slot.dropped

    def close(self) -> None:
        """Stop the thread; a frame left waiting counts as dropped."""
        self._stop.set()
        with self._handled:
            self._handled.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self.slot.discard()


@contextlib.contextmanager
def _quiet_stderr() -> Iterator[None]:
    """OpenCV's and FFmpeg's own warnings silenced while a capture opens
    (the node says what went wrong in one line)."""
    import cv2.utils.logging as cvlog

    level = cvlog.getLogLevel()
    cvlog.setLogLevel(cvlog.LOG_LEVEL_SILENT)
    saved = None
    try:
        saved = os.dup(2)
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 2)
        os.close(null)
    except OSError:
        saved = None
    try:
        yield
    finally:
        if saved is not None:
            os.dup2(saved, 2)
            os.close(saved)
        cvlog.setLogLevel(level)


#: Seconds a driver's capture stamp may lie before its read returned (older: not a capture time of this frame).
DRIVER_STAMP_MAX_AGE = 1.0
#: Seconds a driver's capture stamp may lie after its read returned (the two clocks read a moment apart).
DRIVER_STAMP_SLACK = 0.002


class DriverClock:
    """The wall-clock capture time of a frame from the time its driver
    stamped it, when the backend gives one (OpenCV's V4L2 backend:
    ``CAP_PROP_POS_MSEC`` after a ``read`` is the buffer's ``timestamp`` from
    ``VIDIOC_DQBUF``, in ms: the time the driver took the frame -- for
    uvcvideo and most drivers on ``CLOCK_MONOTONIC``, for a few on
    ``CLOCK_REALTIME``).  Which clock is decided from the stamp itself (the
    one it lies within :data:`DRIVER_STAMP_MAX_AGE` before the read's return
    on); a monotonic stamp is moved to the wall clock by the offset between
    the two clocks measured at each read (``time.time() -
    time.monotonic()``, read back to back).  A stamp on neither clock (0 before
    the first frame, a stream's position in its file, a backend without
    stamps) gives the time the read returned, and :attr:`source` says so.
    ``driver``: whether to look at the backend's stamps at all (a V4L2
    device; a stream's position through FFmpeg is no clock, even if it
    happened to lie near one).
    """

    def __init__(self, driver: bool = True) -> None:
        self.driver = driver
        #: Where the stamps come from: ``"driver (monotonic)"``, ``"driver (realtime)"``, or ``"read"``
        #: (the time ``read()`` returned: later than the capture by the driver's queue and the transfer).
        self.source = "read"

    def stamp(self, cap: Any, wall: float, mono: float) -> float:
        """The capture time (wall clock, s) of the frame ``cap.read()`` just
        returned, at ``wall`` (``time.time()``) and ``mono`` (``time.monotonic()``)."""
        try:
            ms = float(cap.get(cv2.CAP_PROP_POS_MSEC)) if self.driver else math.nan
        except Exception:  # noqa: BLE001 -- a backend without the property
            ms = math.nan
        t = ms / 1000.0
        if math.isfinite(t) and t > 0:
            for clock, now, to_wall in (("monotonic", mono, wall - mono), ("realtime", wall, 0.0)):
                if -DRIVER_STAMP_SLACK <= now - t <= DRIVER_STAMP_MAX_AGE:
                    self.source = f"driver ({clock})"
                    return min(t, now) + to_wall
        self.source = "read"
        return wall


def _has_gstreamer() -> bool:
    for line in cv2.getBuildInformation().splitlines():
        if line.strip().startswith("GStreamer:"):
            return "YES" in line.split(":", 1)[1]
    return False


class CaptureSource(CameraSource):
    """A V4L2 device, a GStreamer pipeline or a stream URL, through OpenCV's
    VideoCapture, read continuously in the background (the driver's queue
    never fills with old frames), each frame stamped with its capture time:
    the driver's when the backend reports it (a V4L2 device: the buffer's
    timestamp, see :class:`DriverClock`), else the wall-clock time its read
    returned (:attr:`stamping` says which)."""

    def __init__(self, spec: str, *, max_failures: int = 5) -> None:
        super().__init__()
        self.name = spec
        kind = camera_kind(spec)
        if kind == "device":
            target: Any = int(spec) if spec.isdigit() else spec
            if isinstance(target, str) and not Path(target).exists():
                raise InputError(f"camera {spec}: no such device")
            api = cv2.CAP_V4L2
        elif kind == "pipeline":
            if not _has_gstreamer():
                raise InputError(f"camera {spec!r}: a GStreamer pipeline, but this OpenCV is built without "
                                 "GStreamer (give a device, a stream URL, or publish the images on a ROS topic)")
            target, api = spec, cv2.CAP_GSTREAMER
        else:
            target, api = spec, cv2.CAP_ANY
        with _quiet_stderr():
            cap = cv2.VideoCapture(target, api)
            if cap.isOpened():
                cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        if not cap.isOpened():
            what = {"device": "device", "pipeline": "pipeline"}.get(kind, "stream")
            raise InputError(f"camera {spec}: the {what} cannot be opened (busy, absent, or not a camera)")
        self._cap = cap
        rate = cap.get(cv2.CAP_PROP_FPS)
        self.fps = float(rate) if rate and math.isfinite(rate) and 0 < rate < 1000 else None
        self._max_failures = max_failures
        self._clock = DriverClock(driver=kind == "device")

    @property
    def stamping(self) -> str:
        """Where the frames' stamps come from (:attr:`DriverClock.source`)."""
        return self._clock.source

    def _run(self) -> None:
        failures, index = 0, 0
        try:
            while not self._stop.is_set():
                ok, image = self._cap.read()
                wall, mono = time.time(), time.monotonic()
                if not ok or image is None:
                    failures += 1
                    if failures >= self._max_failures:
                        raise InputError(f"camera {self.name}: stopped delivering frames")
                    time.sleep(0.01)
                    continue
                failures = 0
                t = self._clock.stamp(self._cap, wall, mono)
                if index == 1 and self._clock.source == "read":  # (the first frame has no stamp in OpenCV)
                    self.notes.append(f"camera {self.name}: OpenCV gives no capture time for its frames; they are "
                                      "stamped when read() returned (later than the capture by the driver's queue "
                                      "and the transfer)")
                self.slot.put(LiveFrame(index, t, image))
                index += 1
        finally:
            self._cap.release()


class ReplaySource(CameraSource):
    """A recording (video file, image folder, or ``topic`` of a bag) played
    as a camera: frame k is released ``(t_k - t_0) / speed`` seconds after
    the first, stamped with the wall-clock time it is due (the first frame's
    release plus that; a camera stamps its exposure, not the moment its
    driver hands the frame on), its own time in the recording as
    ``source_time``.  Images are decoded before their
    release time (a camera's readout), so the stamps keep the recording's
    spacing while decoding keeps up; the next image is decoded once the
    node is done with the frame released (:meth:`~CameraSource.handled`),
    or when its release is near, so that decoding (a PNG of 960x540 takes
    longer than most detectors) does not take the CPU from the detector as
    a camera's readout would not.  ``loop``: play it again and again (frame
    numbers and ``source_time`` going on from one pass to the next).
    ``start_at``: the wall-clock time (UNIX seconds) at which the first
    frame is released, so that several replays (one per robot) run in step;
    default: as soon as the source starts.

    A replay is a camera, also when it is starved: a frame that is ready
    only after the next one was due (the machine too busy for the replay's
    readout) while the node is not done with the last frame released
    (:meth:`~CameraSource.handled`) is dropped (counted,
    :meth:`LatestFrame.skip`), never handed to a busy node late with a stale
    stamp -- at most :data:`MAX_DROPPED_RUN` s of frames in
    a row (of the recording's schedule and of the wall clock: a dropped frame
    is decoded all the same), then one is released however late.  With the slot (a frame not
    taken before the next one is released is replaced), a node slower than
    the frame rate drops frames and is never handed a backlog."""

    def __init__(self, spec: str | Path, *, speed: float = 1.0, topic: str | None = None,
                 fps: float | None = None, loop: bool = False, start_at: float | None = None) -> None:
        super().__init__()
        p = Path(spec)
        self._open = lambda: open_source(p, fps=fps, topic=topic)
        self.loop = loop
        if topic is None and (p.suffix in (".bag", ".mcap", ".db3") or (p / "metadata.yaml").exists()):
            raise InputError(f"{p}: a ROS bag needs the image topic (--topic TOPIC)")
        if not (math.isfinite(speed) and speed > 0):
            raise InputError(f"replay speed must be a finite number > 0, got {speed}")
        self.stream = self._open()
        self.name = self.stream.name
        self.fps = self.stream.fps  # the recording's rate: the clock its detectors run on (source_time)
        self.speed = float(speed)
        if start_at is not None and not math.isfinite(start_at):
            raise InputError(f"--start-at must be a finite UNIX time, got {start_at}")
        self.start_at = start_at
        self.patient = start_at is not None  # waits for its start time

    def _run(self) -> None:
        start = t0 = None
        stream, shift, index = self.stream, 0.0, 0
        period = 1.0 / ((self.fps or 30.0) * self.speed)
        decoding: deque[float] = deque(maxlen=16)  # the recent decoding times, s
        released: LiveFrame | None = None
        put_at = -math.inf  # (time.monotonic() of the last frame released)
        while True:
            first = last = None
            frames = iter(stream)
            while True:
                if released is not None and start is not None:
                    # the next image decoded once the node is done with the last frame, or a bit before it is due
                    margin = 1.5 * max(decoding, default=period) + 0.003
                    due_next = start + (released.source_time - t0) / self.speed + period
                    self._wait_handled(released.index, due_next - margin)
                if self._stop.is_set():
                    return
                c = time.monotonic()
                f = next(frames, None)
                decoding.append(time.monotonic() - c)
                if f is None:
                    break
                t = f.t + shift
                if start is None:
                    start, wall, t0 = time.monotonic(), time.time(), t
                    if self.start_at is not None:
                        start, wall = start + self.start_at - wall, self.start_at
                due = (t - t0) / self.speed
                delay = start + due - time.monotonic()
                if (-delay > period and released is not None and self._handled_index < released.index
                        and time.monotonic() - put_at < MAX_DROPPED_RUN
                        and due - (released.source_time - t0) / self.speed < MAX_DROPPED_RUN):
                    # ready after the next frame was due, the node still busy with the last one: dropped, as a
                    # starved camera driver drops it (a node waiting for frames gets it, however late)
                    self.slot.skip()
                    first, last = first or f, f
                    continue
                if delay > 0 and self._stop.wait(delay):
                    return
                # stamped with the instant it is due, as a camera stamps its exposure (the thread's
                # scheduling delay is the transfer's, not the capture's)
                released = LiveFrame(index + f.index, wall + due, f.image, f.status, source_time=t)
                self.slot.put(released)
                put_at = time.monotonic()
                first, last = first or f, f
            if not self.loop or last is None:
                return
            # Played again from the start, its times going on one frame after the last one's.
            shift += last.t - first.t + 1.0 / (self.stream.fps or 30.0)
            index += last.index + 1
            stream = self._open()


def camera_info_topic(image_topic: str) -> str:
    """The camera_info topic beside an image topic, as ROS camera drivers name
    it: ``/p/image_raw`` and ``/p/image_raw/compressed`` -> ``/p/camera_info``."""
    topic = image_topic[: -len("/compressed")] if image_topic.endswith("/compressed") else image_topic
    return topic.rpartition("/")[0] + "/camera_info"


def compare_cameras(announced: Camera, rig_camera: Camera, where: str) -> str | None:
    """None when a camera_info's calibration agrees with the rig's (K to
    1e-6 relative, the same size and distortion where both give them), else one
    line saying how they differ."""
    diffs = []
    models = getattr(announced, "model", "pinhole"), getattr(rig_camera, "model", "pinhole")
    if models[0] != models[1]:
        diffs.append(f"lens model {models[0]} vs the rig's {models[1]}")
    if not np.allclose(announced.K, rig_camera.K, rtol=1e-6, atol=1e-9):
        fmt = lambda K: f"fx={K[0, 0]:g} fy={K[1, 1]:g} cx={K[0, 2]:g} cy={K[1, 2]:g}"  # noqa: E731
        diffs.append(f"K {fmt(announced.K)} vs the rig's {fmt(rig_camera.K)}")
    if announced.size is not None and rig_camera.size is not None and tuple(announced.size) != tuple(rig_camera.size):
        diffs.append(f"size {announced.size[0]}x{announced.size[1]} vs the rig's "
                     f"{rig_camera.size[0]}x{rig_camera.size[1]}")
    if models[0] == models[1] and not np.allclose(announced.dist, rig_camera.dist, rtol=1e-6, atol=1e-9):
        diffs.append("distortion differs")
    if not diffs:
        return None
    return f"{where} differs from the rig's camera: {'; '.join(diffs)} (detections and the localizer use the " \
           "rig's; fix the rig file if the camera_info is right, or give --camera-info use)"


def camera_from_camera_info(msg: Any, where: str) -> Camera:
    """The camera a ``sensor_msgs/msg/CameraInfo`` announces, checked as a
    calibration to work with: ``k`` a pinhole matrix with positive focal
    lengths, ``d`` as many coefficients as its ``distortion_model`` has
    (``plumb_bob`` 5, ``rational_polynomial`` 8: a pinhole
    :class:`~mutloc.core.camera.Camera`; ``equidistant`` 4: a
    :class:`~mutloc.core.lenses.FisheyeCamera`; none without a model),
    ``width`` and ``height`` given, no binning or region of interest.
    InputError (one line, naming ``where``) otherwise."""
    def bad(why: str) -> InputError:
        return InputError(f"{where}: {why}")

    try:
        k = np.asarray(list(msg.k), float)
        d = np.asarray(list(msg.d), float)
        model = str(msg.distortion_model or "")
        width, height = int(msg.width), int(msg.height)
    except (AttributeError, TypeError, ValueError):
        raise bad("not a camera_info message") from None
    if k.size != 9:
        raise bad(f"k has {k.size} numbers, a 3x3 matrix has 9")
    if not (np.all(np.isfinite(k)) and k[0] > 0 and k[4] > 0):
        raise bad(f"focal lengths must be positive and finite, got fx={k[0]:g} fy={k[4]:g} (an uncalibrated "
                  "camera?)")
    if model:
        if model not in DISTORTION_MODELS:
            raise bad(f"distortion model {model!r} is not supported ({', '.join(DISTORTION_MODELS)})")
        if d.size != DISTORTION_MODELS[model]:
            raise bad(f"{model} has {DISTORTION_MODELS[model]} distortion coefficients, d has {d.size}")
    elif np.any(d != 0):
        raise bad(f"d has {d.size} distortion coefficients but no distortion_model")
    if width <= 0 or height <= 0:
        raise bad(f"image size {width}x{height}: width and height must be given")
    roi = msg.roi
    if int(msg.binning_x) > 1 or int(msg.binning_y) > 1 or int(roi.x_offset) or int(roi.y_offset) or (
            int(roi.width) and (int(roi.width), int(roi.height)) != (width, height)):
        raise bad("binning and regions of interest are not supported (publish the full-resolution camera_info)")
    try:
        if model == "equidistant":
            from ..core.lenses import FisheyeCamera

            return FisheyeCamera(k.reshape(3, 3), d, (width, height))
        return Camera(k.reshape(3, 3), d if model else None, (width, height))
    except MutlocError as exc:
        raise bad(" ".join(str(exc).split())) from None


class RosImageSource(CameraSource):
    """A ROS 2 image topic received over DDS (``sensor_msgs/msg/Image`` in
    rgb8, bgr8, mono8 and the other encodings :func:`mutloc.track.sources.image_from_message`
    reads, or ``CompressedImage`` jpeg/png when the topic ends in
    ``/compressed``), read with sensor-data QoS.  Each frame is stamped with
    its header's stamp (the driver's capture time; the receive time when the
    stamp is zero).  The first message of the camera_info topic beside it is
    read (:func:`camera_from_camera_info`) into :attr:`camera`.  With
    ``use_info`` False it is checked against ``rig_camera``: a difference,
    or a camera_info that holds no valid calibration, is a note for the user
    (the rig's camera is used).  With ``use_info`` the node takes its camera
    model from it: frames are dropped (counted) until it came, and one that
    holds no valid calibration ends the source with that error."""

    patient = True

    def __init__(self, bus: Any, topic: str, *, rig_camera: Camera | None = None, use_info: bool = False) -> None:
        super().__init__()
        from .messages import ros_types

        T = ros_types()
        if not topic.startswith("/"):
            topic = "/" + topic
        self.topic = topic
        self.name = f"ros:{topic}"
        self.compressed = topic.endswith("/compressed")
        self.info_topic = camera_info_topic(topic)
        self.use_info = bool(use_info)
        self._reader = bus.reader(topic, T.CompressedImage if self.compressed else T.Image, sensor=True)
        self._info = bus.reader(self.info_topic, T.CameraInfo, sensor=True)
        self._participant = bus.participant
        self._rig_camera = rig_camera
        self._info_read = False

    @property
    def malformed(self) -> int:
        """Samples on the topics that could not be decoded."""
        return self._reader.malformed + self._info.malformed

    def _check_info(self) -> None:
        if self._info_read:
            return
        for sample in self._info.take():
            self._info_read = True
            where = f"camera_info on {self.info_topic}"
            try:
                self.camera = camera_from_camera_info(sample, where)
            except InputError as exc:
                if self.use_info:
                    raise
                self.notes.append(f"{exc} (the rig's camera is used)")
                self.camera = self._rig_camera
                return
            if self._rig_camera is not None and not self.use_info:
                note = compare_cameras(self.camera, self._rig_camera, where)
                if note:
                    self.notes.append(note)
            return

    def _run(self) -> None:
        require("cyclonedds", "a ROS image topic as the camera")
        from cyclonedds.core import ReadCondition, SampleState, ViewState, InstanceState, WaitSet
        from cyclonedds.util import duration

        waitset = WaitSet(self._participant)
        waitset.attach(ReadCondition(self._reader.native, SampleState.Any | ViewState.Any | InstanceState.Any))
        index = 0
        while not self._stop.is_set():
            waitset.wait(duration(milliseconds=100))
            self._check_info()
            samples = self._reader.take()
            if not samples:
                continue
            if self.use_info and self.camera is None:
                self.slot.skip(len(samples))  # no camera model to detect in yet
                continue
            now = time.time()
            msg = samples[-1]
            st = msg.header.stamp
            t = st.sec + st.nanosec * 1e-9 if (st.sec or st.nanosec) else now
            index += len(samples)
            self.slot.put(LiveFrame(index - 1, t, None, decode=lambda m=msg: image_from_message(m)),
                          skipped=len(samples) - 1)


def camera_kind(spec: str) -> str:
    """What ``--camera SOURCE`` names: ``"ros"`` (``ros:/topic``), ``"device"``
    (``/dev/...`` or a number), ``"pipeline"`` (GStreamer, holds ``!``),
    ``"url"`` (``scheme://...``) or ``"recording"`` (a file or folder)."""
    spec = str(spec)
    if spec.startswith("ros:"):
        return "ros"
    if spec.isdigit() or spec.startswith("/dev/"):
        return "device"
    if "!" in spec:
        return "pipeline"
    if re.match(r"^[A-Za-z][A-Za-z0-9+.-]*://", spec):
        return "url"
    return "recording"


def open_camera(spec: str, *, bus: Any = None, realtime: float | None = None, topic: str | None = None,
                loop: bool = False, rig_camera: Camera | None = None, start_at: float | None = None,
                camera_info: str = "check") -> CameraSource:
    """The :class:`CameraSource` ``spec`` names (see the module docstring),
    not started.  ``realtime``: the replay speed of a recording (1: its own
    rate; required for a recording); ``loop``: replay it again and again;
    ``topic``: a bag's image topic; ``bus``:
    the :class:`mutloc.live.dds.Bus` a ROS topic is read on; ``rig_camera``:
    the calibration a camera_info is checked against; ``start_at``: a
    replay's first frame at that wall-clock time; ``camera_info``: ``check``
    a ROS topic's camera_info against ``rig_camera``, or ``use`` it as the
    camera (see :class:`RosImageSource`).  InputError (one line) when the
    source cannot be opened."""
    kind = camera_kind(spec)
    if camera_info not in CAMERA_INFO_MODES:
        raise InputError(f"--camera-info must be one of {', '.join(CAMERA_INFO_MODES)}, got {camera_info!r}")
    if camera_info == "use" and kind != "ros":
        raise InputError(f"--camera-info use takes the camera model from a ROS camera_info topic; --camera {spec} "
                         "is not a ROS image topic (ros:/TOPIC)")
    if kind != "recording" and topic is not None:
        raise InputError("--topic names the image topic of a bag; for a live ROS topic give --camera ros:TOPIC")
    if kind == "ros":
        name = spec[len("ros:"):]
        if not name.strip("/"):
            raise InputError(f"--camera {spec!r}: give the image topic, e.g. ros:/p/image_raw")
        if bus is None:
            raise InputError("a ROS image topic is read over DDS: a bus is needed")
        return RosImageSource(bus, name, rig_camera=rig_camera, use_info=camera_info == "use")
    if kind == "recording":
        if realtime is None:
            p = Path(spec)
            if not p.exists():
                raise InputError(f"--camera {spec}: no such device, stream, ROS topic (ros:/...) or recording")
            raise InputError(f"--camera {spec}: {RECORDING_NEEDS_REALTIME}")
        return ReplaySource(spec, speed=realtime, topic=topic, loop=loop, start_at=start_at)
    if start_at is not None:
        raise InputError(f"--start-at times a replay; --camera {spec} is live")
    if loop:
        raise InputError(f"--loop replays a recording again and again; --camera {spec} is live")
    if realtime is not None:
        raise InputError(f"--realtime replays a recording; --camera {spec} is live")
    return CaptureSource(spec)
