"""The live localizer when it cannot keep up (issue 38, item 1): samples shed
before they are decoded, and the smoother deferred, caught up with slack, or
skipped past a bound.

No DDS and no wall clock: the localizer is fed ``Observations`` messages
(as their CDR bytes where a reader would hold them) built from simulated
free-running cameras (mutloc.sim.tracking.camera_records, 30 fps, q half a
frame after p, 1 px noise), with the clock given.  Ground truth: the
stamps put into the messages; for the smoothed rows, the same localizer fed
every message in time (smoothing at once).
"""

import itertools
import math
from types import SimpleNamespace

import numpy as np
import pytest

from mutloc.io import save_rig
from mutloc.live import messages as M
from mutloc.live.localizer import Localizer, _take
from mutloc.sim.tracking import camera_records
from mutloc.sim.world import standard_rig
from mutloc.track.filtering import DEFAULT_SMOOTH_LAG

pytest.importorskip("cyclonedds", reason="the live extra (cyclonedds) is part of make test's install")

T0 = 1_800_000_000.0  # the robots' wall clock at the records' time 0
#: Seconds of these records by which the rig check's first full window has agreed (no pose is published
#: before: mutloc.live.rig_gate; test_a_readers_backlog_is_shed_before_it_is_decoded needs poses after it).
READY = 3.0


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("shed")
    rig = standard_rig()
    path = d / "rig.yaml"
    save_rig(rig, path)
    recs = camera_records(rig, duration=READY + 1.5, offsets={"q": 1 / 60}, pixel_sigma=1.0, seed=11)
    return SimpleNamespace(rig=rig, path=path, rid=M.rig_id(path), recs=recs)


def messages(setup, since=0.0, until=math.inf):
    """``[(capture time, message, robot)]`` per camera frame captured in [since, until), in capture order."""
    out, frames = [], {}
    for t, obs, cams in zip(setup.recs.times, setup.recs.frames, setup.recs.cameras):
        for c in cams:
            frames[c] = frames.get(c, 0) + 1
            if since <= t < until:
                out.append((T0 + t, M.observations_message(c, setup.rid, frames[c], T0 + t, obs), c))
    return out


def stamp_ns(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


class BytesReader:
    """What run_localizer's loop takes from a robot's DDS reader: samples as bytes (``take_bytes``),
    decoded one at a time (``decode``) -- here each decode recorded."""

    raw = True

    def __init__(self, data):
        self.data, self.decoded, self.malformed = list(data), [], 0

    def take_bytes(self, limit=256):
        got, self.data = self.data[:limit], self.data[limit:]
        return [(d, None) for d in got]

    def decode(self, data, info=None):
        self.decoded.append(data)
        try:
            return M.observations_from_cdr(data)
        except M.MessageError:
            self.malformed += 1
            return None


def in_time(setup, until):
    """A localizer that kept up with the messages captured before ``until`` (each polled at arrival)."""
    loc = Localizer(setup.path)
    for t, msg, robot in messages(setup, until=until):
        loc.feed(msg, t + 0.005, robot)
    loc.poll(T0 + until + 0.05)
    return loc


# -- shed before decoding ---------------------------------------------------------------------


def _big_endian_head(data: bytes) -> bytes:
    """A little-endian Observations message's bytes with the header, the two strings' lengths and the frame
    number swapped to big-endian (all the peek reads; the rest as it was)."""
    import struct

    out = bytearray(data)
    out[1] = 0
    fields = [4, 8]  # sec, nanosec
    p = 12
    for _ in range(3):  # frame_id, robot, rig_id
        p += -(p - 4) % 4
        fields.append(p)
        p += 4 + struct.unpack_from("<I", data, p)[0]
    p += -(p - 4) % 4
    fields.append(p)  # frame
    for f in fields:
        out[f:f + 4] = data[f:f + 4][::-1]
    return bytes(out)


def test_the_header_is_read_without_decoding_as_the_decoder_reads_it(setup):
    """``observations_peek``: each message's frame_id, stamp (ns) and frame
    number from its CDR bytes, both byte orders, equal to what the full
    decoder gives; bytes it cannot read so are None (decoded, then refused),
    never an exception."""
    msgs = messages(setup, until=0.2)
    for _, msg, robot in msgs:
        data = bytes(msg.serialize())
        assert M.observations_peek(data) == (robot, stamp_ns(msg), msg.frame)
        full = M.observations_from_cdr(data)
        assert M.observations_peek(data) == (full.header.frame_id, stamp_ns(full), full.frame)
    cam = M.observations_message("p", setup.rid, 7, T0 + 1.25, None, frame_id="p/left")
    assert M.observations_peek(bytes(cam.serialize())) == ("p/left", round((T0 + 1.25) * 1e9), 7)
    data = bytes(msgs[3][1].serialize())
    assert M.observations_peek(_big_endian_head(data)) == (msgs[3][2], stamp_ns(msgs[3][1]), msgs[3][1].frame)
    for bad in (data[:15], data[:17], data[:40], b"\x00\x01\x00\x00" + b"\xff" * 40, b"\x00\x02" + data[2:]):
        assert M.observations_peek(bad) is None


def test_a_readers_backlog_is_shed_before_it_is_decoded(setup):
    """The localizer fell behind: a second of both robots' messages waits in
    their readers when it takes them, 0.5 s after the last capture.  Only
    each camera's newest sample is decoded; the others are counted as
    received and shed without being decoded; the two newest are fused, their
    poses published at the newest stamps."""
    loc = in_time(setup, READY)
    assert loc.rig_gate.state == "agrees"  # (poses published from here on)
    late = messages(setup, READY, READY + 1.0)
    readers = {c: BytesReader([bytes(m.serialize()) for _, m, r in late if r == c]) for c in ("p", "q")}
    newest = {c: max(t for t, _, r in late if r == c) for c in ("p", "q")}
    n = {c: sum(r == c for _, _, r in late) for c in ("p", "q")}
    now = max(newest.values()) + 0.5
    before = {c: (loc.counts[c].received, loc.counts[c].fused) for c in ("p", "q")}
    for c, rd in readers.items():
        _take(rd, c, loc, lambda: now)
    for c, rd in readers.items():
        assert len(rd.decoded) == 1 and M.observations_peek(rd.decoded[0])[1] == round(newest[c] * 1e9)
        assert loc.counts[c].shed == n[c] - 1
        assert loc.counts[c].received - before[c][0] == n[c]  # (every sample taken is received: shed or held)
    poses = loc.poll(now + 1.0)
    assert sorted(p.t for p in poses) == pytest.approx(sorted(newest.values()), abs=1e-6)
    assert all(loc.counts[c].fused - before[c][1] == 1 for c in ("p", "q"))


def test_within_max_lag_every_sample_is_decoded(setup):
    """The same backlog taken within ``max_lag`` (0.1 s) of its oldest capture: nothing shed, every sample
    decoded and held; and a camera's newest sample is kept however old it is."""
    loc = in_time(setup, 1.5)
    late = messages(setup, 1.5, 1.6)
    rd = BytesReader([bytes(m.serialize()) for _, m, r in late if r == "p"])
    _take(rd, "p", loc, lambda: late[0][0] + 0.09)
    assert len(rd.decoded) == sum(r == "p" for _, _, r in late) >= 3 and loc.counts["p"].shed == 0
    one = BytesReader([bytes(late[0][1].serialize())])
    loc2 = in_time(setup, 1.5)
    _take(one, late[0][2], loc2, lambda: late[0][0] + 10.0)
    assert len(one.decoded) == 1 and loc2.counts[late[0][2]].shed == 0


# -- the smoother when behind ------------------------------------------------------------------


def rows_of(sunk):
    return [(robot, row.t, str(row.status), None if row.estimate is None else row.estimate.pose.t.tolist(),
             None if row.estimate is None else row.estimate.covariance.tolist()) for row, robot in sunk]


def behind(setup, lag_s, **kw):
    """A localizer with a sink (``--out``: the smoother runs) given every message ``lag_s`` after its
    capture and polled then (always ``lag_s`` behind); ``(localizer, rows sunk, poses, checks)``."""
    sunk, poses, deferred = [], [], []
    loc = Localizer(setup.path, sink=lambda row, robot: sunk.append((row, robot)), **kw)
    for t, msg, robot in messages(setup):
        poses += loc.feed(msg, t + lag_s, robot)
        deferred.append(loc.deferred())
    return loc, sunk, poses, deferred


def test_behind_the_smoother_waits_and_catching_up_gives_the_same_rows(setup):
    """Every record fused 0.3 s after its capture (beyond ``max_lag``): no
    row is smoothed while behind -- none reaches the files, the records wait
    (deferred, counted) -- and :meth:`catch_up` then :meth:`finish` write
    exactly the rows of the same localizer fed every message in time."""
    ref = []
    on_time = Localizer(setup.path, sink=lambda row, robot: ref.append((row, robot)))
    for t, msg, robot in messages(setup):
        on_time.feed(msg, t + 0.005, robot)
    assert len(ref) > 0.8 * on_time.records  # (in time: rows written as the run goes)
    on_time.finish()
    loc, sunk, _, deferred = behind(setup, 0.3, max_deferred=10 ** 6)
    assert loc.records_deferred == loc.records
    assert sunk == [] and deferred[-1] == loc.records - DEFAULT_SMOOTH_LAG - 1
    assert loc.catch_up(lambda: 0.0, 1.0) == deferred[-1] and loc.deferred() == 0
    loc.finish()
    assert loc.records == on_time.records and loc.records_unsmoothed == 0 and "unsmoothed" not in loc.summary()
    assert rows_of(sunk) == rows_of(ref)


def test_catching_up_stops_at_the_end_of_the_slack(setup):
    """:meth:`catch_up` smooths one record at a time while the clock it is given is before ``until``."""
    loc, sunk, _, _ = behind(setup, 0.3, max_deferred=10 ** 6)
    ticks = itertools.count()
    assert loc.catch_up(lambda: next(ticks), 3) == 3
    assert len(sunk) == 3 and loc.deferred() == loc.records - DEFAULT_SMOOTH_LAG - 1 - 3
    assert loc.catch_up(lambda: 5.0, 3) == 0 and len(sunk) == 3


def test_past_max_deferred_the_oldest_rows_are_written_as_the_filter_gave_them(setup):
    """Always behind, with ``max_deferred`` 5: never more than 5 records wait
    for the smoother; the older ones are written unsmoothed (counted, said in
    the summary), their poses those published for them (the causal filter's)
    -- the last records, smoothed at the end, are not."""
    loc, sunk, poses, deferred = behind(setup, 0.3, max_deferred=5)
    assert max(deferred) <= 5
    loc.finish()
    assert loc.records_unsmoothed == loc.records - 5 - DEFAULT_SMOOTH_LAG - 2
    assert f"{loc.records_unsmoothed} records written unsmoothed" in loc.summary()
    published = {round(p.t - T0, 6): p.estimate.pose.t for p in poses}
    assert len(sunk) == loc.records  # (two robots: a row a record)
    # (the rows before the rig check's first window agreed were not published: nothing to compare them with)
    settled = [row for row, _ in sunk[:loc.records_unsmoothed] if row.estimate is not None and row.t - T0 >= 1.0
               and row.t >= loc.rig_gate.agreed]
    assert len(settled) > 30
    for row in settled:
        assert np.array_equal(row.estimate.pose.t, published[round(row.t - T0, 6)])
        assert "smooth_lag" not in row.estimate.extra
    smoothed = [row for row, _ in sunk[loc.records_unsmoothed:]]
    assert all(row.estimate.extra["smooth_lag"] == DEFAULT_SMOOTH_LAG for row in smoothed)
    assert any(not np.array_equal(row.estimate.pose.t, published[round(row.t - T0, 6)]) for row in smoothed)


def test_frames_never_received_are_counted(setup):
    """Frame numbers skipped between a camera's messages are counted as ``not_received`` (its node dropped
    them, or DDS lost them: e.g. overwritten in a full reader) -- whether the messages are decoded or shed
    as bytes; a message seen again adds nothing; a node restarting (its numbers starting over) is no loss."""
    loc = Localizer(setup.path)
    msgs = [(t, m, r) for t, m, r in messages(setup, until=1.0)]
    p = [x for x in msgs if x[2] == "p"]
    q = [x for x in msgs if x[2] == "q"]
    skip_p = {4, 5, 6, 11}  # (p's frames 5..7 and 12 never sent: message index k has frame k + 1)
    for k, (t, m, r) in enumerate(p):
        if k not in skip_p:
            loc.feed(m, t + 0.005, r)
    loc.feed(p[3][1], p[3][0] + 0.5, "p")  # seen again
    assert loc.counts["p"].not_received == len(skip_p)
    # q's messages as bytes, the localizer behind: a backlog shed before decoding, frames 8..9 missing
    late = [bytes(m.serialize()) for k, (_, m, _) in enumerate(q) if k not in (7, 8)]
    _take(BytesReader(late), "q", loc, lambda: q[-1][0] + 0.5)
    assert loc.counts["q"].shed > 0 and loc.counts["q"].not_received == 2
    # p's node restarts: its numbers start over at 1
    again = M.observations_message("p", setup.rid, 1, T0 + 1.5, setup.recs.frames[0])
    loc.feed(again, T0 + 1.505, "p")
    assert loc.counts["p"].not_received == len(skip_p)
    diag = {s.robot: s for s in loc.diagnostics(T0 + 1.6)}
    assert diag["p"].values["not_received"] == len(skip_p) and diag["q"].values["not_received"] == 2
    assert f"not received {len(skip_p) + 2}" in loc.summary()
