"""Streaming outputs survive a killed run: a child process writes rows to
every writer of mutloc.io (CSV, TUM, observation log, rosbag2, MCAP, Rerun, MP4),
reports each row on stdout once written, and is killed (SIGKILL) or
interrupted (SIGINT, or SIGTERM under mutloc.signals.sigterm_as_interrupt as
the ``mutloc`` command runs, with SIGINT ignored as in a background job) mid-run; every file must then parse and hold at least
the rows reported, each identical to what was written.  Plus the readers'
handling of a file cut mid-line."""

import math
import os
import signal
import subprocess
import sys
import warnings

import numpy as np
import pytest

from mutloc.core.geometry import so3_exp
from mutloc.core.observations import ObservationSet
from mutloc.core.pose import Pose
from mutloc.errors import FileFormatError, InputError
from mutloc.io.logs import iter_observation_log
from mutloc.io.ros import POSE_TYPE, TF_TOPIC, McapPoseWriter, Ros2BagWriter
from mutloc.io.trajectory import (TrajectoryCsvWriter, TumWriter, read_trajectory_csv, read_tum,
                                  write_trajectory_csv, write_tum)

N_ROWS = 400  # more than the child lives to write
EXTRA = ("reason", "markers_used")


def expected_row(i):
    """Row ``i`` of the child's run: every fourth frame has no pose."""
    t = 0.05 * i
    posed = i % 4 != 3
    pose = Pose(so3_exp([0.01 * i, 0.02, -0.03 * i]), [0.1 * i, 1.0, 2.0 + 0.001 * i]) if posed else None
    cov = np.diag([1e-4, 2e-4, 3e-4, 1e-3, 2e-3, 3e-3]) * (1 + i) if posed else None
    obs = ObservationSet.from_dict({"p": {"m1": [100.0 + i, 50.5], "m2": [7.25, 3.0 * i]}, "q": {}}, time=t)
    return {"t": t, "status": "solved" if posed else "lost", "pose": pose, "covariance": cov,
            "reason": "" if posed else f"too few markers, frame {i}", "markers_used": "m1 m2" if posed else "",
            "observations": obs}


def frame_levels(i):
    """The grey levels of frame ``i``'s halves: its number in base 18, a digit a half, 12 levels apart."""
    return 20 + 12 * (i % 18), 20 + 12 * ((i // 18) % 18)


def expected_frame(i):
    """Frame ``i`` of the child's video."""
    img = np.empty((48, 64, 3), np.uint8)
    img[:, :32], img[:, 32:] = frame_levels(i)
    return img


CHILD = f"""
import sys, time
sys.path.insert(0, {os.path.dirname(__file__)!r})
from pathlib import Path
from test_streaming_outputs import expected_row, expected_frame, EXTRA, N_ROWS
from mutloc.io.trajectory import TrajectoryCsvWriter, TumWriter
from mutloc.io.logs import ObservationLogWriter
from mutloc.io.ros import Ros2BagWriter, McapPoseWriter
from mutloc.io.rrd import RerunWriter
from mutloc.io.video import VideoWriter
from mutloc.signals import sigterm_as_interrupt

out = Path(sys.argv[1])
stop_signals = sigterm_as_interrupt()
stop_signals.__enter__()  # for the whole run, as the mutloc command does
try:
    with TrajectoryCsvWriter(out / "trajectory.csv", EXTRA) as csv_w, TumWriter(out / "trajectory.tum", "p in q") as tum, \\
            ObservationLogWriter(out / "log.jsonl") as log, Ros2BagWriter(out / "bag", [("p", "q")]) as bag, \\
            Ros2BagWriter(out / "bag_mcap", [("p", "q")], storage="mcap") as bag_mcap, McapPoseWriter(out / "traj.mcap", [("p", "q")]) as mcap, RerunWriter(out / "track.rrd", "p", "q") as rrd, \\
            VideoWriter(out / "annotated.mp4", fps=20) as video:
        print("ready", flush=True)
        for i in range(N_ROWS):
            r = expected_row(i)
            csv_w.write(r)
            tum.write(r["t"], r["pose"])
            log.write(r["t"], r["observations"])
            bag.write(r["t"], r["pose"], r["covariance"])
            bag_mcap.write(r["t"], r["pose"], r["covariance"])
            mcap.write(r["t"], r["pose"], r["covariance"])
            rrd.write(r["t"], r["status"], r["reason"], r["pose"], r["covariance"])
            video.write(expected_frame(i))
            print(i, flush=True)
            time.sleep(0.01)
except KeyboardInterrupt:
    print("interrupted", flush=True)
    sys.exit(130)
"""


def _run_and_stop(out, sig, k):
    """Start the child, wait for ``k`` rows reported, send ``sig``; the rows reported."""
    # SIGINT as in a terminal's foreground job (the default), or ignored as in a background job's for SIGTERM
    sigint = signal.SIG_IGN if sig == signal.SIGTERM else signal.SIG_DFL
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, sigint))
    reported = -1
    try:
        line = proc.stdout.readline()
        assert line == "ready\n", f"child did not start: {line!r} {proc.stderr.read()}"
        while reported < k - 1:
            line = proc.stdout.readline()
            assert line, f"child ended early: {proc.stderr.read()}"
            reported = int(line)
        if sig != signal.SIGKILL:
            proc.send_signal(sig)  # Ctrl-C reaches the child only, as in a terminal's foreground job
            rest, err = proc.communicate(timeout=30)
            assert proc.returncode == 130 and rest.endswith("interrupted\n"), (proc.returncode, rest, err)
            assert "Traceback" not in err, err
            reported = max([reported] + [int(x) for x in rest.split() if x.isdigit()])
        else:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)
            assert proc.returncode == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()
    return reported + 1


def _same_pose(pose, row, atol=1e-8):  # text files: 9 decimals
    np.testing.assert_allclose(pose.t, row["pose"].t, atol=atol)
    np.testing.assert_allclose(pose.R, row["pose"].R, atol=atol)


def _check_files(out, k, clean):
    """Every file parses, holds a prefix of the expected rows, at least ``k`` rows long."""
    rows = [expected_row(i) for i in range(N_ROWS)]
    counts = {}

    csv_rows = read_trajectory_csv(out / "trajectory.csv")
    counts["csv"] = len(csv_rows)
    for got, want in zip(csv_rows, rows):
        assert got["t"] == pytest.approx(want["t"], abs=1e-9) and got["status"] == want["status"]
        assert got["reason"] == want["reason"] and got["markers_used"] == want["markers_used"]
        if want["pose"] is None:
            assert got["pose"] is None and got["sigma"] is None
        else:
            _same_pose(got["pose"], want)
            np.testing.assert_allclose(got["sigma"], np.sqrt(np.diag(want["covariance"])), rtol=1e-6)

    posed = [r for r in rows if r["pose"] is not None]
    times, poses = read_tum(out / "trajectory.tum")
    counts["tum"] = len(times)
    for t, pose, want in zip(times, poses, posed):
        assert t == pytest.approx(want["t"], abs=1e-9)
        _same_pose(pose, want)

    log = list(iter_observation_log(out / "log.jsonl"))
    counts["log"] = len(log)
    for (t, obs), want in zip(log, rows):
        assert t == want["t"] and obs == want["observations"]

    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)

    def check_ros(messages, what):
        """messages: (topic, time ns, decoded) in file order."""
        pose_msgs = [m for topic, _, m in messages if topic == "/mutloc/p_in_q"]
        tf_msgs = [m for topic, _, m in messages if topic == TF_TOPIC]
        assert len(pose_msgs) == len(tf_msgs), what
        for m, tf, want in zip(pose_msgs, tf_msgs, posed):
            stamp = m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec
            assert stamp == pytest.approx(want["t"], abs=1e-9) and m.header.frame_id == "q"
            p = m.pose.pose.position
            np.testing.assert_allclose([p.x, p.y, p.z], want["pose"].t, atol=1e-12)
            (ts,) = tf.transforms
            assert ts.child_frame_id == "p"
            np.testing.assert_allclose([ts.transform.translation.x, ts.transform.translation.y,
                                        ts.transform.translation.z], want["pose"].t, atol=1e-12)
        return len(pose_msgs)

    for bag in ("bag", "bag_mcap"):
        with Reader(out / bag) as reader:
            msgs = [(c.topic, t, store.deserialize_cdr(raw, c.msgtype)) for c, t, raw in reader.messages()]
            meta_count = reader.message_count
        counts[bag] = check_ros(msgs, bag)
        if clean:  # metadata.yaml is final; after a kill it may lag (refreshed every second)
            assert meta_count == len(msgs)
        else:
            assert meta_count <= len(msgs)

    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(out / "traj.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        assert (reader.get_summary() is not None) == clean  # the summary is written at close only
        decoded = [(c.topic, m.log_time, msg) for _, c, m, msg in reader.iter_decoded_messages(log_time_order=False)]
    counts["mcap"] = check_ros(decoded, "mcap")
    with Reader(out / "traj.mcap") as reader:  # rosbags reads the MCAP too, cut or not
        assert check_ros([(c.topic, t, store.deserialize_cdr(raw, c.msgtype)) for c, t, raw in reader.messages()],
                         "mcap (rosbags)") == counts["mcap"]

    import pyarrow as pa
    from rerun.chunk import RrdReader

    status, strips = [], 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a killed run's recording has no footer: rerun warns and scans it
        for chunk in RrdReader(out / "track.rrd").stream().to_chunks():
            if chunk.entity_path == "/status":
                rb = chunk.to_record_batch()
                status += zip(rb.column("time").cast(pa.int64()).to_pylist(), rb.column("TextLog:text").to_pylist())
            strips += chunk.entity_path == "/world/trajectory"
    status.sort()
    counts["rrd"] = len(status)
    for (ns, text), want in zip(status, rows):
        assert ns == round(want["t"] * 1e9)
        assert text == [f"{want['status']}: {want['reason']}" if want["reason"] else want["status"]]
    assert bool(strips) == clean  # the trajectory's line strip is written at close

    import cv2

    cap = cv2.VideoCapture(str(out / "annotated.mp4"))
    frames = []
    while (got := cap.read())[0]:
        frames.append(got[1])
    cap.release()
    counts["video"] = len(frames)
    for i, img in enumerate(frames):  # lossy: within half a level step (the colour conversion alone shifts ~3)
        assert img.shape == (48, 64, 3), img.shape
        np.testing.assert_allclose([img[:, :32].mean(), img[:, 32:].mean()], frame_levels(i), atol=6)

    n_posed_k = sum(r["pose"] is not None for r in rows[:k])
    for name, n in counts.items():
        # A video fragment is closed when the next frame comes: a killed run's video lacks its last frame.
        need = n_posed_k if name in ("tum", "bag", "bag_mcap", "mcap") else k - 1 if name == "video" and not clean else k
        assert n >= need, (name, n, need, counts)
        assert n <= N_ROWS
    return counts


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGINT, signal.SIGTERM], ids=["SIGKILL", "SIGINT", "SIGTERM"])
def test_stopped_run_leaves_every_file_readable(tmp_path, sig):
    k = 12
    reported = _run_and_stop(tmp_path, sig, k)
    assert reported >= k
    counts = _check_files(tmp_path, reported, clean=sig != signal.SIGKILL)
    # No more rows than the child started: at most the one in progress.
    assert counts["csv"] <= reported + 1 and counts["log"] <= reported + 1
    if sig != signal.SIGKILL:  # closed cleanly: every file holds the same rows
        n = counts["csv"]
        n_posed = sum(expected_row(i)["pose"] is not None for i in range(n))
        assert counts == {"csv": n, "tum": n_posed, "log": n, "bag": n_posed, "bag_mcap": n_posed, "mcap": n_posed,
                          "rrd": n, "video": n}, counts
    assert not list(tmp_path.glob(".*.part"))


# --------------------------------------------------------------------------- readers of cut files


def _poses(n):
    return Pose(np.stack([so3_exp([0.1 * i, -0.2, 0.3]) for i in range(n)]), np.arange(3 * n, dtype=float).reshape(n, 3))


def test_tum_cut_at_any_byte_reads_the_complete_lines(tmp_path):
    p = tmp_path / "a.tum"
    write_tum(p, np.arange(3) * 0.5, _poses(3), comment="c")
    data = p.read_bytes()
    ends = [i + 1 for i, b in enumerate(data) if b == ord("\n")]
    whole, poses = read_tum(p)
    for cut in range(len(data) + 1):
        p.write_bytes(data[:cut])
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            times, got = read_tum(p)
        complete = sum(e <= cut for e in ends) - 1  # minus the comment line
        # A cut last line is dropped, with a warning, unless all of it is there but its end of line --
        # or, the first line (no line before to compare its decimals with), cut so little inside its
        # last number that its quaternion is still a rotation within the tolerance.
        whole_line = cut + 1 in ends[1:]
        first = ends[0] < cut < ends[1] - 1
        assert len(times) == max(complete, 0) + whole_line or first and len(times) == 1, cut
        assert bool(caught) == (len(times) == max(complete, 0) and cut not in ends and cut > ends[0]), (cut, caught)
        np.testing.assert_array_equal(times, whole[:len(times)])
        np.testing.assert_allclose(got.R, poses.R[:len(times)], atol=2e-3 if first else 1e-8)


def test_tum_line_cut_inside_its_quaternion_is_refused(tmp_path):
    """A complete line whose last number was cut (or a quaternion that is
    not a rotation): one line naming the file and line; the same line last
    and without end of line: dropped with a warning naming it, the lines
    before read."""
    p = tmp_path / "a.tum"
    lines = ["0.0 1 2 3 0.100000000 -0.200000000 0.050000000 0.973396117\n",
             "0.5 1 2 3 0.600000000 -0.300000000 0.200000000 0.714142843\n"]
    for cut_qw in ("0", "0.", "0.7", "0.71", "0.714"):  # 157 deg off with "0" but 8 numbers all the same
        bad = lines[1].rsplit(" ", 1)[0] + " " + cut_qw
        if cut_qw != "0.714":  # a rotation within 1e-3 (as a file written with 3 decimals): read
            p.write_text(lines[0] + bad + "\n" + lines[0].replace("0.0 ", "1.0 ", 1))
            with pytest.raises(FileFormatError, match=r"a\.tum:2: quaternion .* of norm "):
                read_tum(p)
        p.write_text(lines[0] + bad)
        with pytest.warns(UserWarning, match=r"a\.tum:2: .*dropped"):
            times, _ = read_tum(p)
        assert times.tolist() == [0.0]
    p.write_text(lines[0] + lines[1].rstrip("\n"))  # a hand-written file without a last end of line: all read
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_tum(p)[0].tolist() == [0.0, 0.5]
    p.write_text("0 1 2 3 0.5 0.5 0.5 0.5\n1 1 2 3 0.1 0.1 0.1 0.1\n")  # not normalized: refused, never scaled up
    with pytest.raises(FileFormatError, match=r"a\.tum:2: "):
        read_tum(p)


def test_csv_cut_at_any_row_boundary_or_mid_row(tmp_path):
    p = tmp_path / "t.csv"
    rows = [expected_row(i) for i in (1, 2, 3)]  # rows 2 and 3 (cut below): one with a pose, one without
    write_trajectory_csv(p, rows, extra=EXTRA)
    data = p.read_bytes()
    ends = [i + 1 for i, b in enumerate(data) if b == ord("\n")]
    for cut in range(ends[1] - 1, len(data) + 1):  # the header is written whole (see below)
        p.write_bytes(data[:cut])
        got = read_trajectory_csv(p)
        complete = sum(e <= cut for e in ends) - 1
        # A cut last row is dropped unless only its last column (text) was cut.
        assert len(got) in (complete, complete + 1)
        for g, w in zip(got, rows):
            assert g["status"] == w["status"] and g["t"] == pytest.approx(w["t"])
            assert (g["pose"] is None) == (w["pose"] is None)
            if w["pose"] is not None:
                _same_pose(g["pose"], w)


def test_a_malformed_complete_line_is_still_an_error(tmp_path):
    p = tmp_path / "t.csv"
    write_trajectory_csv(p, [expected_row(i) for i in range(3)], extra=EXTRA)
    lines = p.read_text().splitlines(keepends=True)
    p.write_text(lines[0] + lines[1][: len(lines[1]) // 2] + "\r\n" + lines[2])
    with pytest.raises(FileFormatError, match=r"t\.csv:2: "):
        read_trajectory_csv(p)
    q = tmp_path / "a.tum"
    q.write_text("0 1 2 3 0 0 0 1\n1 2 3\n2 1 2 3 0 0 0 1\n")
    with pytest.raises(FileFormatError, match=r"a\.tum:2: "):
        read_tum(q)


def test_log_cut_mid_line_reads_the_complete_lines(tmp_path):
    from mutloc.io.logs import write_observation_log

    p = tmp_path / "log.jsonl"
    frames = [expected_row(i)["observations"] for i in range(3)]
    write_observation_log(p, frames)
    data = p.read_bytes()
    p.write_bytes(data[:-10])
    got = list(iter_observation_log(p))
    assert len(got) == 2 and all(o == f for (_, o), f in zip(got, frames))


def test_text_file_appears_with_its_header(tmp_path):
    """The header is there as soon as the writer exists (nothing half-made under the name)."""
    with TrajectoryCsvWriter(tmp_path / "t.csv", EXTRA) as w:
        assert read_trajectory_csv(tmp_path / "t.csv") == []
        w.write(expected_row(0))
        assert len(read_trajectory_csv(tmp_path / "t.csv")) == 1  # flushed before close
    with TumWriter(tmp_path / "a.tum", "hello") as w:
        assert (tmp_path / "a.tum").read_text() == "# hello\n"
        assert w.write(0.0, None) is False and w.rows == 0
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.tum", "t.csv"]


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_ros_writers_are_readable_while_open(tmp_path, storage):
    from mcap.reader import make_reader
    from rosbags.rosbag2 import Reader

    rows = [r for r in (expected_row(i) for i in range(5)) if r["pose"] is not None]
    with Ros2BagWriter(tmp_path / "bag", [("p", "q")], storage=storage) as bag, McapPoseWriter(tmp_path / "a.mcap", [("p", "q")]) as m:
        for n, r in enumerate(rows, 1):
            bag.write(r["t"], r["pose"], r["covariance"], track="p")
            m.write(r["t"], r["pose"], r["covariance"])
            with Reader(tmp_path / "bag") as reader:
                assert sum(1 for _ in reader.messages()) == 2 * n
            with open(tmp_path / "a.mcap", "rb") as f:
                assert sum(1 for _ in make_reader(f).iter_messages()) == 2 * n
        assert not bag.write(1.0, None) and not m.write(1.0, Pose(np.eye(3), [math.nan, 0, 0]))
        assert bag.rows == m.rows == len(rows)
    with Reader(tmp_path / "a.mcap") as reader:
        assert {c.topic: c.msgtype for c in reader.connections}["/mutloc/p_in_q"] == POSE_TYPE
    with Reader(tmp_path / "bag") as reader:
        assert reader.message_count == 2 * len(rows) and len(reader.connections) == 2
        assert {x.name for x in (tmp_path / "bag").iterdir()} == {"metadata.yaml",
                                                                 "bag.mcap" if storage == "mcap" else "bag.db3"}
    with McapPoseWriter(tmp_path / "b.mcap", [("p", "q")]) as m:
        for bad in (1, -1, "q"):
            with pytest.raises(InputError, match="no track"):
                m.write(0.0, rows[0]["pose"], track=bad)
    with pytest.raises(InputError, match="bag storage"):
        Ros2BagWriter(tmp_path / "bag2", [("p", "q")], storage="zip")
