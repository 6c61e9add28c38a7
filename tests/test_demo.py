"""`mutloc demo` end to end on rendered images.

The demo runs once (through the command line, with a short sequence) and
every file it writes is checked against the truth recomputed here from the
same built-in worlds, not against numbers the demo reports about itself.
"""

import contextlib
import csv
import io
import json
import re

import cv2
import numpy as np
import pytest

from mutloc.cli.main import main
from mutloc.core.geometry import matrix_from_quaternion_xyzw, rotation_error_deg
from mutloc.errors import InputError
from mutloc.sim.demo import FILES, pair_pose, run_demo
from mutloc.sim.render import moving_world, project_markers, relative_pose, two_robot_world
from mutloc.sim.world import standard_rig

FRAMES = 6  # the default is 30; fewer keep the test short, the code path is the same
FPS = 10.0  # the default
MAX_T_M, MAX_ROT_DEG = 0.02, 0.5


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        status = main(["demo", "--out", str(out), "--frames", str(FRAMES), "--no-progress"])
    assert status == 0
    return out, stdout.getvalue()


@pytest.fixture(scope="module")
def rig():
    return standard_rig("balls")


def _tum(path):
    return np.loadtxt(path, comments="#", ndmin=2)


def test_every_listed_file_is_written(demo):
    out, _ = demo
    for entry in FILES:
        for name in entry.split(", "):
            assert (out / name).exists(), name
    for robot in ("p", "q"):
        assert sorted(p.name for p in (out / "sequence" / robot).iterdir()) == [f"{i:06d}.png" for i in range(FRAMES)]


def test_pair_estimate_matches_the_rendered_truth(demo, rig):
    out, _ = demo
    truth = relative_pose(two_robot_world(rig, pair_pose(), seed=0), "p", "q")
    result = json.loads((out / "result.json").read_text())
    assert (result["from"], result["to"]) == ("p", "q")
    assert sorted(result["markers_used"]) == ["M1", "M2", "M3", "M4"]
    err_t = np.linalg.norm(np.array(result["t"]) - truth.t)
    err_r = rotation_error_deg(np.array(result["R"]), truth.R)
    assert err_t < MAX_T_M and err_r < MAX_ROT_DEG
    # The reported uncertainty (1 px noise assumed) covers the error.
    cov = np.array(result["covariance"])
    assert err_t < 3 * np.sqrt(np.trace(cov[3:, 3:]))
    # The truth file holds the same truth.
    written = json.loads((out / "truth.json").read_text())
    np.testing.assert_allclose(written["t"], truth.t, atol=1e-9)
    np.testing.assert_allclose(written["R"], truth.R, atol=1e-9)


def test_detections_are_at_the_true_marker_projections(demo, rig):
    out, _ = demo
    world = two_robot_world(rig, pair_pose(), seed=0)
    dets = json.loads((out / "detections.json").read_text())
    for robot, others in (("p", ["M1", "M2"]), ("q", ["M3", "M4"])):
        exact = project_markers(world, robot)
        assert sorted(dets[robot]["detections"]) == others
        for name, d in dets[robot]["detections"].items():
            assert np.hypot(*(np.array(d["uv"]) - exact[name])) < 1.0, (robot, name)


def test_images_have_the_cameras_size(demo, rig):
    out, _ = demo
    w, h = rig.robot("q").camera.size
    for name in ("p.png", "q.png", "sequence/p/000000.png", "sequence/q/000000.png"):
        img = cv2.imread(str(out / name))
        assert img is not None and img.shape == (h, w, 3), name
    # Both views side by side.
    annotated = cv2.imread(str(out / "annotated.png"))
    assert annotated is not None and annotated.shape == (h, 2 * w, 3)
    # Not just the two views pasted: the detections and the pose are drawn on them.
    views = np.hstack([cv2.imread(str(out / "p.png")), cv2.imread(str(out / "q.png"))])
    assert np.count_nonzero(np.any(annotated != views, axis=2)) > 1000
    plot = cv2.imread(str(out / "trajectory.png"))
    assert plot is not None and min(plot.shape[:2]) > 300


def test_trajectory_files_match_the_moving_truth(demo, rig):
    out, _ = demo
    world = moving_world(rig, seed=0)
    times = np.arange(FRAMES) / FPS
    with open(out / "trajectory.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == FRAMES
    np.testing.assert_allclose([float(r["t"]) for r in rows], times, atol=1e-6)
    assert all(r["status"] == "solved" for r in rows), [r["status"] for r in rows]

    est = _tum(out / "trajectory.tum")
    assert est.shape == (FRAMES, 8)
    for row in est:
        T = relative_pose(world, "p", "q", row[0])
        assert np.linalg.norm(row[1:4] - T.t) < MAX_T_M, row[0]
        assert rotation_error_deg(matrix_from_quaternion_xyzw(row[4:]), T.R) < MAX_ROT_DEG, row[0]

    true = _tum(out / "truth.tum")
    assert true.shape == (FRAMES, 8)
    np.testing.assert_allclose(true[:, 0], times, atol=1e-9)
    for row in true:
        T = relative_pose(world, "p", "q", row[0])
        np.testing.assert_allclose(row[1:4], T.t, atol=1e-8)
        assert rotation_error_deg(matrix_from_quaternion_xyzw(row[4:]), T.R) < 1e-4

    stamps = (out / "sequence" / "frames.csv").read_text().splitlines()[1:]
    np.testing.assert_allclose([float(s.split(",")[1]) for s in stamps], times, atol=1e-9)


def test_report_and_console_state_the_real_errors(demo, rig):
    out, console = demo
    truth = relative_pose(two_robot_world(rig, pair_pose(), seed=0), "p", "q")
    result = json.loads((out / "result.json").read_text())
    err_cm = 100 * np.linalg.norm(np.array(result["t"]) - truth.t)
    err_deg = rotation_error_deg(np.array(result["R"]), truth.R)
    report = (out / "report.md").read_text()
    m = re.search(r"translation error \*\*([\d.]+) cm\*\*, rotation error \*\*([\d.]+) deg\*\*", report)
    assert m, report
    assert float(m.group(1)) == pytest.approx(err_cm, abs=0.006)
    assert float(m.group(2)) == pytest.approx(err_deg, abs=0.0006)
    assert f"frames solved: **{FRAMES} of {FRAMES}**" in report

    world = moving_world(rig, seed=0)
    est = _tum(out / "trajectory.tum")
    seq_cm = [100 * np.linalg.norm(r[1:4] - relative_pose(world, "p", "q", r[0]).t) for r in est]
    m = re.search(r"translation error median \*\*([\d.]+) cm\*\*, max ([\d.]+) cm", report)
    assert m, report
    assert float(m.group(1)) == pytest.approx(np.median(seq_cm), abs=0.006)
    assert float(m.group(2)) == pytest.approx(np.max(seq_cm), abs=0.006)
    for link in ("annotated.png", "trajectory.png", "result.json", "trajectory.tum", "truth.tum"):
        assert f"({link})" in report

    assert f"error {err_cm:.2f} cm, {err_deg:.3f} deg" in console
    assert f"{FRAMES} of {FRAMES} frames solved" in console
    assert str(out / "report.md") in console


def test_bad_arguments_are_typed_errors(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["demo", "--out", str(blocker), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mutloc: error:") and "not a folder" in err and len(err.strip().splitlines()) == 1
    with pytest.raises(InputError):
        run_demo(tmp_path / "x", frames=0)
    with pytest.raises(InputError):
        run_demo(tmp_path / "x", fps=float("nan"))


def test_fisheye_robots_turned_away_are_localized(demo):
    """The demo's robots with back-to-back fisheyes, back to back: the pose between their body frames from the
    four images against the scene's own placement (not the demo's truth file)."""
    from mutloc.sim.body_scenes import body_pair_pose

    out, console = demo
    T_wq, T_wp = body_pair_pose(2.0, 0, "away")
    truth = T_wq.inverse() @ T_wp
    result = json.loads((out / "fisheye" / "result.json").read_text())
    assert result["status"] == "solved"
    assert np.linalg.norm(np.array(result["t"]) - truth.t) < 0.01
    assert rotation_error_deg(np.array(result["R"]), truth.R) < 0.3
    assert "back cameras only: error" in console
