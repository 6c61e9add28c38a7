"""Live operation for robots with several cameras (SPEC "Live operation", "Robots with several cameras, any
lens"; issue 36 item 4).

- ``mutloc node --camera front=DIR --camera back=DIR`` replays the simulator's two fisheye image folders of
  robot p: one message per processed frame of each camera, ``header.frame_id`` ``p/front`` / ``p/back``, each
  holding what offline detection through that camera's lens finds in the same frame, every pixel near the
  simulator's exact one (the truth: ``truth.json``, independent of the detector).
- The localizer takes ``NAME/CAM`` frame_ids (others refused and counted), fuses a body pair's cameras and
  gives poses near the simulator's true poses; over DDS it publishes each camera's mount on ``/tf_static``
  (transient-local: a reader joining later gets it), equal to the rig's.
- Bad ``--camera`` arguments: one line, non-zero.
- A fisheye's ROS camera_info (``equidistant``) is that camera's calibration: checked, or used to detect in.
- Each camera is a stream of its own in the localizer's reorder buffer.
- A camera's node looks for a missed tag where ``/tf`` puts it, through that camera's mount and lens.

DDS stays on the loopback interface, in domains derived from the pid (messages of another run are told
apart by their rig_id); every child runs in its own process group, killed in a ``finally``.
"""

import json
import math
import os
import signal
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="the live extra (cyclonedds) is part of make test's install")

from mutloc.api import load_rig  # noqa: E402
from mutloc.cli.main import main  # noqa: E402
from mutloc.core.observations import ObservationSet  # noqa: E402
from mutloc.io import save_rig  # noqa: E402
from mutloc.live import messages as M  # noqa: E402
from mutloc.live.dds import Bus  # noqa: E402
from mutloc.live.localizer import Localizer  # noqa: E402
from mutloc.sim.body_scenes import fisheye_pair_rig, moving_body_world  # noqa: E402
from mutloc.sim.render import relative_pose, true_observations  # noqa: E402
from mutloc.track.frames import detect_markers, expanded_rig  # noqa: E402

FRAMES, FPS = 3, 5.0
#: Two domains of this run (loopback only).
T0 = 1.75e9  # the robots' clock at the start of the API tests' records


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """``mutloc simulate --cameras back-to-back-fisheye``: 3 frames at 5 frames/s, 800x500, the robots 1 m
    apart facing each other (the front cameras see the other robot, the back cameras nothing), no room."""
    out = tmp_path_factory.mktemp("bodies")
    assert main(["simulate", "--cameras", "back-to-back-fisheye", "--frames", str(FRAMES), "--fps", str(FPS),
                 "--size", "800x500", "--distance", "1.0", "--no-room", "--out", str(out), "--no-progress"]) == 0
    return out, json.loads((out / "truth.json").read_text())


def _kill(child):
    if child.poll() is None:
        try:
            os.killpg(child.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        child.wait(timeout=10)


def _angle_deg(Ra, Rb):
    return math.degrees(math.acos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1)))


def test_node_with_two_cameras_publishes_each_cameras_detections(scene, dds_domain):
    out, truth = scene
    rig = expanded_rig(load_rig(out / "rig.yaml"))
    T = M.ros_types()
    bus = Bus(dds_domain, loopback=True)
    reader = bus.reader(M.observations_topic("p"), T.Observations, depth=100)
    cmd = [sys.executable, "-m", "mutloc", "node", "--rig", str(out / "rig.yaml"), "--robot", "p",
           "--camera", f"front={out / 'p_front'}", "--camera", f"back={out / 'p_back'}", "--realtime",
           "--loopback", "--domain", str(dds_domain), "--no-progress"]
    child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    got = []
    try:
        deadline = time.monotonic() + 120
        while child.poll() is None:
            assert time.monotonic() < deadline, "the node did not end with its recordings"
            got += reader.take()
            time.sleep(0.01)
        stdout, stderr = child.communicate(timeout=10)
        for _ in range(30):
            got += reader.take()
            time.sleep(0.01)
    finally:
        _kill(child)
        bus.close()
    assert child.returncode == 0, stderr
    rid = M.rig_id(out / "rig.yaml")
    got = [m for m in got if m.rig_id == rid]
    by_camera = {}
    for m in got:
        by_camera.setdefault(m.header.frame_id, []).append(m)
    assert set(by_camera) == {"p/front", "p/back"}, stderr
    # one summary per camera; every processed frame published
    processed = [int(x) for x in __import__("re").findall(r"(\d+) processed", stdout)]
    assert len(processed) == 2 and sum(processed) == len(got), stdout
    seen_front = 0
    for key, msgs in by_camera.items():
        for m in msgs:
            assert m.robot == "p"
            frame = truth["frames"][m.frame]
            assert m.source_time == pytest.approx(frame["timestamp"], abs=1e-9)
            image = cv2.imread(str(out / frame["images"][key]))
            offline = detect_markers(rig, key, image, targets=["q"]).detections
            ours = {o.marker: (o.u, o.v) for o in m.observations}
            assert set(ours) == set(offline), (key, m.frame)
            exact = frame["observations"].get(key, {})
            for name, uv in ours.items():
                assert np.allclose(uv, offline[name].uv, atol=1e-9)
                # near the simulator's exact pixel of the ball's centre: the ball detector through a fisheye
                # view is off by 0.5 px typically, 3.5 px at worst (measured on 18 such frames)
                assert np.hypot(*(np.asarray(uv) - exact[name])) < 4.0, (key, m.frame, name)
            if key == "p/front":
                seen_front += len(ours)
            else:
                assert not exact and not ours  # the back camera faces away from q
    # the two recordings replayed in step, as the robot's cameras captured them: a frame's stamp is the same in both
    stamps = {key: {m.frame: M.stamp_of(m.header) for m in msgs} for key, msgs in by_camera.items()}
    both = set(stamps["p/front"]) & set(stamps["p/back"])
    assert both and all(stamps["p/front"][k] == stamps["p/back"][k] for k in both), stamps
    # (the first frame, always processed, shows one of q's balls to the detector: deterministic)
    assert seen_front >= 1, (stdout, [(m.header.frame_id, m.frame, len(m.observations)) for m in got])


@pytest.mark.parametrize("args, says", [
    (["--camera", "{p_front}"], "robot 'p' has cameras front, back: name the camera"),
    (["--camera", "side={p_front}"], "robot 'p' has no camera 'side' (its cameras: front, back)"),
    (["--camera", "front={p_front}", "--camera", "front={p_back}"], "camera p/front given twice"),
])
def test_bad_camera_arguments_are_one_line_errors(scene, capsys, args, says, dds_domain):
    out, _ = scene
    args = [a.format(p_front=out / "p_front", p_back=out / "p_back") for a in args]
    rc = main(["node", "--rig", str(out / "rig.yaml"), "--robot", "p", *args, "--realtime", "--loopback",
               "--domain", str(dds_domain), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert rc != 0
    assert len(err.splitlines()) == 1 and says in err, err


def test_a_camera_name_for_a_robot_with_one_camera_is_a_one_line_error(tmp_path, capsys, dds_domain):
    assert main(["simulate", "--out", str(tmp_path), "--size", "96x64", "--focal", "80", "--no-room",
                 "--no-progress"]) == 0
    rc = main(["node", "--rig", str(tmp_path / "rig.yaml"), "--robot", "p", "--camera",
               f"front={tmp_path / 'p.png'}", "--realtime", "--loopback", "--domain", str(dds_domain)])
    err = capsys.readouterr().err.strip()
    assert rc != 0 and len(err.splitlines()) == 1 and "robot 'p' has one camera" in err, err


def _equidistant_info(T, camera, t):
    w, h = camera.size
    return T.CameraInfo(header=T.Header(stamp=M.stamp(t), frame_id="p/front"), width=w, height=h,
                        distortion_model="equidistant", d=[float(x) for x in camera.dist],
                        k=[float(x) for x in camera.K.ravel()])


def test_a_fisheye_cameras_ros_topic_with_its_equidistant_camera_info(scene, dds_domain):
    """p's front camera on a ROS image topic whose camera_info says ``equidistant`` (ROS's fisheye model)
    with the rig's calibration: checked, it agrees (no note); used (``--camera-info use``), the node detects
    through the announced fisheye and publishes what offline detection through the rig's finds, frame_id
    p/front.  A pinhole camera_info for that camera is a note naming the lens models."""
    import threading

    from mutloc.live.cameras import RosImageSource, camera_from_camera_info, compare_cameras
    from mutloc.live.node import Node
    from mutloc.core.lenses import FisheyeCamera

    out, truth = scene
    rig = expanded_rig(load_rig(out / "rig.yaml"))
    lens = rig.mount("p/front").camera
    T = M.ros_types()
    announced = camera_from_camera_info(_equidistant_info(T, lens, 0.0), "camera_info")
    assert isinstance(announced, FisheyeCamera) and compare_cameras(announced, lens, "camera_info") is None
    assert np.allclose(announced.K, lens.K) and np.allclose(announced.dist, lens.dist)
    pinhole = camera_from_camera_info(T.CameraInfo(width=800, height=500, distortion_model="plumb_bob",
                                                   d=[0.0] * 5, k=[float(x) for x in lens.K.ravel()]), "ci")
    assert "lens model pinhole vs the rig's fisheye" in compare_cameras(pinhole, lens, "camera_info")

    bus = Bus(dds_domain, loopback=True)
    stop, failed, got, sent = threading.Event(), [], [], {}
    runner = None
    try:
        reader = bus.reader(M.observations_topic("p"), T.Observations)
        raw = bus.writer("/p/front/image_raw", T.Image)
        info = bus.writer("/p/front/camera_info", T.CameraInfo)
        source = RosImageSource(bus, "/p/front/image_raw", rig_camera=lens, use_info=True)
        node = Node(out / "rig.yaml", "p", source, bus, camera="front")

        def run():
            try:
                node.run(stop=stop, status_every=None)
            except Exception as exc:  # noqa: BLE001 -- reported by the test
                failed.append(exc)

        runner = threading.Thread(target=run)
        runner.start()
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and not (raw.get_publication_matched_status().current_count
                                                   and info.get_publication_matched_status().current_count):
            time.sleep(0.02)
        for k in range(FRAMES):
            image = cv2.imread(str(out / truth["frames"][k]["images"]["p/front"]))
            t = time.time()
            sent[round(t, 6)] = k
            info.write(_equidistant_info(T, lens, t))
            h, w = image.shape[:2]
            raw.write(T.Image(header=T.Header(stamp=M.stamp(t), frame_id="p/front"), height=h, width=w,
                              encoding="bgr8", step=3 * w, data=image.tobytes()))
            end = time.monotonic() + 10
            while time.monotonic() < end and not any(round(M.stamp_of(m.header), 6) == round(t, 6) for m in got):
                got += reader.take()
                time.sleep(0.02)
    finally:
        stop.set()
        if runner is not None:
            runner.join(timeout=10)
        bus.close()
    assert not failed, failed
    got = [m for m in got if round(M.stamp_of(m.header), 6) in sent]
    assert len(got) >= FRAMES - 1 and all(m.header.frame_id == "p/front" for m in got)
    found = 0
    for m in got:
        k = sent[round(M.stamp_of(m.header), 6)]
        image = cv2.imread(str(out / truth["frames"][k]["images"]["p/front"]))
        offline = detect_markers(rig, "p/front", image, targets=["q"]).detections
        ours = {o.marker: (o.u, o.v) for o in m.observations}
        assert set(ours) == set(offline), k
        for name, uv in ours.items():
            assert np.allclose(uv, offline[name].uv, atol=1e-6)
        found += len(ours)
    assert found >= 1


# -- the localizer ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """Robots p and q with back-to-back fisheyes, p moving 2 m ahead of q: the rig file and, per frame at 30
    frames/s, every camera's exact pixels (the simulator's projection through lens and mount) plus 0.5 px
    noise, and the true ``T_qp``."""
    rig = fisheye_pair_rig("balls")
    path = tmp_path_factory.mktemp("pair") / "rig.yaml"
    save_rig(rig, path)
    world = moving_body_world(rig, distance=2.0, room=False)
    rng = np.random.default_rng(5)
    frames = []
    for k in range(75):  # (2.5 s: no pose is published before the rig check's first window, 30 records, agreed)
        t = k / 30
        seen = true_observations(world, t)
        obs = {key: {m: (np.asarray(uv) + rng.normal(0, 0.5, 2)).tolist() for m, uv in d.items()}
               for key, d in seen.items()}
        frames.append((t, obs, relative_pose(world, "p", "q", t)))
    assert {k for _, obs, _ in frames for k in obs} == {"p/front", "q/front"}
    return path, rig, frames


def _message(rid, key, frame, t, pixels):
    robot = key.split("/")[0]
    obs = ObservationSet([key] * len(pixels), list(pixels), np.array(list(pixels.values()), float).reshape(-1, 2))
    return M.observations_message(robot, rid, frame, t, obs, frame_id=key)


def test_localizer_fuses_the_cameras_of_a_body_pair(pair):
    path, rig, frames = pair
    rid = M.rig_id(path)
    loc = Localizer(path)
    poses = []
    for k, (t, obs, _) in enumerate(frames):
        for key in rig.observer_keys():  # every camera sends, also when it saw nothing
            assert loc.receive(_message(rid, key, k, T0 + t, obs.get(key, {})), T0 + t + 0.01, key.split("/")[0]) == "held"
        poses += loc.poll(T0 + t + 0.05)
    # a frame_id that is neither the robot nor one of its cameras: refused, counted
    t = T0 + frames[-1][0] + 0.1
    bad = [_message(rid, "p/front", 99, t, {}), _message(rid, "p/front", 98, t, {}),
           _message(rid, "p/front", 97, t, {})]
    bad[0].header.frame_id = "p/side"
    bad[1].header.frame_id = "p"  # (p has two cameras: its frame alone names none)
    bad[2].header.frame_id = "q/front"
    for msg in bad:
        assert loc.receive(msg, t, "p").startswith("refused")
    assert loc.counts["p"].refused_malformed == 3
    # the same frame number and stamp from the other camera is not a duplicate; from the same camera it is
    again = frames[-1][1]
    assert loc.receive(_message(rid, "p/front", len(frames) - 1, T0 + frames[-1][0], again.get("p/front", {})), t,
                       "p") == "duplicate"
    poses += loc.finish()
    assert loc.records == len(frames), loc.summary()
    # one record per frame, p's pose in q's frame near the truth (measured: up to 3.8 cm and 1.7 degrees),
    # from the record at which the rig check's first window (30 records, one test each) agreed
    held = loc.counts["p"].rig_waiting
    assert loc.rig_gate.state == "agrees" and 20 < held < 35
    assert {p.robot for p in poses} == {"p"} and len(poses) + held >= len(frames) - 2
    assert min(p.t for p in poses) >= loc.rig_gate.agreed
    truth = {round(T0 + t, 6): T for t, _, T in frames}
    for p in poses:
        T = truth[round(p.t, 6)]
        assert np.linalg.norm(p.estimate.pose.t - T.t) < 0.08, p
        assert _angle_deg(p.estimate.pose.R, T.R) < 3.5, p


def test_localizer_publishes_the_mounts_on_tf_static_and_poses_over_dds(pair, dds_domain):
    """``mutloc localizer`` over DDS: a reader joining after it started gets ``/tf_static`` (each camera's
    pose on its robot, the rig's), and messages sent as the nodes send them give poses near the truth."""
    path, rig, frames = pair
    rid = M.rig_id(path)
    domain = dds_domain
    cmd = [sys.executable, "-m", "mutloc", "localizer", "--rig", str(path), "--domain", str(domain), "--loopback",
           "--duration", "60"]
    child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    T = M.ros_types()
    static, poses = [], []
    bus = None
    try:
        line = child.stderr.readline()  # the localizer says it is up (after its /tf_static went out)
        assert line.startswith("localizer: rig_id"), line + child.stderr.read()
        time.sleep(0.5)
        bus = Bus(domain, loopback=True)  # joins late: transient-local gives it what was published before
        static_reader = bus.reader(M.TF_STATIC_TOPIC, T.TFMessage, static=True)
        pose_reader = bus.reader("/mutloc/p_in_q", T.PoseWithCovarianceStamped, depth=100)
        writers = {r: bus.writer(M.observations_topic(r), T.Observations) for r in ("p", "q")}
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and not (static and all(
                w.get_publication_matched_status().current_count for w in writers.values())):
            static += [s for s in static_reader.take() if any(x.header.frame_id in "pq" for x in s.transforms)]
            time.sleep(0.05)
        start = time.time() + 0.2
        for k, (t, obs, _) in enumerate(frames):
            while time.time() < start + t:
                time.sleep(0.002)
            for key in rig.observer_keys():
                writers[key.split("/")[0]].write(_message(rid, key, k, start + t, obs.get(key, {})))
            poses += pose_reader.take()
        end = time.monotonic() + 2.0
        while time.monotonic() < end:
            poses += pose_reader.take()
            time.sleep(0.02)
    finally:
        _kill(child)
        if bus is not None:
            bus.close()
    assert static, "no /tf_static for a reader that joined late"
    mounts = {(x.header.frame_id, x.child_frame_id): x.transform for x in static[-1].transforms}
    assert set(mounts) == {(r, f"{r}/{c}") for r in ("p", "q") for c in ("front", "back")}
    for (robot, key), tr in mounts.items():
        pose = rig.mount(key).pose
        q = np.array([tr.rotation.x, tr.rotation.y, tr.rotation.z, tr.rotation.w])
        assert np.allclose([tr.translation.x, tr.translation.y, tr.translation.z], pose.t, atol=1e-12)
        assert min(np.abs(q - pose.quaternion_xyzw).max(), np.abs(q + pose.quaternion_xyzw).max()) < 1e-12
    truth = {round(t, 3): Tqp for t, _, Tqp in frames}
    poses = [p for p in poses if p.header.frame_id == "q"]
    assert len(poses) >= len(frames) // 2, len(poses)
    for p in poses:
        Tqp = truth[round(M.stamp_of(p.header) - start, 3)]
        x = p.pose.pose.position
        assert np.linalg.norm(np.array([x.x, x.y, x.z]) - Tqp.t) < 0.08


def test_each_camera_is_a_stream_the_reorder_buffer_waits_for(pair):
    """p's back camera runs a little behind its front one (another node process, another clock tick): its
    message stamped 2 ms before the front's arrives after it.  The front's waits in the reorder buffer for
    the back camera (a stream of its own, still sending), so both are fused, in one record, none late."""
    path, rig, frames = pair
    rid = M.rig_id(path)
    loc = Localizer(path)
    (t0, obs0, _), (t1, obs1, _) = frames[0], frames[1]
    for key in rig.observer_keys():
        assert loc.receive(_message(rid, key, 0, T0 + t0, obs0.get(key, {})), T0 + t0 + 0.01,
                           key.split("/")[0]) == "held"
    loc.poll(T0 + t0 + 0.05)
    assert loc.records == 1
    arrive = T0 + t1 + 0.005
    for key in ("p/front", "q/front", "q/back"):
        assert loc.receive(_message(rid, key, 1, T0 + t1, obs1.get(key, {})), arrive, key.split("/")[0]) == "held"
    assert loc.poll(arrive) == [] and loc.records == 1  # p/back has not sent frame 1 yet: waited for
    fused = loc.counts["p"].fused
    assert loc.receive(_message(rid, "p/back", 1, T0 + t1 - 0.002, {}), arrive + 0.002, "p") == "held"
    loc.poll(arrive + 0.002)  # (no pose yet: the rig check's window is not full)
    assert loc.records == 2 and loc.counts["p"].dropped_late == 0
    assert loc.counts["p"].fused == fused + 2  # both of p's messages, in one record


def test_a_cameras_node_looks_for_a_missed_tag_through_its_mount_where_tf_puts_it(dds_domain):
    """p's back fisheye (robots back to back, the ray-traced tag scene of test_localize_images_bodies): its
    first look is made to miss q's tags; with the localizer's pose of p in q's frame on /tf, the node finds
    tag Q3 where that pose puts it through the camera's mount and lens and publishes its corners, within
    0.35 px of the ray-traced ones, with frame_id .../back."""
    from types import SimpleNamespace

    from mutloc.core.rig import Marker, Rig, Robot
    from mutloc.detect.base import DetectionResult
    from mutloc.live.cameras import LiveFrame
    from mutloc.live.node import Node
    from test_localize_images_bodies import _corners_truth, facing_away, render

    rig0, poses = facing_away()
    img = render(rig0, poses, keys=["p/back"])["p/back"]
    truth = _corners_truth(rig0, poses, "p/back", "Q3")
    names = {"p": "bodyp_live", "q": "bodyq_live"}  # robot names no other test's /tf uses
    rig = Rig({names[r]: Robot(names[r], None, {n: Marker(n, names[r], m.position, tag=m.tag)
                                                for n, m in rob.markers.items()}, cameras=rob.cameras)
               for r, rob in rig0.robots.items()})
    T = M.ros_types()
    bus = Bus(dds_domain, loopback=True)
    try:
        tf_writer = bus.writer(M.TF_TOPIC, T.TFMessage)
        node = Node(rig, names["p"], SimpleNamespace(fps=15.0, name="frames of a test"), bus,
                    rig_id="body-tag-look-test", camera="back")
        node.detector.detect = lambda frame: DetectionResult()  # the first look misses every tag
        deadline = time.monotonic() + 20
        while tf_writer.get_publication_matched_status().current_count == 0:
            assert time.monotonic() < deadline, "the node never subscribed to /tf"
            time.sleep(0.02)
        T_qp = poses["q"].inverse() @ poses["p"]
        msg = None
        for k in range(40):  # until the transform has arrived (loopback: milliseconds)
            t = time.time()
            tf_writer.write(M.pose_messages(t, T_qp, None, names["p"], names["q"])[1])
            time.sleep(0.01)
            msg = node.process(LiveFrame(k, t + 0.001, img))
            if any(o.marker == "Q3#0" for o in msg.observations):
                break
    finally:
        bus.close()
    assert msg.header.frame_id == "bodyp_live/back" and node.stats.looked_again >= 1
    seen = {o.marker: (o.u, o.v) for o in msg.observations}
    found = np.array([seen[f"Q3#{k}"] for k in range(4)])
    assert np.linalg.norm(found - truth, axis=1).max() < 0.35
