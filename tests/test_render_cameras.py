"""Rendering robots with several cameras and any lens, against ground truth that
does not come from the renderer: an independent Kannala-Brandt projection
written here, the pose the world was built with, and the exact silhouette of a
sphere (its tangent cone's contact circle)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from _oracles import kb_project

import mutloc
from mutloc.cli.main import main
from mutloc.core.camera import Camera
from mutloc.core.geometry import rotation_error_deg, so3_exp
from mutloc.core.pose import Pose
from mutloc.core.rig import Marker, Mount, Rig, Robot
from mutloc.io import load_observations, load_rig
from mutloc.sim import body_scenes as bodies
from mutloc.sim.render import (
    body_box,
    project_markers,
    relative_pose,
    render,
    srgb_to_linear,
    true_observations,
    two_robot_world,
)
from mutloc.sim.scenario import single_frame_pose
from mutloc.sim.world import Light, Sensor, World, WorldRobot, standard_rig


def silhouette_centroid(C: np.ndarray, r: float, K: np.ndarray, k: np.ndarray, n: int = 4000) -> np.ndarray:
    """Area centroid of a sphere's exact image: the contact circle of its tangent cone, projected, shoelace."""
    d = np.linalg.norm(C)
    a = C / d
    e1 = np.cross(a, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    centre = a * (d - r * r / d)
    rho = r * np.sqrt(d * d - r * r) / d
    ph = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    uv = kb_project(K, k, centre + rho * (np.cos(ph)[:, None] * e1 + np.sin(ph)[:, None] * e2))
    x, y = uv[:, 0], uv[:, 1]
    x1, y1 = np.roll(x, -1), np.roll(y, -1)
    cr = x * y1 - x1 * y
    area = cr.sum() / 2
    return np.array([((x + x1) * cr).sum(), ((y + y1) * cr).sum()]) / (6 * area)


def flat(world: World) -> World:
    """Unshaded (ambient only), no bloom: a pixel's linear value is coverage x albedo."""
    world.light = Light(intensity=0.0, ambient=1.0)
    world.sensor = Sensor(bloom_strength=0.0)
    return world


def one_ball_world(theta_deg: float, phi_deg: float, dist: float = 0.8) -> tuple[World, np.ndarray, Mount]:
    """p: the fisheye pair rig's robot p (no body); q: a white ball at ``theta_deg`` off p/front's axis."""
    rig = bodies.fisheye_pair_rig()
    mount = rig.robot("p").cameras["front"]
    th, ph = np.radians(theta_deg), np.radians(phi_deg)
    C_cam = dist * np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
    C_world = mount.pose.apply(C_cam)  # p's frame is the world's
    cam = Camera(np.diag([500.0, 500.0, 1.0]), None, (64, 64))
    q = Robot("q", cam, {"B": Marker("B", "q", np.zeros(3), color=(255, 255, 255), extra={"radius": 0.03})})
    world = World(robots={"p": WorldRobot(rig.robot("p"), Pose.identity(), body=False),
                          "q": WorldRobot(q, Pose(np.eye(3), C_world), body=False)})
    return flat(world), C_cam, mount


@pytest.mark.parametrize("theta, phi", [(85.0, 30.0), (95.0, -120.0), (20.0, 200.0)])
def test_fisheye_ball_centroid_is_where_the_lens_puts_it(theta: float, phi: float) -> None:
    """A ball far off a fisheye's axis (85 and 95 degrees: beyond a pinhole's reach) renders with its
    coverage centroid on the exact silhouette's centroid (to 0.06 px; measured 0.02 px at 85 degrees),
    and near the lens projection of its centre."""
    world, C, mount = one_ball_world(theta, phi)
    lens = mount.camera
    img = render(world, "p/front")
    uv_true = kb_project(lens.K, lens.dist, C)[0]
    sil = silhouette_centroid(C, 0.03, lens.K, lens.dist)
    # the truth function agrees with the independent projection
    obs = project_markers(world, "p/front")
    np.testing.assert_allclose(obs["B"], uv_true, atol=1e-6)
    half = 20
    u0, v0 = int(uv_true[0]) - half, int(uv_true[1]) - half
    patch = img[v0:v0 + 2 * half + 1, u0:u0 + 2 * half + 1, 1] / 255.0
    alpha = srgb_to_linear(patch)
    assert alpha.sum() > 20  # a ball of several pixels, wholly in the window
    assert alpha[0].sum() + alpha[-1].sum() + alpha[:, 0].sum() + alpha[:, -1].sum() == 0
    vv, uu = np.mgrid[v0:v0 + 2 * half + 1, u0:u0 + 2 * half + 1]
    got = np.array([(alpha * uu).sum(), (alpha * vv).sum()]) / alpha.sum()
    assert np.linalg.norm(got - sil) < 0.06, (got, sil)
    # ... and off the projection of the ball's centre by the sphere's own (exact) bias only: up to about
    # 0.5 px for a 3 cm ball at 0.8 m, 95 degrees off the axis, where the lens compresses radially
    bias = np.linalg.norm(sil - uv_true)
    assert bias < 0.6 and np.linalg.norm(got - uv_true) < bias + 0.06, (got, uv_true, bias)


def test_pixels_outside_the_fisheye_circle_are_black() -> None:
    rig = bodies.fisheye_pair_rig(size=(320, 200))
    lens = rig.robot("p").cameras["back"].camera
    world = bodies.body_pair_world(rig, *bodies.body_pair_pose(2.0, 0, "away"), seed=0)
    img = render(world, "p/back").max(axis=2)
    vv, uu = np.mgrid[0:200, 0:320]
    r = np.hypot(uu - lens.K[0, 2], vv - lens.K[1, 2])
    r_circle = lens.K[0, 0] * lens.params[-1]  # f * theta_d at max_angle
    assert np.all(img[r > r_circle + 1.5] == 0)
    assert np.mean(img[r < r_circle - 1.5] > 0) > 0.99  # the room everywhere inside


def test_pinhole_renders_are_unchanged() -> None:
    """Renders of robots with one pinhole camera are bit for bit those of the renderer before lenses
    and mounts (hashes from commit 42b091c)."""
    want = {("balls", 0.0, "p"): "632c8a94c63184e6", ("balls", 0.0, "q"): "67a5417e0864a089",
            ("tags", -0.2, "p"): "f1c650368516ccc0"}
    for (markers, k1, robot), h in want.items():
        rig = standard_rig(markers, size=(320, 180), f=270.0, k1=k1)
        world = two_robot_world(rig, single_frame_pose(2.0, 3), seed=3)
        img = render(world, robot, 0.0, seed=1, noise_sigma=1.0)
        assert hashlib.sha256(img.tobytes()).hexdigest()[:16] == h, (markers, k1, robot)


def test_a_camera_inside_the_body_box_sees_out() -> None:
    """A camera mounted inside the default body volume: the body is cut back behind it, so it sees the
    world (black, no room), not the inside of its own body."""
    lens = bodies.fisheye_pair_rig(size=(160, 100)).robot("p").cameras["front"].camera
    R = bodies._R_FRONT
    robot = Robot("p", None, {"P1": Marker("P1", "p", np.array([0.0, 0.0, 0.3]), color=(255, 0, 0))},
                  cameras={"front": Mount("front", lens, Pose(R, np.array([0.1, 0.0, 0.2])))})
    lo, hi = body_box(robot)
    assert hi[0] < 0.1 and not np.all((lo < [0.1, 0.0, 0.2]) & ([0.1, 0.0, 0.2] < hi))
    world = World(robots={"p": WorldRobot(robot, Pose.identity())})
    img = render(world, "p/front")
    assert img[50, 80].max() == 0  # straight ahead: nothing
    assert img[95:, 60:100].max() > 0  # far down the rim: the body's top, below the camera


def test_localize_back_to_back_fisheyes_facing_away_recovers_the_pose() -> None:
    rig = bodies.fisheye_pair_rig()
    for seed in (0, 1, 2):
        world = bodies.body_pair_world(rig, *bodies.body_pair_pose(2.5, seed, "away"), seed=seed)
        obs = true_observations(world)
        assert sorted(obs) == ["p/back", "q/back"]  # back to back: the front cameras see nothing
        truth = relative_pose(world, "p", "q")
        est = mutloc.localize(rig, obs, "p", "q")
        assert np.linalg.norm(est.t - truth.t) < 1e-6
        assert rotation_error_deg(est.R, truth.R) < 1e-6
        # the true observations are the independent projections through each camera's mount
        for key, seen in obs.items():
            rname, cname = key.split("/")
            other = "q" if rname == "p" else "p"
            mount = rig.robot(rname).cameras[cname]
            T_cam_other = mount.pose.inverse() @ relative_pose(world, other, rname)
            for m, uv in seen.items():
                X = T_cam_other.apply(rig.robot(other).markers[m].position)
                np.testing.assert_allclose(uv, kb_project(mount.camera.K, mount.camera.dist, X)[0], atol=1e-6)


def test_facing_toward_the_front_cameras_see() -> None:
    rig = bodies.fisheye_pair_rig()
    world = bodies.body_pair_world(rig, *bodies.body_pair_pose(2.0, 5, "toward"), room=False)
    assert sorted(true_observations(world)) == ["p/front", "q/front"]
    # back to back, q's back camera sees both of p's markers over p's body
    world = bodies.body_pair_world(rig, *bodies.body_pair_pose(2.0, 5, "away"), room=False)
    assert set(true_observations(world)["q/back"]) == {"M3", "M4"}


def test_simulate_cli_writes_loadable_per_camera_files(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "sim"
    assert main(["simulate", "--out", str(out), "--cameras", "back-to-back-fisheye", "--facing", "away",
                 "--size", "640x400", "--seed", "7", "--no-room"]) == 0
    assert "wrote 1 frame" in capsys.readouterr().out
    rig = load_rig(out / "rig.yaml")
    assert sorted(rig.observer_keys()) == ["p/back", "p/front", "q/back", "q/front"]
    for key in rig.observer_keys():
        lens = rig.mount(key).camera
        assert lens.model == "fisheye" and lens.size == (640, 400)
        img = (out / f"{key.replace('/', '_')}.png")
        assert img.is_file(), key
    truth = json.loads((out / "truth.json").read_text())
    frame = truth["frames"][0]
    assert truth["cameras"] == "back-to-back-fisheye" and truth["facing"] == "away"
    assert sorted(frame["images"]) == sorted(rig.observer_keys())
    obs = load_observations(out / "observations.json")
    assert sorted(obs.to_dict()) == ["p/back", "q/back"]
    T = Pose(np.array(frame["T_qp"]["R"]), np.array(frame["T_qp"]["t"]))
    est = mutloc.localize(rig, json.loads((out / "observations.json").read_text()), "p", "q")
    assert np.linalg.norm(est.t - T.t) < 1e-6 and rotation_error_deg(est.R, T.R) < 1e-6
    # a pair of robots 2 m apart (origins), back to back: p behind q, facing away from it
    assert np.linalg.norm(T.t) == pytest.approx(2.0, rel=0.12) and T.t[0] < 0 and T.R[0, 0] < 0


def test_simulate_cli_sequence_and_refusals(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "seq"
    assert main(["simulate", "--out", str(out), "--cameras", "back-to-back-fisheye", "--frames", "2",
                 "--size", "320x200", "--no-room", "--markers", "lights"]) == 0
    for key in ("p_front", "p_back", "q_front", "q_back"):
        assert sorted(p.name for p in (out / key).iterdir()) == ["000000.png", "000001.png"]
    truth = json.loads((out / "truth.json").read_text())
    assert len(truth["frames"]) == 2 and (out / "truth.tum").is_file() and (out / "frames.csv").is_file()
    assert sorted(truth["frames"][1]["observations"]) == ["p/front", "q/front"]
    capsys.readouterr()
    for extra in (["--facing", "away"], ["--cameras", "back-to-back-fisheye", "--focal", "300"],
                  ["--cameras", "back-to-back-fisheye", "--robots", "3"]):
        assert main(["simulate", "--out", str(tmp_path / "x"), *extra]) != 0
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "Traceback" not in err, (extra, err)


def test_cli_choices_agree_with_the_simulator() -> None:
    from mutloc.cli import simulate

    assert simulate.CAMERA_SETS == bodies.CAMERA_SETS and simulate.FACINGS == bodies.FACINGS
