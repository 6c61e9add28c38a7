"""The live localizer (SPEC "Live operation").

Most tests feed :class:`mutloc.live.localizer.Localizer` the ``Observations``
messages a node would publish -- built from simulated free-running cameras
(mutloc.sim.tracking.camera_records: each camera at 30 fps, q half a frame
after p, every marker projected along a known path with 1 px noise) -- with
their arrival times, without DDS.  Ground truth: the path; the reference for
accuracy: offline ``track`` on the same records.  One test runs ``mutloc
localizer`` as a process over DDS (loopback, its own domain id) with this
process as both robots' nodes and as a subscriber with its own type
definitions.
"""

import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mutloc.cli.main import main
from mutloc.core.observations import ObservationSet
from mutloc.io import save_rig
from mutloc.io.logs import ObservationLogWriter, iter_observation_log
from mutloc.io.trajectory import read_trajectory_csv
from mutloc.live import messages as M
from mutloc.live.localizer import Localizer
from mutloc.sim.team import random_team, team_camera_records
from mutloc.sim.tracking import camera_records
from mutloc.sim.world import standard_rig
from mutloc.track.filtering import FilterOptions
from mutloc.track.outputs import TrackOutputs
from mutloc.track.team import track_team_log
from mutloc.track.tracker import track_log

pytest.importorskip("cyclonedds", reason="the live extra (cyclonedds) is part of make test's install")

T0 = 1_800_000_000.0  # the robots' wall clock at the records' time 0
HALF = {"q": 1 / 60}  # q's camera half a frame after p's, both at 30 fps
LATENCY = 0.008  # capture -> arrival at the localizer
#: Seconds of these records by which the rig check's first full window has agreed (two balls per robot, one
#: camera per record: 30 pools of five records, about 2.5 s; test_poses_match_offline_track_and_the_truth
#: asserts it): no pose is published before (mutloc.live.rig_gate), so the events of the tests come after it.
READY = 3.0


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("live")
    rig = standard_rig()  # two markers per robot: one camera's record alone is "partial"
    path = d / "rig.yaml"
    save_rig(rig, path)
    recs = camera_records(rig, duration=8.0, offsets=HALF, pixel_sigma=1.0, seed=5)
    return SimpleNamespace(rig=rig, path=path, rid=M.rig_id(path), recs=recs)


def truth_at(setup, t):
    """The true T_qp at capture time ``t`` (a message's stamp, rounded to the nanosecond)."""
    k = int(np.argmin(np.abs(setup.recs.times - (t - T0))))
    assert abs(setup.recs.times[k] - (t - T0)) < 1e-5
    return setup.recs.truth[k]


def messages(setup, until=math.inf, since=0.0, robots=("p", "q"), latency=LATENCY, rid=None):
    """``[arrival, message, topic robot]`` per camera frame captured in [since, until), as the nodes publish them."""
    out, frames = [], {}
    for t, obs, cams in zip(setup.recs.times, setup.recs.frames, setup.recs.cameras):
        for c in cams:
            frames[c] = frames.get(c, 0) + 1
            if since <= t < until and c in robots:
                msg = M.observations_message(c, rid or setup.rid, frames[c], T0 + t, obs)
                out.append([T0 + t + latency, msg, c])
    return out


def drive(loc, msgs, finish=True):
    """Deliver ``msgs`` in arrival order, waking the localizer when its buffer is due
    (as run_localizer's loop does); returns ``[(publish time, LivePose)]``."""
    out = []
    for now, msg, topic in sorted(msgs, key=lambda m: m[0]):
        while loc.next_due() is not None and loc.next_due() <= now:
            due = loc.next_due()
            out += [(due, p) for p in loc.poll(due)]
        out += [(now, p) for p in loc.feed(msg, now, topic)]
    if finish:
        end = max(m[0] for m in msgs) + 1.0
        out += [(end, p) for p in loc.finish()]
    return out


def errors(setup, poses):
    """Translation error (m) of each pose against the truth at its stamp."""
    return np.array([np.linalg.norm(p.estimate.t - truth_at(setup, p.t).t) for _, p in poses])


def offline(setup, msgs, lag=0):
    """Offline track of the records these messages carry (in capture order), the causal filter by default."""
    recs = sorted((M.stamp_of(m.header), M.observations_from_message(m).observations) for _, m, _ in msgs)
    return track_log(setup.path, recs, progress=False, filter=FilterOptions(smooth_lag=lag))


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def sigma_t(pose):
    return float(np.sqrt(np.trace(pose.estimate.covariance[3:, 3:])))


# -- accuracy and the replay --------------------------------------------------------------------


def test_poses_match_offline_track_and_the_truth(setup, tmp_path):
    """Every message fused at its capture time: one pose per message (after
    the start), errors against the truth those of offline ``track`` (the
    causal filter) on the same records; ``--out`` writes what track
    writes and the received log, and ``mutloc track --observations`` on that
    log gives the same trajectory file byte for byte."""
    msgs = messages(setup, until=4.0)
    log = ObservationLogWriter(tmp_path / "live" / "log.jsonl")
    with TrackOutputs(tmp_path / "live", "p", "q") as outputs:
        loc = Localizer(setup.path, sink=outputs.write, log=log)
        poses = drive(loc, msgs)
    log.close()
    assert loc.reference == "q" and loc.tracked == ["p"]
    # no pose before the rig check's first full window agreed (before READY); then one per message
    held = loc.counts["p"].rig_waiting
    assert loc.rig_gate.agreed is not None and loc.rig_gate.agreed < T0 + READY and held > 0
    assert min(p.t for _, p in poses) >= loc.rig_gate.agreed - loc.tolerance
    assert loc.records == len(msgs) and len(poses) + held >= len(msgs) - 5
    assert all(p.robot == "p" and p.reference == "q" for _, p in poses)
    # one pose per fused message, stamped with its capture time, in time order
    stamps = [p.t for _, p in poses]
    assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)
    sent = {(m.header.stamp.sec, m.header.stamp.nanosec) for _, m, _ in msgs}
    for _, p in poses:  # the message's own stamp, to the nanosecond
        pm, tf = p.messages()
        assert (pm.header.stamp.sec, pm.header.stamp.nanosec) in sent and tf.transforms[0].header.stamp == pm.header.stamp
    first = min(p.t for _, p in poses) - T0
    live = errors(setup, poses)
    ref = [r for r in offline(setup, msgs).rows if r.estimate is not None and r.t >= first - 1e-6]
    ref_err = np.array([np.linalg.norm(r.estimate.t - truth_at(setup, r.t).t) for r in ref])
    assert rms(live) <= 1.1 * rms(ref_err) + 1e-4, (rms(live), rms(ref_err))
    assert rms(live) < 0.03  # 2 m away, 1 px noise: a few cm at most
    # the replay
    assert main(["track", "--rig", str(setup.path), "--observations", str(tmp_path / "live" / "log.jsonl"),
                 "--out", str(tmp_path / "replay"), "--no-progress"]) == 0
    for name in ("trajectory.csv", "trajectory.tum"):
        assert (tmp_path / "live" / name).read_bytes() == (tmp_path / "replay" / name).read_bytes()
    assert len(read_trajectory_csv(tmp_path / "live" / "trajectory.csv")) == len(msgs)


def test_a_team_is_fused_and_replayed_the_same(tmp_path):
    """Three robots (the team tracker), each camera at its own phase: a
    pose per message of every tracked robot it is about (its observer, the
    robots it saw), in the first robot's frame, near the truth; the
    trajectory files equal those of track_team_log on the received log."""
    rng = np.random.default_rng(2)
    scene = random_team(3, rng, one_way=0.0)
    path = tmp_path / "team.yaml"
    save_rig(scene.rig, path)
    recs = team_camera_records(scene, 1.5, sigma=1.0, seed=2)
    rid = M.rig_id(path)
    log = ObservationLogWriter(tmp_path / "live" / "log.jsonl")
    with TrackOutputs(tmp_path / "live", ["r1", "r2"], "r0") as outputs:
        loc = Localizer(path, sink=outputs.write, log=log)
        msgs = [[T0 + t + LATENCY, M.observations_message(a, rid, k, T0 + t, obs), a]
                for k, (t, a, _, obs) in enumerate(recs)]
        poses = drive(loc, msgs)
    log.close()
    assert loc.reference == "r0" and loc.tracked == ["r1", "r2"]
    times = np.array([t for t, *_ in recs])

    def truth(p):
        world = recs[int(np.argmin(np.abs(times - (p.t - T0))))][2]
        return (world["r0"].inverse() @ world[p.robot]).t

    err = [np.linalg.norm(p.estimate.t - truth(p)) for _, p in poses if p.t > T0 + 0.3]
    about = [{a, *(scene.rig.owner(m) for m in obs.marker)} - {"r0"} for t, a, _, obs in recs]
    published = [set() for _ in recs]
    for _, p in poses:
        published[int(np.argmin(np.abs(times - (p.t - T0))))].add(p.robot)
    assert all(pub <= ab for pub, ab in zip(published, about))  # only robots the message is about ...
    late = [k for k, t in enumerate(times) if t > 0.3]
    assert sum(published[k] == about[k] for k in late) >= 0.95 * len(late)  # ... and all of them
    assert rms(err) < 0.05
    with TrackOutputs(tmp_path / "replay", ["r1", "r2"], "r0") as outputs:
        track_team_log(path, iter_observation_log(tmp_path / "live" / "log.jsonl"), progress=False,
                       sink=outputs.write)
    for r in ("r1", "r2"):
        for ext in ("csv", "tum"):
            name = f"trajectory_{r}.{ext}"
            assert (tmp_path / "live" / name).read_bytes() == (tmp_path / "replay" / name).read_bytes()


def test_candidates_and_unnamed_detections_are_fused_as_the_log_holds_them(setup, tmp_path):
    """Several candidates for one marker: the best-scored one is fused and
    logged (the log's form holds one per marker); a detection without a name
    beside named ones is left out (the filter needs names, the log cannot
    mix them) -- so the replay fuses exactly what the localizer fused."""
    T = M.ros_types()
    msg = M.observations_message("p", setup.rid, 1, T0, None)
    msg.observations = [T.Observation("M1", 100.0, 200.0, 0.4), T.Observation("M1", 130.0, 200.0, 0.9),
                        T.Observation("", 300.0, 100.0, 1.0), T.Observation("M2", 400.0, 210.0, 1.0)]
    log = ObservationLogWriter(tmp_path / "log.jsonl")
    loc = Localizer(setup.path, log=log)
    assert loc.receive(msg, T0 + 0.01, "p") == "held"
    loc.finish()
    log.close()
    ((t, obs),) = list(iter_observation_log(tmp_path / "log.jsonl"))
    assert t == M.stamp_of(msg.header) and obs.marker == ("M1", "M2")
    assert obs.uv.tolist() == [[130.0, 200.0], [400.0, 210.0]]


# -- a node stops, both stop, both come back ------------------------------------------------------


def test_a_robot_that_stops_is_warn_then_stale_while_the_other_goes_on(setup):
    """q's messages stop at 3.5 s: q is WARN after 0.5 s and STALE after
    max-coast (1 s) -- within 1.5 s -- while p's messages go on.  p's camera
    alone sees two of q's markers: two distinct observations tie p to q, not
    the three that fix a pose, so p is coasted on them (``partial``, its
    sigma growing) only while q's last observations are within max-coast;
    then p's pose is no longer published and its diagnostics say why
    (STALE, "tied by 2 distinct observation(s)")."""
    stop = READY + 0.5
    msgs = messages(setup, until=stop) + messages(setup, since=stop, until=stop + 1.5, robots=("p",))
    loc = Localizer(setup.path)
    poses = drive(loc, msgs)
    q_last = T0 + max(t for t, c in zip(setup.recs.times, setup.recs.cameras) if "q" in c and t < stop)
    levels = {dt: {s.robot: s.level for s in loc.diagnostics(q_last + dt)} for dt in (0.3, 0.7, 1.2, 1.49)}
    assert levels[0.3]["q"] == M.OK and levels[0.7]["q"] == M.WARN
    assert levels[1.2]["q"] == M.STALE and levels[1.49]["q"] == M.STALE
    stale = {s.robot: s for s in loc.diagnostics(q_last + 1.2)}["q"]
    assert stale.message.startswith("dropped") and stale.values["received"] == sum(m[2] == "q" for m in msgs)
    after = [p for _, p in poses if p.t > q_last]
    assert len(after) >= 25 and all(str(p.status) == "partial" for p in after)
    assert max(p.t for p in after) <= q_last + loc.max_coast  # none published once nothing ties p for max-coast
    p_sent = sum(m[2] == "p" and M.stamp_of(m[1].header) > q_last + loc.max_coast for m in msgs)
    assert p_sent >= 10 and loc.counts["p"].untied == p_sent  # p's records went on: not published, counted
    p_end = {s.robot: s for s in loc.diagnostics(T0 + stop + 1.5)}["p"]
    assert p_end.level == M.STALE and "tied by 2 distinct observation(s)" in p_end.message
    assert p_end.values["ties"] == 2
    s = np.array([sigma_t(p) for p in after])
    assert s[-1] > 3 * s[0] and np.mean(np.diff(s) > 0) > 0.7
    assert rms(errors(setup, [(0, p) for p in after])) < 3 * np.mean(s)  # honest about its growing sigma


def test_both_stop_then_come_back(setup):
    """Both nodes stop at 2.5 s: no pose is published more than max-coast
    + 0.5 s later (none at all: nothing is fused), both are STALE; they
    come back at 4 s: poses again within 1 s of their first observations."""
    loc = Localizer(setup.path)
    poses = drive(loc, messages(setup, until=2.5), finish=False)
    stop, back = T0 + 2.5, T0 + 4.0
    poses += [(t, p) for t in np.arange(stop, back, 0.01) for p in loc.poll(t)]  # the loop wakes, nothing comes
    assert {s.robot: s.level for s in loc.diagnostics(back - 0.01)} == {"p": M.STALE, "q": M.STALE}
    poses += drive(loc, messages(setup, since=4.0, until=5.5))
    assert not [t for t, _ in poses if stop + 1.0 + 0.5 < t < back]
    first = min(p.t for t, p in poses if p.t >= back)
    assert first - back < 1.0
    assert rms(errors(setup, [(t, p) for t, p in poses if p.t > first + 0.5])) < 0.03


def test_a_coasting_track_is_published_only_within_max_coast(setup):
    """From 3.5 s both nodes see nothing (their messages go on, empty): the
    track coasts, ``predicted`` poses are published for max-coast seconds,
    then none -- a stale pose is never published as current; p's
    diagnostics say why (nothing ties it), q's that its node is alive."""
    blind = READY + 0.5
    msgs = messages(setup, until=blind)
    for now, msg, c in messages(setup, since=blind, until=blind + 2.0):
        msg.observations = []
        msgs.append([now, msg, c])
    loc = Localizer(setup.path, max_coast=0.5)
    poses = [p for _, p in drive(loc, msgs)]
    last_measured = max(p.t for p in poses if str(p.status) != "predicted")
    coasted = [p for p in poses if str(p.status) == "predicted"]
    assert coasted and max(p.t for p in coasted) <= last_measured + 0.5
    assert max(p.t for p in coasted) > last_measured + 0.4  # (it did coast, up to the limit)
    assert not [p for p in poses if p.t > last_measured + 0.5]
    diag = {s.robot: s for s in loc.diagnostics(T0 + blind + 2.0)}
    assert diag["q"].level == M.OK and diag["p"].level == M.STALE
    assert "tied by 0 distinct observation(s)" in diag["p"].message


# -- abuse ------------------------------------------------------------------------------------------


def _malformed(setup, rng, n_fuzz=500, n_bad=500):
    """``(kind, object or bytes)``: fuzzed bytes of a message (of another
    rig, so that nothing fuzzed can pass for one of ours), and messages a
    node of this rig would never send."""
    obs = ObservationSet.from_dict({"p": {"M1": [612.25, 281.5], "M2": [701.0, 280.4]}})
    template = bytes(M.observations_message("p", "ffffffffffffffff", 7, T0 + 1.0, obs).serialize())
    out = []
    for _ in range(n_fuzz):
        b = bytearray(template)
        how = rng.integers(3)
        if how == 0:
            for k in rng.integers(4, len(b), size=rng.integers(1, 6)):
                b[k] = rng.integers(256)
        elif how == 1:
            b = b[:rng.integers(0, len(b))]
        else:
            b = bytearray(rng.integers(0, 256, rng.integers(1, 200), dtype=np.uint8).tobytes())
        out.append(("bytes", bytes(b)))

    def bad(k):
        m = M.observations_message("p", setup.rid, 10**6 + k, T0 + 1.0, obs)
        kind = k % 10
        if kind == 0:
            m.observations[0].u = float("nan")
        elif kind == 1:
            m.robot = "x"
        elif kind == 2:
            m.header.frame_id = "q"
        elif kind == 3:
            m.header.stamp.nanosec = 2_000_000_000
        elif kind == 4:
            m.observations[1].marker = "M9"  # not in the rig
        elif kind == 5:
            m.observations[1].marker = "M3"  # p's own marker
        elif kind == 6:
            m.observations[0].u = 1e7  # far outside the image
        elif kind == 7:
            m.observations = [None]
        elif kind == 8:
            return None
        else:
            m.robot = "q"  # q's name on p's topic
        return m

    out += [("object", bad(k)) for k in range(n_bad)]
    return out


def test_malformed_and_foreign_messages_are_counted_and_change_nothing(setup):
    """1,000 malformed messages (500 fuzzed byte strings, 500 messages no
    node of the rig sends) and 100 of another rig, interleaved with the
    nodes' messages: every one refused and counted, the poses exactly those
    of the clean run."""
    clean = drive(Localizer(setup.path), messages(setup, until=2.0))
    rng = np.random.default_rng(0)
    garbage = _malformed(setup, rng)
    foreign = messages(setup, until=2.0, rid="0123456789abcdef")[::2][:100]
    msgs = messages(setup, until=2.0)
    loc = Localizer(setup.path)
    T = M.ros_types()
    poses, k = [], 0
    for i, (now, msg, topic) in enumerate(msgs):
        for kind, junk in garbage[k:k + 10]:
            if kind == "bytes":
                try:
                    junk = T.Observations.deserialize(junk)
                except Exception:  # what dds.Reader counts as malformed
                    loc.malformed("p")
                    continue
            loc.receive(junk, now - 1e-4, "p")
        k += 10
        if i < len(foreign):
            loc.receive(foreign[i][1], now - 1e-4, foreign[i][2])
        poses += loc.feed(msg, now, topic)
    poses += loc.finish()
    assert k >= len(garbage)
    p, q = loc.counts["p"], loc.counts["q"]
    assert p.refused + q.refused + loc.unattributed == len(garbage) + len(foreign)
    assert p.refused_rig_id + q.refused_rig_id >= len(foreign) and p.refused_malformed >= 500
    assert loc.records == len(msgs) and p.dropped_late == q.dropped_late == 0
    got = [(x.t, str(x.status), x.estimate.t.tolist()) for x in poses]
    assert got == [(x.t, str(x.status), x.estimate.t.tolist()) for _, x in clean]
    diag = {s.robot: s.values for s in loc.diagnostics(T0 + 2.0)}
    assert diag["p"]["refused"] == p.refused and diag["p"]["refused_malformed"] == p.refused_malformed


def test_duplicates_are_counted_and_ignored(setup):
    msgs = messages(setup, until=2.0)
    clean = drive(Localizer(setup.path), msgs)
    loc = Localizer(setup.path)
    dup = [[now + 0.002, type(m).deserialize(m.serialize()), c] for now, m, c in messages(setup, until=2.0)]
    poses = drive(loc, messages(setup, until=2.0) + dup)
    assert loc.counts["p"].duplicates + loc.counts["q"].duplicates == len(msgs)
    assert [(x.t, x.estimate.t.tolist()) for _, x in poses] == [(x.t, x.estimate.t.tolist()) for _, x in clean]


def backlog(setup, since, until):
    """The messages captured in [since, until), all received (a backlog the localizer has not polled)."""
    msgs = messages(setup, since=since, until=until)
    return sorted(msgs, key=lambda m: m[0])


def test_a_backlog_is_shed_to_each_cameras_newest_message(setup):
    """The localizer fell behind: 0.9 s of both cameras' messages waits
    when it polls 0.5 s after the last capture.  Each camera's older messages
    are shed (counted per robot, never fused, not in the log), its newest is
    fused -- the pose published is the newest capture's, close to the truth
    there -- and p's newest is not coalesced into q's newer one."""
    loc = Localizer(setup.path)
    drive(loc, messages(setup, until=READY), finish=False)  # tracking, keeping up: nothing shed
    loc.poll(T0 + READY + 0.05)  # (what is held fused, in time)
    assert loc.counts["p"].shed == loc.counts["q"].shed == 0
    late = backlog(setup, READY, READY + 0.9)  # (within max-coast of the last in time: the ties hold)
    for now, msg, topic in late:
        assert loc.receive(msg, now, topic) == "held"
    newest = {c: max(M.stamp_of(m.header) for _, m, t in late if t == c) for c in ("p", "q")}
    n = {c: sum(t == c for _, _, t in late) for c in ("p", "q")}
    fused_before = {c: loc.counts[c].fused for c in ("p", "q")}
    now = max(newest.values()) + 0.5
    poses = loc.poll(now)
    for c in ("p", "q"):
        assert loc.counts[c].shed == n[c] - 1
        assert loc.counts[c].fused - fused_before[c] == 1
    assert sorted(p.t for p in poses) == sorted(newest.values())  # one pose each: p's newest, q's newest
    # what was fused is what offline track gives on the records kept: the first READY s and the two newest
    kept = messages(setup, until=READY) + [m for m in late if M.stamp_of(m[1].header) in newest.values()]
    ref = offline(setup, kept).rows[-2:]
    assert [r.t for r in ref] == [p.t - T0 for p in sorted(poses, key=lambda p: p.t)] or \
        [r.t for r in ref] == [p.t for p in sorted(poses, key=lambda p: p.t)]
    for r, p in zip(ref, sorted(poses, key=lambda p: p.t)):
        assert np.allclose(r.estimate.t, p.estimate.t, atol=1e-9)
    assert loc.counts["p"].dropped_late == loc.counts["q"].dropped_late == 0
    assert "shed %d" % (n["p"] + n["q"] - 2) in loc.summary()


def test_shedding_waits_for_max_lag_and_reads_the_clock_per_record(setup):
    """Within ``max_lag`` of its capture a backlog is fused whole; the
    clock is read again before each record, so a message whose camera has a
    newer one waiting is shed once the fusing has taken it past ``max_lag``."""
    msgs = backlog(setup, 2.0, 2.2)
    loc = Localizer(setup.path)
    drive(loc, messages(setup, until=2.0), finish=False)
    loc.poll(T0 + 2.0 + 0.05)  # (what is held fused, in time)
    for now, msg, topic in msgs[:4]:  # p, q, p, q: a frame each, half a frame apart
        loc.receive(msg, now, topic)
    first = M.stamp_of(msgs[0][1].header)
    assert [t for _, _, t in msgs[:4]] == ["p", "q", "p", "q"]
    reads = iter([first + 0.05] + [first + 0.5] * 10)  # the first record fused in time, then the clock jumps
    loc.poll(first + 0.05, lambda: next(reads))
    assert (loc.counts["p"].shed, loc.counts["q"].shed) == (0, 1)  # q's first shed; p's first was in time
    loc2 = Localizer(setup.path)
    drive(loc2, messages(setup, until=2.0), finish=False)
    loc2.poll(T0 + 2.0 + 0.05)
    for now, msg, topic in msgs:
        loc2.receive(msg, now, topic)
    loc2.poll(M.stamp_of(msgs[0][1].header) + 0.09)  # max_lag not reached by the oldest: all fused
    assert loc2.counts["p"].shed == loc2.counts["q"].shed == 0
    assert not loc2._held or all(h.arrival + loc2.reorder > first + 0.09 for h in loc2._held)


def test_shedding_is_warn_in_the_diagnostics_for_five_seconds(setup):
    """A robot that had messages shed is WARN, "falling behind: shed N of M",
    with ``shed`` among its key-values, for 5 s after the last shed; a robot
    nothing was shed of says nothing of it."""
    loc = Localizer(setup.path)
    drive(loc, messages(setup, until=2.0), finish=False)
    loc.poll(T0 + 2.0 + 0.05)  # (what is held fused, in time)
    for now, msg, topic in backlog(setup, 2.0, 2.5):
        if topic == "p":
            loc.receive(msg, now, topic)
    now = T0 + 2.5 + 0.2
    loc.poll(now)
    diag = {s.robot: s for s in loc.diagnostics(now + 0.1)}
    p, q = loc.counts["p"], loc.counts["q"]
    assert p.shed > 0 and q.shed == 0
    assert diag["p"].level == M.WARN
    assert f"falling behind: shed {p.shed} of {p.received}" in diag["p"].message
    assert diag["p"].values["shed"] == p.shed and diag["q"].values["shed"] == 0
    assert "falling behind" not in diag["q"].message
    assert loc.level("p", now + 0.1) == M.OK  # (its last observation 0.3 s old: only the shedding makes p WARN)
    # said for 5 s after the last shed (the recording ends at 6 s: p is stale by then, for its age)
    assert "falling behind" in {s.robot: s for s in loc.diagnostics(now + 4.9)}["p"].message
    assert "falling behind" not in {s.robot: s for s in loc.diagnostics(now + 5.1)}["p"].message


def test_reordered_messages_are_fused_in_time_order_and_late_ones_dropped(setup):
    """p's messages take 25 ms, q's 2 ms: q's frame half a frame after p's
    arrives first; the reorder buffer fuses both in time order, the poses
    those of the in-order run.  Messages of p delayed by 0.2 s come after
    later records were fused: counted as dropped late, never fused."""
    clean = drive(Localizer(setup.path), messages(setup, until=2.0))
    msgs = messages(setup, until=2.0, robots=("p",), latency=0.025) + messages(setup, until=2.0, robots=("q",),
                                                                               latency=0.002)
    order = sorted(msgs, key=lambda m: m[0])
    capture = [M.stamp_of(m[1].header) for m in order]
    assert any(b < a for a, b in zip(capture, capture[1:]))  # they do arrive out of order
    loc = Localizer(setup.path)
    poses = drive(loc, msgs)
    assert loc.counts["p"].dropped_late == loc.counts["q"].dropped_late == 0
    assert [(x.t, x.estimate.t.tolist()) for _, x in poses] == [(x.t, x.estimate.t.tolist()) for _, x in clean]
    late = messages(setup, until=2.0)
    for m in late[40:60:4]:
        if m[2] == "p":
            m[0] += 0.2
    n_late = sum(m[0] - M.stamp_of(m[1].header) > 0.1 for m in late)
    loc = Localizer(setup.path)
    poses = drive(loc, late)
    assert n_late >= 2 and loc.counts["p"].dropped_late == n_late and loc.records == len(late) - n_late


def test_a_stamp_fused_twice_goes_on_tf_once(setup):
    """Synchronized cameras at 30 fps, q's messages 31 ms after p's (beyond
    the 30 ms reorder window, before p's next frame): p's message of each
    stamp is fused on its own, q's of the same stamp after it as another
    record.  Each fused message still gives a pose
    on the pose topic, but /tf gets each robot's stamps once and in
    increasing order (tf2 drops a repeated stamp with a warning)."""
    both = SimpleNamespace(**{**vars(setup), "recs": camera_records(setup.rig, duration=READY + 1.0,
                                                                  pixel_sigma=1.0, seed=5)})
    sync = messages(both)
    stamps = {}
    for _, m, c in sync:
        stamps.setdefault(M.stamp_of(m.header), set()).add(c)
    assert sum(len(v) == 2 for v in stamps.values()) >= 10  # frames of both cameras at one stamp
    late = [[now + (0.031 if c == "q" else 0.0), m, c] for now, m, c in sync]
    loc = Localizer(setup.path)
    poses = [p for _, p in drive(loc, late)]
    on_tf = [p.stamp_ns for p in poses if p.tf]
    ready = loc.rig_gate.agreed  # (no pose before the rig check's first window agreed)
    assert ready is not None and len(poses) > len(on_tf) >= 0.9 * len([t for t in stamps if t > ready])
    assert all(b > a for a, b in zip(on_tf, on_tf[1:]))
    assert set(on_tf) == {p.stamp_ns for p in poses}


def test_a_fifth_of_the_messages_lost(setup):
    """20% of the messages never arrive: the rest are fused, the errors
    those of offline track on what arrived."""
    rng = np.random.default_rng(1)
    msgs = [m for m in messages(setup, until=READY + 2.0) if rng.random() >= 0.2]
    loc = Localizer(setup.path)
    poses = drive(loc, msgs)
    held = loc.counts["p"].rig_waiting  # (before the rig check's first window agreed)
    assert loc.records == len(msgs) and len(poses) + held >= len(msgs) - 10 and len(poses) > len(msgs) / 4
    first = min(p.t for _, p in poses) - T0
    ref = [r for r in offline(setup, msgs).rows if r.estimate is not None and r.t >= first - 1e-6]
    ref_err = np.array([np.linalg.norm(r.estimate.t - truth_at(setup, r.t).t) for r in ref])
    assert rms(errors(setup, poses)) <= 1.1 * rms(ref_err) + 1e-4


def test_clock_skew(setup):
    """q's clock 0.2 s ahead: every q message is stamped in the future
    beyond --max-clock-skew and refused (counted); p goes on alone.  0.03 s
    ahead: within the skew, fused."""
    def skewed(dt):
        out = messages(setup, until=2.0, robots=("p",))
        for now, m, c in messages(setup, until=2.0, robots=("q",)):
            m.header.stamp = M.stamp(M.stamp_of(m.header) + dt)
            out.append([now, m, c])
        return out

    loc = Localizer(setup.path)
    drive(loc, skewed(0.2))
    n_q = sum(1 for t, c in zip(setup.recs.times, setup.recs.cameras) if "q" in c and t < 2.0)
    assert loc.counts["q"].refused_clock == n_q and loc.counts["q"].fused == 0 and loc.counts["p"].fused > 50
    q = {s.robot: s for s in loc.diagnostics(T0 + 2.0)}["q"]  # none taken, all refused: WARN, saying why
    assert q.level == M.WARN and f"refused {n_q} observations: stamped {0.2 - LATENCY:.3f} s in the future" \
        in q.message, q.message
    loc = Localizer(setup.path)
    drive(loc, skewed(0.03))
    assert loc.counts["q"].refused_clock == 0 and loc.counts["q"].fused == n_q


def test_bad_settings_are_one_line_errors(setup, tmp_path):
    from mutloc.errors import InputError

    with pytest.raises(InputError, match="reference"):
        Localizer(setup.path, reference="z")
    with pytest.raises(InputError, match="rig_id"):
        Localizer(setup.rig)
    with pytest.raises(InputError, match="max_clock_skew"):
        Localizer(setup.path, max_clock_skew=-1)
    assert main(["localizer", "--rig", str(tmp_path / "none.yaml"), "--loopback", "--duration", "1"]) == 2


# -- over DDS -----------------------------------------------------------------------------------------


@dataclass
class _Received:
    """Pose messages received by the subscriber below, with their arrival times."""

    poses: list = field(default_factory=list)
    diagnostics: list = field(default_factory=list)


def _own_types():
    """geometry_msgs and diagnostic_msgs written here from the ROS 2 definitions (not mutloc's)."""
    from dataclasses import dataclass as idl, field as f

    from cyclonedds.idl import IdlStruct
    from cyclonedds.idl.types import array, byte, float64, int32, sequence, uint32

    @idl
    class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
        sec: int32
        nanosec: uint32

    @idl
    class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
        stamp: Time
        frame_id: str

    @idl
    class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
        x: float64
        y: float64
        z: float64

    @idl
    class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
        x: float64
        y: float64
        z: float64
        w: float64

    @idl
    class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
        position: Point
        orientation: Quaternion

    @idl
    class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
        pose: Pose
        covariance: array[float64, 36]

    @idl
    class PoseWithCovarianceStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovarianceStamped_"):
        header: Header
        pose: PoseWithCovariance

    @idl
    class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
        key: str
        value: str

    @idl
    class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
        level: byte
        name: str
        message: str
        hardware_id: str
        values: sequence[KeyValue] = f(default_factory=list)

    @idl
    class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
        header: Header
        status: sequence[DiagnosticStatus] = f(default_factory=list)

    return PoseWithCovarianceStamped, DiagnosticArray


def _fuzzer(bus):
    """A writer on p's observation topic that puts arbitrary bytes on the wire."""
    T = M.ros_types()

    class Raw(T.Observations):
        def serialize(self, use_version_2=False, **_):
            return self.raw

    return bus.writer(M.observations_topic("p"), T.Observations), Raw


#: test_over_dds: q's node stops (s), then p's, then both come back.
Q_STOP, P_STOP, BACK = READY + 1.0, READY + 2.5, READY + 4.0


def test_over_dds(setup, tmp_path, dds_domain):
    """``mutloc localizer`` over DDS (loopback, a domain of this run): this
    process publishes both robots' observations in real time, garbage and
    another rig's messages on p's topic, and reads the poses and
    diagnostics with its own type definitions.  >= 90% of the expected
    poses arrive (after the rig check's first window), near the truth; q stopped: WARN then STALE within 1.5 s,
    p partial; both stopped: no pose after max-coast + 0.5 s; both back:
    poses within 1 s; Ctrl-C: exit 130, the files named, and replaying the
    received log with track gives the trajectory file it wrote."""
    from cyclonedds.core import Policy, Qos
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from mutloc.live.dds import Bus

    domain = dds_domain
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "mutloc", "localizer", "--rig", str(setup.path), "--domain", str(domain),
           "--loopback", "--out", str(out), "--duration", "60"]
    # Ctrl-C's SIGINT reaches the child also when this test runs as a background job (which ignores SIGINT)
    child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    got = _Received()
    try:
        line = child.stderr.readline()  # the localizer says it is up
        assert line.startswith("localizer: rig_id"), line + child.stderr.read()
        bus = Bus(domain, loopback=True)
        PoseMsg, DiagMsg = _own_types()
        qos = Qos(Policy.Reliability.Reliable(max_blocking_time=100_000_000), Policy.Durability.Volatile,
                  Policy.History.KeepLast(100))
        pose_reader = DataReader(bus.participant, Topic(bus.participant, "rt/mutloc/p_in_q", PoseMsg), qos=qos)
        diag_reader = DataReader(bus.participant, Topic(bus.participant, "rt/diagnostics", DiagMsg), qos=qos)
        T = M.ros_types()
        writers = {r: bus.writer(M.observations_topic(r), T.Observations) for r in ("p", "q")}
        fuzz, Raw = _fuzzer(bus)
        deadline = time.time() + 10
        while time.time() < deadline and not (pose_reader.get_matched_publications()
                                               and all(w.get_matched_subscriptions() for w in writers.values())):
            time.sleep(0.05)
        assert all(w.get_matched_subscriptions() for w in writers.values()), "no discovery"

        def take():
            now = time.time()
            got.poses += [(now, s) for s in pose_reader.take(N=100) if hasattr(s, "header")]
            got.diagnostics += [(now, s) for s in diag_reader.take(N=100) if hasattr(s, "header")]

        start = time.time() + 0.2
        rng = np.random.default_rng(3)
        junk = [b for kind, b in _malformed(setup, rng, n_fuzz=300, n_bad=0)]
        sent_junk = foreign = 0
        frames = {"p": 0, "q": 0}
        plan = []  # (time offset, robot, record index): p and q until 4 s, p alone until 5.5 s, both from 7 s
        for i, (t, cams) in enumerate(zip(setup.recs.times, setup.recs.cameras)):
            for c in cams:
                frames[c] += 1
                if t < Q_STOP or (t < P_STOP and c == "p") or BACK <= t < BACK + 0.5:
                    plan.append((t, c, frames[c], i))
        for t, c, frame, i in plan:
            while time.time() < start + t:
                take()
                time.sleep(0.002)
            obs = setup.recs.frames[i]
            writers[c].write(M.observations_message(c, setup.rid, frame, start + t, obs))
            if t < 2.0 and c == "p":  # garbage and another rig's messages, between the nodes' own
                for b in junk[sent_junk:sent_junk + 5]:
                    raw = Raw()
                    raw.raw = b
                    try:
                        fuzz.write(raw)
                    except Exception:  # bytes DDS itself refuses to send
                        pass
                sent_junk += 5
                fuzz.write(M.observations_message("p", "0123456789abcdef", 10**6 + frame, start + t, obs))
                foreign += 1
        end = time.time()
        while time.time() < end + 0.6:
            take()
            time.sleep(0.01)
        child.send_signal(signal.SIGINT)
        stdout, stderr = child.communicate(timeout=30)
        take()
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
            child.wait()
    assert child.returncode == 130, stderr
    assert stderr.strip().splitlines()[-1].startswith("interrupted:") and "log.jsonl" in stderr
    # >= 90% of the expected poses (one per message after the start), near the truth
    stamps = [(a, M.stamp_of(s.header) - start, s) for a, s in got.poses]
    # (p's messages while nothing has tied it for max-coast are not published: q's last before P_STOP + 1 s)
    q_last = max(t for t, c, *_ in plan if c == "q" and t < P_STOP)
    due = [t for t, *_ in plan if t > 0.2 and not q_last + 1.0 < t < P_STOP]
    expected = len(due)
    have = {round(t, 4) for _, t, _ in stamps}
    missing = [round(t, 3) for t in due if round(t, 4) not in have]
    # (a loaded machine makes the localizer shed messages, counted in its summary: no pose for those; nor for
    # those fused before the rig check's first window agreed, counted too)
    shed = int(re.findall(r"records fused; \d+ poses published;.*?, shed (\d+)", stderr)[-1])
    held = int(re.findall(r"poses not published: (\d+) waiting for the rig check", stderr)[-1])
    assert held > 0 and min(t for _, t, _ in stamps) > 1.0  # (none from the first second: the rig not tested yet)
    assert sum(1 for _, t, _ in stamps if t > 0.2) >= 0.9 * (expected - shed - held), (missing, shed, held, stderr)
    err = [np.linalg.norm(np.array([s.pose.pose.position.x, s.pose.pose.position.y, s.pose.pose.position.z])
                          - truth_at(setup, T0 + t).t) for _, t, s in stamps if t < Q_STOP]
    assert rms(err) < 0.03
    # q stopped after Q_STOP: WARN then STALE within 1.5 s, p's poses partial with growing sigma
    q_level = [(a - start, {x.hardware_id: x for x in d.status}) for a, d in got.diagnostics]
    warn = [a for a, st in q_level if st["q"].level == M.WARN and Q_STOP < a]
    stale = [a for a, st in q_level if st["q"].level == M.STALE and Q_STOP < a < BACK]
    assert warn and stale and min(warn) < min(stale) < Q_STOP + 1.5
    # p, its two markers seen by p's camera alone: partial, then not published once q's last observations
    # are max-coast (1 s) old, its diagnostics saying so
    p_status = [st["p"] for a, st in q_level if Q_STOP + 0.2 < a < Q_STOP + 0.8]
    assert p_status and all(dict((kv.key, kv.value) for kv in s.values)["status"] == "partial" for s in p_status)
    p_dropped = [st["p"] for a, st in q_level if Q_STOP + 1.1 < a < P_STOP + 0.4]
    assert p_dropped and all(s.level == M.STALE and "tied by 2 distinct" in s.message for s in p_dropped)
    assert not [t for _, t, _ in stamps if Q_STOP + 1.0 < t < P_STOP]
    sig = [(t, math.sqrt(sum(s.pose.covariance[k * 7] for k in range(3)))) for _, t, s in stamps
           if Q_STOP < t < Q_STOP + 1.0]
    assert sig[-1][1] > 2 * sig[0][1]
    # both stopped after P_STOP: no pose published after max-coast + 0.5 s; back at BACK: poses within 1 s
    assert not [a for a, t, _ in stamps if start + P_STOP + 1.5 < a < start + BACK]
    assert min(t for _, t, _ in stamps if t >= BACK) < BACK + 1.0
    # garbage and the other rig: counted in the diagnostics, the localizer stayed up throughout
    last = {x.hardware_id: dict((kv.key, kv.value) for kv in x.values) for x in got.diagnostics[-1][1].status}
    assert int(last["p"]["refused"]) >= foreign and int(last["p"]["refused_rig_id"]) >= 0.9 * foreign
    # the replay of the received log gives the trajectory it wrote
    assert main(["track", "--rig", str(setup.path), "--observations", str(out / "log.jsonl"), "--out",
                 str(tmp_path / "replay"), "--no-progress"]) == 0
    assert (out / "trajectory.csv").read_bytes() == (tmp_path / "replay" / "trajectory.csv").read_bytes()


def test_a_reader_takes_in_bulk_and_counts_each_undecodable_sample(setup, dds_domain):
    """dds.Reader takes every waiting sample in one call: each undecodable
    one is counted once and skipped, every valid one is returned, in order."""
    from mutloc.live.dds import Bus

    T = M.ros_types()
    bus = Bus(dds_domain, loopback=True)
    try:
        reader = bus.reader(M.observations_topic("p"), T.Observations, depth=100)
        writer, Raw = _fuzzer(bus)
        deadline = time.time() + 10
        while time.time() < deadline and not writer.get_matched_subscriptions():
            time.sleep(0.02)
        obs = ObservationSet.from_dict({"p": {"M1": [612.25, 281.5], "M2": [701.0, 280.4]}})
        valid = [M.observations_message("p", setup.rid, k, T0 + k / 30, obs) for k in range(30)]
        # well-formed CDR (Cyclone's C layer refuses bytes that are not) whose marker name is not UTF-8
        odd = ObservationSet.from_dict({"p": {"ZZ": [1.0, 2.0]}})
        junk = [bytes(M.observations_message("p", setup.rid, 100 + k, T0, odd).serialize()).replace(
            b"ZZ\0", bytes([0xC0 + k % 32, 0xFF, 0])) for k in range(20)]
        for b in junk:
            with pytest.raises(M.MessageError, match="utf-8"):
                M.observations_from_cdr(b)
        sent = []
        for k, msg in enumerate(valid):
            writer.write(msg)
            sent.append(msg)
            if k < len(junk):
                raw = Raw()
                raw.raw = junk[k]
                writer.write(raw)
        got, deadline = [], time.time() + 10
        while time.time() < deadline and len(got) + reader.malformed < len(valid) + len(junk):
            got += reader.take(limit=1000)
            time.sleep(0.02)
        assert reader.malformed == len(junk)
        assert got == sent
    finally:
        bus.close()


#: A ROS 2 subscriber at its most stalled: subscribed to p's pose and /tf with ROS 2's
#: default QoS (reliable, keep-last 10), matched, then stopped (SIGSTOP): it never acknowledges a sample.
STALLED_SUBSCRIBER = """
import os, signal, sys, time
from mutloc.live import messages as M
from mutloc.live.dds import Bus
T = M.ros_types()
bus = Bus(int(sys.argv[1]), loopback=True)
readers = [bus.reader("/mutloc/p_in_q", T.PoseWithCovarianceStamped), bus.reader("/tf", T.TFMessage)]
while not all(r.native.get_matched_publications() for r in readers):
    time.sleep(0.02)
print("matched", flush=True)
os.kill(os.getpid(), signal.SIGSTOP)
"""


def test_a_stalled_subscriber_does_not_hold_the_poses_back(setup, dds_domain):
    """With a subscriber process that matched the localizer's writers and
    then stopped, another subscriber still receives >= 90% of the poses the
    localizer published (a reliable keep-last writer does not wait for its
    slowest reader), and none of its writes failed.

    What the localizer published is its own count (``poses_published`` in
    ``/diagnostics``, read once every message sent is accounted for: fused,
    shed, late, duplicate or refused), not the messages sent: on a loaded
    machine this process and the localizer are descheduled now and then, the
    messages then arrive in bursts more than ``--max-lag`` behind their
    capture and the localizer sheds some (as it should: counted, tested in
    test_live_shedding.py) -- fewer poses, none of them held back by the
    stalled reader.  Every wait is for an event, with a generous timeout."""
    import select

    from cyclonedds.core import Policy

    from mutloc.live.dds import WRITE_MAX_BLOCKING, Bus

    domain = dds_domain
    cmd = [sys.executable, "-m", "mutloc", "localizer", "--rig", str(setup.path), "--domain", str(domain),
           "--loopback", "--duration", "300"]
    child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    stalled = None
    bus = None
    try:
        line = child.stderr.readline()
        assert line.startswith("localizer: rig_id"), line + child.stderr.read()
        stalled = subprocess.Popen([sys.executable, "-c", STALLED_SUBSCRIBER, str(domain)], stdout=subprocess.PIPE,
                                   text=True, start_new_session=True)
        assert select.select([stalled.stdout], [], [], 60)[0] and stalled.stdout.readline().strip() == "matched"
        T = M.ros_types()
        bus = Bus(domain, loopback=True)
        reader = bus.reader("/mutloc/p_in_q", T.PoseWithCovarianceStamped, depth=100)
        diagnostics = bus.reader(M.DIAGNOSTICS_TOPIC, T.DiagnosticArray, depth=100)
        writers = {r: bus.writer(M.observations_topic(r), T.Observations) for r in ("p", "q")}
        deadline = time.monotonic() + 60
        while not (reader.native.get_matched_publications()
                   and all(w.get_matched_subscriptions() for w in writers.values())):
            assert time.monotonic() < deadline, "the localizer and this process did not match in 60 s"
            time.sleep(0.02)
        assert Path(f"/proc/{stalled.pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "T"  # stopped
        # the pose writer as discovered: ROS 2's default QoS (what ROS 2 subscriptions match); keep-last:
        # Cyclone DDS never makes it wait for acknowledgements, and its write blocks 10 ms at most
        qos = reader.native.get_matched_publication_data(reader.native.get_matched_publications()[0]).qos
        assert qos[Policy.History] == Policy.History.KeepLast(10)
        assert qos[Policy.Durability] == Policy.Durability.Volatile
        assert isinstance(qos[Policy.Reliability], Policy.Reliability.Reliable)
        assert qos[Policy.Reliability].max_blocking_time <= WRITE_MAX_BLOCKING
        got: list = []
        start = time.time() + 0.2
        frames, sent = {"p": 0, "q": 0}, []
        for t, obs, cams in zip(setup.recs.times, setup.recs.frames, setup.recs.cameras):
            if t >= READY + 4.5:
                break
            for c in cams:
                frames[c] += 1
                while time.time() < start + t:
                    got += reader.take()
                    time.sleep(0.002)
                writers[c].write(M.observations_message(c, setup.rid, frames[c], start + t, obs))
                sent.append(t)

        def accounted(st):  # every message sent received and fused, shed, late, duplicate or refused
            kv = {v.key: int(v.value) for v in st.values if v.key in _ACCOUNTS}
            return kv["received"] == frames[st.hardware_id] and kv["received"] == sum(
                kv[k] for k in _ACCOUNTS if k != "received")

        final, deadline = None, time.monotonic() + 120
        while final is None:
            assert time.monotonic() < deadline and child.poll() is None, "messages not accounted for in 120 s"
            got += reader.take()
            for d in diagnostics.take():
                if len(d.status) == 2 and all(accounted(s) for s in d.status):
                    final = {s.hardware_id: {v.key: v.value for v in s.values} for s in d.status}
            time.sleep(0.01)
        published = int(final["p"]["poses_published"])
        # the poses published, as they come (until all are here, or none came for 5 s)
        last_new = time.monotonic()
        while len({M.stamp_of(s.header) for s in got}) < published and time.monotonic() < last_new + 5.0:
            new = reader.take()
            if new:
                got += new
                last_new = time.monotonic()
            time.sleep(0.01)
        assert Path(f"/proc/{stalled.pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "T"  # stalled throughout
    finally:
        for proc in (stalled, child):
            if proc is not None and proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        if bus is not None:
            bus.close()
    assert final["p"]["poses_unsent"] == "0" and final["q"]["poses_unsent"] == "0", final
    have = {round(M.stamp_of(s.header) - start, 4) for s in got}
    assert published >= 10 and len(have) <= published, (len(have), final)
    assert len(have) >= 0.9 * published, (len(have), len(sent), final)


#: The diagnostics key-values that account for every message a robot's topic brought.
_ACCOUNTS = ("received", "fused", "shed", "dropped_late", "duplicates", "refused")


def test_sigterm_ends_the_localizer_as_ctrl_c_does(setup, tmp_path, dds_domain):
    """SIGTERM (systemd, ``docker stop``) to ``mutloc localizer --out DIR``
    started as a background job would be (SIGINT ignored): it finishes as on
    Ctrl-C -- exit 130, the summary naming its files, every observation
    received in DIR/log.jsonl and the trajectory of all of them written (the
    track of that log gives the same file)."""
    from mutloc.live.dds import Bus

    domain = dds_domain
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "mutloc", "localizer", "--rig", str(setup.path), "--domain", str(domain),
           "--loopback", "--out", str(out), "--duration", "120"]
    child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    bus = None
    sent = 0
    try:
        line = child.stderr.readline()  # the localizer says it is up
        assert line.startswith("localizer: rig_id"), line + child.stderr.read()
        bus = Bus(domain, loopback=True)
        T = M.ros_types()
        writers = {r: bus.writer(M.observations_topic(r), T.Observations) for r in ("p", "q")}
        deadline = time.monotonic() + 30
        while not all(w.get_matched_subscriptions() for w in writers.values()):
            assert time.monotonic() < deadline, "no discovery"
            time.sleep(0.05)
        start = time.time() + 0.2
        frames = {"p": 0, "q": 0}
        for t, obs, cams in zip(setup.recs.times, setup.recs.frames, setup.recs.cameras):
            if t >= 1.5:
                break
            for c in cams:
                frames[c] += 1
                while time.time() < start + t:
                    time.sleep(0.002)
                writers[c].write(M.observations_message(c, setup.rid, frames[c], start + t, obs))
                sent += 1
                last_stamp = start + t
        log = out / "log.jsonl"
        deadline = time.monotonic() + 60  # the last message logged as received: then stopped

        def logged_last():
            lines = log.read_text().splitlines() if log.exists() else []
            return bool(lines) and lines[-1].endswith("}") and json.loads(lines[-1])["time"] >= last_stamp - 0.01

        while not logged_last():
            assert child.poll() is None and time.monotonic() < deadline, child.stderr.read()
            time.sleep(0.05)
        os.killpg(child.pid, signal.SIGTERM)
        _, stderr = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
            child.wait()
        if bus is not None:
            bus.close()
    assert child.returncode == 130, stderr
    last = stderr.strip().splitlines()[-1]
    assert last.startswith("interrupted:") and "Traceback" not in stderr, stderr
    assert str(out / "log.jsonl") in last and str(out / "trajectory.csv") in last, stderr
    records = list(iter_observation_log(out / "log.jsonl"))
    assert records[-1][0] == pytest.approx(last_stamp, abs=0.01) and len(records) > 20
    rows = read_trajectory_csv(out / "trajectory.csv")
    assert len(rows) == len(records) > 20  # the last records too: the smoother's window flushed at the end
    assert main(["track", "--rig", str(setup.path), "--observations", str(out / "log.jsonl"), "--out",
                 str(tmp_path / "replay"), "--no-progress"]) == 0
    assert (out / "trajectory.csv").read_bytes() == (tmp_path / "replay" / "trajectory.csv").read_bytes()
