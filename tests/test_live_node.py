"""``mutloc node`` (SPEC "Live operation"): a simulated camera replayed in
real time, or images on a ROS 2 topic, give one Observations message per
processed frame, and each message holds what offline detection finds in the
same frame (the independent check: the log ``track --observations-out``
writes for the same images).  The nodes run as robot q: in this scene p's
camera sees one of q's balls partly hidden, which a pair track measures a
second time where the pose from both images puts it (its log holds that);
a node has one image only and sends what its detector found.  A detector slower than the camera drops frames
(counted), never queues them.  Bad cameras and robots: one line, non-zero.

DDS stays on the loopback interface, in a domain id no other running process holds (the ``dds_domain``
fixture, tests/dds_domains.py); every
child runs in its own process group, killed in a ``finally``.
"""

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="the live extra (cyclonedds) is part of make test's install")

from mutloc.api import load_rig, localize  # noqa: E402
from mutloc.cli.main import main  # noqa: E402
from mutloc.errors import InputError, MutlocError  # noqa: E402
from mutloc.live.cameras import (CaptureSource, LatestFrame, LiveFrame, ReplaySource, RosImageSource,  # noqa: E402
                                 camera_from_camera_info)
from mutloc.live.dds import Bus  # noqa: E402
from mutloc.live.messages import DIAGNOSTICS_TOPIC, observations_topic, rig_id, ros_types, stamp, stamp_of  # noqa: E402
from mutloc.live.node import Node  # noqa: E402
from mutloc.sim.scenario import write_simulation  # noqa: E402
from mutloc.track.sources import open_streams  # noqa: E402
from mutloc.track.tracker import track  # noqa: E402

N_FRAMES = 10


@pytest.fixture(scope="module")
def sim(tmp_path_factory):
    """A small simulated sequence and the offline detections of its frames
    (``track --observations-out``'s log): ``{frame: {marker: (u, v)}}`` per robot."""
    out = tmp_path_factory.mktemp("sim")
    write_simulation(out, frames=N_FRAMES, size=(480, 270), focal=400.0)
    log = out / "offline.jsonl"
    track(out / "rig.yaml", open_streams({"p": out / "p", "q": out / "q"}), observations_out=log, progress=False)
    offline = {"p": {}, "q": {}}
    for k, line in enumerate(log.read_text().splitlines()):
        entry = json.loads(line)
        for robot in offline:
            offline[robot][k] = {m: tuple(uv) for m, uv in entry["observations"].get(robot, {}).items()}
    assert all(len(offline["q"][k]) >= 2 for k in range(N_FRAMES)), "the offline detections must not be trivial"
    times = [float(line.split(",")[1]) for line in (out / "frames.csv").read_text().splitlines()[1:]]
    return out, offline, times


def _ours(messages, out):
    """The messages of this test's rig (another test run could share a domain id, never the rig)."""
    rid = rig_id(out / "rig.yaml")
    return [m for m in messages if m.rig_id == rid]


def _seen(msg):
    return {o.marker: (o.u, o.v) for o in msg.observations}


def _child(args):
    cmd = [sys.executable, "-m", "mutloc", "node", *args]
    # SIGINT (Ctrl-C) reaches the child also when this test runs as a background job (which ignores SIGINT)
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _kill(child):
    if child.poll() is None:
        try:
            os.killpg(child.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        child.wait(timeout=10)


def _summary_counts(text):
    m = re.search(r"(\d+) frames captured .*?, (\d+) processed .*?, (\d+) dropped", text)
    assert m, text
    return tuple(int(x) for x in m.groups())


def test_replayed_folder_publishes_what_offline_detection_finds(sim, dds_domain):
    out, offline, times = sim
    domain = dds_domain
    T = ros_types()
    bus = Bus(domain, loopback=True)
    reader = bus.reader(observations_topic("q"), T.Observations)
    start = time.time()
    child = _child(["--rig", str(out / "rig.yaml"), "--robot", "q", "--camera", str(out / "q"), "--realtime",
                    "--loopback", "--domain", str(domain), "--no-progress"])
    got = []
    try:
        deadline = time.monotonic() + 120
        while child.poll() is None:
            assert time.monotonic() < deadline, "the node did not end with its recording"
            got += reader.take()
            time.sleep(0.01)
        stdout, stderr = child.communicate(timeout=10)
        end = time.time()
        for _ in range(20):
            got += reader.take()
            time.sleep(0.01)
    finally:
        _kill(child)
        bus.close()
    assert child.returncode == 0, stderr
    got = _ours(got, out)
    captured, processed, dropped = _summary_counts(stdout)
    assert captured == N_FRAMES and processed + dropped == N_FRAMES
    assert processed >= N_FRAMES // 2, stdout  # a 480x270 frame takes a few ms of a 33 ms period
    assert len(got) == processed, "every processed frame is published, reliably, on loopback"
    frames = [m.frame for m in got]
    assert frames == sorted(set(frames))
    rid = rig_id(out / "rig.yaml")
    for m in got:
        assert (m.robot, m.header.frame_id, m.rig_id) == ("q", "q", rid)
        assert m.source_time == pytest.approx(times[m.frame], abs=1e-9)
        assert start <= stamp_of(m.header) <= end  # stamped with the wall clock at release
        assert _seen(m) == offline["q"][m.frame], f"frame {m.frame}"
    stamps = np.array([stamp_of(m.header) for m in got])
    source = np.array([m.source_time for m in got])
    # released at the recording's own rate: the stamps keep its spacing (to scheduling jitter)
    assert np.all(np.diff(stamps) > 0)
    assert np.max(np.abs((stamps - stamps[0]) - (source - source[0]))) < 0.15  # 0.3 s if released at once


class _SlowDetector:
    """The node's detector taking ``delay`` seconds longer per frame."""

    def __init__(self, detector, delay):
        self.detector, self.delay = detector, delay

    def feed(self, frame):
        self.detector.feed(frame)

    def detect(self, frame):
        time.sleep(self.delay)
        return self.detector.detect(frame)


def test_a_detector_slower_than_the_camera_drops_frames_and_takes_the_newest(sim, dds_domain):
    out, offline, _ = sim
    T = ros_types()
    bus = Bus(dds_domain, loopback=True)
    try:
        reader = bus.reader(observations_topic("q"), T.Observations)
        node = Node(out / "rig.yaml", "q", ReplaySource(out / "q", speed=1.0), bus)
        node.detector = _SlowDetector(node.detector, 0.1)  # three camera periods per frame
        stats = node.run(status_every=None, subscriber_timeout=5.0)
        time.sleep(0.2)
        got = _ours(reader.take(), out)
    finally:
        bus.close()
    assert stats.captured == N_FRAMES
    assert stats.dropped > 0 and stats.processed + stats.dropped == N_FRAMES
    assert len(got) == stats.processed == len(stats.latencies)
    frames = [m.frame for m in got]
    assert frames[0] == 0
    # Never queued: after each slow frame the node takes the newest, about three frames on.
    assert np.mean(np.diff(frames)) >= 2.0, frames
    for m in got:
        assert _seen(m) == offline["q"][m.frame]


def test_a_node_falling_behind_says_so_in_a_line_and_its_diagnostics(sim, dds_domain):
    """A detector slower than the camera: the node says "falling behind:
    dropped N of the last M frames" (a warning line, counting the frames it
    dropped) and its diagnostics are WARN with the same words."""
    out, _, _ = sim
    bus = Bus(dds_domain, loopback=True)
    lines, sent = [], []
    try:
        node = Node(out / "rig.yaml", "q", ReplaySource(out / "q", speed=1.0), bus, diagnostics=True,
                    report=lines.append)
        node.diagnostics = SimpleNamespace(write=sent.append)  # (its messages, as DDS would take them)
        node.detector = _SlowDetector(node.detector, 0.1)  # three camera periods per frame
        stats = node.run(status_every=None, subscriber_timeout=0.5)
        node._publish_diagnostics()
    finally:
        bus.close()
    assert stats.dropped > 0
    said = [re.search(r"falling behind: dropped (\d+) of the last (\d+) frames", ln) for ln in lines]
    said = [m for m in said if m]
    assert said, lines
    n, m = (int(x) for x in said[0].groups())
    assert 0 < n <= stats.dropped and n < m <= stats.captured
    status = sent[-1].status[0]
    assert status.level == 1 and f"falling behind: dropped {stats.dropped} of the last {stats.captured} frames" \
        in status.message, status  # (WARN; the whole run is within the 5 s window)


def test_a_starved_replay_drops_frames_instead_of_releasing_them_late(sim, monkeypatch):
    """A replay whose readout is slower than its frame rate (every image
    ready 2.5 periods after the last: the machine too busy) is a starved
    camera: a frame ready after the next one was due is dropped and counted,
    never handed on late with a stale stamp -- but never more than
    ``MAX_DROPPED_RUN`` s of frames in a row (here 0.25 s)."""
    import mutloc.live.cameras as cameras

    out, _, times = sim
    period = times[1] - times[0]
    monkeypatch.setattr(cameras, "MAX_DROPPED_RUN", 0.25)
    source = ReplaySource(out / "q", speed=1.0)

    def slow(frames):
        for f in frames:
            time.sleep(2.5 * period)
            yield f

    source.stream = slow(list(source.stream))
    source.start()
    taken = []
    try:
        while not source.finished:
            frame = source.take(3.0)
            if frame is not None:
                taken.append(frame.index)
    finally:
        source.close()
    assert taken[0] == 0 and len(taken) >= 2, taken  # released again once 0.25 s of frames were dropped
    run = int(np.ceil(0.25 / period))
    assert all(1 < b - a <= run + 1 for a, b in zip(taken, taken[1:])), taken  # dropped, at most 0.25 s in a row
    assert source.captured == N_FRAMES and source.dropped == N_FRAMES - len(taken)


def test_a_looped_replay_goes_on_in_frame_numbers_and_time(sim):
    out, _, times = sim
    source = ReplaySource(out / "q", speed=10.0, loop=True).start()
    taken = []
    try:
        while len(taken) < 3 * N_FRAMES // 2:
            frame = source.take(5.0)
            assert frame is not None
            taken.append(frame)
            time.sleep(0.001)
    finally:
        source.close()
    # each pass goes on one frame (1 / the stream's rate) after the last one's time; a loaded machine can make
    # the replay drop hundreds of passes, so the rule is applied exactly rather than with the frames.csv spacing
    lap = times[-1] - times[0] + 1.0 / source.fps
    for f in taken:
        k, rounds = f.index % N_FRAMES, f.index // N_FRAMES
        assert f.source_time == pytest.approx(times[k] + rounds * lap, abs=1e-9)
        assert np.array_equal(f.image, cv2.imread(str(out / "q" / f"{k:06d}.png")))
    assert any(f.index >= N_FRAMES for f in taken)


def test_replays_started_at_one_time_run_in_step(sim):
    """Two replays given one --start-at release their frame k at
    start + (t_k - t_0) on the wall clock (a few ms of scheduling apart),
    not when each was started."""
    out, _, times = sim
    start_at = time.time() + 0.4
    sources = [ReplaySource(out / r, speed=2.0, start_at=start_at) for r in ("p", "q")]
    sources[0].start()
    time.sleep(0.15)  # the second one starts later
    sources[1].start()
    try:
        for src in sources:
            f = src.take(5.0)
            assert f is not None
            due = start_at + (times[f.index] - times[0]) / 2.0
            assert abs(f.t - due) < 0.03, (f.index, f.t - due)
    finally:
        for src in sources:
            src.close()


def test_latest_frame_keeps_only_the_newest():
    slot = LatestFrame()
    for k in range(5):
        slot.put(LiveFrame(k, float(k), None))
    assert slot.take(0).index == 4
    assert (slot.captured, slot.dropped) == (5, 4)
    assert slot.take(0.01) is None and not slot.finished
    slot.put(LiveFrame(5, 5.0, None), skipped=2)  # a ROS batch: two older messages skipped for it
    slot.end()
    assert slot.take(0).index == 5 and slot.finished
    assert (slot.captured, slot.dropped) == (8, 6)


@pytest.mark.parametrize("camera, says", [
    ("/dev/video97", "no such device"),
    ("97", "cannot be opened"),
    ("rtsp://127.0.0.1:9/none", "cannot be opened"),
    ("videotestsrc ! videoconvert ! appsink", "GStreamer"),
    ("/no/such/recording", "no such device, stream, ROS topic"),
    ("FOLDER", "--realtime"),
    ("ros:/", "give the image topic"),
])
def test_a_camera_that_cannot_be_opened_is_one_line_and_non_zero(sim, capsys, camera, says, dds_domain):
    out, _, _ = sim
    camera = str(out / "q") if camera == "FOLDER" else camera
    status = main(["node", "--rig", str(out / "rig.yaml"), "--robot", "q", "--camera", camera, "--loopback",
                   "--domain", str(dds_domain)])
    err = capsys.readouterr().err.strip()
    assert status == 2
    assert len(err.splitlines()) == 1 and err.startswith("mutloc: error:") and says in err, err


def test_an_unknown_robot_is_one_line_and_non_zero(sim):
    out, _, _ = sim
    child = _child(["--rig", str(out / "rig.yaml"), "--robot", "zz", "--camera", "0", "--loopback"])
    try:
        _, err = child.communicate(timeout=60)
    finally:
        _kill(child)
    assert child.returncode == 2
    assert err.strip().splitlines() == [err.strip()] and "unknown robot 'zz'" in err, err


def _image_message(T, image, t, encoding):
    h, w = image.shape[:2]
    data = {"rgb8": image[:, :, ::-1], "bgr8": image, "mono8": cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)}[encoding]
    return T.Image(header=T.Header(stamp=stamp(t), frame_id="q_camera"), height=h, width=w, encoding=encoding,
                   step=data.strides[0], data=np.ascontiguousarray(data).tobytes())


def _wait_matched(writer, timeout=30.0):
    deadline = time.monotonic() + timeout
    while writer.get_publication_matched_status().current_count == 0:
        assert time.monotonic() < deadline, "the node never subscribed"
        time.sleep(0.02)


def test_a_ros_image_topic_is_a_camera_and_ctrl_c_ends_the_node_cleanly(sim, dds_domain):
    out, offline, _ = sim
    T = ros_types()
    domain = dds_domain
    bus = Bus(domain, loopback=True)
    reader = bus.reader(observations_topic("q"), T.Observations)
    images = bus.writer("/q/image_raw", T.Image)
    info = bus.writer("/q/camera_info", T.CameraInfo)
    child = _child(["--rig", str(out / "rig.yaml"), "--robot", "q", "--camera", "ros:/q/image_raw", "--loopback",
                    "--domain", str(domain), "--status-every", "0.2"])
    sent, got = {}, []
    try:
        _wait_matched(images)
        _wait_matched(info)
        # A camera_info whose focal length is not the rig's: the node says so (once).
        info.write(T.CameraInfo(header=T.Header(stamp=stamp(time.time()), frame_id="q_camera"), height=270,
                                width=480, distortion_model="plumb_bob", d=[0.0] * 5,
                                k=[410.0, 0, 239.5, 0, 410.0, 134.5, 0, 0, 1]))
        deadline = time.monotonic() + 60
        while not reader.take() and time.monotonic() < deadline:  # warm-up done when a first frame comes back
            images.write(_image_message(T, cv2.imread(str(out / "q" / "000000.png")), time.time(), "bgr8"))
            time.sleep(0.2)
        for k, encoding in zip(range(1, N_FRAMES), ["rgb8", "bgr8"] * N_FRAMES):
            t = time.time()
            sent[round(t, 6)] = k
            images.write(_image_message(T, cv2.imread(str(out / "q" / f"{k:06d}.png")), t, encoding))
            time.sleep(0.1)
            got += reader.take()
        time.sleep(0.3)
        got += reader.take()
        os.killpg(child.pid, signal.SIGINT)
        _, stderr = child.communicate(timeout=30)
    finally:
        _kill(child)
        bus.close()
    mine = [m for m in _ours(got, out) if round(stamp_of(m.header), 6) in sent]
    assert len(mine) >= (N_FRAMES - 1) // 2, (len(mine), stderr)
    for m in mine:
        assert _seen(m) == offline["q"][sent[round(stamp_of(m.header), 6)]]  # stamped with the header's stamp
    assert child.returncode == 130, stderr
    lines = stderr.strip().splitlines()
    assert lines[-1].startswith("interrupted: node q:") and "Traceback" not in stderr, stderr
    warned = [ln for ln in lines if "camera_info on /q/camera_info differs" in ln]
    assert len(warned) == 1 and "fx=410" in warned[0] and "fx=400" in warned[0], stderr
    assert any(re.search(r"node q: \d+ captured, \d+ processed", ln) for ln in lines), stderr  # the status line


def test_compressed_images_on_a_ros_topic(sim, dds_domain):
    """CompressedImage (png: lossless, so the detections are offline's)
    through the library, in this process; an undecodable one is a corrupt
    frame, counted, not published, and the node goes on."""
    out, offline, _ = sim
    T = ros_types()
    bus = Bus(dds_domain, loopback=True)
    stop = threading.Event()
    try:
        reader = bus.reader(observations_topic("q"), T.Observations)
        diagnostics = bus.reader(DIAGNOSTICS_TOPIC, T.DiagnosticArray)
        packed = bus.writer("/q/image_raw/compressed", T.CompressedImage)
        source = RosImageSource(bus, "/q/image_raw/compressed")
        node = Node(out / "rig.yaml", "q", source, bus, diagnostics=True)
        runner = threading.Thread(target=node.run, kwargs=dict(stop=stop, status_every=None))
        runner.start()
        _wait_matched(packed)
        sent = {}
        for k in range(3):
            t = time.time()
            ok, png = cv2.imencode(".png", cv2.imread(str(out / "q" / f"{k:06d}.png")))
            sent[round(t, 6)] = k
            packed.write(T.CompressedImage(header=T.Header(stamp=stamp(t), frame_id="q"), format="png",
                                           data=png.tobytes()))
            time.sleep(0.3)
        packed.write(T.CompressedImage(header=T.Header(stamp=stamp(time.time()), frame_id="q"), format="jpeg",
                                       data=b"not an image"))
        time.sleep(1.1)
        got = _ours(reader.take(), out)
        status = [s for d in diagnostics.take() for s in d.status if s.name == "mutloc node: q"]
    finally:
        stop.set()
        runner.join(timeout=10)
        bus.close()
    assert [sent[round(stamp_of(m.header), 6)] for m in got] == [0, 1, 2]
    for m in got:
        assert _seen(m) == offline["q"][sent[round(stamp_of(m.header), 6)]]
    assert node.stats.corrupt == 1 and node.stats.processed == 3
    # the node's own /diagnostics, once a second: its counts as key-values
    last = {kv.key: kv.value for kv in status[-1].values}
    assert status[-1].hardware_id == "q" and last["processed"] == "3" and last["corrupt"] == "1"


def test_an_opencv_capture_is_read_in_the_background_keeping_the_newest_frame(sim, tmp_path):
    """A capture OpenCV opens (here a video file, as a stream would be) is read
    as fast as it delivers; a slow consumer gets the newest frame, the others
    are counted as dropped; a capture that stops delivering is an error."""
    out, _, _ = sim
    video = tmp_path / "camera.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (480, 270))
    for k in range(30):
        writer.write(cv2.imread(str(out / "q" / f"{k % N_FRAMES:06d}.png")))
    writer.release()
    source = CaptureSource(str(video)).start()
    taken = []
    try:
        deadline = time.monotonic() + 30
        while not source.finished and time.monotonic() < deadline:
            frame = source.take(0.5)
            if frame is not None:
                taken.append(frame)
                time.sleep(0.05)  # a detector slower than the capture
    finally:
        source.close()
    assert source.error is not None and "stopped delivering frames" in source.error
    assert source.captured == 30 and len(taken) < 30 and source.dropped == 30 - len(taken)
    assert [f.index for f in taken] == sorted({f.index for f in taken})
    assert all(f.image.shape == (270, 480, 3) for f in taken)
    assert np.all(np.diff([f.t for f in taken]) > 0) and abs(taken[0].t - time.time()) < 60


def test_a_node_for_blinking_lights_starts_and_publishes(tmp_path, dds_domain):
    """A lights rig: the node's warm-up (its detectors on blank images) must
    not stall the blinking lights' tracker (a full-range noise image once
    gave it a blob on every pixel to track: the node never got to its first
    frame).  Replayed, every frame is captured and most are published."""
    write_simulation(tmp_path, markers="lights", frames=12, size=(480, 270), focal=400.0)
    child = _child(["--rig", str(tmp_path / "rig.yaml"), "--robot", "q", "--camera", str(tmp_path / "q"),
                    "--realtime", "--domain", str(dds_domain), "--loopback", "--duration", "4", "--no-progress"])
    try:
        out, err = child.communicate(timeout=90)
    finally:
        _kill(child)
    assert child.returncode == 0, err
    captured, processed, dropped = _summary_counts(out)
    assert captured == 12 and processed >= 6 and processed + dropped == captured


# -- a ROS camera_info that is not the rig's camera (--camera-info) ------------------------------------------------


def _camera_info(T, camera, t=0.0, model=None):
    """The CameraInfo of ``camera`` (plumb_bob, 5 coefficients, unless ``model``)."""
    w, h = camera.size
    return T.CameraInfo(header=T.Header(stamp=stamp(t), frame_id="q_camera"), width=w, height=h,
                        distortion_model=model or "plumb_bob", d=[float(x) for x in camera.dist[:5]],
                        k=[float(x) for x in camera.K.ravel()])


def _run_ros_node(domain, rig, images, info, use_info, frames=None):
    """A node for q (``rig``) in this process on a ROS topic (``--camera-info use`` when
    ``use_info``); ``info`` (a CameraInfo) is published beside each image of ``images``.
    Returns (node, {stamp: frame k} of the images sent, messages received, the node's error)."""
    T = ros_types()
    bus = Bus(domain, loopback=True)
    stop = threading.Event()
    failed = []
    try:
        reader = bus.reader(observations_topic("q"), T.Observations)
        raw = bus.writer("/q/image_raw", T.Image)
        info_writer = bus.writer("/q/camera_info", T.CameraInfo)
        source = RosImageSource(bus, "/q/image_raw", rig_camera=load_rig(rig).robot("q").camera, use_info=use_info)
        node = Node(rig, "q", source, bus)

        def run():
            try:
                node.run(stop=stop, status_every=None)
            except InputError as exc:
                failed.append(exc)

        runner = threading.Thread(target=run)
        runner.start()
        _wait_matched(raw)
        _wait_matched(info_writer)
        sent, got = {}, []
        for k in frames if frames is not None else range(len(images)):
            t = time.time()
            sent[round(t, 6)] = k
            info_writer.write(info)
            raw.write(_image_message(T, cv2.imread(str(images[k])), t, "bgr8"))
            # the next frame only once this one's message is in (or the node stopped): a loaded
            # machine slows the node down, it must not make it drop the frames this test counts
            waiting = time.monotonic() + 60.0
            while not failed and time.monotonic() < waiting:
                got += reader.take()
                if any(round(stamp_of(m.header), 6) == round(t, 6) for m in got):
                    break
                time.sleep(0.02)
            if failed:
                break
        got += reader.take()
    finally:
        stop.set()
        runner.join(timeout=10)
        bus.close()
    return node, sent, [m for m in got if round(stamp_of(m.header), 6) in sent], (failed or [None])[0]


@pytest.fixture(scope="module")
def other_camera(sim, tmp_path_factory):
    """The sim's scene rendered by another camera in q (and p): focal 450 instead
    of 400, barrel distortion k1 = -0.15, 512x288 instead of 480x270."""
    out = tmp_path_factory.mktemp("other_camera")
    write_simulation(out, frames=3, size=(512, 288), focal=450.0, k1=-0.15)
    return out


def _pose_error(rig, sim_truth, k, q_pixels):
    """Translation (m) and rotation (deg) error of the pose localized from p's true
    pixels and ``q_pixels`` (rig pixels) against frame ``k``'s truth."""
    frame = sim_truth[k]
    est = localize(rig, {"p": frame["observations"]["p"], "q": q_pixels})
    true_R = np.asarray(frame["T_qp"]["R"])
    dR = est.pose.R @ true_R.T
    angle = np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(est.pose.t - np.asarray(frame["T_qp"]["t"]))), float(angle)


def test_camera_info_use_detects_in_the_announced_camera_and_publishes_rig_pixels(sim, other_camera, dds_domain):
    """q's images come from a camera whose camera_info differs from the rig's
    (focal, distortion, size).  With --camera-info use the node detects in
    that camera and publishes the pixels the rig's camera would have seen:
    they match the rendered truth of the rig's camera, and the pose from them
    matches the true pose.  Checked only (the default), the node warns, naming
    the differences, and its pixels are the other camera's (the pose is off)."""
    out, _, _ = sim
    truth = json.loads((out / "truth.json").read_text())["frames"]
    assert np.allclose(json.loads((other_camera / "truth.json").read_text())["frames"][1]["T_qp"]["t"],
                       truth[1]["T_qp"]["t"]), "the same scene"
    other = load_rig(other_camera / "rig.yaml").robot("q").camera
    T = ros_types()
    images = [other_camera / "q" / f"{k:06d}.png" for k in range(3)]
    node, sent, got, error = _run_ros_node(dds_domain, out / "rig.yaml", images, _camera_info(T, other), True)
    assert error is None, error
    assert node.camera is not None and node.camera.size == (512, 288)
    assert len(got) >= 2
    for m in got:
        k = sent[round(stamp_of(m.header), 6)]
        seen, exact = _seen(m), truth[k]["observations"]["q"]
        assert set(seen) == set(exact)
        for marker, uv in seen.items():
            assert np.hypot(*(np.subtract(uv, exact[marker]))) < 1.0, (marker, uv, exact[marker])
        dt, dr = _pose_error(out / "rig.yaml", truth, k, seen)
        assert dt < 0.02 and dr < 1.0, (dt, dr)

    # checked only: a warning names the differences, and images of another size than the rig's stop the node
    node, sent, got, error = _run_ros_node(dds_domain, out / "rig.yaml", images, _camera_info(T, other), False,
                                           frames=[0, 0])
    notes = node.source.notes
    assert isinstance(error, InputError) and "image is 512x288 but robot 'q''s calibration is 480x270" in str(error)
    assert node.camera is None and not got
    assert len(notes) == 1 and "fx=450" in notes[0] and "fx=400" in notes[0] and "512x288" in notes[0] \
        and "distortion differs" in notes[0] and "--camera-info use" in notes[0], notes


def test_camera_info_checked_gives_the_other_cameras_pixels_and_a_wrong_pose(sim, other_camera):
    """Without --camera-info use the rig's camera is assumed: the same frames
    through a node in the library give the other camera's pixels, which the
    truth of the rig's camera and the pose disagree with (what ``use`` fixes)."""
    out, _, _ = sim
    truth = json.loads((out / "truth.json").read_text())["frames"]
    rig = load_rig(out / "rig.yaml")
    other_rig = load_rig(other_camera / "rig.yaml")
    # q's detections in the other camera's images, taken as rig pixels (what a checking node sends)
    from mutloc.track.frames import detect_markers, expanded_rig

    image = cv2.imread(str(other_camera / "q" / "000001.png"))
    seen = detect_markers(expanded_rig(other_rig), "q", image, targets=["p"]).pixels()
    exact = truth[1]["observations"]["q"]
    assert max(np.hypot(*np.subtract(seen[m], exact[m])) for m in exact) > 10.0
    try:
        dt, dr = _pose_error(rig, truth, 1, seen)
    except MutlocError:
        return  # inconsistent: refused, also not the pose
    assert dt > 0.05 or dr > 2.0, (dt, dr)


@pytest.mark.parametrize("change, says", [
    (dict(k=[0.0] * 9), "focal lengths must be positive"),
    (dict(d=[-0.1, 0.0, 0.0]), "plumb_bob has 5 distortion coefficients, d has 3"),
    (dict(distortion_model="kannala_brandt", d=[0.0] * 4), "distortion model 'kannala_brandt' is not supported"),
    (dict(distortion_model="equidistant", d=[0.0] * 5), "equidistant has 4 distortion coefficients, d has 5"),
    (dict(width=0, height=0), "image size 0x0"),
    (dict(binning_x=2, binning_y=2), "binning"),
])
def test_a_bad_camera_info_is_one_line(sim, change, says):
    out, _, _ = sim
    T = ros_types()
    info = _camera_info(T, load_rig(out / "rig.yaml").robot("q").camera)
    for key, value in change.items():
        setattr(info, key, value)
    with pytest.raises(InputError) as err:
        camera_from_camera_info(info, "camera_info on /q/camera_info")
    text = str(err.value)
    assert text.startswith("camera_info on /q/camera_info: ") and says in text and "\n" not in text, text


def test_a_node_using_a_bad_camera_info_stops_with_one_line(sim, other_camera, dds_domain):
    """--camera-info use: a camera_info with no focal length, or images of
    another size than it says, stop the node with a one-line InputError;
    checked only, the bad camera_info is a warning and the rig's camera is used."""
    out, _, _ = sim
    T = ros_types()
    images = [other_camera / "q" / "000000.png"]
    zero = _camera_info(T, load_rig(other_camera / "rig.yaml").robot("q").camera)
    zero.k = [0.0] * 9
    _, _, got, error = _run_ros_node(dds_domain, out / "rig.yaml", images, zero, True, frames=[0, 0, 0])
    assert isinstance(error, InputError) and not got
    assert "camera_info on /q/camera_info: focal lengths must be positive" in str(error)
    assert "\n" not in str(error)
    # the rig's camera (480x270) announced, 512x288 images sent
    rig_info = _camera_info(T, load_rig(out / "rig.yaml").robot("q").camera)
    _, _, got, error = _run_ros_node(dds_domain, out / "rig.yaml", images, rig_info, True, frames=[0, 0])
    assert isinstance(error, InputError) and not got
    assert str(error) == "camera ros:/q/image_raw: image is 512x288 but its camera_info says 480x270"
    node, _, _, error = _run_ros_node(dds_domain, out / "rig.yaml", [out / "q" / "000000.png"], zero, False,
                                      frames=[0, 0])
    assert error is None and node.camera is None
    assert node.source.notes == ["camera_info on /q/camera_info: focal lengths must be positive and finite, got fx=0 "
                                 "fy=0 (an uncalibrated camera?) (the rig's camera is used)"]


def test_camera_info_use_needs_a_ros_topic(sim, capsys, dds_domain):
    out, _, _ = sim
    status = main(["node", "--rig", str(out / "rig.yaml"), "--robot", "q", "--camera", str(out / "q"), "--realtime",
                   "--camera-info", "use", "--loopback", "--domain", str(dds_domain)])
    err = capsys.readouterr().err.strip()
    assert status == 2 and len(err.splitlines()) == 1 and "--camera-info use" in err and "ros:/" in err, err


@pytest.mark.parametrize("kind, at_least", [("balls", 1), ("tags", 8), ("lights", 2)])
def test_the_warm_up_shows_the_detectors_the_markers_they_look_for(kind, at_least):
    """A node warms its detectors up on drawn images of the other robots'
    markers, so that the kernels a first real detection needs are loaded
    before the first frame (bench_live.py measures the difference): the
    detectors must find them there -- the tags' corners, the blinking
    lights by their blink, named -- or the warm-up would not reach those kernels."""
    from mutloc.sim.world import standard_rig
    from mutloc.track.frames import expanded_rig
    from mutloc.track.sources import Frame
    from mutloc.track.tracker import ObserverDetector
    from mutloc.live.node import warm_up_images

    rig = expanded_rig(standard_rig(kind, size=(480, 270), f=400.0))
    images = warm_up_images(rig, ["p"], (480, 270), 30.0)
    assert all(im.shape == (270, 480, 3) for im in images)
    detector = ObserverDetector(rig, "q", ["p"], 30.0)
    found = set()
    for k, image in enumerate(images):
        frame = Frame(k, k / 30.0, image)
        detector.feed(frame)
        found |= set(detector.detect(frame).detections)
    assert len(found) >= at_least and found <= set(rig.robot("p").markers), sorted(found)
    assert len(images) == (36 if kind == "lights" else 1)  # lights: 1.2 s of blinking at 30 frames/s


def test_a_replay_decodes_the_next_image_once_the_node_is_done_with_a_frame(sim):
    """A replayed image is decoded while the node is idle -- after it said it
    was done with the frame before (``handled``) -- not while its detector
    runs; with no word from the node, in time for the next frame's release."""
    out, _, times = sim
    period = times[1] - times[0]
    source = ReplaySource(out / "q", speed=1.0)
    decoded = {}

    def stream(frames):
        for f in frames:
            decoded[f.index] = time.monotonic()  # the image is read (decoded) now
            yield f

    source.stream = stream(list(source.stream))
    source.start()
    try:
        handled = {}
        for k in range(4):
            frame = source.take(5.0)
            assert frame is not None and frame.index == k
            if k < 2:  # a node: busy 3 ms with the frame, then done
                time.sleep(0.003)
                handled[k] = time.monotonic()
                source.handled(frame)
            else:  # a consumer that never says it is done
                pass
        released = source.slot.captured
    finally:
        source.close()
    assert released >= 4
    for k in (0, 1):
        assert decoded[k + 1] >= handled[k], k  # not while the node worked on frame k
        assert decoded[k + 1] - handled[k] < 0.6 * period  # but at once after (not near frame k + 1's release)
    # frame 3 without a word: decoded late in frame 2's period, and frame 3 still came (taken above)
    assert decoded[3] - decoded[2] > 0.5 * period


def _renamed(rig, names):
    """``rig`` with its robots renamed (``{old: new}``): robot names no other test's /tf uses."""
    from mutloc.core.rig import Marker, Rig, Robot

    return Rig({names[r]: Robot(names[r], rob.camera, {n: Marker(n, names[r], m.position, tag=m.tag)
                                                        for n, m in rob.markers.items()})
                for r, rob in rig.robots.items()})


def test_a_node_looks_for_a_missed_tag_where_the_localizers_pose_puts_it(dds_domain):
    """q's node misses p's tag seen 52 degrees off its normal at 3 m; with the localizer's pose of p on /tf
    (stamped with the frame's time) it finds the tag there and publishes its corners -- against the
    rendered corners.  Transforms of other frames are ignored and counted; a pose a metre off finds nothing."""
    from types import SimpleNamespace

    from mutloc.core.pose import Pose
    from mutloc.detect.tags import corner_marker_names, find_tag_near
    from mutloc.live.messages import TF_TOPIC, pose_messages
    from test_tag_look import first_look, steep_scenes

    T = ros_types()
    # Frames whose first look missed the tag, where it can be decoded at all (one of the eight cannot).
    scenes = [(rig, T_qp, images, truth) for rig, T_qp, images, truth in steep_scenes()
              if "TP#0" not in first_look(rig, images)[1]["q"].detections
              and find_tag_near(images["q"], rig.robot("p").markers["TP"], truth) is not None][:3]
    assert len(scenes) == 3
    names = {"p": "tagp_live", "q": "tagq_live"}
    rig = _renamed(scenes[0][0], names)
    bus = Bus(dds_domain, loopback=True)
    try:
        tf_writer = bus.writer(TF_TOPIC, T.TFMessage)
        node = Node(rig, names["q"], SimpleNamespace(fps=15.0, name="frames of a test"), bus, rig_id="tag-look-test")
        _wait_matched(tf_writer)
        k = 0

        def publish_and_process(T_qp, image, extra=()):
            nonlocal k
            t = time.time()
            _, tf = pose_messages(t, T_qp, None, names["p"], names["q"])
            tf.transforms.extend(extra)
            tf_writer.write(tf)
            msg = None
            for _ in range(40):  # until the transform has arrived (loopback: milliseconds)
                k += 1
                msg = node.process(LiveFrame(k, t + 0.001 * k, image))
                if any(o.marker == "TP#0" for o in msg.observations) or node._tf:
                    break
                time.sleep(0.01)
            return msg

        foreign = T.TransformStamped(header=T.Header(stamp=stamp(time.time()), frame_id="odom"),
                                     child_frame_id="base_link")
        # Between the rig's robots, but no rotation (a zero quaternion): not a pose either.
        zero = T.TransformStamped(header=T.Header(stamp=stamp(time.time()), frame_id=names["q"]),
                                  child_frame_id=names["p"],
                                  transform=T.Transform(rotation=T.Quaternion(x=0.0, y=0.0, z=0.0, w=0.0)))
        for rig_k, T_qp, images, truth in scenes:
            node._tf.clear()
            looked = node.stats.looked_again
            msg = publish_and_process(T_qp, images["q"], [foreign, zero])
            seen = _seen(msg)
            assert all(c in seen for c in corner_marker_names("TP"))
            assert max(np.hypot(*(np.array(seen[c]) - x)) for c, x in zip(corner_marker_names("TP"), truth)) < 0.35
            assert node.stats.looked_again == looked + 1
        assert node.stats.tf_foreign >= 6 and node.stats.tf_malformed == 0
        # A pose a metre to the side: the window holds no tag, nothing is published for it.
        node._tf.clear()
        msg = publish_and_process(Pose.from_rotvec([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]) @ scenes[0][1], scenes[0][2]["q"])
        assert "TP#0" not in _seen(msg)
    finally:
        bus.close()


class _TfBus:
    """A bus holding the two topics a node with tags to look for uses, without DDS: the observations it
    writes are kept, ``/tf`` gives the messages a test queued (a localizer's, at the stamps it chose)."""

    def __init__(self):
        self.queued, self.written = [], []

    def writer(self, topic, cls):
        return SimpleNamespace(write=self.written.append)

    def reader(self, topic, cls):
        bus = self

        class TfReader:
            malformed = 0

            def take(self):
                out, bus.queued[:] = list(bus.queued), []
                return out

        return TfReader()

    def publish(self, t, poses, reference):
        """One ``/tf`` message stamped ``t``: ``{robot: T_reference_robot}``."""
        from mutloc.live.messages import pose_messages

        msgs = [pose_messages(t, T, None, robot, reference)[1] for robot, T in poses.items()]
        self.queued.append(ros_types().TFMessage(transforms=[tr for m in msgs for tr in m.transforms]))


def _decodable_misses(n):
    """``n`` of tests/test_tag_look.py's steep scenes whose first look missed p's tag, where it can be
    decoded at all (one of the eight cannot)."""
    from mutloc.detect.tags import find_tag_near
    from test_tag_look import first_look, steep_scenes

    scenes = [(rig, T_qp, images, truth) for rig, T_qp, images, truth in steep_scenes()
              if "TP#0" not in first_look(rig, images)[1]["q"].detections
              and find_tag_near(images["q"], rig.robot("p").markers["TP"], truth) is not None][:n]
    assert len(scenes) == n
    return scenes


def _tag_corners_error(msg, truth):
    """The worst published corner of p's tag against the rendered truth (px); None if not all published."""
    from mutloc.detect.tags import corner_marker_names

    seen = _seen(msg)
    if not all(c in seen for c in corner_marker_names("TP")):
        return None
    return max(np.hypot(*(np.array(seen[c]) - x)) for c, x in zip(corner_marker_names("TP"), truth))


def test_a_node_that_is_not_the_reference_looks_where_the_localizers_poses_put_the_tag():
    """A team of three whose localizer's reference is r: /tf holds T_rp and T_rq.  q's node (not the
    reference) finds p's steep tag where T_rq^-1 T_rp puts it, at the rendered corners."""
    from mutloc.core.pose import Pose
    from test_tag_look import T_RQ, team_of_three

    T_rq = Pose.from_rotvec(*T_RQ)
    for rig, T_qp, images, truth in _decodable_misses(2):
        bus = _TfBus()
        node = Node(team_of_three(rig), "q", SimpleNamespace(fps=15.0, name="frames of a test"), bus,
                    rig_id="tag-look-test")
        bus.publish(50.0, {"p": T_rq @ T_qp, "q": T_rq}, "r")
        msg = node.process(LiveFrame(0, 50.0, images["q"]), taken=50.0)
        err = _tag_corners_error(msg, truth)
        assert err is not None and err < 0.35
        assert node.stats.looked_again == 1 and bus.written == [msg]


def test_a_node_uses_a_pose_from_tf_only_within_its_age_limit():
    """The localizer's pose of p (stamped t0) places p's steep tag in q's frames taken within
    TF_MAX_AGE of t0, before or after; in frames further away it is not used (nothing is looked for).
    The stamps are the test's: no clock involved."""
    from mutloc.live.node import TF_MAX_AGE

    (rig, T_qp, images, truth), = _decodable_misses(1)
    bus = _TfBus()
    node = Node(rig, "q", SimpleNamespace(fps=15.0, name="frames of a test"), bus, rig_id="tag-look-test")
    t0 = 100.0
    bus.publish(t0, {"p": T_qp}, "q")
    found = {}
    for k, dt in enumerate((-1.2, -0.8, 0.0, 0.8, 1.2)):
        t = t0 + dt * TF_MAX_AGE
        looked = node.stats.looked_again
        err = _tag_corners_error(node.process(LiveFrame(k, t, images["q"]), taken=t), truth)
        found[dt] = err is not None
        assert node.stats.looked_again == looked + found[dt]
        assert err is None or err < 0.35
    assert found == {-1.2: False, -0.8: True, 0.0: True, 0.8: True, 1.2: False}


def test_topics_per_camera_are_checked_and_matched_to_their_cameras():
    """``--topic CAM=TOPIC`` per camera, a bare TOPIC for the one camera; a topic of a camera not given, a camera
    given two topics or a bare topic beside several cameras: one line each."""
    from mutloc.live.node import camera_topics

    two = [("front", "a.bag"), ("back", "b.bag")]
    assert camera_topics(two, ["back=/p/back/image_raw", "front=/p/front/image_raw"]) == [
        "/p/front/image_raw", "/p/back/image_raw"]
    assert camera_topics(two, ["back=/p/back/image_raw"]) == [None, "/p/back/image_raw"]
    assert camera_topics(two, None) == [None, None]
    assert camera_topics([(None, "a.bag")], ["/q/image_raw"]) == ["/q/image_raw"]
    for topics, words in ((["side=/p/side"], "no --camera side"), (["front=/a", "front=/b"], "two topics"),
                          (["/p/image_raw"], "one --topic CAM=TOPIC per camera")):
        with pytest.raises(InputError, match=words):
            camera_topics(two, topics)


def test_a_node_of_two_cameras_replays_each_camera_from_its_own_bag_topic(tmp_path, dds_domain, capsys):
    """``mutloc node --camera front=BAG --camera back=BAG --topic front=T1 --topic back=T2``: each camera's
    frames come from its own topic (the node names each camera's source), and a bag's wrong topic is one line."""
    from test_sources import write_bag

    from mutloc.io import save_rig
    from mutloc.sim.body_scenes import fisheye_pair_rig

    rig = fisheye_pair_rig()
    save_rig(rig, tmp_path / "rig.yaml")
    cams = list(rig.robots["p"].cameras)
    assert len(cams) == 2
    w, h = rig.robots["p"].cameras[cams[0]].camera.size
    blank = [np.zeros((int(h), int(w), 3), np.uint8)] * 3
    for c in cams:
        write_bag(tmp_path / f"bag_{c}", 2, f"/p/{c}/image_raw", blank, [100.0, 100.1, 100.2])
    argv = ["node", "--rig", str(tmp_path / "rig.yaml"), "--robot", "p", "--realtime", "--loopback",
            "--domain", str(dds_domain), "--no-progress"]
    for c in cams:
        argv += ["--camera", f"{c}={tmp_path / f'bag_{c}'}", "--topic", f"{c}=/p/{c}/image_raw"]
    assert main(argv) == 0
    err = capsys.readouterr().err
    for c in cams:
        assert re.search(rf"camera \S*bag_{c}:/p/{c}/image_raw \(p/{c}\)", err), err
    # the wrong topic for a camera: its bag has no such topic
    argv[argv.index(f"{cams[1]}=/p/{cams[1]}/image_raw")] = f"{cams[1]}=/p/{cams[0]}/image_raw"
    assert main(argv) == 2
    lines = [x for x in capsys.readouterr().err.strip().splitlines() if not x.startswith("mutloc node: robot p")]
    assert len(lines) == 1 and f"bag_{cams[1]}: no topic '/p/{cams[0]}/image_raw'" in lines[0], lines
