"""``mutloc simulate``'s odometry and clocks: each moving robot's drifting
odometry agrees with the simulator's truth within the noise it is said to
have, and a robot's clock offset moves exactly its stamps."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from scipy.stats import chi2

from mutloc.cli.main import main
from mutloc.core.geometry import so3_exp, so3_log
from mutloc.core.odometry import OdometryNoise
from mutloc.core.pose import Pose
from mutloc.io.trajectory import read_tum
from mutloc.track.odometry import read_tum_odometry


def _spec_error(est: Pose, true: Pose) -> np.ndarray:
    return np.concatenate([so3_log(true.R @ est.R.T), true.t - est.t])


def _perturbed(pose: Pose, e: np.ndarray) -> Pose:
    return Pose(so3_exp(e[:3]) @ pose.R, pose.t + e[3:])


def _predict(A: Pose, D0: Pose, Dn: Pose) -> Pose:
    """T_ref_n(t1) from T_ref_n(t0) and both robots' own motion from t0 to t1."""
    return D0.inverse() @ A @ Dn


def test_odometry_of_two_moving_robots_predicts_their_relative_pose_within_its_covariance(tmp_path):
    """r1's pose in r0's frame carried from t0 to t1 by both robots' odometry
    (what fusing it will do): the error against the truth at t1, over 60
    disjoint stretches, is as large as the two increments' covariances say
    (NEES with the simulator's own noise), and within the default's."""
    out = tmp_path / "team"
    assert main(["simulate", "--out", str(out), "--robots", "3", "--frames", "121", "--fps", "10", "--no-images",
                 "--speed", "1.0", "--turn-rate", "70", "--seed", "5", "--odometry-drift", "1,0.3"]) == 0
    truth = json.loads((out / "truth.json").read_text())
    times = np.array([f["timestamp"] for f in truth["frames"]])
    rel = {i: Pose(np.array(f["robots"]["r1"]["R"]), np.array(f["robots"]["r1"]["t"]))
           for i, f in enumerate(truth["frames"])}
    stated = OdometryNoise(distance=0.01, deg_per_m=0.3, turn=0.0, floor_m=1e-7, floor_deg=1e-7)
    odo = {n: read_tum_odometry(out / f"odometry_{n}.tum", noise=stated) for n in ("r0", "r1")}
    default = {n: read_tum_odometry(out / f"odometry_{n}.tum") for n in ("r0", "r1")}
    nees, nees_default, moved = [], [], []
    for i in range(0, 120, 2):  # 0.2 s stretches
        j = i + 2
        A, B = rel[i], rel[j]
        for source, out_list in ((odo, nees), (default, nees_default)):
            i0, i1 = (source[n].increment(times[i], times[j]) for n in ("r0", "r1"))
            pred = _predict(A, i0.pose, i1.pose)
            # the prediction's covariance: both increments' errors through it (numerical Jacobian)
            J = np.zeros((6, 12))
            for k in range(12):
                e = np.zeros(12)
                e[k] = 1e-7
                Jk = _spec_error(pred, _predict(A, _perturbed(i0.pose, e[:6]), _perturbed(i1.pose, e[6:])))
                J[:, k] = Jk / 1e-7
            C = J[:, :6] @ i0.covariance @ J[:, :6].T + J[:, 6:] @ i1.covariance @ J[:, 6:].T
            err = _spec_error(pred, B)
            out_list.append(err @ np.linalg.solve(C, err))
        moved.append(float(np.linalg.norm(i1.pose.t)))
    nees = np.array(nees)
    assert np.median(moved) > 0.1  # the robots move: about 20 cm per stretch
    lo, hi = chi2.ppf([0.0005, 0.9995], 6 * len(nees)) / len(nees)
    assert lo < nees.mean() < hi, nees.mean()
    assert np.max(nees_default) < chi2.ppf(0.999, 6), (nees.mean(), np.max(nees_default))


def _frames(path):
    with open(path, newline="") as fh:
        return [(int(r["frame"]), float(r["timestamp"])) for r in csv.DictReader(fh)]


def test_a_clock_offset_moves_exactly_that_robots_stamps(tmp_path):
    common = ["simulate", "--frames", "3", "--size", "64x48", "--no-room", "--no-progress", "--seed", "2"]
    assert main([*common, "--out", str(tmp_path / "a")]) == 0
    assert main([*common, "--out", str(tmp_path / "b"), "--clock-offset", "p=0.04"]) == 0
    a, b = tmp_path / "a", tmp_path / "b"
    ta, tb = (json.loads((d / "truth.json").read_text()) for d in (a, b))
    assert "clock_offsets" not in ta and tb["clock_offsets"] == {"p": 0.04}
    assert [f["timestamp"] for f in ta["frames"]] == [f["timestamp"] for f in tb["frames"]]  # true times kept
    shared = _frames(a / "frames.csv")
    assert not (a / "p" / "frames.csv").exists()
    assert _frames(b / "q" / "frames.csv") == shared
    assert [(k, round(t, 9)) for k, t in _frames(b / "p" / "frames.csv")] == [(k, round(t - 0.04, 9))
                                                                             for k, t in shared]
    for robot, shift in (("p", 0.04), ("q", 0.0)):
        (sa, pa), (sb, pb) = read_tum(a / f"odometry_{robot}.tum"), read_tum(b / f"odometry_{robot}.tum")
        np.testing.assert_allclose(sb, sa - shift, atol=1e-9)
        np.testing.assert_allclose(pb.t, pa.t, atol=1e-9)
    # the default rate: 50 Hz over the sequence
    sa, _ = read_tum(a / "odometry_p.tum")
    np.testing.assert_allclose(np.diff(sa), 0.02, atol=1e-9)
    assert sa[-1] >= ta["frames"][-1]["timestamp"]


@pytest.mark.parametrize("argv, message", [
    (["--frames", "3", "--clock-offset", "q=0.1"], "q is the reference"),
    (["--frames", "3", "--clock-offset", "z=0.1"], "unknown robot 'z'"),
    (["--clock-offset", "p=0.1"], "for sequences"),
    (["--frames", "3", "--odometry-rate", "20", "--cameras", "back-to-back-fisheye"], "for sequences"),
    (["--frames", "3", "--robots", "3", "--no-images", "--clock-offset", "r0=0.1"], "r0 is the reference"),
])
def test_refusals(tmp_path, capsys, argv, message):
    assert main(["simulate", "--out", str(tmp_path / "x"), *argv]) != 0
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_bad_drift_is_an_argument_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "--out", str(tmp_path / "x"), "--frames", "3", "--odometry-drift", "1"])
    assert exc.value.code != 0 and "PCT,DEG_PER_M" in capsys.readouterr().err


def test_a_robot_standing_still_gets_no_odometry_file(tmp_path):
    from mutloc.sim.odometry import write_odometry

    still = Pose.from_rotvec([0.1, 0.2, 0.3], [1.0, 2.0, 3.0])
    written = write_odometry(tmp_path, {"a": lambda t: still, "b": lambda t: Pose.from_rotvec([0, t, 0], [t, 0, 0])},
                             1.0, rate=50.0, drift=(1.0, 0.3), seed=0, clock_offset={})
    assert written == ["odometry_b.tum"] and sorted(p.name for p in tmp_path.iterdir()) == written
