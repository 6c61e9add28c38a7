"""Teams (SPEC "Teams"): joint localization of any number of robots, against
the ground truth of synthetic teams."""

import json

import numpy as np
import pytest

import mutloc
from mutloc.core.team import solve_team
from mutloc.errors import (InconsistentObservationsError, ObservationError, RigError, TooFewObservationsError,
                           UnknownMarkerError)
from mutloc.sim.team import chain_team, random_team, team_rig
from mutloc.team import team_problem


def _error(est_pose, true_pose):
    """(left rotation-vector error, translation error), the covariance's order."""
    dtheta = mutloc.Pose(true_pose.R @ est_pose.R.T, np.zeros(3)).rotvec
    return np.r_[dtheta, true_pose.t - est_pose.t]


def _one_way_pairs(scene):
    return {(a, b) for a, b in scene.links if (b, a) not in scene.links}


def test_noise_free_random_teams_exact():
    rng = np.random.default_rng(0)
    one_way = 0
    for n in [3, 4, 5, 6, 7, 8] * 4:
        scene = random_team(n, rng)
        one_way += len(_one_way_pairs(scene))
        team = mutloc.localize_team(scene.rig, scene.observations())
        truth = scene.truth()
        assert team.reference == "r0" and team.unlocalized == []
        assert team.robots == scene.names[1:]
        assert team.status == "solved"
        for r in scene.names:
            assert team.poses[r].translation_error(truth[r]) < 1e-6
            assert team.poses[r].rotation_error_deg(truth[r]) < 1e-5
        a, b = scene.names[1], scene.names[-1]
        rel = team.relative(a, b)
        true_rel = truth[b].inverse() @ truth[a]
        assert (rel.source, rel.target) == (a, b)
        assert rel.pose.translation_error(true_rel) < 1e-6
        assert rel.pose.rotation_error_deg(true_rel) < 1e-5
    assert one_way > 10  # the teams did include pairs seen one way only


def test_reference_choice_is_the_same_optimum():
    rng = np.random.default_rng(1)
    scene = random_team(5, rng)
    obs = scene.observations(1.0, rng)
    a = mutloc.localize_team(scene.rig, obs)
    b = mutloc.localize_team(scene.rig, obs, reference="r2")
    assert b.reference == "r2" and "r2" not in b.robots and "r0" in b.robots
    for r in scene.names:
        expected = a.poses["r2"].inverse() @ a.poses[r]
        assert b.poses[r].translation_error(expected) < 1e-7
        assert b.poses[r].rotation_error_deg(expected) < 1e-5
    # the covariance of r0 in r2's frame is the propagated one of r2 in r0's
    np.testing.assert_allclose(b.covariance("r0"), a.relative("r0", "r2").covariance, rtol=1e-5, atol=1e-12)


def test_warm_start_reaches_the_same_optimum():
    rng = np.random.default_rng(2)
    scene = random_team(6, rng)
    obs = scene.observations(1.0, rng)
    cold = mutloc.localize_team(scene.rig, obs)
    start = {r: mutloc.Pose.from_rotvec(T.rotvec + rng.normal(0, 0.02, 3), T.t + rng.normal(0, 0.05, 3))
             for r, T in scene.truth().items()}
    warm = mutloc.localize_team(scene.rig, obs, initial=start)
    for r in scene.names:
        assert warm.poses[r].translation_error(cold.poses[r]) < 1e-8
    np.testing.assert_allclose(warm.joint_covariance, cold.joint_covariance, rtol=1e-5, atol=1e-14)


def test_relative_covariance_matches_finite_differences():
    """relative() propagates the joint covariance with the Jacobian of
    T_b^-1 T_a; check that Jacobian numerically."""
    from mutloc.core.geometry import so3_exp
    from mutloc.core.team import relative_jacobian

    rng = np.random.default_rng(3)
    Ta = mutloc.Pose.from_rotvec(rng.normal(size=3), rng.normal(size=3))
    Tb = mutloc.Pose.from_rotvec(rng.normal(size=3), rng.normal(size=3))
    Ja, Jb = relative_jacobian(Ta.R, Ta.t, Tb.R, Tb.t)
    T0 = Tb.inverse() @ Ta
    h = 1e-6
    for which, J in (("a", Ja), ("b", Jb)):
        num = np.zeros((6, 6))
        for k in range(6):
            d = np.zeros(6)
            d[k] = h
            A, B = Ta, Tb
            pert = mutloc.Pose(so3_exp(d[:3]) @ (A if which == "a" else B).R, (A if which == "a" else B).t + d[3:])
            A, B = (pert, B) if which == "a" else (A, pert)
            T = B.inverse() @ A
            num[:, k] = np.r_[mutloc.Pose(T.R @ T0.R.T, np.zeros(3)).rotvec, T.t - T0.t] / h
        np.testing.assert_allclose(J, num, atol=1e-5)


@pytest.mark.slow
def test_monte_carlo_joint_crb_and_nees():
    """sigma = 1 px, 500 random teams of 3-8 robots: the joint estimate's
    RMSE is within 10% of the joint Cramer-Rao bound and each robot's
    covariance is consistent (mean NEES 6 +- 0.6), also for relative poses."""
    rng = np.random.default_rng(4)
    nees, nees_rel, err_t, crb_t, err_r, crb_r = [], [], [], [], [], []
    unlocalized = 0
    for _ in range(500):
        scene = random_team(int(rng.integers(3, 9)), rng)
        obs = scene.observations(1.0, rng)
        team = mutloc.localize_team(scene.rig, obs, confidence=1.0)
        truth = scene.truth()
        problem, names, _ = team_problem(scene.rig, obs)
        for r in team.unlocalized:
            # only robots (nearly) nobody sees and that see (nearly) nobody
            i = names.index(r)
            assert problem.counts()[i].sum() + problem.counts()[:, i].sum() < 3
        unlocalized += len(team.unlocalized)
        # the bound: the information at the true poses
        at_truth = solve_team(problem, 0, initial=(np.array([truth[n].R for n in names]),
                                                   np.array([truth[n].t for n in names]),
                                                   np.array([n in team.poses for n in names])), max_iter=0)
        crb = at_truth.covariance(1.0)
        for i, r in enumerate(team.robots):
            e = _error(team.poses[r], truth[r])
            nees.append(e @ np.linalg.solve(team.covariance(r), e))
            err_r.append(e[:3] @ e[:3])
            err_t.append(e[3:] @ e[3:])
            crb_r.append(np.trace(crb[6 * i:6 * i + 3, 6 * i:6 * i + 3]))
            crb_t.append(np.trace(crb[6 * i + 3:6 * i + 6, 6 * i + 3:6 * i + 6]))
        a, b = team.robots[0], team.robots[-1]
        if a != b:
            rel = team.relative(a, b)
            e = _error(rel.pose, truth[b].inverse() @ truth[a])
            nees_rel.append(e @ np.linalg.solve(rel.covariance, e))
    assert unlocalized < 0.02 * len(nees)
    ratio_t = np.sqrt(np.mean(err_t) / np.mean(crb_t))
    ratio_r = np.sqrt(np.mean(err_r) / np.mean(crb_r))
    assert 0.9 <= ratio_t <= 1.1, ratio_t
    assert 0.9 <= ratio_r <= 1.1, ratio_r
    assert abs(np.mean(nees) - 6.0) <= 0.6, np.mean(nees)
    assert abs(np.mean(nees_rel) - 6.0) <= 0.6, np.mean(nees_rel)


def test_chain_joint_beats_chained_pairs_at_the_far_end():
    """Six robots in a line, each seeing the next two ahead (one-way ties):
    chaining the pair estimates r0->r1->...->r5 uses only neighbours; the
    joint estimate also uses the skips and is at least 1.5x better at r5."""
    rng = np.random.default_rng(5)
    joint, chained = [], []
    for _ in range(150):
        scene = chain_team(6, rng)
        obs = scene.observations(1.0, rng)
        names = scene.names
        far = names[-1]
        truth = scene.truth()[far]
        team = mutloc.localize_team(scene.rig, obs, confidence=1.0)
        joint.append(team.poses[far].translation_error(truth))
        T = mutloc.Pose.identity()
        for a, b in zip(names[:-1], names[1:]):
            T = T @ mutloc.localize(scene.rig, obs, source=b, target=a, confidence=1.0).pose
        chained.append(T.translation_error(truth))
    rms = lambda x: np.sqrt(np.mean(np.square(x)))  # noqa: E731
    assert rms(chained) >= 1.5 * rms(joint), (rms(chained), rms(joint))


def test_disconnected_robot_is_unlocalized():
    rng = np.random.default_rng(6)
    scene = random_team(5, rng)
    # r4 sees nobody and nobody sees it
    scene.links = {(a, b) for a, b in scene.links if "r4" not in (a, b)}
    team = mutloc.localize_team(scene.rig, scene.observations())
    assert team.unlocalized == ["r4"]
    assert "r4" not in team.poses and "r4" not in team.robots
    d = json.loads(json.dumps(team.to_dict()))
    assert "r4" not in d["robots"] and d["unlocalized"] == ["r4"]
    assert team.joint_covariance.shape == (18, 18)
    truth = scene.truth()
    for r in team.robots:
        assert team.poses[r].translation_error(truth[r]) < 1e-6
    with pytest.raises(ObservationError, match="not localized"):
        team.covariance("r4")


def _three_robot_scene():
    """p (reference), q and r facing each other on a triangle."""
    from mutloc.sim.team import TeamScene, level_pose

    rig = team_rig(["p", "q", "r"])
    world = {}
    for i, name in enumerate(["p", "q", "r"]):
        a = 2 * np.pi * i / 3
        pos = np.array([1.5 * np.cos(a), -0.5, 1.5 * np.sin(a)])
        world[name] = level_pose(pos, np.arctan2(-pos[0], -pos[2]), np.zeros(3))
    return TeamScene(rig, world)


def test_two_observations_need_more_ties():
    """r sees two of q's markers and q sees none of r: four equations for six
    unknowns, r is unlocalized.  A third observation (p's camera sees one of
    r's markers) makes a minimal 2-1 problem: r is placed but unverified
    (several exact poses fit three observations).  A fourth (p sees two of
    r's markers, a 2-2 problem) over-determines it: r is found exactly."""
    scene = _three_robot_scene()
    vis = scene.visible()
    pq = [v for v in vis if {v[0], v[1].split("_")[0]} == {"p", "q"}]
    r_sees_q = [v for v in vis if v[0] == "r" and v[1].startswith("q_")][:2]
    p_sees_r = [v for v in vis if v[0] == "p" and v[1].startswith("r_")][:2]
    assert len(pq) >= 6 and len(r_sees_q) == 2 and len(p_sees_r) == 2
    team = mutloc.localize_team(scene.rig, scene.observations(visible=pq + r_sees_q))
    assert team.unlocalized == ["r"] and team.robots == ["q"] and team.unverified == []
    team = mutloc.localize_team(scene.rig, scene.observations(visible=pq + r_sees_q + p_sees_r[:1]))
    assert team.unlocalized == [] and team.unverified == ["r"]
    assert team.to_dict()["unverified"] == ["r"]
    team = mutloc.localize_team(scene.rig, scene.observations(visible=pq + r_sees_q + p_sees_r))
    assert team.unlocalized == [] and team.robots == ["q", "r"] and team.unverified == []
    truth = scene.truth()
    for name in ("q", "r"):
        assert team.poses[name].translation_error(truth[name]) < 1e-6
        assert team.poses[name].rotation_error_deg(truth[name]) < 1e-5


def test_to_dict_is_the_spec_team_json():
    rng = np.random.default_rng(7)
    scene = random_team(4, rng)
    team = mutloc.localize_team(scene.rig, scene.observations(1.0, rng), reference="r1")
    d = json.loads(json.dumps(team.to_dict()))
    assert d["reference"] == "r1"
    assert set(d["robots"]) == {"r0", "r2", "r3"}
    for name, entry in d["robots"].items():
        assert {"R", "t", "quaternion_xyzw", "covariance"} <= set(entry)
        np.testing.assert_allclose(entry["t"], team.poses[name].t)
        assert np.array(entry["covariance"]).shape == (6, 6)
    assert d["unlocalized"] == [] and d["pixel_sigma"] == 1.0
    assert d["observations_used"] == len(scene.observations())
    assert d["reprojection_rms_px"] > 0 and d["status"] == "solved"


def test_a_wrong_observation_is_rejected_and_too_many_are_an_error():
    rng = np.random.default_rng(8)
    scene = random_team(5, rng)
    vis = scene.visible()
    a, m, uv = vis[3]
    vis[3] = (a, m, uv + np.array([25.0, -20.0]))
    obs = scene.observations(0.5, rng, vis)
    team = mutloc.localize_team(scene.rig, obs, pixel_sigma=0.5)
    assert [(r["observer"], r["marker"]) for r in team.rejected] == [(a, m)]
    assert team.status == "solved" and team.to_dict()["rejected"][0]["residual_px"] > 10
    # Reference: the same noisy observations without the wrong one, solved as they are.
    clean = {k: dict(v) for k, v in obs.to_dict().items()}
    del clean[a][m]
    oracle = mutloc.localize_team(scene.rig, clean, pixel_sigma=0.5, reject_outliers=False)
    truth = scene.truth()
    for r in team.robots:
        # measured: 5.8, 7.9, 11.1, 7.3 mm from the truth, the same poses as the reference (to 1e-15 m)
        assert team.poses[r].translation_error(truth[r]) < 0.035
        assert team.poses[r].translation_error(oracle.poses[r]) < 1e-4
    with pytest.raises(InconsistentObservationsError) as info:
        mutloc.localize_team(scene.rig, scene.observations(0.5, rng, vis), pixel_sigma=0.5, reject_outliers=False)
    assert info.value.estimate.status == "rejected"
    # the same scene seen with twice the noise it claims, everywhere
    with pytest.raises(InconsistentObservationsError):
        mutloc.localize_team(scene.rig, scene.observations(3.0, rng), pixel_sigma=1.0)


def test_bad_inputs_are_typed_errors():
    rng = np.random.default_rng(9)
    scene = random_team(4, rng)
    obs = scene.observations().to_dict()
    rig = scene.rig
    bad = {k: dict(v) for k, v in obs.items()}
    bad["r1"]["r1_m0"] = (100.0, 100.0)
    with pytest.raises(ObservationError, match="own marker"):
        mutloc.localize_team(rig, bad)
    bad = dict(obs, r9={"r1_m0": (100.0, 100.0)})
    with pytest.raises(ObservationError, match="unknown robot"):
        mutloc.localize_team(rig, bad)
    bad = {k: dict(v) for k, v in obs.items()}
    bad["r1"]["nosuch"] = (100.0, 100.0)
    with pytest.raises(UnknownMarkerError):
        mutloc.localize_team(rig, bad)
    with pytest.raises(ObservationError, match="reference"):
        mutloc.localize_team(rig, obs, reference="r9")
    with pytest.raises(TooFewObservationsError):
        mutloc.localize_team(rig, {"r1": {"r2_m0": (400.0, 300.0)}})
    with pytest.raises(ObservationError, match="named markers"):
        mutloc.localize_team(rig, {"r1": [(400.0, 300.0)]})
    d = rig.to_dict()
    d["robots"]["r2"]["markers"]["r1_m0"] = d["robots"]["r2"]["markers"].pop("r2_m0")
    with pytest.raises(RigError, match="r1_m0"):
        mutloc.load_rig(d)
