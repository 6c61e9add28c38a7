"""``mutloc simulate``: every file written, loadable with mutloc's own loaders,
and consistent with an independent projection of the ground-truth pose."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from mutloc.cli.main import main
from mutloc.core.geometry import matrix_from_quaternion_xyzw
from mutloc.io import load_observations, load_rig


def project(cam, X: np.ndarray) -> np.ndarray:
    uv, _ = cv2.projectPoints(np.asarray(X, float).reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K,
                              cam.dist[: max(cam.n_dist, 5)])
    return uv.reshape(-1, 2)


def check_frame(rig, frame: dict) -> tuple[np.ndarray, np.ndarray]:
    """T_qp of a truth frame is a rotation whose quaternion matches R, and the
    observations are its exact projections; returns (R, t)."""
    R = np.array(frame["T_qp"]["R"])
    t = np.array(frame["T_qp"]["t"])
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    np.testing.assert_allclose(matrix_from_quaternion_xyzw(frame["T_qp"]["quaternion_xyzw"]), R, atol=1e-9)
    obs = load_observations(frame["observations"]).to_dict()
    for observer, other, (Ro, to) in (("q", "p", (R, t)), ("p", "q", (R.T, -R.T @ t))):
        cam = rig.robot(observer).camera
        names = list(rig.robot(other).markers)
        want = project(cam, rig.robot(other).marker_positions(names) @ Ro.T + to)
        assert sorted(obs[observer]) == sorted(names)
        for name, uv in zip(names, want):
            np.testing.assert_allclose(obs[observer][name], uv, atol=1e-6)
    return R, t


def test_single_frame(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "sim"
    assert main(["simulate", "--out", str(out), "--distance", "2.5", "--k1", "-0.3", "--seed", "4"]) == 0
    assert "wrote 1 frame" in capsys.readouterr().out
    for name in ("rig.yaml", "p.png", "q.png", "truth.json", "observations.json"):
        assert (out / name).is_file(), name
    rig = load_rig(out / "rig.yaml")
    assert sorted(rig.robots) == ["p", "q"]
    cam = rig.robot("q").camera
    assert cam.size == (960, 540) and cam.dist[0] == pytest.approx(-0.3)
    for robot in ("p", "q"):
        img = cv2.imread(str(out / f"{robot}.png"))
        assert img is not None and img.shape == (540, 960, 3)
    truth = json.loads((out / "truth.json").read_text())
    assert len(truth["frames"]) == 1
    _, t = check_frame(rig, truth["frames"][0])
    assert np.linalg.norm(t) == pytest.approx(2.5, rel=0.05)
    assert load_observations(out / "observations.json") == load_observations(truth["frames"][0]["observations"])


def test_sequence(tmp_path: Path) -> None:
    out = tmp_path / "seq"
    args = ["simulate", "--out", str(out), "--frames", "3", "--fps", "10", "--markers", "lights",
            "--size", "320x240", "--focal", "300", "--noise", "2", "--jpeg", "90", "--blur", "1.5"]
    assert main(args) == 0
    for robot in ("p", "q"):
        files = sorted(p.name for p in (out / robot).iterdir())
        assert files == ["000000.png", "000001.png", "000002.png"]
        assert cv2.imread(str(out / robot / "000002.png")).shape == (240, 320, 3)
    rig = load_rig(out / "rig.yaml")
    assert all(m.blink_hz for r in rig.robots.values() for m in r.markers.values())
    with open(out / "frames.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["frame", "timestamp"]
    assert [(int(a), float(b)) for a, b in rows[1:]] == [(0, 0.0), (1, pytest.approx(0.1)), (2, pytest.approx(0.2))]
    truth = json.loads((out / "truth.json").read_text())
    tum = [line.split() for line in (out / "truth.tum").read_text().splitlines() if not line.startswith("#")]
    assert len(truth["frames"]) == len(tum) == 3
    prev = None
    for frame, row in zip(truth["frames"], tum):
        R, t = check_frame(rig, frame)
        vals = np.array(row, float)
        assert vals[0] == pytest.approx(frame["timestamp"])
        np.testing.assert_allclose(vals[1:4], t, atol=1e-8)
        np.testing.assert_allclose(matrix_from_quaternion_xyzw(vals[4:]), R, atol=1e-7)
        if prev is not None:
            assert np.linalg.norm(t - prev) > 1e-3  # p moves
        prev = t


@pytest.mark.parametrize("kind", ["tags", "cylinders"])
def test_other_marker_kinds(tmp_path: Path, kind: str) -> None:
    out = tmp_path / kind
    assert main(["simulate", "--out", str(out), "--markers", kind, "--size", "480x270", "--focal", "400",
                 "--no-room", "--noise", "0"]) == 0
    rig = load_rig(out / "rig.yaml")
    truth = json.loads((out / "truth.json").read_text())
    check_frame(rig, truth["frames"][0])
    assert truth["frames"][0]["hidden"] == {"p": [], "q": []}
    if kind == "tags":
        d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
        _, ids, _ = cv2.aruco.ArucoDetector(d).detectMarkers(cv2.imread(str(out / "q.png"), cv2.IMREAD_GRAYSCALE))
        assert sorted(ids.ravel().tolist()) == sorted(m.tag["id"] for m in rig.robot("p").markers.values())
    else:
        assert all("cylinder" in m.extra for m in rig.robot("p").markers.values())


def test_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["simulate", "--out", str(blocker)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mutloc: error:") and len(err.strip().splitlines()) == 1
    assert main(["simulate", "--out", str(tmp_path / "k"), "--k1", "-3"]) == 2
    err = capsys.readouterr().err
    assert "k1" in err and len(err.strip().splitlines()) == 1
    with pytest.raises(SystemExit):
        main(["simulate", "--out", str(tmp_path / "x"), "--markers", "smoke"])
    with pytest.raises(SystemExit):
        main(["simulate", "--out", str(tmp_path / "x"), "--size", "big"])


def test_simulated_cameras_at_their_own_times_are_tracked(tmp_path, capsys):
    """simulate --camera-offset/--camera-fps renders each camera at its own
    times (each folder its own frames.csv); track takes every frame at its
    own time and holds the rendered truth."""
    import json

    import numpy as np

    from mutloc.io.trajectory import read_trajectory_csv, read_tum

    out = tmp_path / "sim"
    assert main(["simulate", "--out", str(out), "--frames", "6", "--fps", "15", "--camera-offset", "q=0.0333",
                 "--no-progress"]) == 0
    truth = json.loads((out / "truth.json").read_text())
    assert [f["cameras"] for f in truth["frames"]] == [["p"], ["q"]] * 6
    q_times = [float(line.split(",")[1]) for line in (out / "q" / "frames.csv").read_text().splitlines()[1:]]
    assert np.allclose(q_times, 0.0333 + np.arange(6) / 15)
    assert main(["track", "--rig", str(out / "rig.yaml"), "--stream", f"p={out / 'p'}", "--stream",
                 f"q={out / 'q'}", "--out", str(tmp_path / "trk"), "--no-progress"]) == 0
    rows = read_trajectory_csv(tmp_path / "trk" / "trajectory.csv")
    times, poses = read_tum(out / "truth.tum")
    assert len(rows) == 12 and np.allclose([r["t"] for r in rows], times, atol=1e-6)
    err = [r["pose"].translation_error(T) for r, T in zip(rows, poses) if r["pose"] is not None]
    assert len(err) >= 8 and np.median(err) < 0.01
    capsys.readouterr()
    for bad in (["--frames", "1", "--camera-fps", "q=15"], ["--frames", "4", "--camera-offset", "q=0.5"],
                ["--frames", "4", "--camera-fps", "r=15"], ["--frames", "4", "--camera-fps", "q=fast"]):
        assert main(["simulate", "--out", str(tmp_path / "bad"), *bad]) == 2
        err_text = capsys.readouterr().err.strip()
        assert len(err_text.splitlines()) == 1 and "camera" in err_text


def test_simulated_team_cameras_at_their_own_times(tmp_path):
    """A team whose cameras capture a third of a frame apart: every capture
    instant holds one camera's observations, at its own time."""
    out = tmp_path / "team"
    assert main(["simulate", "--out", str(out), "--robots", "3", "--markers", "tags", "--frames", "4", "--fps", "10",
                 "--camera-offset", "r1=0.0333", "--camera-offset", "r2=0.0667", "--no-images", "--no-progress"]) == 0
    truth = json.loads((out / "truth.json").read_text())
    frames = truth["frames"]
    assert [f["cameras"] for f in frames] == [["r0"], ["r1"], ["r2"]] * 4
    assert np.allclose([f["timestamp"] for f in frames],
                       np.sort(np.r_[np.arange(4) / 10, 0.0333 + np.arange(4) / 10, 0.0667 + np.arange(4) / 10]))
    assert all(set(f["observations"]) <= set(f["cameras"]) for f in frames)
    assert any(f["observations"] for f in frames)
