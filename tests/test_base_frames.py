"""Robot base frames: ``base_from_camera`` per robot, markers given in the
base frame (``frame: base``), and a track written base to base."""

import numpy as np
import pytest

from mutloc.cli.main import main
from mutloc.core.geometry import so3_exp, so3_log
from mutloc.core.pose import Pose, sandwich_covariance
from mutloc.errors import RigError
from mutloc.io import load_rig, save_rig
from mutloc.io.logs import write_observation_log
from mutloc.io.trajectory import read_trajectory_csv, read_tum
from mutloc.sim.render import default_path
from mutloc.sim.tracking import observation_sequence
from mutloc.sim.world import standard_rig

# Cameras 0.4 / 0.3 m above their bases, p's pitched down 10 degrees; bases are x forward, z up (ROS).
CAM_TO_BASE = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # optical -> x fwd, y left, z up
B = {"p": Pose(CAM_TO_BASE @ so3_exp([np.radians(10.0), 0.0, 0.0]), [0.1, 0.0, 0.4]),
     "q": Pose(CAM_TO_BASE, [0.05, 0.02, 0.3])}


def _rig_dict():
    """The standard ball rig with base frames; p's markers written in p's base frame."""
    d = standard_rig("balls").to_dict()
    d["robots"]["p"]["base_from_camera"] = {"R": B["p"].R.tolist(), "t": B["p"].t.tolist()}
    d["robots"]["q"]["base_from_camera"] = {"rotation": so3_log(B["q"].R).tolist(), "t": B["q"].t.tolist()}
    for m in d["robots"]["p"]["markers"].values():
        m["position"] = B["p"].apply(m["position"]).tolist()
        m["frame"] = "base"
    return d


def test_markers_in_the_base_frame_load_into_the_camera_frame(tmp_path):
    rig = load_rig(_rig_dict())
    std = standard_rig("balls")
    for name in ("M3", "M4", "M1", "M2"):
        np.testing.assert_allclose(rig.marker(name).position, std.marker(name).position, atol=1e-12)
    assert rig.robot("p").base_from_camera.rotation_error_deg(B["p"]) < 1e-9
    assert rig.robot("q").base_from_camera.rotation_error_deg(B["q"]) < 1e-6
    save_rig(rig, tmp_path / "rig.yaml")  # written in the camera frame, base frames kept
    back = load_rig(tmp_path / "rig.yaml")
    np.testing.assert_allclose(back.marker("M3").position, rig.marker("M3").position, atol=1e-12)
    assert back.robot("p").base_from_camera.translation_error(B["p"]) < 1e-12


@pytest.mark.parametrize("robot_spec,marker_spec,words", [
    ({"t": [0, 0, 0]}, None, ["base_from_camera", "exactly one of"]),
    ({"R": [[1, 0, 0], [0, 1, 0], [0, 0, -1]], "t": [0, 0, 0]}, None, ["not a rotation"]),
    ({"rotation": [0, 0, 0], "t": [0, 0, 400]}, None, ["millimetres"]),
    ({"rotaton": [0, 0, 0], "t": [0, 0, 0]}, None, ["did you mean 'rotation'"]),
    (None, {"position": [0.1, 0, 0], "frame": "base"}, ["needs the robot's base_from_camera"]),
    ({"rotation": [0, 0, 0], "t": [0, 0, 0]}, {"position": [0.1, 0, 0], "frame": "world"}, ["frame must be"]),
])
def test_bad_base_keys_are_named(robot_spec, marker_spec, words):
    d = standard_rig("balls").to_dict()
    if robot_spec is not None:
        d["robots"]["q"]["base_from_camera"] = robot_spec
    if marker_spec is not None:
        d["robots"]["q"]["markers"]["M1"] = marker_spec
    with pytest.raises(RigError) as info:
        load_rig(d)
    for w in words:
        assert w in str(info.value)


def test_sandwich_covariance_matches_sampling():
    rng = np.random.default_rng(0)
    T = default_path()(1.0)
    A, C = B["q"], B["p"].inverse()
    L = np.diag([0.01, 0.02, 0.005, 0.03, 0.01, 0.05])
    cov = sandwich_covariance(A, T, C, L @ L.T)
    ref = A @ T @ C
    samples = []
    for _ in range(4000):
        d = L @ rng.normal(size=6)
        Ts = A @ Pose(so3_exp(d[:3]) @ T.R, T.t + d[3:]) @ C
        samples.append(np.r_[so3_log(Ts.R @ ref.R.T), Ts.t - ref.t])
    np.testing.assert_allclose(np.sqrt(np.diag(np.cov(np.array(samples).T))), np.sqrt(np.diag(cov)), rtol=0.06)


def test_track_base_to_base(tmp_path, capsys):
    rig = load_rig(_rig_dict())
    seq = observation_sequence(rig, default_path(2.0, 12.0, 0.3), duration=1.0, fps=30.0, pixel_sigma=1.0, seed=1,
                               blind=())
    save_rig(_rig_dict(), tmp_path / "rig.yaml")
    write_observation_log(tmp_path / "log.jsonl", seq.frames)
    args = ["track", "--rig", str(tmp_path / "rig.yaml"), "--observations", str(tmp_path / "log.jsonl"),
            "--no-progress"]
    assert main(args + ["--out", str(tmp_path / "cam")]) == 0
    assert main(args + ["--out", str(tmp_path / "base"), "--frames", "base", "--bag", str(tmp_path / "bag")]) == 0
    cam = read_trajectory_csv(tmp_path / "cam" / "trajectory.csv")
    base = read_trajectory_csv(tmp_path / "base" / "trajectory.csv")
    assert [r["status"] for r in cam] == [r["status"] for r in base]
    errs, rots = [], []
    for rc, rb, T in zip(cam, base, seq.truth):
        truth = B["q"] @ T @ B["p"].inverse()
        errs.append(rb["pose"].translation_error(truth))
        rots.append(rb["pose"].rotation_error_deg(truth))
        # The same estimate, moved exactly: camera-frame pose composed with the base frames.
        moved = B["q"] @ rc["pose"] @ B["p"].inverse()
        assert rb["pose"].translation_error(moved) < 1e-7
    assert np.median(errs) < 0.02 and max(errs) < 0.06 and np.median(rots) < 0.5 and max(rots) < 2.0
    assert "base frame" in (tmp_path / "base" / "trajectory.tum").read_text().splitlines()[0]
    from rosbags.rosbag2 import Reader

    with Reader(tmp_path / "bag") as reader:
        assert {c.topic for c in reader.connections} == {"/mutloc/p_base_in_q_base", "/tf"}
    capsys.readouterr()
    # A robot without its base frame: a one-line error before any tracking.
    d = _rig_dict()
    for m in d["robots"]["p"]["markers"].values():
        m["position"] = B["p"].inverse().apply(m["position"]).tolist()
        del m["frame"]
    del d["robots"]["p"]["base_from_camera"]
    save_rig(d, tmp_path / "rig2.yaml")
    assert main(["track", "--rig", str(tmp_path / "rig2.yaml"), "--observations", str(tmp_path / "log.jsonl"),
                 "--out", str(tmp_path / "x"), "--frames", "base"]) == 2
    err = capsys.readouterr().err
    assert "base_from_camera" in err and "'p'" in err and err.count("\n") == 1
    assert not (tmp_path / "x").exists()
    times, _ = read_tum(tmp_path / "base" / "trajectory.tum")
    assert len(times) == len(base)
