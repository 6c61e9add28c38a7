"""The paper's baselines (mutloc.baselines) and the geometry the experiments
stand on, each against ground truth: random poses and points, rendered
scenes with known pose, exact room geometry."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mutloc.baselines.dugas import dugas_pose
from mutloc.baselines.egomotion import MIN_INLIERS, Matches, egomotion_pose
from mutloc.baselines.tag import tag_pose
from mutloc.core.geometry import rotation_error_deg
from mutloc.core.triangulate import triangulate_midpoint
from mutloc.errors import DegenerateGeometryError, NoSolutionError, ObservationError
from mutloc.io.pointcloud import read_ply, write_ply
from mutloc.sim.render import relative_pose, render, surface_distance, two_robot_world
from mutloc.sim.synthetic import facing_pose
from mutloc.sim.world import standard_rig

LIGHTS = np.array([[0.15, 0.0, 0.0], [-0.15, 0.0, 0.0]])


def _random_facing(rng):
    return facing_pose(rng.uniform(0.8, 4.0), *np.radians(rng.uniform(-25, 25, 2)), rng.uniform(-0.6, 0.6),
                       tilt=np.radians(rng.uniform(-8, 8, 3)))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_dugas_closed_form_exact_on_noise_free_bearings(seed):
    rng = np.random.default_rng(seed)
    T = _random_facing(rng)
    hp, hq = rng.uniform(0.05, 0.3, 2)
    ep, eq = (np.array([1.0, rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2)]) for _ in range(2))
    Lp = np.array([hp * ep / np.linalg.norm(ep), -hp * ep / np.linalg.norm(ep)])
    Lq = np.array([hq * eq / np.linalg.norm(eq), -hq * eq / np.linalg.norm(eq)])
    est = dugas_pose(T.inverse().apply(Lq), T.apply(Lp), Lp, Lq, corrections=4)
    assert np.linalg.norm(est.t - T.t) < 1e-5 * np.linalg.norm(T.t)
    assert rotation_error_deg(est.R, T.R) < 1e-3


def test_dugas_bisector_only_is_approximate_and_corrections_converge():
    rng = np.random.default_rng(4)
    errs = {0: [], 2: []}
    for _ in range(50):
        T = _random_facing(rng)
        for c in errs:
            est = dugas_pose(T.inverse().apply(LIGHTS), T.apply(LIGHTS), LIGHTS, LIGHTS, corrections=c)
            errs[c].append(np.linalg.norm(est.t - T.t))
    assert np.median(errs[2]) < 1e-3 * np.median(errs[0])


def test_dugas_rejects_lights_not_centred_on_the_camera():
    off = LIGHTS + [0.0, 0.05, 0.0]
    T = facing_pose(2.0)
    with pytest.raises(DegenerateGeometryError):
        dugas_pose(T.inverse().apply(LIGHTS), T.apply(off), off, LIGHTS)


def _projected_matches(rng, T_qp, n, K):
    """Pixels of random points in front of both cameras: (p's, q's)."""
    pts = []
    while len(pts) < n:
        X = rng.uniform([-2, -1, 0.5], [2, 1, 5])
        Xp = T_qp.inverse().apply(X)
        if X[2] > 0.3 and Xp[2] > 0.3:
            pts.append(X)
    X = np.array(pts)
    Xp = T_qp.inverse().apply(X)
    proj = lambda Y: (Y[:, :2] / Y[:, 2:]) * K[0, 0] + K[:2, 2]  # noqa: E731
    return proj(Xp), proj(X)


def test_egomotion_recovers_the_pose_from_exact_matches_with_the_oracle_scale():
    rng = np.random.default_rng(0)
    rig = standard_rig("balls")
    cam = rig.robot("p").camera
    for _ in range(5):
        T = facing_pose(2.0, *np.radians(rng.uniform(-60, 60, 2)), rng.uniform(-1, 1))
        uv_p, uv_q = _projected_matches(rng, T, 80, cam.K)
        est, inliers = egomotion_pose(None, None, cam, cam, float(np.linalg.norm(T.t)), matches=Matches(uv_p, uv_q))
        assert inliers.sum() >= 75
        assert np.linalg.norm(est.t - T.t) < 1e-3
        assert rotation_error_deg(est.R, T.R) < 0.05


def test_egomotion_refuses_too_few_matches():
    rig = standard_rig("balls")
    cam = rig.robot("p").camera
    uv_p, uv_q = _projected_matches(np.random.default_rng(1), facing_pose(2.0, 0.5), MIN_INLIERS - 1, cam.K)
    with pytest.raises(NoSolutionError):
        egomotion_pose(None, None, cam, cam, 2.0, matches=Matches(uv_p, uv_q))


@pytest.fixture(scope="module")
def tag_scene():
    from mutloc.experiments.localization import localization_rig

    rig = localization_rig()
    T = facing_pose(1.5, np.radians(8.0), np.radians(-4.0), 0.2)
    world = two_robot_world(rig, T, seed=5)
    return rig, world, render(world, "q", seed=1)


def test_tag_baseline_pose_close_to_the_truth(tag_scene):
    rig, world, img_q = tag_scene
    truth = relative_pose(world, "p", "q")
    est = tag_pose(img_q, rig.robot("p").markers["TP"], rig.robot("q").camera)
    # One-sided and from a 12 cm tag: centimetres and degrees, not millimetres.
    assert np.linalg.norm(est.t - truth.t) < 0.08
    assert rotation_error_deg(est.R, truth.R) < 8.0


def test_tag_baseline_reports_a_missing_tag(tag_scene):
    rig, _world, img_q = tag_scene
    with pytest.raises(ObservationError):
        tag_pose(np.full_like(img_q, 128), rig.robot("p").markers["TP"], rig.robot("q").camera)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_midpoint_triangulation_exact_for_exact_rays(seed):
    rng = np.random.default_rng(seed)
    T = _random_facing(rng)
    X = rng.uniform([-1, -1, 0.3], [1, 1, 3], (20, 3))
    Xp = T.inverse().apply(X)
    Y, ok = triangulate_midpoint(X / np.linalg.norm(X, axis=1)[:, None], Xp / np.linalg.norm(Xp, axis=1)[:, None], T)
    assert np.allclose(Y[ok], X[ok], atol=1e-8)
    assert ok.mean() > 0.8


def test_surface_distance_is_exact_for_room_and_robots():
    world = two_robot_world(standard_rig("balls"), facing_pose(2.0), seed=2)
    room = world.room
    cx, cy = room.center
    sx, sy = room.size
    rng = np.random.default_rng(0)
    # Points on the floor and the far walls lie on the surface.
    floor = np.column_stack([rng.uniform(cx - sx / 2, cx + sx / 2, 50), rng.uniform(cy - sy / 2, cy + sy / 2, 50),
                             np.zeros(50)])
    wall = np.column_stack([np.full(20, cx + sx / 2), rng.uniform(cy - sy / 2, cy + sy / 2, 20),
                            rng.uniform(0, room.height, 20)])
    assert np.abs(surface_distance(world, np.vstack([floor, wall]))).max() < 1e-9
    # A point high above the robots: nearest is the ceiling (or a wall).
    P = np.array([[cx, cy, room.height - 0.3]])
    expect = min(0.3, sx / 2, sy / 2)
    assert surface_distance(world, P)[0] == pytest.approx(expect)
    # A ball's centre is one radius from its surface.
    c = world.pose("q").apply(world.robot("q").robot.markers["M1"].position)
    assert surface_distance(world, c[None])[0] == pytest.approx(0.03, abs=1e-9)


def test_ply_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    P = rng.normal(size=(100, 3))
    C = rng.integers(0, 256, (100, 3))
    write_ply(tmp_path / "c.ply", P, C)
    Q, D = read_ply(tmp_path / "c.ply")
    assert np.allclose(Q, P, atol=1e-6 * np.abs(P).max()) and np.array_equal(D, C)
