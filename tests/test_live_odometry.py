"""Odometry received live (SPEC "The robots' own motion and clocks"; mutloc.live.odometry).

Ground truth: the simulator (:func:`mutloc.sim.team.random_team` of two
robots moving by :func:`mutloc.sim.team.team_motion`, up to 0.72 m/s), both
cameras at 30 fps with 1 px noise, each robot's odometry at 50 Hz from its
true motion with the simulator's drift (1 % of the distance, 0.3 deg/m:
:func:`mutloc.sim.odometry.drifting_odometry`).  The messages are those the
nodes and a ROS odometry publisher send, fed to
:class:`mutloc.live.localizer.Localizer` with their arrival times (no DDS);
one test runs ``mutloc localizer --odometry`` over DDS (loopback, a domain of
this run).
"""

import math
import os
import signal
import subprocess
import sys
import time
from types import SimpleNamespace

import numpy as np
import pytest

from mutloc.cli.main import main
from mutloc.core.geometry import so3_log
from mutloc.core.odometry import Odometry
from mutloc.core.pose import Pose
from mutloc.io import save_rig
from mutloc.io.logs import ObservationLogWriter
from mutloc.io.trajectory import read_tum
from mutloc.live import messages as M
from mutloc.live.localizer import Localizer
from mutloc.live.odometry import LiveOdometry, OdometryStream
from mutloc.sim.odometry import drifting_odometry, odometry_times
from mutloc.sim.team import TeamScene, random_team, team_motion
from mutloc.track.filtering import FilterOptions
from mutloc.track.odometry import read_tum_odometry
from mutloc.track.outputs import TrackOutputs

pytest.importorskip("cyclonedds", reason="the live extra (cyclonedds) is part of make test's install")

T0 = 1_800_000_000.0  # the robots' wall clock at the scene's time 0
FPS = 30.0
ODO_RATE = 50.0
DURATION = 6.0
GAP = (2.5, 4.5)  # nothing seen: someone walks between the robots
LATENCY = 0.006  # capture -> arrival
NEES_5SIGMA = 45.0  # chi-square 6 dof at 1 - 5.7e-7 (two-sided 5 sigma)
ROBOTS = ("r0", "r1")
TOPICS = {"r0": "/r0/odom", "r1": "/r1/odom"}


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("live_odometry")
    seed = 4
    team = random_team(2, np.random.default_rng(seed), one_way=0.0)
    at = team_motion(team, seed=seed, amplitude=0.3, speed=0.6, yaw_deg=8.0)
    path = d / "rig.yaml"
    save_rig(team.rig, path)
    rng = np.random.default_rng([seed, 77])
    frames = []  # (t, observations of the frame, truth T_r1_r0)
    for k in range(int(DURATION * FPS)):
        t = k / FPS
        snap = TeamScene(team.rig, at(t), team.links, team.max_range)
        obs = snap.observations(1.0, rng)
        if GAP[0] <= t < GAP[1]:
            obs = obs.take(np.empty(0, np.int64))
        frames.append((t, obs, snap.truth("r1")["r0"]))
    times = odometry_times(0.0, DURATION, ODO_RATE)
    odo = {n: drifting_odometry(lambda t, n=n: at(t)[n], times, drift_pct=1.0, deg_per_m=0.3, seed=seed, stream=k)
           for k, n in enumerate(team.names)}
    return SimpleNamespace(path=path, rid=M.rig_id(path), frames=frames, odo_times=times, odo=odo,
                           truth={round(t, 6): T for t, _, T in frames})


def observation_messages(s):
    """``[arrival, kind, robot, message]`` of each robot's camera frames (nothing seen: an empty message)."""
    out = []
    for k, (t, obs, _) in enumerate(s.frames):
        for r in ROBOTS:
            out.append([T0 + t + LATENCY, "obs", r, M.observations_message(r, s.rid, k + 1, T0 + t, obs)])
    return out


def odometry_messages(s, robots=ROBOTS, covariance=None):
    out = []
    for r in robots:
        for t, R, tv in zip(s.odo_times, s.odo[r].R, s.odo[r].t):
            out.append([T0 + t + LATENCY, "odo", r, M.odometry_message(T0 + t, Pose(R, tv), covariance, r)])
    return out


def drive(loc, msgs, timed=False):
    """Deliver ``msgs`` in arrival order, waking the localizer when its buffer is due
    (as run_localizer's loop does); returns the poses published (``timed``: with the time of each)."""
    out = []
    for now, kind, robot, msg in sorted(msgs, key=lambda m: m[0]):
        while loc.next_due() is not None and loc.next_due() <= now:
            due = loc.next_due()
            out += [(due, p) for p in loc.poll(due)]
        if kind == "odo":
            loc.receive_odometry(robot, msg, now)
            out += [(now, p) for p in loc.poll(now)]
        else:
            out += [(now, p) for p in loc.feed(msg, now, robot)]
    out += [(math.inf, p) for p in loc.finish()]
    return out if timed else [p for _, p in out]


def nees_and_error(s, p):
    """(6-dof NEES, translation error m) of a published pose against the truth at its stamp."""
    T = s.truth[round(p.t - T0, 6)]
    e = np.concatenate([so3_log(T.R @ p.estimate.pose.R.T), T.t - p.estimate.pose.t])
    return float(e @ np.linalg.solve(p.estimate.covariance, e)), float(np.linalg.norm(e[3:]))


def in_gap(p):
    return GAP[0] + 0.1 <= p.t - T0 < GAP[1]


def test_through_two_seconds_unseen_the_odometry_keeps_the_pose_near_the_truth(scene, tmp_path):
    """Two seconds with nothing seen (both nodes still send their frames,
    empty): with both robots' odometry received live every message in the
    stretch gives a published pose of r0 in r1 within 5 cm of the truth and
    5 sigma; with --out, replaying the log with the odometry files the
    localizer wrote gives its trajectory file byte for byte."""
    msgs = observation_messages(scene) + odometry_messages(scene)
    log = ObservationLogWriter(tmp_path / "live" / "log.jsonl")
    tums = {}

    def tum(r):
        tums[r] = open(tmp_path / "live" / f"odometry_{r}.tum", "w")
        return tums[r]

    with TrackOutputs(tmp_path / "live", "r0", "r1") as outputs:
        loc = Localizer(scene.path, sink=outputs.write, log=log, max_coast=3.0,
                        odometry=LiveOdometry(TOPICS, tum=tum, max_clock_skew=0.05))
        poses = drive(loc, msgs)
    log.close()
    for f in tums.values():
        f.close()
    assert loc.reference == "r1" and loc.tracked == ["r0"]
    gap = [p for p in poses if in_gap(p)]
    sent = [m for m in msgs if m[1] == "obs" and m[2] == "r0" and in_gap(SimpleNamespace(t=M.stamp_of(m[3].header)))]
    assert len({p.t for p in gap}) == len(sent) > 50  # a pose for every message in the stretch
    checks = np.array([nees_and_error(scene, p) for p in gap])
    assert checks[:, 1].max() < 0.05, checks[:, 1].max()
    assert checks[:, 0].max() < NEES_5SIGMA, checks[:, 0].max()
    counts = {r: loc.odometry.counts[r] for r in ROBOTS}
    assert all(c.used == len(scene.odo_times) and c.refused == 0 and c.uncovered == 0 for c in counts.values())
    # the replay: track with the log and the odometry the localizer used
    assert main(["track", "--rig", str(scene.path), "--observations", str(tmp_path / "live" / "log.jsonl"),
                 "--odometry", f"r0={tmp_path / 'live' / 'odometry_r0.tum'}",
                 "--odometry", f"r1={tmp_path / 'live' / 'odometry_r1.tum'}",
                 "--out", str(tmp_path / "replay"), "--no-progress"]) == 0
    for name in ("trajectory.csv", "trajectory.tum"):
        assert (tmp_path / "live" / name).read_bytes() == (tmp_path / "replay" / name).read_bytes()
    # the localizer given those TUM files instead of the topics (localizer --odometry NAME=FILE) publishes the same
    files = {r: read_tum_odometry(tmp_path / "live" / f"odometry_{r}.tum") for r in ROBOTS}
    again = drive(Localizer(scene.path, max_coast=3.0, filter=FilterOptions(smooth_lag=0, odometry=files)),
                  observation_messages(scene))
    assert [(p.t, p.estimate.pose.t.tolist(), p.estimate.covariance.tolist()) for p in again] == \
        [(p.t, p.estimate.pose.t.tolist(), p.estimate.covariance.tolist()) for p in poses]


def test_without_odometry_the_same_stretch_is_coasted_far_off(scene):
    """The control: the same messages without the odometry (and --max-coast 3
    so that the coasted poses are published): beyond 5 cm in the stretch."""
    loc = Localizer(scene.path, max_coast=3.0)
    poses = drive(loc, observation_messages(scene))
    err = [nees_and_error(scene, p)[1] for p in poses if in_gap(p)]
    assert err and max(err) > 0.05, max(err)


def _bad_odometry(scene):
    """r0's odometry messages with bad ones among them, and how many of each kind."""
    T = M.ros_types()
    good = odometry_messages(scene, robots=("r0",))
    out, kinds = [], {"frame": 0, "invalid": 0, "clock": 0, "not_increasing": 0, "jump": 0, "malformed": 0}
    for k, (now, _, r, msg) in enumerate(good):
        out.append([now, "odo", r, msg])
        if k % 10 != 5:
            continue
        kind = list(kinds)[(k // 10) % len(kinds)]
        bad = T.Odometry.deserialize(msg.serialize())
        if kind == "frame":
            bad.child_frame_id = "r1"
        elif kind == "invalid":
            if (k // 10) % 2:
                bad.pose.pose.position.x = math.nan
            else:
                q = bad.pose.pose.orientation
                q.x, q.y, q.z, q.w = 2 * q.x, 2 * q.y, 2 * q.z, 2 * q.w  # not a unit quaternion
        elif kind == "clock":
            bad.header.stamp = M.stamp(now + 5.0)
        elif kind == "not_increasing":
            bad.header.stamp = M.stamp(M.stamp_of(msg.header) - 0.5)  # time going backwards
        elif kind == "jump":
            bad.header.stamp = M.stamp(M.stamp_of(msg.header) + 0.01)  # between two samples, 3 m away
            bad.pose.pose.position.x += 3.0
        else:
            bad = SimpleNamespace(header=msg.header)  # not an Odometry at all
        kinds[kind] += 1
        out.append([now + 1e-4, "odo", r, bad])
    return out, kinds


def test_bad_odometry_is_refused_counted_and_said_once(scene):
    """A wrong child_frame_id, NaN, a non-unit quaternion, a stamp in the
    future, time going backwards, a jump, something that is not an Odometry:
    each refused or rejected and counted by kind in /diagnostics, the reason
    said once per kind; the poses are those of the clean odometry, exactly."""
    bad, kinds = _bad_odometry(scene)
    said = []
    loc = Localizer(scene.path, max_coast=3.0, odometry=LiveOdometry({"r0": "/r0/odom"}), notify=said.append)
    poses = drive(loc, observation_messages(scene) + bad)
    clean = Localizer(scene.path, max_coast=3.0, odometry=LiveOdometry({"r0": "/r0/odom"}))
    ref = drive(clean, observation_messages(scene) + odometry_messages(scene, robots=("r0",)))
    assert [(p.t, p.estimate.pose.t.tolist()) for p in poses] == [(p.t, p.estimate.pose.t.tolist()) for p in ref]
    values = {s.robot: s for s in loc.diagnostics(T0 + DURATION)}["r0"]
    v = values.values
    assert v["odometry_refused_frame"] == kinds["frame"] and v["odometry_refused_invalid"] == kinds["invalid"]
    assert v["odometry_refused_clock"] == kinds["clock"] and v["odometry_refused_malformed"] == kinds["malformed"]
    assert v["odometry_rejected_not_increasing"] == kinds["not_increasing"]
    assert v["odometry_rejected_jump"] == kinds["jump"] and v["odometry_resets"] == 0
    assert v["odometry_refused"] == sum(kinds[k] for k in ("frame", "invalid", "clock", "malformed"))
    assert v["odometry_received"] == len(bad) and v["odometry_used"] == len(scene.odo_times)
    assert values.level == M.WARN and "refused" in values.message and "odometry" in values.message
    lines = [x for x in said if "odometry" in x]
    for kind in ("frame", "invalid", "clock", "malformed"):
        assert sum(f"refused odometry ({kind})" in x for x in lines) == 1, lines
    assert "child_frame_id 'r1' is not robot 'r0'" in " ".join(lines)


def test_an_odometry_all_refused_holds_no_record_back(scene):
    """r1's odometry, every message of another robot's frame: refused, and the
    records are fused when they would be without it (not after the 0.1 s a
    record waits for an odometry that comes)."""
    bad = odometry_messages(scene, robots=("r1",))
    for m in bad:
        m[3].child_frame_id = "r0"
    loc = Localizer(scene.path, odometry=LiveOdometry({"r1": "/r1/odom"}))
    timed = drive(loc, observation_messages(scene) + bad, timed=True)
    ref = drive(Localizer(scene.path), observation_messages(scene), timed=True)
    assert loc.odometry.counts["r1"].refused_frame == len(bad) and loc.odometry.counts["r1"].used == 0
    assert [(w, p.t, p.estimate.pose.t.tolist()) for w, p in timed] == \
        [(w, p.t, p.estimate.pose.t.tolist()) for w, p in ref] and len(ref) > 100


def test_the_stream_takes_what_a_whole_file_takes(scene):
    """OdometryStream, a sample at a time, against Odometry on the same
    samples at once: the same samples kept (outliers dropped, a reset, a gap,
    time going back) and the same increments and covariances, bit for bit."""
    rng = np.random.default_rng(9)
    times = scene.odo_times.copy()
    R, t = scene.odo["r0"].R.copy(), scene.odo["r0"].t.copy()
    t[40] += 2.0  # an outlier
    t[120:] += 1.5  # a reset of the odometry frame
    times[200:] += 0.8  # a gap
    times[250] = times[249]  # time standing still
    keep = np.ones(len(times), dtype=bool)
    keep[260] = False  # a sample lost
    whole = Odometry(times[keep], Pose(R[keep], t[keep]))
    stream = OdometryStream("test")
    for k in np.flatnonzero(keep):
        stream.add(times[k], R[k], t[k])
    assert whole.counts == stream.counts and stream.resets == 1
    np.testing.assert_array_equal(whole.times, stream.times)
    for _ in range(200):
        a, b = np.sort(rng.uniform(whole.start, whole.end, 2))
        assert whole.covers(a, b) == stream.covers(a, b)
        if whole.covers(a, b):
            x, y = whole.increment(a, b), stream.increment(a, b)
            np.testing.assert_array_equal(x.pose.R, y.pose.R)
            np.testing.assert_array_equal(x.pose.t, y.pose.t)
            np.testing.assert_array_equal(x.covariance, y.covariance)
    # a stream keeps the last `keep` seconds: the same increments there
    short = OdometryStream("test", keep=1.0)
    for k in np.flatnonzero(keep):
        short.add(times[k], R[k], t[k])
    assert len(short) < len(stream) and short.times[0] > whole.end - 2.1 and short.end == whole.end
    for _ in range(50):
        a, b = np.sort(rng.uniform(whole.end - 1.0, whole.end, 2))
        assert short.covers(a, b) == whole.covers(a, b)
        if whole.covers(a, b):
            np.testing.assert_array_equal(whole.increment(a, b).covariance, short.increment(a, b).covariance)
            np.testing.assert_array_equal(whole.increment(a, b).pose.t, short.increment(a, b).pose.t)


def test_over_dds_the_localizer_subscribes_to_the_odometry(scene, tmp_path, dds_domain):
    """``mutloc localizer --odometry r0=ros:/r0/odom --odometry r1=ros:/r1/odom``
    over DDS (loopback, a domain of this run): this process publishes both
    robots' frames (nothing seen for two seconds) and their odometry in real
    time, with odometry of another robot's frame among r0's.  Through the
    unseen stretch >= 90% of r0's frames give a pose, each within 5 cm of the
    truth and 5 sigma; the diagnostics count the odometry received and the
    refused messages; Ctrl-C: DIR/odometry_NAME.tum holds the samples used."""
    from mutloc.live.dds import Bus

    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "mutloc", "localizer", "--rig", str(scene.path), "--domain", str(dds_domain),
           "--loopback", "--out", str(out), "--duration", "60", "--max-coast", "3",
           "--odometry", "r0=ros:/r0/odom", "--odometry", "r1=ros:/r1/odom"]
    child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    poses, diagnostics = [], []
    foreign = 0
    try:
        line = child.stderr.readline()  # the localizer says it is up
        assert line.startswith("localizer: rig_id") and "odometry from r0 /r0/odom, r1 /r1/odom" in line, \
            line + child.stderr.read()
        bus = Bus(dds_domain, loopback=True)
        T = M.ros_types()
        pose_reader = bus.reader(M.pose_topic("r0", "r1"), T.PoseWithCovarianceStamped, depth=200)
        diag_reader = bus.reader(M.DIAGNOSTICS_TOPIC, T.DiagnosticArray, depth=50)
        obs_w = {r: bus.writer(M.observations_topic(r), T.Observations) for r in ROBOTS}
        odo_w = {r: bus.writer(TOPICS[r], T.Odometry) for r in ROBOTS}
        writers = [*obs_w.values(), *odo_w.values()]
        deadline = time.time() + 20
        while time.time() < deadline and not (pose_reader.native.get_matched_publications()
                                               and all(w.get_matched_subscriptions() for w in writers)):
            time.sleep(0.05)
        assert all(w.get_matched_subscriptions() for w in writers), "no discovery"
        start = time.time() + 0.3
        plan = [(t, "obs", r, M.observations_message(r, scene.rid, k + 1, start + t, obs))
                for k, (t, obs, _) in enumerate(scene.frames) for r in ROBOTS]
        for r in ROBOTS:
            for t, R, tv in zip(scene.odo_times, scene.odo[r].R, scene.odo[r].t):
                plan.append((t, "odo", r, M.odometry_message(start + t, Pose(R, tv), None, r)))
        for k, t in enumerate(scene.odo_times[::25]):  # another robot's frame on r0's topic: refused
            plan.append((t + 0.001, "odo", "r0", M.odometry_message(start + t, Pose(np.eye(3), [0, 0, 0]), None, "r1")))
            foreign += 1
        plan.sort(key=lambda x: x[0])

        def take():
            now = time.time()
            poses.extend((now, s) for s in pose_reader.take())
            diagnostics.extend((now, s) for s in diag_reader.take())

        for t, kind, r, msg in plan:
            while time.time() < start + t:
                take()
                time.sleep(0.001)
            (obs_w if kind == "obs" else odo_w)[r].write(msg)
        end = time.time()
        while time.time() < end + 1.0:
            take()
            time.sleep(0.01)
        child.send_signal(signal.SIGINT)
        stdout, stderr = child.communicate(timeout=60)
        take()
        bus.close()
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
            child.wait()
    assert child.returncode == 130, stderr
    # through the unseen stretch: a pose per r0 frame (>= 90% on a loaded machine), near the truth, honest
    frames = [t for t, _, _ in scene.frames if GAP[0] + 0.1 <= t < GAP[1]]
    got = {}
    for _, s in poses:
        t = M.stamp_of(s.header) - start
        if GAP[0] + 0.1 <= t < GAP[1]:
            got[round(t, 4)] = s
    assert len(got) >= 0.9 * len(frames), (len(got), len(frames), stderr)
    for t, s in got.items():
        truth = scene.truth[round(min(scene.truth, key=lambda x: abs(x - t)), 6)]
        p = s.pose.pose
        est = Pose.from_quaternion_xyzw([p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w],
                                        [p.position.x, p.position.y, p.position.z])
        e = np.concatenate([so3_log(truth.R @ est.R.T), truth.t - est.t])
        from mutloc.io.ros import spec_covariance

        nees = float(e @ np.linalg.solve(spec_covariance(s.pose.covariance), e))
        assert np.linalg.norm(e[3:]) < 0.05 and nees < NEES_5SIGMA, (t, np.linalg.norm(e[3:]), nees)
    # the diagnostics: every odometry message counted, the foreign frame refused
    last = {x.hardware_id: {kv.key: kv.value for kv in x.values} for x in diagnostics[-1][1].status}
    n = len(scene.odo_times)
    assert int(last["r1"]["odometry_received"]) >= 0.9 * n and int(last["r1"]["odometry_refused"]) == 0
    assert int(last["r0"]["odometry_refused_frame"]) >= 0.9 * foreign
    assert int(last["r0"]["odometry_refused"]) == int(last["r0"]["odometry_refused_frame"])
    assert sum("refused odometry (frame)" in x for x in stderr.splitlines()) == 1, stderr
    # the odometry used, for the replay
    times, _ = read_tum(out / "odometry_r1.tum")
    assert len(times) >= 0.9 * n and np.all(np.diff(times) > 0)
    assert "odometry_r0.tum" in stderr


@pytest.mark.parametrize("args, words", [
    (["--odometry", "r7=ros:/r7/odom"], "no robot 'r7' in the rig"),
    (["--odometry", "r0=bag:/r0/odom"], "live, there is no bag"),
    (["--odometry", "r0=ros:odom"], "a live topic is ros:/TOPIC"),
    (["--odometry", "r0=ros:/a", "--odometry", "r0=ros:/b"], "r0"),
    (["--odometry", "r0=ros:/a", "--odometry-noise", "distance=-1"], "distance"),
    (["--odometry", "r0=/nonexistent/odometry.tum"], "/nonexistent/odometry.tum"),
])
def test_bad_odometry_arguments_are_one_line_errors(scene, capsys, args, words):
    code = main(["localizer", "--rig", str(scene.path), "--duration", "1", "--loopback", *args])
    err = capsys.readouterr().err.strip()
    assert code != 0 and words in err and len(err.splitlines()) == 1 and "Traceback" not in err, err


def test_demo_odometry_needs_live(tmp_path, capsys):
    assert main(["demo", "--odometry", "--out", str(tmp_path)]) != 0
    err = capsys.readouterr().err.strip()
    assert "--odometry is for the live demo: add --live" in err and len(err.splitlines()) == 1
