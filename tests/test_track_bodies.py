"""Tracking robots with several cameras, any lens (SPEC "Robots with several cameras, any lens"): `mutloc track`
over observation logs keyed ROBOT/CAMERA and over one image stream per camera, against the simulator's truth.

Pixels are the exact projections of the simulated markers through each fisheye (mount pose and lens), plus
Gaussian noise; the poses the tracker reports (between robot frames) are compared row by row with the
simulated relative pose at the row's time: within a few of the row's own sigmas (NEES), statuses as the SPEC
says for the observations each record holds."""

import json

import numpy as np
import pytest
from _shared_inputs import shared

from mutloc.cli.main import main
from mutloc.core.geometry import so3_exp, so3_log
from mutloc.core.observations import ObservationSet
from mutloc.core.pose import Pose
from mutloc.core.rig import Rig
from mutloc.errors import ObservationError
from mutloc.io.logs import write_observation_log
from mutloc.io.trajectory import read_trajectory_csv, read_tum
from mutloc.sim.bodies import back_to_back_fisheye, body_observations
from mutloc.sim.body_scenes import fisheye_pair_rig, moving_body_world, write_cameras_simulation
from mutloc.sim.render import project_markers, relative_pose
from mutloc.track.team import track_team_log
from mutloc.track.tracker import track_log

SIGMA = 0.7
#: chi-square, 6 degrees of freedom, at the two-sided 5-sigma tail (5.7e-7)
NEES_5_SIGMA = 39.49


def _nees(pose: Pose, truth: Pose, cov: np.ndarray) -> tuple[float, float]:
    """(translation error m, NEES) of a row's pose against the truth (SPEC perturbation)."""
    e = np.r_[so3_log(truth.R @ pose.R.T), truth.t - pose.t]
    return float(np.linalg.norm(e[3:])), float(e @ np.linalg.solve(cov, e))


def _pair_log(facing: str, *, offset: float = 0.0, frames: int = 45, seed: int = 0):
    """Two robots with back-to-back fisheyes (p moving), each camera a record of its own at 30 fps (q's cameras
    ``offset`` s after p's: not synchronized), the exact pixels plus noise; ``(rig, world, [(t, obs)])``."""
    rig = fisheye_pair_rig("balls", size=(640, 400))
    world = moving_body_world(rig, facing=facing, room=False)
    rng = np.random.default_rng(seed)
    records: dict[float, dict] = {}
    for i in range(frames):
        for key in rig.observer_keys():
            t = round(i / 30 + (offset if key.startswith("q") else 0.0), 6)
            cam = rig.mount(key).camera
            seen = {}
            for m, uv in project_markers(world, key, t).items():
                x = np.asarray(uv) + SIGMA * rng.standard_normal(2)
                if np.all(np.isfinite(cam.pixels_to_bearings(x[None]))):  # noise may push a pixel off the lens
                    seen[m] = x.tolist()
            if seen:
                records.setdefault(t, {})[key] = seen
    log = [(t, ObservationSet.from_dict(records[t], time=t)) for t in sorted(records)]
    return rig, world, log


def test_pair_log_facing_each_other_tracked_within_its_sigmas():
    rig, world, log = _pair_log("toward")
    assert all(set(o.observer) == {"p/front", "q/front"} for _, o in log)  # the front cameras see each other
    traj = track_log(rig, log, pixel_sigma=SIGMA, progress=False)
    assert len(traj.rows) == len(log)
    errs, nees = [], []
    for row in traj.rows:
        assert row.status.value == "solved", (row.t, row.status, row.reason)
        e, n = _nees(row.estimate.pose, relative_pose(world, "p", "q", row.t), row.estimate.covariance)
        errs.append(e)
        nees.append(n)
    assert max(nees) < NEES_5_SIGMA and 3.0 < np.mean(nees) < 9.0  # consistent: E[NEES] = 6
    assert np.median(errs) < 0.08


def test_pair_log_facing_away_unsynchronized_cameras():
    # Back to back: only the back cameras see the other robot; q's frames 11 ms after p's, so each record
    # holds one camera's two observations -- partial, fused at its own time (SPEC "Observation logs").
    rig, world, log = _pair_log("away", offset=0.011)
    assert {k for _, o in log for k in o.observer} == {"p/back", "q/back"}
    assert all(len(set(o.observer)) == 1 for _, o in log)
    traj = track_log(rig, log, pixel_sigma=SIGMA, progress=False)
    statuses = [row.status.value for row in traj.rows]
    # the track starts from the first records together, then every record updates it
    assert statuses.count("partial") >= len(statuses) - 5 and set(statuses) <= {"too_few", "partial", "solved",
                                                                                "rejected"}
    assert statuses.count("rejected") <= 2
    nees = []
    for row in traj.rows:
        if row.estimate is None:
            assert row.t < 0.2  # before the start only
            continue
        e, n = _nees(row.estimate.pose, relative_pose(world, "p", "q", row.t), row.estimate.covariance)
        nees.append(n)
        assert e < 0.2
    assert len(nees) >= len(log) - 5
    assert max(nees) < NEES_5_SIGMA and np.mean(nees) < 9.0


def _team_log(frames: int = 30):
    """Three robots with back-to-back fisheyes and three markers each, standing round a circle, turning and
    swaying; every camera's view at 15 fps; ``(rig, truth per record (T_a_b, T_a_c), [(t, obs)])``."""
    layout = [(-0.1, 0.12, 0.5), (-0.1, -0.12, 0.5), (0.1, 0.0, 0.62)]
    rig = Rig({n: back_to_back_fisheye(n, {f"{n}{j}": xyz for j, xyz in enumerate(layout)}) for n in "abc"})

    def poses(t):
        out = {}
        for i, n in enumerate("abc"):
            ang = 2 * np.pi * i / 3 + 0.2 * np.sin(t + i)
            yaw = ang + (np.pi if i == 1 else np.pi / 2) + 0.3 * np.sin(0.7 * t + i)
            out[n] = Pose(so3_exp([0.0, 0.0, yaw]), 1.5 * np.array([np.cos(ang), np.sin(ang), 0.0]))
        return out

    rng = np.random.default_rng(1)
    log, truth = [], []
    for i in range(frames):
        t = i / 15
        P = poses(t)
        obs = body_observations(rig, P, sigma=SIGMA, rng=rng)
        for key in obs:
            cam = rig.mount(key).camera
            obs[key] = {m: uv for m, uv in obs[key].items()
                        if np.all(np.isfinite(cam.pixels_to_bearings(np.array([uv]))))}
        log.append((t, ObservationSet.from_dict(obs, time=t)))
        truth.append({n: P["a"].inverse() @ P[n] for n in "bc"})
    return rig, truth, log


def test_team_of_three_bodies_log():
    rig, truth, log = _team_log()
    keys = {k for _, o in log for k in o.observer}
    assert {"a/front", "a/back", "c/back"} <= keys  # several cameras of one robot at once
    traj = track_team_log(rig, log, "a", pixel_sigma=SIGMA, progress=False)
    assert traj.reference == "a" and traj.robots == ["b", "c"]
    for r in ("b", "c"):
        rows = traj.tracks[r].rows
        assert len(rows) == len(log)
        nees, errs = [], []
        for row, T in zip(rows, truth):
            assert row.status.value == "solved", (r, row.t, row.status, row.reason)
            e, n = _nees(row.estimate.pose, T[r], row.estimate.covariance)
            errs.append(e)
            nees.append(n)
        assert max(nees) < NEES_5_SIGMA and np.mean(nees) < 9.0
        assert np.median(errs) < 0.02


def test_cli_log_keyed_by_camera_and_bad_keys(tmp_path, capsys):
    rig, world, log = _pair_log("away", frames=12)
    from mutloc.io import save_rig

    save_rig(rig, tmp_path / "rig.yaml")
    write_observation_log(tmp_path / "log.jsonl", [o for _, o in log])
    out = tmp_path / "out"
    assert main(["track", "--rig", str(tmp_path / "rig.yaml"), "--observations", str(tmp_path / "log.jsonl"),
                 "--out", str(out), "--pixel-sigma", str(SIGMA), "--no-progress"]) == 0
    rows = read_trajectory_csv(out / "trajectory.csv")
    assert len(rows) == len(log) and all(r["status"] == "solved" for r in rows)
    times, poses = read_tum(out / "trajectory.tum")
    for t, R, tt in zip(times, poses.R, poses.t):
        T = relative_pose(world, "p", "q", float(t))
        assert np.degrees(np.linalg.norm(so3_log(R @ T.R.T))) < 3.0 and np.linalg.norm(tt - T.t) < 0.2
    # a camera the robot does not have, a robot with several cameras named alone: one line, non-zero
    for bad, said in ((["--stream", "p/side=x", "--stream", "q/back=y"], "unknown camera 'side'"),
                      (["--stream", "p=x", "--stream", "q/back=y"], "give one stream per camera"),
                      (["--observations", str(tmp_path / "log.jsonl"), "--frames", "base"], "already are in its robot")):
        capsys.readouterr()
        assert main(["track", "--rig", str(tmp_path / "rig.yaml"), *bad, "--out", str(tmp_path / "o2")]) != 0
        err = capsys.readouterr().err.strip()
        assert said in err and len(err.splitlines()) == 1 and "Traceback" not in err


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """One short rendered sequence (small images, no room), robots back to back."""
    # once per test run, also when pytest -n hands this module's tests to both workers (tests/_shared_inputs.py)

    def make():
        d = tmp_path_factory.mktemp("sim")
        write_cameras_simulation(d, facing="away", frames=5, size=(480, 300), room=False, seed=2)
        return d

    return shared(tmp_path_factory, "track-bodies-rendered-away-seed2", make)


def test_rendered_streams_per_camera_facing_away(rendered, tmp_path, capsys):
    """`mutloc track --stream ROBOT/CAMERA=DIR` per camera, robots back to back (only the back cameras see each
    other), each row against truth.tum."""
    d = rendered
    out = tmp_path / "out"
    streams = [a for k in ("p/front", "p/back", "q/front", "q/back")
               for a in ("--stream", f"{k}={d / k.replace('/', '_')}")]
    assert main(["track", "--rig", str(d / "rig.yaml"), *streams, "--out", str(out), "--no-progress",
                 "--observations-out", str(tmp_path / "log.jsonl")]) == 0
    rows = read_trajectory_csv(out / "trajectory.csv")
    assert [r["status"] for r in rows] == ["solved"] * 5
    times, poses = read_tum(out / "trajectory.tum")
    t_true, truth = read_tum(d / "truth.tum")
    np.testing.assert_allclose(times, t_true, atol=1e-6)
    for row, R, t, Rt, tt in zip(rows, poses.R, poses.t, truth.R, truth.t):
        sig = row["sigma"]
        e = np.r_[so3_log(Rt @ R.T), tt - t]
        assert np.all(np.abs(e) < 5 * sig + np.r_[[0.002] * 3, [0.005] * 3]), (e, sig)
    # the team tracker over the same streams (--reference: a team of two): the same poses within their sigmas
    assert main(["track", "--rig", str(d / "rig.yaml"), *streams, "--reference", "q", "--out", str(tmp_path / "team"),
                 "--no-progress"]) == 0
    team_rows = read_trajectory_csv(tmp_path / "team" / "trajectory_p.csv")
    assert [r["status"] for r in team_rows] == ["solved"] * 5
    for row, Rt, tt in zip(team_rows, truth.R, truth.t):
        e = np.r_[so3_log(Rt @ row["pose"].R.T), tt - row["pose"].t]
        assert np.all(np.abs(e) < 5 * row["sigma"] + np.r_[[0.002] * 3, [0.005] * 3]), (e, row["sigma"])
    # the detections are logged keyed by camera: the back cameras only
    keys = {k for line in (tmp_path / "log.jsonl").read_text().splitlines() for k in json.loads(line)["observations"]}
    assert keys == {"p/back", "q/back"}
    # a camera left without a stream is not used, and said so
    capsys.readouterr()
    assert main(["track", "--rig", str(d / "rig.yaml"), "--stream", f"p/back={d / 'p_back'}", "--stream",
                 f"q/back={d / 'q_back'}", "--out", str(tmp_path / "o2"), "--no-progress"]) == 0
    assert "no --stream for cameras p/front, q/front: not used" in capsys.readouterr().err
    with pytest.raises(ObservationError, match="unknown camera"):
        from mutloc.track.team import require_streams

        require_streams(rig_of(d), ["p/back", "q/top"])


def rig_of(d):
    from mutloc import load_rig

    return load_rig(d / "rig.yaml")


def test_tag_looked_for_where_the_track_puts_it_through_a_body_camera_s_mount():
    """tests/test_tag_look.py's steep tags, q made a body whose one camera is mounted turned and shifted in its
    frame (``q/cam``): the track's prediction (between robot frames) places p's tag in q's image through the
    mount -- at the tag's true corners -- and a prediction a metre off finds nothing."""
    from dataclasses import replace

    from mutloc.core.rig import Mount, Robot
    from mutloc.detect.tags import corner_marker_names
    from mutloc.track.tag_look import look_where_tracked
    from test_tag_look import first_look, steep_scenes

    M = Pose(so3_exp([0.3, -0.5, 0.2]), np.array([0.1, -0.2, 0.3]))  # T_body_camera of q's camera
    checked = 0
    for rig, T, images, truth in steep_scenes()[:5]:
        ex, dets, _ = first_look(rig, images)
        if "TP#0" in dets["q"].detections:
            continue
        q = ex.robot("q")
        body = Robot("q", None, {n: replace(m, position=M.apply(m.position)) for n, m in q.markers.items()},
                     cameras={"cam": Mount("cam", q.camera, M)})
        bodies = Rig({"p": ex.robot("p"), "q": body})
        off = Pose.from_rotvec([0.0, np.radians(1.0), 0.0], [0.03, -0.02, 0.04])
        pred = {"q": Pose.identity(), "p": M @ off @ T}  # T_qp between robot frames (p's is its camera's)
        found, notes = look_where_tracked(bodies, {"q/cam": images["q"]}, {"q/cam": dets["q"]}, lambda: pred)
        got = [found["q/cam"].detections.get(c) for c in corner_marker_names("TP")]
        if all(d is not None for d in got):
            checked += 1
            assert max(np.hypot(*(d.uv - x)) for d, x in zip(got, truth)) < 0.35
            assert notes == [("p", "q/cam saw tag TP where the track put it (looked for again)")]
        far = {"q": Pose.identity(), "p": M @ Pose.from_rotvec([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]) @ T}
        none, notes = look_where_tracked(bodies, {"q/cam": images["q"]}, {"q/cam": dets["q"]}, far)
        assert "TP#0" not in none["q/cam"].detections and notes == []
    assert checked >= 3


def test_bags_one_topic_per_camera(rendered, tmp_path):
    """A bag's image topic named per camera (``--topic p/back=/p/back/image_raw``); a camera_info taken per
    camera keeps the camera's pose on the robot."""
    import cv2

    from mutloc import load_rig
    from mutloc.core.camera import Camera
    from mutloc.track.sources import rig_with_bag_cameras
    from test_sources import write_bag

    d = rendered
    t_true, truth = read_tum(d / "truth.tum")
    args = []
    for key in ("p/back", "q/back"):
        folder = d / key.replace("/", "_")
        images = [cv2.imread(str(f)) for f in sorted(folder.glob("*.png"))]
        write_bag(tmp_path / key.replace("/", "_"), 2, f"/{key}/image_raw", images, list(100.0 + t_true))
        args += ["--stream", f"{key}={tmp_path / key.replace('/', '_')}", "--topic", f"{key}=/{key}/image_raw"]
    out = tmp_path / "out"
    assert main(["track", "--rig", str(d / "rig.yaml"), *args, "--out", str(out), "--no-progress"]) == 0
    rows = read_trajectory_csv(out / "trajectory.csv")
    assert [r["status"] for r in rows] == ["solved"] * 5
    np.testing.assert_allclose([r["t"] for r in rows], 100.0 + t_true, atol=1e-6)
    for row, Rt, tt in zip(rows, truth.R, truth.t):
        e = np.r_[so3_log(Rt @ row["pose"].R.T), tt - row["pose"].t]
        assert np.all(np.abs(e) < 5 * row["sigma"] + np.r_[[0.002] * 3, [0.005] * 3]), (e, row["sigma"])
    # --camera-info per camera: the lens from the bag, the pose from the rig
    K = [[500.0, 0, 239.5], [0, 500.0, 149.5], [0, 0, 1]]
    write_bag(tmp_path / "info", 2, "/p/back/image_raw", images[:1], [100.0], K=K)
    rig = load_rig(d / "rig.yaml")
    new = rig_with_bag_cameras(rig, {"p/back": tmp_path / "info"}, {"p/back": "/p/back/camera_info"})
    mount = new.mount("p/back")
    assert isinstance(mount.camera, Camera) and np.allclose(mount.camera.K, K)
    assert np.allclose(mount.pose.R, rig.mount("p/back").pose.R) and np.allclose(mount.pose.t,
                                                                                 rig.mount("p/back").pose.t)
    assert new.mount("p/front").camera is rig.mount("p/front").camera
