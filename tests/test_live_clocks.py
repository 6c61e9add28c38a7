"""The localizer's ``--clock-offsets estimate`` (SPEC "The robots' own motion and clocks"), against the
simulator's truth: a two-robot team (r0 the reference) whose r1 stamps its observations on a clock that is
off (``clock_offset``, truth.json's ``clock_offsets``: what is added to r1's stamps to put them on r0's).

The :class:`~mutloc.live.localizer.Localizer` is fed the messages the nodes would publish, without DDS,
each arriving 8 ms after its true capture time; the clock offsets' work is done after every message (as
the wire loop does it in its slack).  One test runs :func:`~mutloc.live.localizer.run_localizer` over DDS
(loopback, a domain of its own) for ``DIR/clock_offsets.json``."""

import json
import math

import numpy as np
import pytest

from mutloc.api import load_rig
from mutloc.live import messages as M
from mutloc.live.localizer import Localizer
from mutloc.sim.scenario import write_team_simulation
from mutloc.sim.truth_log import truth_log
from mutloc.track.clocks import clock_offsets_json
from mutloc.track.frames import expanded_rig

T0 = 1_800_000_000.0  # the reference's wall clock at the simulation's time 0
LATENCY = 0.008
#: a window evaluated every 1.5 s of stamps (default: 2 s every 10), a coarser first search (+-0.15 s)
SETTINGS = {"window": 1.5, "period": 1.5, "search": 0.15, "grid": 7}


@pytest.fixture(scope="module")
def moving(tmp_path_factory):
    """The rig file and truth of two robots driving at 0.7 m/s (r1's clock offset set per test)."""
    out = tmp_path_factory.mktemp("moving")
    write_team_simulation(out, robots=2, frames=120, fps=30.0, seed=1, images=False, room=False, speed=0.7,
                          clock_offset={"r1": 0.04})
    return out / "rig.yaml", json.loads((out / "truth.json").read_text())


def _offset(truth, offset):
    """The same scene with r1's clock ``offset`` s off (its stamps the true times minus it)."""
    return {**truth, "clock_offsets": {"r1": offset}}


def _messages(rig_path, truth):
    """``(arrival, message, robot)`` per robot and frame, stamped on the robot's clock, in arrival order."""
    rid, rig = M.rig_id(rig_path), expanded_rig(load_rig(rig_path))
    offsets = truth.get("clock_offsets", {})
    out, frames = [], {}
    for t, obs in truth_log(truth, seed=1):
        for robot in dict.fromkeys(rig.observer(o)[0] for o in obs.observer):
            frames[robot] = frames.get(robot, 0) + 1
            true_time = t + offsets.get(robot, 0.0)
            out.append((T0 + true_time + LATENCY, M.observations_message(robot, rid, frames[robot], T0 + t, obs),
                        robot))
    return sorted(out, key=lambda m: m[0])


class _Log:
    """What the localizer fused: ``(time, observer robots)`` per record."""

    def __init__(self):
        self.records = []

    def write(self, t, obs):
        self.records.append((t, {o for o in obs.observer}))


def _drive(loc, msgs):
    for now, msg, robot in msgs:
        while loc.next_due() is not None and loc.next_due() <= now:
            loc.poll(loc.next_due())
        loc.feed(msg, now, robot)
        loc.clock_work(lambda: 0.0, math.inf)  # (the window's work at once: the wire loop does it in slack)
    loc.finish()


def _nearest_true_time(truth, t):
    ts = T0 + np.array([f["timestamp"] for f in truth["frames"]])
    return float(np.min(np.abs(ts - t)))


def test_a_40_ms_offset_is_estimated_and_every_later_stamp_corrected(moving):
    rig_path, truth = moving[0], _offset(moving[1], 0.04)
    log = _Log()
    loc = Localizer(rig_path, clock_offsets=SETTINGS, log=log, reference="r0")
    msgs = _messages(rig_path, truth)
    _drive(loc, msgs)
    c = loc.clocks.estimate("r1")
    assert c.offset_s is not None, c.reason
    assert abs(c.offset_s - 0.04) < 0.005, c
    assert 0 < c.sigma_s < 0.02 and abs(c.offset_s - 0.04) < 3 * c.sigma_s, c
    # the diagnostics say it, in seconds
    values = {s.robot: s.values for s in loc.diagnostics(T0 + 6.0)}
    assert float(values["r1"]["clock_offset_s"]) == pytest.approx(c.offset_s, abs=1e-6)
    assert float(values["r1"]["clock_offset_sigma_s"]) == pytest.approx(c.sigma_s, abs=1e-6)
    assert values["r0"]["clock_offset_s"] == "0"
    # the records with r1's observations fused after the first estimate are at their true capture times
    # (within 2 ms; 40 ms off is 6.7 ms from the nearest frame at 30 fps), as are r0's all along
    r1 = [t for t, obs in log.records if "r1" in obs]
    assert max(_nearest_true_time(truth, t) for t in r1[-40:]) < 0.002
    assert max(_nearest_true_time(truth, t) for t, obs in log.records if "r0" in obs) < 0.002
    # uncorrected, r1's messages come 40 ms "before" r0's of the same instant and so after records fused
    # later than them: most are dropped as late; corrected, most are fused
    plain = Localizer(rig_path, reference="r0")
    _drive(plain, msgs)
    assert loc.counts["r1"].fused > 2 * plain.counts["r1"].fused, (loc.counts["r1"], plain.counts["r1"])
    assert max(_nearest_true_time(truth, t) for t in r1[:3]) > 0.005  # (before the estimate: as sent)
    assert "clock offsets: r1 +" in loc.summary()


def test_robots_that_barely_move_leave_the_offset_undetermined_and_the_stamps_as_sent(tmp_path):
    write_team_simulation(tmp_path, robots=2, frames=120, fps=30.0, seed=1, images=False, room=False, speed=0.002,
                          turn_rate=0.01, clock_offset={"r1": 0.04})
    rig_path, truth = tmp_path / "rig.yaml", json.loads((tmp_path / "truth.json").read_text())
    log = _Log()
    loc = Localizer(rig_path, clock_offsets=SETTINGS, log=log, reference="r0")
    _drive(loc, _messages(rig_path, truth))
    assert loc.clocks.estimator.evaluated >= 2
    c = loc.clocks.estimate("r1")
    assert c.offset_s is None and c.sigma_s is None and c.reason, c
    values = {s.robot: s.values for s in loc.diagnostics(T0 + 4.0)}["r1"]
    assert values["clock_offset_s"] == "none" and values["clock_offset_sigma_s"] == "none"
    assert values["clock_offset_status"].startswith("cannot be determined yet (")
    r1 = [t for t, obs in log.records if "r1" in obs]
    assert min(_nearest_true_time(truth, t) for t in r1) > 0.039  # never shifted
    assert json.loads(json.dumps(clock_offsets_json(loc.clocks.estimator.estimates()))) == {
        "r1": {"offset_s": None, "sigma_s": None, "reason": c.reason}}


def test_max_clock_skew_is_judged_on_the_corrected_stamps(moving):
    """r1's clock 80 ms ahead: its messages arrive stamped 72 ms in the future (beyond the 50 ms allowed)
    and are refused -- until its offset is estimated (from the refused messages too); then taken."""
    rig_path, truth = moving[0], _offset(moving[1], -0.08)
    msgs = _messages(rig_path, truth)
    plain = Localizer(rig_path, reference="r0")
    _drive(plain, msgs)
    assert plain.counts["r1"].fused == 0 and plain.counts["r1"].refused_clock > 100
    loc = Localizer(rig_path, clock_offsets=SETTINGS, reference="r0")
    _drive(loc, msgs)
    c = loc.clocks.estimate("r1")
    assert c.offset_s is not None and abs(c.offset_s + 0.08) < 0.005, c
    assert loc.counts["r1"].fused > 60, loc.counts["r1"]
    assert loc.counts["r1"].refused_clock < plain.counts["r1"].refused_clock * 0.6


def test_the_localizer_over_dds_writes_clock_offsets_json(moving, tmp_path, dds_domain):
    """run_localizer with --out and --clock-offsets estimate: DIR/clock_offsets.json as track writes it
    (no robot heard: every offset undetermined, and said so)."""
    pytest.importorskip("cyclonedds", reason="the live extra (cyclonedds) is part of make test's install")
    from mutloc.live.localizer import run_localizer

    rig_path = moving[0]
    out = tmp_path / "out"
    run = run_localizer(rig_path, reference="r0", domain=dds_domain, out=out, loopback=True, duration=0.3,
                        clock_offsets=True)
    got = json.loads((out / "clock_offsets.json").read_text())
    assert got == {"r1": {"offset_s": None, "sigma_s": None, "reason": "no window evaluated yet"}}
    assert str(out / "clock_offsets.json") in run.summary()
