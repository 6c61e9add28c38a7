"""Teams (SPEC "Teams"), issue 36 item 2: a robot whose few observations fit
two distant poses within their noise is never reported solved at one of
them (mutloc.core.team.other_poses): it is unverified, the other poses in
``team.candidates(name)``; well-tied robots stay solved.  Scenes: three
robots r0, r1 seeing each other well and r2 tied to them by a few views of
its markers (r2's camera sees nothing), against the simulator's truth."""

import numpy as np
import pytest

import mutloc
from mutloc.core.team import AMBIGUITY_SIGMAS, solve_team
from mutloc.errors import UnverifiedError
from mutloc.sim.team import random_team
from mutloc.team import require_verified, team_problem

# r2's ties as (observer, marker k of r2, relabelled at random per draw):
# "4": marker 0 seen by r0 and r1, marker 1 by r0, marker 2 by r1 (8 equations, 6 unknowns);
# "5": markers 0, 1 by both, marker 2 by r0 (the held-out scene); "3": exactly three
PATTERNS = {"3": [(0, 0), (0, 1), (1, 2)],
            "4": [(0, 0), (1, 0), (0, 1), (1, 2)],
            "5": [(0, 0), (1, 0), (0, 1), (1, 1), (0, 2)],
            "6": [(0, 0), (1, 0), (0, 1), (1, 1), (0, 2), (1, 3)]}


def _scenes(pattern, n, seed, sigma=1.0, robots=3):
    """``n`` seeded draws: (scene, observations) with r2 tied by ``pattern``
    only and the other robots by every marker they see of each other."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        scene = random_team(robots, rng, one_way=0.0, radius=2.0)
        names = scene.names
        vis = scene.visible()
        base = [v for v in vis if "r2" not in (v[0], v[1].split("_")[0])]
        by = {(v[0], v[1]): v for v in vis}
        perm = rng.permutation(4)
        keys = [(names[o], f"r2_m{perm[k]}") for o, k in PATTERNS[pattern]]
        if len(base) < 8 or not all(k in by for k in keys):
            continue
        out.append((scene, scene.observations(sigma, rng, visible=base + [by[k] for k in keys])))
    return out


def _basin_of_truth(scene, obs):
    """r2's pose at the joint optimum reached from the simulator's truth (the
    minimum in the truth's basin: where a right answer is, under noise)."""
    truth = scene.truth()
    problem, names, _ = team_problem(scene.rig, obs)
    sol = solve_team(problem, 0, initial=(np.array([truth[n].R for n in names]), np.array([truth[n].t for n in names]),
                                          np.ones(len(names), dtype=bool)))
    i = names.index("r2")
    return mutloc.Pose(sol.Rs[i], sol.ts[i])


def _sigmas(team, name, other):
    """Mahalanobis distance of ``other`` from the estimate of ``name`` (its covariance)."""
    T = team.poses[name]
    e = np.r_[mutloc.Pose(other.R @ T.R.T, np.zeros(3)).rotvec, other.t - T.t]
    return float(np.sqrt(e @ np.linalg.solve(team.covariance(name), e)))


def _among(candidates, pose, deg=3.0, metres=0.03):
    rot = np.atleast_1d(candidates.rotation_error_deg(pose))
    tr = np.atleast_1d(candidates.translation_error(pose))
    return bool(np.any((rot < deg) & (tr < metres)))


@pytest.mark.parametrize("pattern", ["4", "5"])
def test_weakly_tied_robot_is_never_solved_far_from_the_truth(pattern):
    """Today (before the search) 18% of the "4" draws and 2% of the "5" ones
    were solved 40-170 deg off with a covariance of a few degrees.  Now a
    robot reported solved is within the covariance of the truth's basin, and
    one left unverified for a second pose has the truth among its
    candidates; r1 (tied by a dozen observations) is always solved at the
    truth."""
    draws = {"4": 40, "5": 60}[pattern]
    flagged = 0
    for scene, obs in _scenes(pattern, draws, seed=int(pattern)):
        team = mutloc.localize_team(scene.rig, obs)
        truth = scene.truth()
        assert team.status == "solved" and "r2" in team.poses
        assert "r1" not in team.unverified and team.robot_status("r1") == "solved"
        assert _sigmas(team, "r1", truth["r1"]) < 5.0
        right = _basin_of_truth(scene, obs)
        if team.robot_status("r2") == "solved":
            # within the covariance it claims
            assert _sigmas(team, "r2", right) < AMBIGUITY_SIGMAS, (pattern, team.poses["r2"].rotation_error_deg(right))
            assert len(team.candidates("r2")) == 1
        else:
            assert "r2" in team.ambiguous and "r2" in team.unverified
            flagged += 1
            C = team.candidates("r2")
            assert len(C) >= 2 and C[0].rotation_error_deg(team.poses["r2"]) < 1e-4
            assert _among(C, right)
            # the others lie far beyond the covariance
            assert max(_sigmas(team, "r2", T) for T in C[1:]) > AMBIGUITY_SIGMAS
    assert flagged >= 1


def test_three_ties_list_every_exact_pose():
    """Exactly three observations (noise-free): several exact poses, r2
    unverified as before; the truth is now always among its candidates,
    even when the pose reported is another exact one."""
    wrong = 0
    for scene, obs in _scenes("3", 25, seed=3, sigma=0.0):
        team = mutloc.localize_team(scene.rig, obs)
        truth = scene.truth()["r2"]
        assert team.unverified == ["r2"]
        wrong += team.poses["r2"].rotation_error_deg(truth) > 1.0
        assert _among(team.candidates("r2"), truth, deg=1e-3, metres=1e-5)
    assert wrong >= 1  # some draws did report another exact pose


def test_well_tied_robots_stay_solved_beside_an_ambiguous_one():
    """Five robots, four seeing each other well, r2 tied by four
    observations: only r2 may be unverified; every other robot is solved at
    the truth with no other candidate; the flagged r2 is refused without
    --allow-unverified, named with the poses its observations fit, and the
    team JSON lists them.  r2 on six observations stays solved."""
    flagged = 0
    for scene, obs in _scenes("4", 12, seed=11, robots=5):
        team = mutloc.localize_team(scene.rig, obs)
        truth = scene.truth()
        for r in ("r1", "r3", "r4"):
            assert team.robot_status(r) == "solved" and r not in team.ambiguous
            assert len(team.candidates(r)) == 1
            assert _sigmas(team, r, truth[r]) < 5.0
        if team.robot_status("r2") == "solved":
            assert _sigmas(team, "r2", _basin_of_truth(scene, obs)) < AMBIGUITY_SIGMAS
            continue
        flagged += 1
        assert team.unverified == ["r2"] and list(team.ambiguous) == ["r2"]
        with pytest.raises(UnverifiedError, match="r2: its observations fit"):
            require_verified(team, allow_unverified=False)
        require_verified(team, allow_unverified=True)
        d = team.to_dict()
        assert d["unverified"] == ["r2"] and len(d["ambiguous"]["r2"]) == len(team.candidates("r2")) - 1
        assert _among(team.candidates("r2"), _basin_of_truth(scene, obs))
    assert flagged >= 1
    # r2 on six observations (two markers seen by both, two by one each) is
    # searched too (AMBIGUITY_TIES) and fits one pose: solved at the truth
    for scene, obs in _scenes("6", 10, seed=6):
        team = mutloc.localize_team(scene.rig, obs)
        assert team.unverified == [] and team.ambiguous == {}
        assert _sigmas(team, "r2", scene.truth()["r2"]) < 5.0
