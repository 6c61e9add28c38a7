"""The example files of the manual (docs/examples/, shown in docs/formats.md)
load with the library and give the poses they claim.

Ground truth: ``truth.json``, ``log_truth.tum`` and ``team_truth.json`` are
the poses ``mutloc simulate`` placed the robots at, and the observation
files are the projections (or detections) seen in those scenes; the pose files
(``result.json``, ``trajectory.*``, ``team_result.json``) are what mutloc
printed for them.  A change that breaks an example -- a renamed key, a
format the reader no longer accepts, an output that no longer matches the
command -- fails here.  docs/formats.md names the command that wrote each
output file: run it again when a deliberate change moves the output.

Every ``python`` block of README.md and of the manual's pages (getting
started, the guides) runs as written: a page's blocks in order, in one
namespace, as a reader would paste them, in a folder holding the files the
page's text has the reader make before (the project's own examples, the
simulator's rig and logs).  A block that is not meant to run says so just
above its fence, ``<!-- docs-test: not run: REASON -->``, and every such
block is listed in :data:`NOT_RUN` (so none is skipped in silence).
docs/guides/cameras.md is run by its own test, which also checks what it
prints.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

import mutloc
from mutloc.core.rig import MarkerKind
from mutloc.io.logs import iter_observation_log
from mutloc.io.trajectory import CSV_COLUMNS, read_trajectory_csv, read_tum
from mutloc.track.tracker import track_log

EXAMPLES = Path(__file__).resolve().parents[1] / "docs" / "examples"

# Every file under docs/examples and the test that reads it.
TESTED = {
    "rig.yaml": "test_pair_example",
    "observations.json": "test_pair_example",
    "truth.json": "test_pair_example",
    "result.json": "test_pair_example",
    "rig_camera_files.yaml": "test_camera_files",
    "cameras/p_camera_info.yaml": "test_camera_files",
    "cameras/q_opencv.xml": "test_camera_files",
    "rig_marker_kinds.yaml": "test_marker_kinds",
    "rig_cameras.yaml": "test_cameras_example",
    "cameras/p_back_camera_info.yaml": "test_cameras_example",
    "cameras/q_camchain.yaml": "test_cameras_example",
    "log.jsonl": "test_log_example",
    "log_truth.tum": "test_log_example",
    "trajectory.csv": "test_log_example",
    "trajectory.tum": "test_log_example",
    "team_rig.yaml": "test_team_example",
    "team_observations.json": "test_team_example",
    "team_truth.json": "test_team_example",
    "team_result.json": "test_team_example",
    "experiment_noise_results.json": "test_experiment_results",
}


def ex(name: str) -> Path:
    return EXAMPLES / name


def pose_errors(R, t, R_gt, t_gt) -> tuple[float, float]:
    """(translation error in metres, rotation error in degrees), the SPEC's measures."""
    return mutloc.translation_error(t, t_gt), mutloc.rotation_error_deg(np.asarray(R), np.asarray(R_gt))


def test_every_example_is_tested():
    on_disk = {str(p.relative_to(EXAMPLES)) for p in EXAMPLES.rglob("*") if p.is_file()}
    assert on_disk == set(TESTED), "an example file without a test (or a test of a missing file)"


def test_pair_example():
    rig = mutloc.load_rig(ex("rig.yaml"))
    assert list(rig.robots) == ["p", "q"]
    assert {m.kind for r in rig.robots.values() for m in r.markers.values()} == {MarkerKind.BALL}
    obs = mutloc.load_observations(ex("observations.json"))
    est = mutloc.localize(rig, obs)
    truth = json.loads(ex("truth.json").read_text())
    assert (est.source, est.target) == (truth["from"], truth["to"])
    assert est.status == "solved"
    dt, dr = pose_errors(est.R, est.t, truth["R"], truth["t"])
    assert dt < 1e-3 and dr < 0.05, (dt, dr)

    # result.json is what `mutloc localize` prints for these files
    shown = json.loads(ex("result.json").read_text())
    now = json.loads(json.dumps(est.to_dict(), default=lambda a: np.asarray(a).tolist()))
    spec_keys = {"from", "to", "R", "t", "quaternion_xyzw", "reprojection_rms_px", "covariance", "pixel_sigma",
                 "markers_used"}
    assert spec_keys <= set(shown) and set(shown) <= set(now)
    assert (shown["from"], shown["to"]) == (truth["from"], truth["to"])
    np.testing.assert_allclose(shown["R"], now["R"], atol=1e-6)
    np.testing.assert_allclose(shown["t"], now["t"], atol=1e-6)
    np.testing.assert_allclose(shown["covariance"], now["covariance"], rtol=1e-3, atol=1e-12)
    assert sorted(shown["markers_used"]) == sorted(now["markers_used"]) == ["M1", "M2", "M3", "M4"]
    assert shown["status"] == "solved" and shown["consistency"]["passed"]


def test_camera_files():
    inline = mutloc.load_rig(ex("rig.yaml"))
    from_files = mutloc.load_rig(ex("rig_camera_files.yaml"))
    for name in ("p", "q"):
        a, b = inline.robot(name).camera, from_files.robot(name).camera
        np.testing.assert_array_equal(a.K, b.K)
        assert a.size == b.size == (960, 540)
        assert not np.any(b.dist)
    a = mutloc.localize(inline, mutloc.load_observations(ex("observations.json")))
    b = mutloc.localize(from_files, mutloc.load_observations(ex("observations.json")))
    np.testing.assert_allclose(a.t, b.t, atol=1e-12)


def test_cameras_example():
    """Each camera where the example's comments put it: the optical axis (camera z) and right (camera x) of each
    camera in its robot's base_link (x forward, y left, z up), the lens from its file."""
    rig = mutloc.load_rig(ex("rig_cameras.yaml"))
    assert rig.observer_keys() == ["p/front", "p/back", "q/left", "q/right"]
    where = {  # key: (centre, axis, right)
        "p/front": ([0.12, 0, 0.30], [1, 0, 0], [0, -1, 0]),
        "p/back": ([-0.12, 0, 0.30], [-1, 0, 0], [0, 1, 0]),
        "q/left": ([0.10, 0.05, 0.25], [1, 0, 0], [0, -1, 0]),
        "q/right": ([0.10, -0.05, 0.25], [1, 0, 0], [0, -1, 0]),
    }
    for key, (centre, axis, right) in where.items():
        m = rig.mount(key)
        assert m.camera.model == "fisheye" and m.camera.size == (1280, 800)
        np.testing.assert_allclose(m.pose.t, centre, atol=1e-12)
        np.testing.assert_allclose(m.pose.R[:, 2], axis, atol=1e-12)
        np.testing.assert_allclose(m.pose.R[:, 0], right, atol=1e-12)
    np.testing.assert_array_equal(rig.mount("p/back").camera.dist, [0.011, -0.0035, 0.0005, -0.0001])
    np.testing.assert_array_equal(rig.mount("q/right").camera.K, [[290.1, 0, 641.2], [0, 290.3, 398.8], [0, 0, 1]])


def test_marker_kinds():
    rig = mutloc.load_rig(ex("rig_marker_kinds.yaml"))
    kinds = {m.name: m.kind for r in rig.robots.values() for m in r.markers.values()}
    assert kinds == {"L1": MarkerKind.LIGHT, "L2": MarkerKind.LIGHT, "T0": MarkerKind.TAG,
                     "C1": MarkerKind.CYLINDER, "X1": MarkerKind.POINT}
    # L2 is given in p's base frame: stored in the camera frame, x_cam = R^T (x_base - t)
    R = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)
    t = np.array([0.1, 0.0, 0.4])
    np.testing.assert_allclose(rig.marker("L2").position, R.T @ (np.array([0.07, -0.15, 0.45]) - t), atol=1e-12)
    np.testing.assert_allclose(rig.robot("p").base_from_camera.R, R, atol=1e-12)
    assert rig.marker("X1").extra["x_note"].startswith("keys starting with x_ are yours")
    assert rig.marker("T0").tag["family"] == "tag36h11" and rig.marker("T0").tag["size"] == 0.1


def test_log_example():
    rig = mutloc.load_rig(ex("rig.yaml"))
    frames = list(iter_observation_log(ex("log.jsonl")))
    times = [t for t, _ in frames]
    assert len(frames) == 10 and times == sorted(times)
    assert frames[6][1].observers == ["p"]     # one camera's record
    traj = track_log(rig, frames, progress=False)
    statuses = [r.status.value for r in traj.rows]
    assert statuses == ["solved"] * 6 + ["partial"] + ["solved"] * 3

    truth_t, truth = read_tum(ex("log_truth.tum"))
    np.testing.assert_allclose(truth_t, times)
    for row, R_gt, t_gt in zip(traj.rows, truth.R, truth.t):
        dt, dr = pose_errors(row.estimate.R, row.estimate.t, R_gt, t_gt)
        assert dt < 0.01 and dr < 0.5, (row.t, dt, dr)

    # trajectory.csv / .tum are what `mutloc track --observations log.jsonl` writes
    rows = read_trajectory_csv(ex("trajectory.csv"))
    header = ex("trajectory.csv").read_text().splitlines()[0].split(",")
    assert tuple(header[: len(CSV_COLUMNS)]) == CSV_COLUMNS
    assert [r["status"] for r in rows] == statuses
    tum_t, tum = read_tum(ex("trajectory.tum"))
    np.testing.assert_allclose(tum_t, [r["t"] for r in rows])
    for shown, row, R_tum, t_tum in zip(rows, traj.rows, tum.R, tum.t):
        np.testing.assert_allclose(shown["pose"].t, t_tum, atol=1e-9)
        dt, dr = pose_errors(shown["pose"].R, shown["pose"].t, row.estimate.R, row.estimate.t)
        assert dt < 2e-3 and dr < 0.1, (row.t, dt, dr)
        sigma = np.sqrt(np.diag(row.estimate.covariance))
        np.testing.assert_allclose(shown["sigma"], sigma, rtol=0.2)


def test_team_example():
    rig = mutloc.load_rig(ex("team_rig.yaml"))
    team = mutloc.localize_team(rig, mutloc.load_observations(ex("team_observations.json")))
    truth = json.loads(ex("team_truth.json").read_text())
    assert team.reference == truth["reference"] == "r0"
    assert sorted(team.robots) == sorted(truth["robots"]) and team.unlocalized == []
    for name, gt in truth["robots"].items():
        dt, dr = pose_errors(team.poses[name].R, team.poses[name].t, gt["R"], gt["t"])
        assert dt < 1e-3 and dr < 0.05, (name, dt, dr)
    shown = json.loads(ex("team_result.json").read_text())
    assert {"reference", "robots", "unlocalized", "reprojection_rms_px", "pixel_sigma",
            "observations_used"} <= set(shown)
    for name, entry in shown["robots"].items():
        assert {"R", "t", "quaternion_xyzw", "covariance"} <= set(entry)
        np.testing.assert_allclose(entry["t"], team.poses[name].t, atol=1e-4)
        assert np.array(entry["covariance"]).shape == (6, 6)
    assert shown["observations_used"] == team.observations_used == 16


def test_experiment_results():
    res = json.loads(ex("experiment_noise_results.json").read_text())
    assert res["experiment"] == "noise" and isinstance(res["seed"], int)
    n = len(res["sigma_px"])
    assert n >= 1

    def check(methods):
        assert set(methods) >= {"best_root", "refined", "crlb"}
        for m in methods.values():
            for key in ("median_translation_m", "median_rotation_deg"):
                assert len(m[key]) == n and all(math.isfinite(v) and v >= 0 for v in m[key])

    check(res["methods"])
    assert res["by_distance_m"]
    for entry in res["by_distance_m"].values():
        check(entry["methods"])


@pytest.mark.parametrize("name", ["observations.json", "team_observations.json"])
def test_observation_examples_name_rig_markers(name):
    # every observed marker belongs to another robot of the matching rig
    rig = mutloc.load_rig(ex("team_rig.yaml" if name.startswith("team") else "rig.yaml"))
    data = json.loads(ex(name).read_text())
    for observer, seen in data.items():
        for marker in seen:
            assert rig.owner(marker) != observer


GUIDES = EXAMPLES.parent / "guides"
ROOT = EXAMPLES.parents[1]
#: The pages whose python blocks run (README.md, getting started, every guide).
PAGES = ["README.md", "docs/getting-started.md", *sorted(f"docs/guides/{p.name}" for p in GUIDES.glob("*.md"))]
NOT_RUN_MARK = re.compile(r"<!-- docs-test: not run: (.+?) -->\s*$")
#: (page, index of the python block on it): why it is not run.  Exactly the blocks marked so.
NOT_RUN = {
    ("docs/getting-started.md", 0): "a script run on your own chessboard photos (python calibrate_camera.py OUT PHOTOS)",
}


def _blocks(text: str, lang: str) -> list[str]:
    return re.findall(rf"^```{lang}\n(.*?)^```", text, re.DOTALL | re.MULTILINE)


def _python_blocks(page: str) -> list[tuple[str, str | None]]:
    """``(code, reason)`` of each python block of ``page``, ``reason`` the
    not-run mark just above its fence (None: the block runs)."""
    lines = (ROOT / page).read_text(encoding="utf-8").splitlines(keepends=True)
    out, i = [], 0
    while i < len(lines):
        if lines[i].rstrip() == "```python":
            above = next((ln for ln in reversed(lines[:i]) if ln.strip()), "")
            mark = NOT_RUN_MARK.search(above)
            j = next(k for k in range(i + 1, len(lines)) if lines[k].startswith("```"))
            out.append(("".join(lines[i + 1:j]), mark.group(1) if mark else None))
            i = j
        i += 1
    return out


def test_not_run_blocks_are_marked_and_counted():
    """Every python block of the pages either runs (below) or is marked not
    to, and the marked ones are exactly :data:`NOT_RUN`."""
    marked = {(page, k): reason for page in PAGES for k, (_, reason) in enumerate(_python_blocks(page)) if reason}
    assert marked == NOT_RUN
    ran = sum(1 for page in PAGES for _, reason in _python_blocks(page) if reason is None)
    assert ran >= 9 and len(NOT_RUN) == 1, (ran, len(NOT_RUN))


def _copy(name: str, to: Path) -> None:
    to.parent.mkdir(parents=True, exist_ok=True)
    to.write_bytes(ex(name).read_bytes())


def _setup_readme(d: Path) -> dict:
    (d / "docs").symlink_to(ROOT / "docs")  # the README's paths are from the repository's root
    return {}


def _setup_getting_started(d: Path) -> dict:
    _copy("rig.yaml", d / "sim" / "rig.yaml")  # what `mutloc simulate --out sim` wrote, earlier on the page
    _copy("observations.json", d / "sim" / "observations.json")
    return {}


def _setup_calibration(d: Path) -> dict:
    """A recording of the standard ball rig, and the rig measured 1-2 cm off (the page's `track --observations-out`)."""
    from mutloc.io import save_rig
    from mutloc.io.logs import write_observation_log
    from mutloc.sim.calibration import ball_rig, pair_sequence, perturb_rig

    rng = np.random.default_rng(9)
    truth = ball_rig(2)
    save_rig(mutloc.load_rig(perturb_rig(truth, rng)), d / "rig.yaml")
    (d / "trk").mkdir()
    write_observation_log(d / "trk" / "log.jsonl", pair_sequence(truth, 30, rng, pixel_sigma=0.5).frames)
    return {}


def _setup_live(d: Path) -> dict:
    """The rig, and one message of p's node as the localizer receives it (the page's `message`, arriving `now`)."""
    import time

    from mutloc.live.messages import observations_message, rig_id

    _copy("rig.yaml", d / "rig.yaml")
    now = time.time()
    obs = mutloc.load_observations(ex("observations.json"))
    return {"message": observations_message("p", rig_id(d / "rig.yaml"), 1, now, obs), "now": now}


def _setup_teams(d: Path) -> dict:
    _copy("team_rig.yaml", d / "team" / "rig.yaml")  # what `mutloc simulate --robots 3` wrote, earlier on the page
    _copy("team_observations.json", d / "team" / "observations.json")
    return {}


def _setup_tracking(d: Path) -> dict:
    """The rig and a log (the examples'), and two short videos of the demo's scene as the cameras' recordings."""
    import cv2

    from mutloc.sim.render import moving_world, render
    from mutloc.sim.world import standard_rig

    _copy("rig.yaml", d / "rig.yaml")
    _copy("log.jsonl", d / "traj" / "log.jsonl")
    (d / "out").mkdir()
    world = moving_world(standard_rig("balls"), seed=0)
    for robot in ("p", "q"):
        video = cv2.VideoWriter(str(d / f"{robot}.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (960, 540))
        for i in range(3):
            video.write(render(world, robot, i / 10.0, seed=i))
        video.release()
    return {}


SETUPS = {"README.md": _setup_readme, "docs/getting-started.md": _setup_getting_started,
          "docs/guides/calibration.md": _setup_calibration, "docs/guides/live.md": _setup_live,
          "docs/guides/teams.md": _setup_teams, "docs/guides/tracking.md": _setup_tracking}


def test_every_page_with_python_is_run():
    with_code = {page for page in PAGES if _python_blocks(page)}
    assert with_code == set(SETUPS) | {"docs/guides/cameras.md"}  # cameras.md: test_cameras_guide_code_runs


def _run_page(page: str, d: Path, monkeypatch) -> dict:
    """Run the page's blocks (but the marked ones) in ``d`` after its setup; the namespace."""
    monkeypatch.chdir(d)
    ns: dict = {"__name__": "__guide__", **SETUPS[page](d)}
    for code, reason in _python_blocks(page):
        if reason is None:
            exec(compile(code, page, "exec"), ns)  # noqa: S102 -- the manual's own code
    return ns


@pytest.mark.parametrize("page", sorted(SETUPS))
def test_page_code_runs(page, tmp_path, monkeypatch, capsys):
    ns = _run_page(page, tmp_path, monkeypatch)
    printed = capsys.readouterr().out
    if page in ("README.md", "docs/getting-started.md"):
        truth = json.loads(ex("truth.json").read_text())  # the pose the example's observations were made at
        est = ns["est"]
        assert est.status == "solved"
        dt, dr = pose_errors(est.R, est.t, truth["R"], truth["t"])
        assert dt < 1e-3 and dr < 0.05, (dt, dr)
    elif page == "docs/guides/teams.md":
        truth = json.loads(ex("team_truth.json").read_text())
        for name, gt in truth["robots"].items():
            dt, dr = pose_errors(ns["team"].poses[name].R, ns["team"].poses[name].t, gt["R"], gt["t"])
            assert dt < 1e-3 and dr < 0.05, (name, dt, dr)
    elif page == "docs/guides/tracking.md":
        assert len(ns["traj"].rows) == 3 and "3 frames" in ns["traj"].summary()  # the videos' three frames
        assert printed.startswith("10 frames") and (tmp_path / "out" / "trajectory.csv").exists()
    elif page == "docs/guides/calibration.md":
        assert (tmp_path / "calibrated.yaml").exists() and "M1" in printed
    elif page == "docs/guides/live.md":
        assert len(ns["loc"].diagnostics(ns["now"])) == 2


def test_cameras_guide_code_runs(capsys):
    """docs/guides/cameras.md: every ``python`` block runs, in order, in one namespace, as a reader would
    paste them; the output shown after "It prints:" is what the example prints; the pose is right; the
    fisheye calibration function recovers a known lens from synthetic chessboard corners."""
    text = (GUIDES / "cameras.md").read_text(encoding="utf-8")
    blocks = _blocks(text, "python")
    assert len(blocks) >= 3
    ns: dict = {"__name__": "__guide__"}
    for code in blocks:
        exec(compile(code, "docs/guides/cameras.md", "exec"), ns)  # noqa: S102 -- the manual's own code
    printed = capsys.readouterr().out.splitlines()
    shown = re.search(r"It prints:\s*```text\n(.*?)```", text, re.DOTALL)
    assert shown, "the guide shows no output after 'It prints:'"
    expected = shown.group(1).strip().splitlines()
    assert printed[: len(expected)] == expected

    est, truth = ns["est"], ns["truth"]
    assert est.status == "solved"
    dt, dr = pose_errors(est.R, est.t, truth.R, truth.t)
    assert dt < 0.03 and dr < 0.5, (dt, dr)
    assert np.linalg.norm(ns["poses"].t[0] - est.t) < 0.03

    # calibrate_fisheye: 9 x 6 corners, 5 cm squares, seen by a known fisheye with 0.1 px noise
    from mutloc.core.geometry import so3_exp

    cam = mutloc.FisheyeCamera([[300, 0, 640], [0, 300, 400], [0, 0, 1]], [0.01, -0.003, 0.0005, -0.0001],
                               (1280, 800))
    board = np.array([[i * 0.05, j * 0.05, 0.0] for j in range(6) for i in range(9)])
    rng = np.random.default_rng(0)
    obj, img = [], []
    while len(obj) < 12:
        R = so3_exp(rng.normal(0, 0.6, 3))
        t = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), rng.uniform(0.3, 0.6)])
        uv = cam.project((board - board.mean(0)) @ R.T + t)
        if np.all(np.isfinite(uv)) and np.all(cam.in_image(uv)):
            obj.append(board)
            img.append(uv + rng.normal(0, 0.1, uv.shape))
    entry = ns["calibrate_fisheye"](obj, img, (1280, 800))
    lens = mutloc.load_rig({"robots": {"x": {"camera": entry, "markers": {}}}}).robot("x").camera
    assert lens.model == "fisheye"
    np.testing.assert_allclose(lens.K, cam.K, atol=1.0)
    # the calibrated lens images the field it was calibrated on as the true one does
    seen = np.vstack(img)
    np.testing.assert_allclose(lens.pixels_to_bearings(seen), cam.pixels_to_bearings(seen), atol=2e-3)
