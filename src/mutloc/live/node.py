"""``mutloc node``: one robot's detector on the wire (SPEC "Live operation").

A node takes the newest frame of its camera (:mod:`mutloc.live.cameras`),
finds the other robots' markers in it with the detectors ``track`` uses
(:class:`mutloc.track.tracker.ObserverDetector`: every marker kind of the
rig, blinking-light trackers keeping their state from frame to frame) and
publishes one ``mutloc_msgs/msg/Observations`` message per processed frame
on ``/mutloc/NAME/observations`` -- also when nothing was seen -- stamped
with the frame's capture time.  Frames it has no time for are dropped at the
camera (never queued) and counted; a node that dropped frames in the last
:data:`BEHIND_WINDOW` s says "falling behind: dropped N of the last M frames"
(a warning line, and WARN in its diagnostics).

A tag of another robot the detector missed (small, seen far off its normal)
is looked for again where the localizer's latest poses put it: the node
reads ``/tf`` (the localizer publishes every robot's pose there) and, for a
frame within :data:`TF_MAX_AGE` of those poses, searches a window around the
predicted tag (:func:`mutloc.track.tag_look.look_where_tracked`).  The tag
is decoded from the frame's own pixels; transforms between frames that are
not robots of the rig (other ROS nodes' trees) are ignored and counted.

A robot with several cameras (rig ``cameras:``) runs one :class:`Node` per
camera (``camera``: its name), each with its own source, detecting through
its own lens and mount (:func:`mutloc.track.frames.detect_markers` with the
camera's key) and publishing on the robot's topic with ``header.frame_id``
``NAME/CAMERA``; :func:`run_nodes` runs them together, each in its own
thread (``mutloc node --camera front=SRC --camera back=SRC``).

>>> from mutloc.live.dds import Bus
>>> from mutloc.live.cameras import open_camera
>>> bus = Bus(7, loopback=True)                                     # doctest: +SKIP
>>> node = Node("rig.yaml", "p", open_camera("sim/p", realtime=1.0), bus)  # doctest: +SKIP
>>> stats = node.run()                                              # doctest: +SKIP
>>> print(stats.summary())                                          # doctest: +SKIP
"""

from __future__ import annotations

import math
import re
import threading
import time
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..api import load_rig
from ..core.camera import Camera
from ..core.observations import ObservationSet
from ..core.pose import Pose
from ..core.rig import MarkerKind, Mount, Rig
from ..errors import InputError, MutlocError
from ..signals import exit_on_stop
from ..detect.tags import tag_corner_points
from ..track.frames import expanded_rig
from ..track.sources import Frame
from ..track.tag_look import look_where_tracked
from ..track.tracker import DEFAULT_FPS, ObserverDetector
from .cameras import CameraSource, LiveFrame, ReplaySource
from .messages import (DIAGNOSTICS_TOPIC, OK, TF_TOPIC, WARN, RobotStatus, diagnostics_message,
                       observations_message, observations_topic, rig_id as rig_file_id, ros_types, stamp_of)

__all__ = ["Node", "NodeStats", "percentile_ms", "warm_up_images", "warm_up_detector", "camera_key",
           "camera_arguments", "with_camera",
           "run_nodes", "LATENCY_WINDOW", "TF_MAX_AGE", "BEHIND_WINDOW"]

#: The latencies a node keeps (the most recent: an hour at 30 frames/s), so a node running for days stays small.
LATENCY_WINDOW = 108_000
#: Seconds over which a node counts the frames it dropped ("falling behind: dropped N of the last M frames").
BEHIND_WINDOW = 5.0
#: A robot's pose from ``/tf`` predicts where its tags are in frames at most this far (s) from its stamp.
TF_MAX_AGE = 0.25


def percentile_ms(values: Any, q: float) -> float:
    """The ``q``-th percentile of ``values`` (seconds) in milliseconds (NaN when empty)."""
    return float(np.percentile(np.asarray(values, float), q) * 1e3) if len(values) else float("nan")


@dataclass
class NodeStats:
    """What a node did: frames captured by its camera, processed (one
    message published each), dropped (replaced by a newer frame before the
    detector was free), corrupt (unreadable, not published), out of order
    (a stamp not after the previous frame's, not published); ``latencies``:
    capture -> publish of the published messages, seconds (the last
    :data:`LATENCY_WINDOW`)."""

    robot: str
    source: str
    topic: str
    captured: int = 0
    processed: int = 0
    dropped: int = 0
    corrupt: int = 0
    out_of_order: int = 0
    unexpressed: int = 0  # detections left out: the rig's camera cannot express their ray (--camera-info use)
    #: Tags found again where the localizer's poses (``/tf``) put them; transforms on ``/tf`` not between two
    #: robots of the rig (ignored); ``/tf`` samples that could not be decoded.
    looked_again: int = 0
    tf_foreign: int = 0
    tf_malformed: int = 0
    markers_seen: int = 0  # in the last processed frame
    #: ``(time.monotonic(), captured, dropped)`` about once a second over the last :data:`BEHIND_WINDOW` s.
    window: deque = field(default_factory=lambda: deque(maxlen=int(BEHIND_WINDOW) + 1))
    latencies: deque = field(default_factory=lambda: deque(maxlen=LATENCY_WINDOW))
    #: Per published message, seconds: ``(capture -> taken by the node, detection (wall), detection (this
    #: thread's CPU), detected -> written)`` (the last :data:`LATENCY_WINDOW`).
    stages: deque = field(default_factory=lambda: deque(maxlen=LATENCY_WINDOW))
    started: float = field(default_factory=time.monotonic)
    #: This process's CPU time (all threads: camera, detection, DDS) at the start and at the last frame, s.
    cpu_started: float = field(default_factory=time.process_time)
    cpu_now: float = field(default_factory=time.process_time)

    @property
    def fps(self) -> float:
        """Processed frames per second since the start."""
        dt = time.monotonic() - self.started
        return self.processed / dt if dt > 0 else 0.0

    def _latency(self) -> str:
        if not self.latencies:
            return ""
        recent = list(self.latencies)[-300:]
        return f", capture->publish p50 {percentile_ms(recent, 50):.1f} ms p99 {percentile_ms(recent, 99):.1f} ms"

    def note_counts(self, now: float) -> None:
        """Remember the counts at ``now`` (monotonic) for :meth:`behind` (once a second is enough)."""
        if not self.window or now - self.window[-1][0] >= 1.0:
            self.window.append((now, self.captured, self.dropped))

    def behind(self) -> str:
        """``falling behind: dropped N of the last M frames`` when frames were dropped over the window, else ""."""
        if not self.window:
            return ""
        _, c0, d0 = self.window[0]
        n, m = self.dropped - d0, self.captured - c0
        return f"falling behind: dropped {n} of the last {m} frames" if n > 0 else ""

    def status_line(self) -> str:
        """One line for the periodic status."""
        return (f"node {self.robot}: {self.captured} captured, {self.processed} processed ({self.fps:.1f}/s), "
                f"{self.dropped} dropped{self._latency()}, {self.markers_seen} markers in the last frame")

    def stage_line(self) -> str:
        """Where capture -> publish went: p50/p99 of each stage, ms (empty before the first message)."""
        if not self.stages:
            return ""
        a = np.asarray(self.stages, float)
        parts = [f"{name} {percentile_ms(a[:, k], 50):.1f}/{percentile_ms(a[:, k], 99):.1f}"
                 for k, name in enumerate(("waiting", "detect", "detect cpu", "publish"))]
        cpu = (self.cpu_now - self.cpu_started) / max(1, self.captured) * 1e3
        return (f"node {self.robot} stages p50/p99 ms: " + ", ".join(parts)
                + f"; process cpu {cpu:.1f} ms per frame captured")

    def summary(self) -> str:
        """The line printed at exit."""
        extra = "".join(f", {n} {what}" for n, what in (
            (self.corrupt, "corrupt"), (self.out_of_order, "out of order"),
            (self.unexpressed, "detections outside the rig's camera"),
            (self.looked_again, "tags found again where the localizer's poses put them")) if n)
        lat = ""
        if self.latencies:
            lat = (f"; capture->publish p50 {percentile_ms(self.latencies, 50):.1f} ms, "
                   f"p99 {percentile_ms(self.latencies, 99):.1f} ms")
        return (f"node {self.robot}: {self.captured} frames captured from {self.source}, {self.processed} processed "
                f"(published on {self.topic}), {self.dropped} dropped{extra}{lat}")


def camera_key(rig: Rig, robot: str, camera: str | None) -> str:
    """The observation key of ``robot``'s camera ``camera`` (SPEC "Robots with
    several cameras, any lens"): ``ROBOT`` for a robot given with one
    ``camera`` (``camera`` None), ``ROBOT/CAMERA`` for a camera of a robot with
    ``cameras`` (``camera`` may be None when it has only one).  InputError
    (one line, naming the robot's cameras) otherwise."""
    r = rig.robot(robot)
    if r.cameras is None:
        if camera is not None:
            raise InputError(f"robot {robot!r} has one camera (rig 'camera:'): give --camera SOURCE, without a "
                             f"camera name (got {camera!r})")
        return robot
    names = ", ".join(r.cameras)
    if camera is None:
        if len(r.cameras) == 1:
            return r.observer_key(next(iter(r.cameras)))
        first = next(iter(r.cameras))
        raise InputError(f"robot {robot!r} has cameras {names}: name the camera of each source "
                         f"(--camera {first}=SOURCE, one --camera per camera this node runs)")
    if camera not in r.cameras:
        raise InputError(f"robot {robot!r} has no camera {camera!r} (its cameras: {names})")
    return r.observer_key(camera)


#: ``--camera CAM=SOURCE``: a camera name (no spaces, ``/``, ``:``, ``!`` or ``=``) before the first ``=``.
_NAMED = re.compile(r"^([^\s/:!=]+)=(.+)$")


def camera_arguments(rig: Rig, robot: str, specs: list[str]) -> list[tuple[str | None, str]]:
    """``(camera, source)`` of each ``--camera`` argument of ``mutloc node``:
    ``CAM=SOURCE`` names a camera of a robot with ``cameras``, a bare
    ``SOURCE`` is the one camera of a robot (a GStreamer pipeline's or URL's
    own ``=`` are not taken for a name: a name has no spaces, ``/``, ``:`` or
    ``!``).  InputError (one line) for a camera the robot does not have, one
    named twice, several sources for a robot with one camera, or a bare
    source for a robot with several (see :func:`camera_key`)."""
    r = rig.robot(robot)
    out: list[tuple[str | None, str]] = []
    for spec in specs:
        m = _NAMED.match(spec)
        if m is not None and not (r.cameras is None and Path(spec).exists()):
            camera, source = m.group(1), m.group(2)
        else:
            camera, source = None, spec
        camera_key(rig, robot, camera)  # (an unknown camera, or one missing: one line)
        out.append((camera, source))
    if r.cameras is None and len(out) > 1:
        raise InputError(f"robot {robot!r} has one camera: give one --camera SOURCE, got {len(out)}")
    keys = [camera_key(rig, robot, c) for c, _ in out]
    twice = sorted({k for k in keys if keys.count(k) > 1})
    if twice:
        raise InputError(f"--camera: camera {twice[0]} given twice")
    return out


def camera_topics(cameras: list[tuple[str | None, str]], topics: list[str] | None) -> list[str | None]:
    """The bag image topic of each of ``cameras`` (:func:`camera_arguments`'
    result) from ``mutloc node``'s ``--topic`` arguments: ``CAM=TOPIC`` for a
    named camera, a bare ``TOPIC`` for the one camera given (None: no topic).
    InputError (one line) for a topic of a camera not given with --camera, a
    camera given two topics, or a bare topic where several cameras are given."""
    topics = topics or []
    named: dict[str, str] = {}
    bare: list[str] = []
    for spec in topics:
        m = _NAMED.match(spec)
        if m is None:
            bare.append(spec)
            continue
        camera, topic = m.group(1), m.group(2)
        if camera not in {c for c, _ in cameras if c is not None}:
            given = ", ".join(c for c, _ in cameras if c is not None) or "none named"
            raise InputError(f"--topic {spec}: no --camera {camera}=... was given (cameras: {given})")
        if camera in named:
            raise InputError(f"--topic: camera {camera} given two topics")
        named[camera] = topic
    if bare and (named or len(bare) > 1 or len(cameras) > 1):
        raise InputError("--topic: with several cameras give one --topic CAM=TOPIC per camera")
    if bare:
        return [bare[0]]
    return [named.get(c) if c is not None else None for c, _ in cameras]


def with_camera(rig: Rig, key: str, camera: Any) -> Rig:
    """``rig`` with the camera of observation key ``key`` replaced by ``camera`` (its mount's pose kept)."""
    rname, cname = rig.observer(key)
    r = rig.robots[rname]
    if r.cameras is None:
        new = replace(r, camera=camera)
    else:
        cams = dict(r.cameras)
        cams[cname] = Mount(cname, camera, cams[cname].pose)
        new = replace(r, cameras=cams)
    return Rig({**rig.robots, rname: new})


def run_nodes(nodes: list["Node"], **options: Any) -> list["NodeStats"]:
    """Run the nodes of one robot's cameras (each :meth:`Node.run` with
    ``options``), each camera's detection in its own thread, until every
    source ends, ``duration`` passed, or Ctrl-C (``KeyboardInterrupt`` goes
    on once every node stopped; their :attr:`Node.stats` hold what was done).
    The first error of a node stops them all and is raised.  One node runs in
    the calling thread."""
    if len(nodes) == 1:
        return [nodes[0].run(**options)]
    stop = options.pop("stop", None) or threading.Event()
    for node in nodes:
        node.warm_up()
    replays = [n.source for n in nodes if isinstance(n.source, ReplaySource)]
    if len(replays) > 1 and all(r.start_at is None for r in replays):
        # a robot's recordings replayed in step, as its cameras captured them: the first frames released together
        for n in nodes:
            if isinstance(n.source, ReplaySource):
                n.wait_for_subscriber(options.get("subscriber_timeout", 3.0))
        options["subscriber_timeout"] = 0.0  # (waited for above)
        start = time.time() + 0.2
        for r in replays:
            r.start_at, r.patient = start, True
    errors: list[BaseException] = []

    def one(node: "Node") -> None:
        try:
            node.run(stop=stop, **options)
        except BaseException as exc:  # noqa: BLE001 -- handed to the caller's thread
            errors.append(exc)
            stop.set()

    threads = [threading.Thread(target=one, args=(n,), name=f"mutloc node {n.key}", daemon=True) for n in nodes]
    for th in threads:
        th.start()
    try:
        while any(th.is_alive() for th in threads):
            for th in threads:
                th.join(timeout=0.1)
    except KeyboardInterrupt:
        stop.set()
        for th in threads:
            th.join(timeout=5.0)
        raise
    if errors:
        raise errors[0]
    return [n.stats for n in nodes]


def warm_up_images(rig: Rig, others: list[str], size: tuple[int, int], fps: float) -> list[np.ndarray]:
    """Images of ``size`` (width, height) showing the markers of ``others``
    as a camera might: coloured balls, tags (their printed pattern), blinking
    lights switching at their rates over 1.2 s of frames at ``fps`` (their
    tracker names a light after 0.7 s of blink history); none when there is
    nothing to draw.  What :meth:`Node.warm_up` runs the detectors on."""
    import cv2

    from ..detect.tags import tag_spec
    from ..sim.world import tag_image

    markers = [m for r in others for m in rig.robot(r).markers.values()
               if m.kind in (MarkerKind.BALL, MarkerKind.LIGHT, MarkerKind.TAG)]
    if not markers:
        return []
    w, h = size
    cell = max(24, min(w, h) // 6)  # one marker per cell of a grid
    cols = max(1, w // cell)
    places = [((k % cols) * cell + cell // 2, (k // cols) * cell + cell // 2) for k in range(len(markers))]
    lights = any(m.kind == MarkerKind.LIGHT for m in markers)
    n = int(math.ceil(1.2 * fps)) if lights else 1
    images = []
    for k in range(n):
        t = k / fps
        img = np.full((h, w, 3), 60, np.uint8)
        for m, (x, y) in zip(markers, places):
            if y + cell // 2 > h:
                break  # (more markers than the grid holds: those drawn suffice)
            bgr = tuple(int(c) for c in (m.color or (255, 255, 255))[::-1])
            radius = max(4, cell // 5)
            if m.kind == MarkerKind.BALL:
                cv2.circle(img, (x, y), radius, bgr, -1, cv2.LINE_AA)
            elif m.kind == MarkerKind.LIGHT:
                if math.sin(2 * math.pi * float(m.blink_hz) * t) >= 0:
                    cv2.circle(img, (x, y), radius // 2 + 1, bgr, -1, cv2.LINE_AA)
            else:
                try:
                    family, tag_id, _ = tag_spec(m)
                    pattern = tag_image(family, tag_id)
                except MutlocError:
                    continue
                side = (cell * 3 // 4) // pattern.shape[0] * pattern.shape[0]
                if side < pattern.shape[0] * 2:
                    continue
                tag = cv2.resize(pattern, (side, side), interpolation=cv2.INTER_NEAREST)
                x0, y0 = x - side // 2, y - side // 2
                img[y0:y0 + side, x0:x0 + side] = tag[:, :, None]
        images.append(cv2.GaussianBlur(img, (3, 3), 0.8))
    return images


def warm_up_detector(rig: Rig, key: str, others: list[str], fps: float) -> None:
    """Run a throwaway detector of camera ``key`` (looking for ``others``'
    markers) on a blank and a noise image, then on drawn images of the
    markers (:func:`warm_up_images`): every kernel it uses is compiled (on a
    cold cache) or loaded.  What is detected is thrown away."""
    w, h = rig.mount(key).camera.size or (640, 480)
    spare = ObserverDetector(rig, key, others, fps)
    # faint noise: full-range noise is a blob on every pixel, and the blinking lights' tracker
    # would spend minutes giving each a track
    noise = np.random.default_rng(0).integers(0, 8, (h, w, 3), dtype=np.uint8)
    images = [np.zeros((h, w, 3), np.uint8), noise, *warm_up_images(rig, others, (w, h), fps)]
    for k, image in enumerate(images):
        frame = Frame(k, k / fps, image)
        spare.feed(frame)
        spare.detect(frame)


class Node:
    """Robot ``robot``'s node: detections of ``source``'s frames published on ``bus``.

    ``rig``: the rig file (or a Rig, then ``rig_id`` must be given: the
    SPEC's id of the rig file the localizer loads); ``fps``: the rate the
    blinking-light trackers assume (default the source's, else 30);
    ``diagnostics``: also publish the node's own ``/diagnostics`` status once
    a second; ``report(line)``: where status lines and notes go; ``camera``:
    the camera of a robot with several cameras (its name in the rig; None
    for a robot with one camera), see :func:`camera_key`.

    A source that announces its own camera model and asks for it to be used
    (a ROS topic with ``--camera-info use``: ``source.use_info``) has the
    detectors work in that camera (its intrinsics, distortion and image
    size), and each published pixel re-expressed in the rig's camera of this
    robot -- the pixel the rig's camera would see along the same ray -- so
    the message keeps its documented meaning (rig pixels) and a localizer that
    knows only the rig file gets the right bearings.  A detection whose ray
    the rig's camera cannot express (behind it, beyond half an image outside
    it, or where its distortion does not invert) is left out and counted
    (:attr:`NodeStats.unexpressed`)."""

    def __init__(self, rig: Any, robot: str, source: CameraSource, bus: Any, *, rig_id: str | None = None,
                 fps: float | None = None, diagnostics: bool = False,
                 report: Callable[[str], None] | None = None, camera: str | None = None) -> None:
        if rig_id is None:
            if not isinstance(rig, (str, Path)):
                raise InputError("a node given a loaded rig needs its rig_id (of the rig file the localizer reads)")
            rig_id = rig_file_id(rig)
        self.rig: Rig = expanded_rig(load_rig(rig))
        #: The camera's observation key: ``ROBOT``, or ``ROBOT/CAMERA`` on a robot with several cameras.
        self.key = camera_key(self.rig, robot, camera)
        self.others = [r for r in self.rig.robots if r != robot]
        if not self.others:
            raise InputError(f"robot {robot!r} is alone in the rig: no other robot's markers to look for")
        self.robot, self.rig_id, self.source, self.bus = robot, rig_id, source, bus
        self.detector_fps = float(fps or source.fps or DEFAULT_FPS)
        self.detector = ObserverDetector(self.rig, self.key, self.others, self.detector_fps)
        self.topic = observations_topic(robot)
        T = ros_types()
        self.writer = bus.writer(self.topic, T.Observations)
        self.diagnostics = bus.writer(DIAGNOSTICS_TOPIC, T.DiagnosticArray) if diagnostics else None
        self.report = report or (lambda line: None)
        self.stats = NodeStats(self.key, source.name, self.topic)
        self._last_t = -np.inf
        self._warm = False
        self._said: set[str] = set()
        self.use_info = bool(getattr(source, "use_info", False))
        #: The camera the detectors work in when it is not the rig's (``use_info``: the camera_info's).
        self.camera: Camera | None = None
        # The localizer's poses, to look for missed tags where they put them: only with oriented tags to find.
        tags = any(m.tag is not None and tag_corner_points(m) is not None
                   for o in self.others for m in self.rig.robot(o).markers.values())
        self.tf = bus.reader(TF_TOPIC, T.TFMessage) if tags else None
        #: child robot -> (parent robot, stamp, T_parent_child), the newest of each.
        self._tf: dict[str, tuple[str, float, Pose]] = {}

    def warm_up(self) -> None:
        """Load every compiled kernel the detectors use before the first frame
        (:func:`warm_up_detector`).  A kernel first needed when a marker is
        first seen costs up to half a second (Numba loading it and its
        registries): the frame, and those behind it, would be that late, and
        a blinking light's tracker would miss frames."""
        self._warm = True
        with exit_on_stop(f"interrupted while loading the detectors: node {self.key}: 0 frames captured"):
            warm_up_detector(self.rig, self.key, self.others, self.detector_fps)

    def subscribers(self) -> int:
        """How many readers the observations topic has now."""
        return int(self.writer.get_publication_matched_status().current_count)

    def wait_for_subscriber(self, timeout: float) -> bool:
        """Wait up to ``timeout`` seconds for a reader of the observations topic."""
        deadline = time.monotonic() + timeout
        while self.subscribers() == 0:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.02)
        return True

    def process(self, frame: LiveFrame, taken: float | None = None) -> Any:
        """Detect, publish and return the ``Observations`` message of ``frame``
        (None for a frame that is not published: corrupt, or out of order);
        ``taken``: the wall-clock time the node took it from the camera (default now)."""
        s = self.stats
        taken = time.time() if taken is None else taken
        if frame.image is None:
            s.corrupt += 1
            return None
        if not frame.t > self._last_t:
            s.out_of_order += 1
            return None
        self._last_t = frame.t
        if self.use_info:
            self._check_camera(frame)
        # A replayed frame's detectors run on the recording's own clock (the blink trackers' timing).
        seen = Frame(frame.index, frame.source_time if isinstance(self.source, ReplaySource) else frame.t,
                     frame.image)
        t0, c0 = time.time(), time.thread_time()
        self.detector.feed(seen)
        found = self.detector.detect(seen)
        if self.tf is not None:
            found = self._look_where_tracked(frame, found)
        t1, c1 = time.time(), time.thread_time()
        obs = found.observations(self.key, frame.t)
        if self.camera is not None:
            obs = self._in_rig_pixels(obs)
        msg = observations_message(self.robot, self.rig_id, frame.index, frame.t, obs, frame.source_time,
                                   frame_id=self.key)
        self.writer.write(msg)
        done = time.time()
        s.latencies.append(done - frame.t)
        s.stages.append((taken - frame.t, t1 - t0, c1 - c0, done - t1))
        s.cpu_now = time.process_time()
        s.processed += 1
        s.markers_seen = len(msg.observations)
        return msg

    def _read_tf(self) -> None:
        """Keep the newest pose of each robot of the rig from ``/tf``; count the rest."""
        robots = self.rig.robots
        for msg in self.tf.take():
            for tr in msg.transforms:
                parent, child = tr.header.frame_id, tr.child_frame_id
                if parent not in robots or child not in robots or parent == child:
                    self.stats.tf_foreign += 1
                    continue
                t = stamp_of(tr.header)
                r, x = tr.transform.rotation, tr.transform.translation
                quat, trans = np.array([r.x, r.y, r.z, r.w], float), np.array([x.x, x.y, x.z], float)
                if not (np.all(np.isfinite(quat)) and np.all(np.isfinite(trans)) and math.isfinite(t)
                        and abs(float(np.linalg.norm(quat)) - 1.0) < 1e-3):
                    self.stats.tf_foreign += 1  # not a pose: a non-unit or non-finite quaternion, a bad stamp
                    continue
                if child in self._tf and self._tf[child][1] > t:
                    continue
                pose = Pose.from_quaternion_xyzw(quat, trans)
                self._tf[child] = (parent, t, pose)
        self.stats.tf_malformed = self.tf.malformed

    def _look_where_tracked(self, frame: LiveFrame, found: Any) -> Any:
        """``found`` with the missed tags found where the localizer's poses put them."""
        self._read_tf()
        recent = {c: (p, T) for c, (p, t, T) in self._tf.items() if abs(frame.t - t) <= TF_MAX_AGE}
        refs = {p for p, _ in recent.values()}
        if len(refs) != 1:
            return found  # none yet, or poses of two localizers with different references: no common frame
        (ref,) = refs
        predicted = {ref: Pose.identity(), **{c: T for c, (_, T) in recent.items()}}
        if self.robot not in predicted:
            return found
        out, notes = look_where_tracked(self.detector.rig, {self.key: frame.image}, {self.key: found}, predicted)
        self.stats.looked_again += len(notes)
        return out[self.key]

    def _check_camera(self, frame: LiveFrame) -> None:
        """Detect in the camera the source announced (the first frame: the
        detectors set up for it); InputError when the image is not its size."""
        camera = self.source.camera
        if camera is None:
            raise InputError(f"camera {self.source.name}: a frame came before its camera model")
        if self.camera is None:
            rig_camera = self.rig.mount(self.key).camera
            self.camera = camera
            self.detector = ObserverDetector(with_camera(self.rig, self.key, camera), self.key, self.others,
                                             self.detector_fps)
            self.report(f"camera model from {getattr(self.source, 'info_topic', self.source.name)}: {camera!r}; "
                        f"pixels published in the rig's camera {rig_camera!r}")
        h, w = frame.image.shape[:2]
        if (w, h) != tuple(camera.size):
            raise InputError(f"camera {self.source.name}: image is {w}x{h} but its camera_info says "
                             f"{camera.size[0]}x{camera.size[1]}")

    def _in_rig_pixels(self, obs: ObservationSet) -> ObservationSet:
        """``obs`` (pixels of :attr:`camera`) as pixels of the rig's camera
        along the same rays; detections it cannot express are left out (counted)."""
        if not len(obs):
            return obs
        rig_camera = self.rig.mount(self.key).camera
        keep, uv = [], []
        for i, pix in enumerate(obs.uv):
            try:
                ray = self.camera.pixels_to_bearings(pix)
                out = rig_camera.project(ray)
                back = rig_camera.pixels_to_bearings(out)
            except MutlocError:
                continue
            if rig_camera.size is not None:
                w, h = rig_camera.size
                if not (-0.5 * w <= out[0] <= 1.5 * w and -0.5 * h <= out[1] <= 1.5 * h):
                    continue
            if np.all(np.isfinite(out)) and float(ray @ back) > 1.0 - 1e-9:  # the ray comes back: invertible there
                keep.append(i)
                uv.append(out)
        self.stats.unexpressed += len(obs) - len(keep)
        return ObservationSet([obs.observer[i] for i in keep], [obs.marker[i] for i in keep],
                              np.asarray(uv, float).reshape(-1, 2), obs.time[keep] if len(keep) else None,
                              obs.score[keep])

    def _publish_diagnostics(self) -> None:
        s = self.stats
        notes = list(self.source.notes)
        behind = s.behind()
        level = WARN if notes or behind or (s.captured > 10 and s.dropped > s.captured / 2) else OK
        message = "; ".join([*([behind] if behind else []), *notes]) or ("running" if s.processed else
                                                                         "waiting for frames")
        values = {"captured": s.captured, "processed": s.processed, "dropped": s.dropped, "corrupt": s.corrupt,
                  "fps": f"{s.fps:.2f}", "source": s.source, "topic": s.topic}
        if self.tf is not None:
            values.update(tags_found_again=s.looked_again, tf_ignored=s.tf_foreign, tf_malformed=s.tf_malformed)
        if s.latencies:
            values["latency_p50_ms"] = f"{percentile_ms(list(s.latencies)[-300:], 50):.1f}"
        if self.key != self.robot:
            values["camera"] = self.key
        self.diagnostics.write(diagnostics_message(time.time(), [RobotStatus(self.robot, level, message, values)],
                                                   name="mutloc node" if self.key == self.robot
                                                   else f"mutloc node {self.key}"))

    def run(self, *, stop: threading.Event | None = None, duration: float | None = None,
            status_every: float | None = 5.0, first_frame_timeout: float = 5.0,
            subscriber_timeout: float = 3.0) -> NodeStats:
        """Process frames until the source ends (a replay), ``stop`` is set,
        ``duration`` seconds passed, or Ctrl-C (``KeyboardInterrupt`` goes on,
        :attr:`stats` holds what was done).  A replay starts once the
        observations topic has a reader (or after ``subscriber_timeout`` s),
        so a recording is not half played to nobody.  InputError (one line)
        when the camera delivers no frame within ``first_frame_timeout``
        seconds (a ROS topic waits), fails, or gives images of another size
        than the rig's calibration."""
        s = self.stats
        if not self._warm:
            self.warm_up()
        if isinstance(self.source, ReplaySource):
            self.wait_for_subscriber(subscriber_timeout)
        self.source.start()
        s.started = begin = time.monotonic()
        s.cpu_started = time.process_time()
        next_status = begin + status_every if status_every else float("inf")
        next_diag = begin
        next_behind = begin  # (a falling-behind line at most every BEHIND_WINDOW s)
        s.window.clear()
        s.note_counts(begin)
        try:
            while not (stop is not None and stop.is_set()):
                now = time.monotonic()
                if duration is not None and now - begin >= duration:
                    break
                frame = self.source.take(timeout=0.1)
                s.captured, s.dropped = self.source.captured, self.source.dropped
                if frame is not None:
                    self.process(frame, time.time())
                    self.source.handled(frame)
                elif self.source.finished:
                    if self.source.error:
                        raise InputError(self.source.error)
                    break
                elif s.captured == 0 and not self.source.patient and now - begin > first_frame_timeout:
                    raise InputError(f"camera {self.source.name}: no frame in {first_frame_timeout:g} s")
                for note in self.source.notes:
                    if note not in self._said:
                        self._said.add(note)
                        self.report(f"warning: {note}")
                now = time.monotonic()
                s.note_counts(now)
                behind = s.behind()
                if behind and now >= next_behind:
                    self.report(f"warning: node {self.key}: {behind}")
                    next_behind = now + BEHIND_WINDOW
                if self.diagnostics is not None and now >= next_diag:
                    self._publish_diagnostics()
                    next_diag = now + 1.0
                if now >= next_status:
                    self.report(s.status_line())
                    next_status = now + status_every
        finally:
            self.source.close()
            s.captured, s.dropped = self.source.captured, self.source.dropped
        return s
