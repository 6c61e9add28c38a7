"""Teams of robots with several cameras and any lens (issue 36): `localize_team` on rays from several
centres per robot, against the simulator's truth (``mutloc.sim.bodies`` projects every marker through
every lens, observations keyed ``ROBOT/CAMERA``)."""

from __future__ import annotations

import numpy as np
import pytest

import mutloc
from mutloc.core.camera import Camera
from mutloc.core.geometry import so3_exp, so3_log
from mutloc.core.observations import ObservationSet
from mutloc.core.pose import Pose
from mutloc.core.rig import Marker, Rig, Robot
from mutloc.errors import ObservationError
from mutloc.sim.bodies import OPTICAL_IN_BASE, body_observations, random_body
from mutloc.team import localize_team, team_problem


def _poses(rng: np.random.Generator, names: list[str], spread: float = 3.0) -> dict[str, Pose]:
    """Robots on the floor 1.2 m apart at least, any headings, slightly tilted."""
    poses: dict[str, Pose] = {}
    for n in names:
        while True:
            t = np.r_[rng.uniform(-spread, spread, 2), rng.normal(0, 0.05)]
            if all(np.linalg.norm(t[:2] - p.t[:2]) > 1.2 for p in poses.values()):
                break
        poses[n] = Pose(so3_exp([rng.normal(0, 0.05), rng.normal(0, 0.05), rng.uniform(0, 2 * np.pi)]), t)
    return poses


def _team(rng: np.random.Generator) -> tuple[Rig, dict[str, Pose]]:
    names = [f"r{i}" for i in range(int(rng.integers(3, 6)))]
    rig = Rig({n: random_body(rng, n, n_markers=int(rng.integers(3, 6))) for n in names})
    return rig, _poses(rng, names)


def _noisy(rig: Rig, obs: dict, rng: np.random.Generator, sigma: float = 1.0) -> dict:
    """``obs`` plus Gaussian pixel noise; a noisy pixel pushed past the rim of a fisheye's or an omni lens's
    image (which the pair solver refuses as well, naming it) is dropped."""
    out: dict = {}
    for key, seen in obs.items():
        cam = rig.mount(key).camera
        for m, uv in seen.items():
            p = np.asarray(uv) + sigma * rng.standard_normal(2)
            if np.all(np.isfinite(np.asarray(cam.pixels_to_bearings(p), float))):
                out.setdefault(key, {})[m] = p.tolist()
    return out


def _truth(poses: dict[str, Pose], ref: str, name: str) -> Pose:
    return poses[ref].inverse() @ poses[name]


def _ties(rig: Rig, obs: dict) -> dict[frozenset, int]:
    count: dict[frozenset, int] = {}
    for key, seen in obs.items():
        a = rig.observer(key)[0]
        for m in seen:
            pair = frozenset((a, rig.owner(m)))
            count[pair] = count.get(pair, 0) + 1
    return count


def test_noise_free_random_teams_are_exact():
    """3-5 bodies of 2-3 cameras (fisheye 180-200 deg, omni, pinhole) anywhere around each other: every
    robot tied to the reference is found at its exact pose, and none tied by three observations or more
    to the localized ones is left out."""
    rng = np.random.default_rng(36)
    localized = 0
    for _ in range(25):
        rig, poses = _team(rng)
        obs = body_observations(rig, poses)
        team = localize_team(rig, obs, "r0", confidence=1.0)
        assert team.reprojection_rms_px < 1e-6
        for n in team.robots:
            T = _truth(poses, "r0", n)
            assert np.linalg.norm(team.poses[n].t - T.t) < 1e-7, n
            assert np.linalg.norm(so3_log(team.poses[n].R @ T.R.T)) < 1e-8, n
            localized += 1
        held = {"r0", *team.robots}
        ties = _ties(rig, obs)
        for n in team.unlocalized:
            assert sum(c for pair, c in ties.items() if n in pair and pair & held) < 3, n
    assert localized >= 50


def test_noise_free_through_every_camera_key_alone():
    """The same team whichever robot is the reference; its rows are keyed by camera, so a rig whose bodies
    see each other through back cameras only is solved as well (the rays leave the cameras' centres)."""
    rng = np.random.default_rng(5)
    rig, poses = _team(rng)
    obs = body_observations(rig, poses)
    for ref in rig.robots:
        team = localize_team(rig, obs, ref, confidence=1.0)
        assert team.unlocalized == []
        for n in team.robots:
            assert np.linalg.norm(team.poses[n].t - _truth(poses, ref, n).t) < 1e-7


def test_noisy_teams_covariance_is_honest():
    """sigma = 1 px: over a few hundred robots the 6-D NEES of each verified robot's pose (its marginal
    covariance from the joint one) averages 6 -- the covariance is in pixels, through each lens's
    Jacobian -- and the joint chi-square statistic averages its degrees of freedom.

    Tolerances: the NEES's mean over n robots has a standard deviation of sqrt(12 / n) (~0.2 for the
    ~300 here; robots of one team are correlated a little, and the linearisation adds a small bias), so
    [5.2, 6.8] is about 4 of them either side; the chi2 / dof ratio's mean over ~70 teams of ~40 degrees
    of freedom each has a deviation near 0.03: [0.85, 1.15]."""
    rng = np.random.default_rng(2026)
    nees, ratio = [], []
    for _ in range(110):
        rig, poses = _team(rng)
        obs = _noisy(rig, body_observations(rig, poses), rng)
        try:
            team = localize_team(rig, obs, "r0", reject_outliers=False, confidence=1.0)
        except mutloc.errors.TooFewObservationsError:
            continue
        if team.consistency.dof > 0:
            ratio.append(team.consistency.chi2 / team.consistency.dof)
        for n in team.robots:
            if n in team.unverified:
                continue
            T = _truth(poses, "r0", n)
            e = np.r_[so3_log(team.poses[n].R @ T.R.T), team.poses[n].t - T.t]
            nees.append(float(e @ np.linalg.solve(team.covariance(n), e)))
    assert len(nees) >= 250 and len(ratio) >= 60
    assert 5.2 < np.mean(nees) < 6.8, np.mean(nees)
    assert np.max(nees) < 60.0
    assert 0.85 < np.mean(ratio) < 1.15, np.mean(ratio)


def _pinhole_robot(name: str, markers: dict) -> Robot:
    cam = Camera([[700.0, 0, 639.5], [0, 700.0, 399.5], [0, 0, 1]], [0.02, -0.01, 0, 0, 0], (1280, 800))
    return Robot(name, cam, {m: Marker(m, name, np.asarray(p, float)) for m, p in markers.items()})


def test_a_pinhole_robot_among_bodies():
    """A robot given with ``camera:`` (its frame the optical one, keyed by its name alone) in a team of
    bodies: the team is solved on rays, the pinhole robot's rows rays from its origin, in any role."""
    rng = np.random.default_rng(11)
    # the pinhole robot looks along its z: markers on its "back" (negative z) face the others
    pin = _pinhole_robot("c", {"C0": [0.15, 0.0, -0.1], "C1": [-0.15, 0.05, -0.1], "C2": [0.0, -0.2, -0.15],
                               "C3": [0.05, 0.2, -0.05]})
    done = 0
    for _ in range(12):
        bodies = {f"r{i}": random_body(rng, f"r{i}", n_markers=4) for i in range(3)}
        rig = Rig({**bodies, "c": pin})
        poses = _poses(rng, list(bodies), spread=1.5)
        # the pinhole robot stands back and looks at the group
        yaw = rng.uniform(0, 2 * np.pi)
        at = np.array([4.0 * np.cos(yaw), 4.0 * np.sin(yaw), 0.4])
        poses["c"] = Pose(so3_exp([0, 0, yaw + np.pi]) @ OPTICAL_IN_BASE, at)
        obs = body_observations(rig, poses)
        assert "c" in obs and all("/" in k for k in obs if k != "c")
        problem, _, _ = team_problem(rig, ObservationSet.from_dict(obs))
        assert problem.frames is not None
        for ref in ("c", "r0"):
            try:
                team = localize_team(rig, obs, ref, confidence=1.0)
            except mutloc.errors.TooFewObservationsError:
                continue
            if "c" not in team.poses or len(team.robots) < 3:
                continue
            for n in team.robots:
                assert np.linalg.norm(team.poses[n].t - _truth(poses, ref, n).t) < 1e-7, (ref, n)
            done += 1
    assert done >= 6


def test_pinhole_teams_stay_in_pixels():
    """A rig of one-pinhole robots keeps the pixel path (no ray frames): today's numbers."""
    rig = Rig({"p": _pinhole_robot("p", {"A": [0, 0, 0]}), "q": _pinhole_robot("q", {"B": [0, 0, 0]})})
    problem, _, _ = team_problem(rig, ObservationSet.from_dict({"p": {"B": [600.0, 400.0]}}))
    assert problem.frames is None


@pytest.mark.parametrize("key, message", [
    ("r1/side2", r"unknown camera 'r1/side2' \(robot 'r1' has cameras front, back\)"),
    ("r1", r"robot 'r1' has cameras front, back: key its observations by camera \(r1/front, \.\.\.\)"),
    ("r9/front", r"unknown robot 'r9/front'"),
])
def test_bad_camera_keys_are_named_in_one_line(key, message):
    rng = np.random.default_rng(3)
    while True:
        rig, poses = _team(rng)
        if list(rig.robots["r1"].cameras) == ["front", "back"]:
            break
    obs = body_observations(rig, poses)
    moved = next(k for k in obs if k.startswith("r1/"))
    bad = {k: v for k, v in obs.items() if k != moved}
    bad[key] = obs[moved]
    with pytest.raises(ObservationError, match=message) as info:
        localize_team(rig, bad, "r0")
    assert "\n" not in str(info.value)


def test_a_pixel_outside_the_lens_is_named():
    rng = np.random.default_rng(3)
    rig, poses = _team(rng)
    obs = body_observations(rig, poses)
    key = next(k for k in obs if rig.mount(k).camera.model == "fisheye")
    m = next(iter(obs[key]))
    cam = rig.mount(key).camera
    # beyond the image circle (still within the margin the image-size check allows)
    uv = next(p for p in ([2.0, 2.0], [-300.0, -200.0], [-600.0, -390.0])
              if not np.all(np.isfinite(np.asarray(cam.pixels_to_bearings(np.array(p)), float))))
    bad = {k: dict(v) for k, v in obs.items()}
    bad[key][m] = uv
    with pytest.raises(ObservationError, match=rf"observations\['{key}'\]\['{m}'\]: pixel \({uv[0]:.2f}, "
                                               rf"{uv[1]:.2f}\) is outside what the fisheye lens images"):
        localize_team(rig, bad, "r0")


def test_a_robot_held_only_by_two_markers_seen_from_two_robots():
    """A robot that sees nobody, seen at two markers by each of two robots: no pair problem holds it, the
    generalized minimal solver does (rays from cameras of two placed robots, each from its own centre)."""
    rng = np.random.default_rng(8)
    done = 0
    while done < 3:
        rig, poses = _team(rng)
        obs = body_observations(rig, poses)
        x = list(rig.robots)[-1]
        # every other robot's views of x, by robot (one camera's rows first)
        views: dict[str, list[tuple[str, str]]] = {}
        for key, seen in obs.items():
            a = rig.observer(key)[0]
            if a != x:
                views.setdefault(a, []).extend((key, m) for m in seen if rig.owner(m) == x)
        holders = [a for a, v in views.items() if len({m for _, m in v}) >= 2]
        if len(holders) < 2:
            continue
        kept: dict = {}
        for key, seen in obs.items():
            a = rig.observer(key)[0]
            if a != x:
                kept[key] = {m: uv for m, uv in seen.items() if rig.owner(m) != x}
        used: set = set()
        for a in holders[:2]:
            marks = [(k, m) for k, m in views[a] if m not in used][:2]
            if len(marks) < 2:
                break
            for k, m in marks:
                kept[k][m] = obs[k][m]
                used.add(m)
        else:
            kept = {k: v for k, v in kept.items() if v}
            team = localize_team(rig, kept, "r0", confidence=1.0)
            if any(n not in team.robots for n in rig.robots if n not in ("r0", x)):
                continue  # the others must hold x
            assert x in team.robots
            for n in team.robots:
                assert np.linalg.norm(team.poses[n].t - _truth(poses, "r0", n).t) < 1e-7, n
            done += 1


def test_the_joint_bound_is_the_pixels_information():
    """``team_pixel_information`` (numerical derivatives of each lens, the benchmark's Cramér-Rao bound) at the
    truth equals the information the team solver reports at its noise-free optimum (analytic, its own
    weighting), for bodies and for one-pinhole robots; over one robot it is the pair's ``pixel_information``."""
    from mutloc.sim.bodies import pixel_information, random_team, team_pixel_information

    rng = np.random.default_rng(36)
    pairs = 0
    for pinhole in (False, True, False, True):
        rig, poses = random_team(rng, 3, pinhole=pinhole)
        truth = body_observations(rig, poses)
        est = localize_team(rig, truth, "r0", confidence=1.0)
        rel = {r: poses["r0"].inverse() @ poses[r] for r in poses}
        info = team_pixel_information(rig, truth, "r0", rel, list(est.robots))
        assert info.shape == est.information.shape == (6 * len(est.robots),) * 2
        assert np.allclose(info, est.information, rtol=1e-5, atol=1e-6 * np.abs(info).max())
        for r in est.robots:  # each robot with the reference alone, where they observe each other
            alone = {k: {m: uv for m, uv in v.items() if {rig.observer(k)[0], rig.owner(m)} == {"r0", r}}
                     for k, v in truth.items()}
            alone = {k: v for k, v in alone.items() if v}
            if sum(len(v) for v in alone.values()) >= 3:
                pairs += 1
                assert np.allclose(team_pixel_information(rig, alone, "r0", rel, [r]),
                                   pixel_information(rig, alone, r, "r0", rel[r]), rtol=1e-6, atol=1e-9)
    assert pairs >= 4
