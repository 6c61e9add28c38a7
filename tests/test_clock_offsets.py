"""Clock offsets estimated from a log (SPEC "The robots' own motion and clocks", ``--clock-offsets estimate``),
against the simulator's truth: a two-robot team whose r1 runs 40 ms behind r0 (``clock_offset``, recorded in
``truth.json`` as what is added to r1's stamps)."""

import json

import numpy as np
import pytest

from mutloc.api import load_rig
from mutloc.cli.main import main
from mutloc.io.logs import ObservationLogWriter
from mutloc.sim.scenario import write_team_simulation
from mutloc.sim.truth_log import truth_log
from mutloc.track.clocks import estimate_clock_offsets, shift_records
from mutloc.track.frames import expanded_rig
from mutloc.track.team import track_team_log

FRAMES = 90  # 3 s at 30 fps
FAST = {"grid": 7, "tol": 0.002}  # a coarser search than the default: seconds, not tens


@pytest.fixture(scope="module")
def moving(tmp_path_factory):
    out = tmp_path_factory.mktemp("clocks")
    write_team_simulation(out, robots=2, frames=FRAMES, fps=30.0, seed=0, images=False, room=False, speed=0.7,
                          clock_offset={"r1": 0.04})
    truth = json.loads((out / "truth.json").read_text())
    return out, expanded_rig(load_rig(out / "rig.yaml")), truth


def _median_error_cm(traj, truth) -> float:
    """r1's median translation error (cm) over the rows with a pose, the truth interpolated at each row's time."""
    ts = np.array([f["timestamp"] for f in truth["frames"]])
    xyz = np.array([f["robots"]["r1"]["t"] for f in truth["frames"]])
    errs = []
    for row in traj.tracks["r1"].rows:
        if row.estimate is None or not ts[0] <= row.t <= ts[-1]:
            continue
        true = np.array([np.interp(row.t, ts, xyz[:, i]) for i in range(3)])
        errs.append(np.linalg.norm(row.estimate.pose.t - true))
    assert len(errs) > FRAMES // 2
    return 100 * float(np.median(errs))


def test_shift_records_moves_exactly_the_robots_own_stamps(moving):
    out, rig, truth = moving
    log = truth_log(truth, seed=0)
    assert shift_records(rig, log, {}) == log
    moved = shift_records(rig, log, {"r1": 0.04})
    stamps = {o: [sorted(t for t, obs in recs for k in range(len(obs)) if obs.observer[k] == o) for recs in (log, moved)]
              for o in ("r0", "r1")}
    np.testing.assert_array_equal(stamps["r0"][1], stamps["r0"][0])
    np.testing.assert_allclose(stamps["r1"][1], np.array(stamps["r1"][0]) + 0.04, atol=1e-12)
    assert all(np.all(obs.time == t) for t, obs in moved)
    assert [t for t, _ in moved] == sorted(t for t, _ in moved)
    # back on the true times: each frame's r0 and r1 observations at its time (one record, or two rounding apart)
    true = np.array([f["timestamp"] for f in truth["frames"]])
    gaps = [np.abs(true - t).min() for t, _ in moved]
    assert max(gaps) < 1e-9 and len(moved) < 2 * len(true)


def test_a_40_ms_offset_is_found_and_the_corrected_track_is_as_good_as_a_synchronized_one(moving):
    out, rig, truth = moving
    off = truth["clock_offsets"]["r1"]
    log = truth_log(truth, seed=0)
    found = estimate_clock_offsets(rig, log, "r0", **FAST)
    c = found["r1"]
    assert c.offset_s is not None, c.reason
    assert abs(c.offset_s - off) < 0.005, (c, off)
    assert abs(c.offset_s - off) < 3 * c.sigma_s, (c, off)
    assert 0.0002 < c.sigma_s < 0.005, c
    corrected = track_team_log(rig, shift_records(rig, log, {"r1": c.offset_s}), "r0", progress=False)
    synchronized = track_team_log(rig, truth_log(truth, seed=0, clocks=False), "r0", progress=False)
    uncorrected = track_team_log(rig, log, "r0", progress=False)
    e_c, e_s, e_u = (_median_error_cm(t, truth) for t in (corrected, synchronized, uncorrected))
    assert e_c <= 1.25 * e_s, (e_c, e_s, e_u)
    assert e_u > 1.25 * e_s, (e_c, e_s, e_u)  # the offset matters in this scene (else the test shows nothing)


def test_robots_that_do_not_move_cannot_determine_it(moving):
    out, rig, truth = moving
    still = dict(truth, frames=[dict(f, observations=truth["frames"][0]["observations"]) for f in truth["frames"]])
    found = estimate_clock_offsets(rig, truth_log(still, seed=1), "r0", **FAST)
    assert found["r1"].offset_s is None and found["r1"].sigma_s is None
    assert "barely move" in found["r1"].reason or "edge" in found["r1"].reason, found["r1"]


def test_track_writes_clock_offsets_json_and_prints_them(moving, tmp_path, capsys):
    out, rig, truth = moving
    log = tmp_path / "log.jsonl"
    w = ObservationLogWriter(log)
    for t, obs in truth_log(truth, seed=2):
        w.write(t, obs)
    w.close()
    args = ["track", "--rig", str(out / "rig.yaml"), "--observations", str(log), "--reference", "r0",
            "--no-progress", "--out", str(tmp_path / "o")]
    assert main([*args, "--clock-offsets", "estimate"]) == 0
    printed = capsys.readouterr().out
    data = json.loads((tmp_path / "o" / "clock_offsets.json").read_text())
    assert set(data) == {"r1"} and set(data["r1"]) == {"offset_s", "sigma_s"}
    assert abs(data["r1"]["offset_s"] - 0.04) < 0.005
    assert f"clock offset of r1: {data['r1']['offset_s'] * 1000:+.1f} ms" in printed
    assert (tmp_path / "o" / "trajectory_r1.tum").exists()


def test_clock_offsets_need_the_filter(moving, tmp_path, capsys):
    out, rig, truth = moving
    log = tmp_path / "log.jsonl"
    log.write_text("")
    base = ["track", "--rig", str(out / "rig.yaml"), "--reference", "r0", "--no-progress", "--out",
            str(tmp_path / "o"), "--clock-offsets", "estimate"]
    assert main([*base, "--observations", str(log), "--filter", "none"]) != 0
    assert "needs --filter cv" in capsys.readouterr().err


def test_a_robots_odometry_is_put_on_the_reference_clock_by_its_offset(moving):
    from mutloc.core.odometry import Odometry
    from mutloc.io.trajectory import read_tum
    from mutloc.track.filtering import FilterOptions
    from mutloc.track.team_tracker import TeamTracker

    out, rig, truth = moving
    stamps, poses = read_tum(out / "odometry_r1.tum")  # on r1's clock: the true times minus 40 ms
    odo = Odometry(stamps, poses, source="sim r1")
    tracker = TeamTracker(rig, "r0", options=FilterOptions(odometry={"r1": odo}, clock_offsets={"r1": 0.04}))
    held, offset = tracker.filter.odometry[tracker.filter.index("r1")]
    assert held is odo and offset == truth["clock_offsets"]["r1"]
