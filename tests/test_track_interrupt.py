"""`track` written as it runs (issue: outputs appended as rows become
final): stopped by SIGINT, SIGTERM or SIGKILL mid-run, every file written
parses and holds the frames finished so far, identical to what a complete
run over the same records reports; SIGTERM (systemd, ``docker stop``) ends
it as Ctrl-C does, also when the child ignores SIGINT (a background job).

The child reads its observation log from a named pipe, so the test decides
how far it gets: it writes records, waits for the rows to be written, then
stops it.  The child always runs in its own process group, killed in a
``finally``.
"""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from mutloc.io import save_rig
from mutloc.io.logs import ObservationLogWriter
from mutloc.io.trajectory import read_trajectory_csv, read_tum
from mutloc.sim.tracking import camera_records
from mutloc.sim.world import standard_rig
from mutloc.track.filtering import DEFAULT_SMOOTH_LAG
from mutloc.track.tracker import track_log

N_WRITTEN = 60  # records fed before the stop (of 120)


def _lines(path, frames):
    with ObservationLogWriter(path) as w:
        for f in frames:
            w.write(float(f.times[0]), f)
    return path.read_text().splitlines(keepends=True)


def _csv_rows(path):
    return read_trajectory_csv(path) if path.exists() else []


def _bag_poses(bag):
    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic.startswith("/mutloc/")]
        return [(ts, reader.deserialize(raw, c.msgtype)) for c, ts, raw in reader.messages(connections=conns)]


def _mcap_poses(path):
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return [m for _, ch, m in make_reader(f).iter_messages() if ch.topic.startswith("/mutloc/")]


def _sigint(action):
    """A ``preexec_fn`` giving the child SIGINT's ``action`` whatever the test
    process has (a background job, and what it starts, ignores SIGINT)."""
    return lambda: signal.signal(signal.SIGINT, action)


def _feed_then_stop(tmp_path, args, lines, written, sig, sigint=signal.SIG_DFL):
    """Run ``mutloc track`` reading its log from a named pipe (``args``: the
    options after it; SIGINT's action ``sigint`` in the child), feed it
    ``lines``, wait until ``written()`` says its files hold what was fed,
    then stop it with ``sig``.  Returns (exit status, stderr); the child's
    process group is always killed."""
    fifo = tmp_path / "log.pipe"
    os.mkfifo(fifo)
    cmd = [sys.executable, "-m", "mutloc", "track", "--rig", str(tmp_path / "rig.yaml"), "--observations", str(fifo),
           *args, "--no-progress"]
    child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                             preexec_fn=_sigint(sigint))
    try:
        with open(fifo, "w") as pipe:  # blocks until the child opens it
            pipe.writelines(lines)
            pipe.flush()
            deadline = time.monotonic() + 120
            while not written():
                assert child.poll() is None, child.stderr.read().decode()
                assert time.monotonic() < deadline, "the rows were not written as the track ran"
                time.sleep(0.1)
            time.sleep(0.3)
            os.killpg(child.pid, sig)
            child.wait(timeout=60)
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
            child.wait()
    return child.returncode, child.stderr.read().decode()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL], ids=["SIGINT", "SIGTERM", "SIGKILL"])
def test_stopped_track_leaves_every_file_readable(tmp_path, sig):
    """SIGTERM is sent to a child that ignores SIGINT, as a background job's does."""
    rig = standard_rig()
    save_rig(rig, tmp_path / "rig.yaml")
    recs = camera_records(rig, duration=4.0, offsets={"q": 1 / 60}, seed=11)
    lines = _lines(tmp_path / "all.jsonl", recs.frames)
    out = tmp_path / "out"
    # Rows are final DEFAULT_SMOOTH_LAG + 1 records after they came.
    code, err = _feed_then_stop(
        tmp_path, ["--out", str(out), "--bag", str(tmp_path / "bag"), "--mcap", str(tmp_path / "poses.mcap")],
        lines[:N_WRITTEN], lambda: len(_csv_rows(out / "trajectory.csv")) >= N_WRITTEN - DEFAULT_SMOOTH_LAG - 1, sig,
        sigint=signal.SIG_IGN if sig == signal.SIGTERM else signal.SIG_DFL)
    # The reference: a complete run over the records the child had.
    ref = track_log(rig, [(float(f.times[0]), f) for f in recs.frames[:N_WRITTEN]], progress=False)
    rows = _csv_rows(out / "trajectory.csv")
    if sig != signal.SIGKILL:
        assert code == 130, err
        assert "interrupted" in err and "frames finished" in err and "Traceback" not in err
        assert len(rows) == N_WRITTEN  # every record it had, reported as if the log ended there
    else:
        assert code == -signal.SIGKILL
        assert N_WRITTEN - DEFAULT_SMOOTH_LAG - 1 <= len(rows) <= N_WRITTEN
    for got, want in zip(rows, ref.rows):
        assert got["t"] == pytest.approx(want.t, abs=1e-9) and got["status"] == str(want.status)
        if want.estimate is None:
            assert got["pose"] is None
        else:
            assert np.allclose(got["pose"].t, want.estimate.t, atol=1e-8)
            assert np.allclose(got["sigma"], np.sqrt(np.diag(want.estimate.covariance)), rtol=1e-6, atol=1e-12)
    posed = sum(r["pose"] is not None for r in rows)
    times, _ = read_tum(out / "trajectory.tum")
    assert len(times) == posed
    assert len(_bag_poses(tmp_path / "bag")) == posed
    assert len(_mcap_poses(tmp_path / "poses.mcap")) == posed


def test_stopped_team_track_leaves_every_robot_s_files(tmp_path):
    """A team (three robots, the joint filter; rows final DEFAULT_SMOOTH_LAG
    + 1 records after they came) stopped with SIGINT: each robot's
    trajectory_NAME.csv holds every record it had (smoothed as if the log
    ended there), equal to a complete run over those records, and the bag
    one pose per row with a pose."""
    from mutloc.sim.team import random_team, team_sequence
    from mutloc.track.team import track_team_log

    scene = random_team(3, np.random.default_rng(4), one_way=0.0)
    save_rig(scene.rig, tmp_path / "rig.yaml")
    seq = team_sequence(scene, 40, 20.0, sigma=1.0, seed=4)
    lines = _lines(tmp_path / "all.jsonl", [obs for _, _, obs in seq])
    out = tmp_path / "out"
    robots = scene.names[1:]
    n = 20
    code, err = _feed_then_stop(tmp_path, ["--out", str(out), "--bag", str(tmp_path / "bag")], lines[:n],
                                lambda: all(len(_csv_rows(out / f"trajectory_{r}.csv")) >= n - DEFAULT_SMOOTH_LAG - 1
                                            for r in robots),
                                signal.SIGINT)
    assert code == 130 and "interrupted" in err and "Traceback" not in err
    ref = track_team_log(scene.rig, [(t, obs) for t, _, obs in seq[:n]], progress=False)
    posed = 0
    for r in robots:
        rows = _csv_rows(out / f"trajectory_{r}.csv")
        want = ref.tracks[r].rows
        assert len(rows) == n == len(want)
        for got, w in zip(rows, want):
            assert got["status"] == str(w.status)
            if w.estimate is not None:
                assert np.allclose(got["pose"].t, w.estimate.t, atol=1e-8)
        posed += sum(row["pose"] is not None for row in rows)
        times, _ = read_tum(out / f"trajectory_{r}.tum")
        assert len(times) == sum(row["pose"] is not None for row in rows)
    assert posed > 0 and len(_bag_poses(tmp_path / "bag")) == posed


@pytest.mark.parametrize("team", [False, True], ids=["pair", "team"])
def test_stopped_before_the_first_record_names_no_file(tmp_path, team):
    """SIGTERM while the log has given nothing yet: exit 130 and the message
    names no file, as none was written (it used to name every output)."""
    from mutloc.sim.team import random_team

    rig = random_team(3, np.random.default_rng(4), one_way=0.0).rig if team else standard_rig()
    save_rig(rig, tmp_path / "rig.yaml")
    out = tmp_path / "out"
    code, err = _feed_then_stop(tmp_path, ["--out", str(out), "--bag", str(tmp_path / "bag"),
                                           "--mcap", str(tmp_path / "poses.mcap")], [], lambda: True, signal.SIGTERM)
    assert code == 130, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("interrupted:") and "no files written" in last, err
    assert "trajectory" not in err and "poses.mcap" not in err and "bag" not in last, err
    assert not out.exists() or not any(out.iterdir())
    assert not (tmp_path / "bag").exists() and not (tmp_path / "poses.mcap").exists()
