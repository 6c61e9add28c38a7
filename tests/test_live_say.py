"""The localizer says what is wrong (issue 38, "Say what is wrong"): messages
it refuses make their robot WARN in ``/diagnostics`` with the counts and why,
and a line on stderr once per cause (then rate-limited); another localizer
publishing on the same domain is detected and named.  Messages from simulated
free-running cameras (mutloc.sim.tracking.camera_records); over DDS on
loopback, each test on its own domain (the ``dds_domain`` fixture)."""

import os
import re
import select
import signal
import subprocess
import sys
import time
from types import SimpleNamespace

import pytest

from mutloc.io import save_rig
from mutloc.live import messages as M
from mutloc.live.localizer import NOTICE_HOLD, NOTICE_PERIOD, Localizer
from mutloc.sim.tracking import camera_records
from mutloc.sim.world import standard_rig

pytest.importorskip("cyclonedds", reason="the live extra (cyclonedds) is part of make test's install")

T0 = 1_800_000_000.0
OTHER_RIG = "0123456789abcdef"


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("say")
    rig = standard_rig()
    path = d / "rig.yaml"
    save_rig(rig, path)
    recs = camera_records(rig, duration=4.5, offsets={"q": 1 / 60}, pixel_sigma=1.0, seed=5)
    return SimpleNamespace(rig=rig, path=path, rid=M.rig_id(path), recs=recs)


def plan(setup, until):
    """``(t, robot, frame, record index)`` of each camera frame before ``until`` (s), in capture order."""
    out, frames = [], {}
    for i, (t, cams) in enumerate(zip(setup.recs.times, setup.recs.cameras)):
        for c in cams:
            frames[c] = frames.get(c, 0) + 1
            if t < until:
                out.append((t, c, frames[c], i))
    return out


def test_refused_messages_are_warn_with_why_and_printed_once_then_rate_limited(setup):
    """q's node runs with another rig file: every q message refused; q is
    WARN (not "no observations received") naming both rig_ids and the count,
    one printed line for it over 2 s, another with the count after
    NOTICE_PERIOD; p's messages with a frame_id that is no camera of p are
    named too; NOTICE_HOLD after the last refusal the WARN is gone."""
    lines = []
    loc = Localizer(setup.path, notify=lines.append)
    n_q = 0
    for t, c, frame, i in plan(setup, 2.0):
        rid = setup.rid if c == "p" else OTHER_RIG
        msg = M.observations_message(c, rid, frame, T0 + t, setup.recs.frames[i])
        n_q += c == "q"
        loc.feed(msg, T0 + t + 0.008, c)
    status = {s.robot: s for s in loc.diagnostics(T0 + 2.0)}
    q = status["q"]
    assert q.level == M.WARN, q
    assert q.message == (f"refused {n_q} observations: rig_id {OTHER_RIG} is not this rig's ({setup.rid}): "
                         "its node runs with another rig file"), q.message
    assert q.values["refused_rig_id"] == n_q and q.values["fused"] == 0
    # p's own messages are fine (nothing refused of it); with every q message refused only p's camera ties p
    # to q, by two markers: p is not published and says so
    assert "refused" not in status["p"].message and status["p"].values["refused"] == 0
    assert status["p"].level == M.STALE and "tied by 2 distinct observation(s)" in status["p"].message
    assert len(lines) == 1 and lines[0].startswith("robot q: refused observations (rig_id): rig_id 0123"), lines
    # a frame_id that is neither p nor one of its cameras
    bad = M.observations_message("p", setup.rid, 10**6, T0 + 2.0, setup.recs.frames[0])
    bad.header.frame_id = "p/nosuchcamera"
    assert loc.receive(bad, T0 + 2.01, "p").startswith("refused")
    p = {s.robot: s for s in loc.diagnostics(T0 + 2.02)}["p"]
    # (p stays STALE: not published, see above; the refusal is named beside it)
    assert p.level == M.STALE and "refused 1 observations" in p.message and "p/nosuchcamera" in p.message, p
    assert len(lines) == 2 and lines[1].startswith("robot p: refused observations (malformed)") and \
        "p/nosuchcamera" in lines[1], lines
    # rate-limited: the next q refusal after NOTICE_PERIOD prints one line with the count since
    later = T0 + 2.0 + NOTICE_PERIOD + 0.5
    loc.receive(M.observations_message("q", OTHER_RIG, 10**6, later, setup.recs.frames[0]), later, "q")
    assert len(lines) == 3 and "robot q:" in lines[2] and re.search(rf"\({n_q} more in the last \d+ s\)", lines[2])
    # the WARN for refusals holds NOTICE_HOLD: then q (nothing ever taken) is STALE again, saying so
    q = {s.robot: s for s in loc.diagnostics(later + NOTICE_HOLD + 0.1)}["q"]
    assert q.level == M.STALE and q.message == "no observations received", q


def _localizer(setup, domain):
    cmd = [sys.executable, "-m", "mutloc", "localizer", "--rig", str(setup.path), "--domain", str(domain),
           "--loopback", "--duration", "60"]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _ready(child):
    assert select.select([child.stderr], [], [], 60)[0], "the localizer did not start"
    line = child.stderr.readline()
    assert line.startswith("localizer: rig_id"), line + child.stderr.read()


def _run(setup, children, domain, rid_of, until=1.5):
    """Publish the robots' observations in real time (``rid_of[robot]`` their rig_id); the
    diagnostics received, then each child stopped by Ctrl-C: ``(diagnostics, [stderr])``."""
    from mutloc.live.dds import Bus

    T = M.ros_types()
    bus = Bus(domain, loopback=True)
    try:
        diag = bus.reader(M.DIAGNOSTICS_TOPIC, T.DiagnosticArray, depth=100)
        writers = {r: bus.writer(M.observations_topic(r), T.Observations) for r in rid_of}
        deadline = time.time() + 20
        while time.time() < deadline and not all(
                len(w.get_matched_subscriptions()) >= len(children) for w in writers.values()):
            time.sleep(0.02)
        got = []
        start = time.time() + 0.1
        for t, c, frame, i in plan(setup, until):
            if c not in writers:
                continue
            while time.time() < start + t:
                got += diag.take()
                time.sleep(0.002)
            writers[c].write(M.observations_message(c, rid_of[c], frame, start + t, setup.recs.frames[i]))
        end = time.time() + 1.2  # two diagnostics periods and more
        while time.time() < end:
            got += diag.take()
            time.sleep(0.01)
    finally:
        bus.close()
    errs = []
    for child in children:
        child.send_signal(signal.SIGINT)
    for child in children:
        errs.append(child.communicate(timeout=30)[1])
    return got, errs


def test_over_dds_another_rig_is_warn_and_printed_once(setup, dds_domain):
    """Over DDS: q's node with another rig file -> the localizer's /diagnostics
    say q WARN "refused N observations: rig_id ... is not this rig's (...)",
    its stderr one line for it, and nothing about another localizer (its own
    poses are not another's)."""
    child = _localizer(setup, dds_domain)
    try:
        _ready(child)
        got, (err,) = _run(setup, [child], dds_domain, {"p": setup.rid, "q": OTHER_RIG})
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
            child.wait()
    sent_q = sum(1 for t, c, *_ in plan(setup, 1.5) if c == "q")
    q = {s.hardware_id: s for s in got[-1].status}["q"]
    kv = {v.key: v.value for v in q.values}
    assert q.level == M.WARN, (q, err)
    assert re.fullmatch(rf"refused (\d+) observations: rig_id {OTHER_RIG} is not this rig's \({setup.rid}\): .*",
                        q.message), q.message
    assert int(kv["refused_rig_id"]) == int(q.message.split()[1]) >= 0.9 * sent_q
    said = [ln for ln in err.splitlines() if "refused observations" in ln]
    assert len(said) == 1 and said[0].startswith("localizer: robot q: refused observations (rig_id)"), err
    assert "another localizer" not in err and "p_in_q" not in q.message


def test_over_dds_a_second_localizer_is_detected_and_named(setup, dds_domain):
    """Two localizers on one domain, both fed the same observations: each
    names the other (its pid) in /diagnostics (p WARN "another localizer
    publishes on this domain: ...") and once on its stderr."""
    children = [_localizer(setup, dds_domain), _localizer(setup, dds_domain)]
    try:
        for child in children:
            _ready(child)
        got, errs = _run(setup, children, dds_domain, {"p": setup.rid, "q": setup.rid}, until=4.0)
    finally:
        for child in children:
            if child.poll() is None:
                os.killpg(child.pid, signal.SIGKILL)
                child.wait()
    for me, other, err in ((children[0], children[1], errs[0]), (children[1], children[0], errs[1])):
        said = [ln for ln in err.splitlines() if "another localizer publishes on this domain" in ln]
        assert len(said) == 1, err
        assert f"by mutloc localizer pid {other.pid} " in said[0] and f"pid {me.pid} " not in said[0], said
        warned = [s for d in got for s in d.status if s.hardware_id == "p" and s.level == M.WARN
                  and "another localizer publishes on this domain: /" in s.message
                  and f"mutloc localizer pid {other.pid} " in s.message]
        assert warned, [s.message for d in got for s in d.status]
