"""Team solver edge cases (exact data): exact pixels are always solved
exactly, robots tied only by observations spread over several robots or
as a group are placed (the generalized minimal solver), and a group held by
exactly three observations keeps its pose, flagged unverified.  Ground
truth: the synthetic scenes' poses."""

import numpy as np

import mutloc
from mutloc.core.team import _NoSuchChoice, initial_poses, solve_team
from mutloc.sim.team import random_team
from mutloc.team import team_problem

TOL_T, TOL_DEG = 1e-6, 1e-5


def _restricted(n, seed, core, extra):
    """A random team of ``n`` whose observations are all those among the
    robots ``core`` plus, per (observer, owner) in ``extra``, the owner's
    markers of the listed indices (None: all); and whether every listed
    marker was visible."""
    rng = np.random.default_rng(seed)
    scene = random_team(n, rng, one_way=0.0)
    scene.links = None
    keep, got = [], set()
    for a, m, uv in scene.visible():
        b, k = m.rsplit("_m", 1)
        if a in core and b in core:
            keep.append((a, m, uv))
        elif (a, b) in extra and (extra[(a, b)] is None or int(k) in extra[(a, b)]):
            keep.append((a, m, uv))
            got.add((a, m))
    wanted = {(a, f"{b}_m{k}") for (a, b), ks in extra.items() if ks is not None for k in ks}
    pairs_all = {(a, b) for (a, b), ks in extra.items() if ks is None}
    ok = wanted <= got and all(sum(1 for a, m in got if (a, m.rsplit("_m", 1)[0]) == p) >= 3 for p in pairs_all)
    return scene, keep, ok


def _scenes(n, core, extra, count, seeds=range(200)):
    out = []
    for seed in seeds:
        scene, keep, ok = _restricted(n, seed, core, extra)
        if ok:
            out.append((seed, scene, scene.observations(visible=keep)))
            if len(out) == count:
                return out
    raise AssertionError(f"only {len(out)} scenes of the construction")


def _assert_exact(team, scene, robots=None):
    truth = scene.truth(team.reference)
    for r in robots or scene.names:
        assert team.poses[r].translation_error(truth[r]) < TOL_T, r
        assert team.poses[r].rotation_error_deg(truth[r]) < TOL_DEG, r


def _observations_of(scene, obs):
    problem, names, _ = team_problem(scene.rig, obs)
    return problem, names, np.bincount(np.r_[problem.cam, problem.own], minlength=len(names))


def test_noise_free_random_teams_are_solved_exactly():
    """120 seeded random teams of 3-8 robots: >= 99% exact (every robot in an
    observation within 1e-6 m), a refusal only when the reference itself is
    in fewer than three observations, and no robot in >= 4 observations
    left without a pose."""
    rng = np.random.default_rng(2401)
    exact = refused = 0
    n_scenes = 120
    for _ in range(n_scenes):
        scene = random_team(int(rng.integers(3, 9)), rng)
        obs = scene.observations()
        problem, names, seen = _observations_of(scene, obs)
        try:
            team = mutloc.localize_team(scene.rig, obs)
        except mutloc.errors.TooFewObservationsError:
            assert seen[0] < 3
            refused += 1
            continue
        assert all(seen[names.index(r)] < 4 for r in team.unlocalized)
        truth = scene.truth()
        exact += all(T.translation_error(truth[r]) < TOL_T and T.rotation_error_deg(truth[r]) < TOL_DEG
                     for r, T in team.poses.items())
    assert exact + refused >= 0.99 * n_scenes and refused <= 3, (exact, refused)


def test_reference_tied_only_through_other_robots_single_observations():
    """r0 (the reference) is seen once by each of r1, r2, r3 and sees none
    of them: three rays from three cameras (a non-central problem no pair
    solver covers).  The joint problem has exact poses: r1..r3 are placed,
    flagged unverified (three observations hold them), and fit exactly.
    With a fourth (r0 sees one marker of r1) they are the truth."""
    core = {"r1", "r2", "r3"}
    extra = {("r1", "r0"): [0], ("r2", "r0"): [1], ("r3", "r0"): [3]}
    for seed, scene, obs in _scenes(4, core, extra, 3):
        team = mutloc.localize_team(scene.rig, obs)
        assert team.unlocalized == [] and sorted(team.unverified) == ["r1", "r2", "r3"], seed
        assert team.reprojection_rms_px < 1e-6
    extra[("r0", "r1")] = [0]
    for seed, scene, obs in _scenes(4, core, extra, 3):
        team = mutloc.localize_team(scene.rig, obs)
        assert team.unlocalized == [] and team.unverified == [], seed
        _assert_exact(team, scene)


def test_reference_sees_one_marker_of_each_of_several_robots():
    """r0 sees one marker of r1, r2 and r3 and one more of r3; nobody sees
    r0's markers: the group r1..r3, solved among itself, is placed by the
    reference's four rays (the truth)."""
    core = {"r1", "r2", "r3"}
    extra = {("r0", "r1"): [0], ("r0", "r2"): [1], ("r0", "r3"): [0, 2]}
    for seed, scene, obs in _scenes(4, core, extra, 3):
        team = mutloc.localize_team(scene.rig, obs)
        assert team.unlocalized == [] and team.unverified == [], seed
        _assert_exact(team, scene)


def test_group_held_by_exactly_three_observations_keeps_its_poses():
    """r3 and r4 see each other well; three single observations, spread over
    both of them and three other robots, are all that tie them to r0..r2.
    Each is in >= 4 observations: both get poses fitting every observation
    exactly, flagged unverified (never silently dropped)."""
    core = {"r0", "r1", "r2"}
    extra = {("r3", "r4"): None, ("r4", "r3"): None, ("r0", "r3"): [0], ("r1", "r4"): [1], ("r3", "r2"): [2]}
    for seed, scene, obs in _scenes(5, core, extra, 3):
        _, names, seen = _observations_of(scene, obs)
        assert seen[names.index("r3")] >= 4 and seen[names.index("r4")] >= 4
        team = mutloc.localize_team(scene.rig, obs)
        assert team.unlocalized == [] and sorted(team.unverified) == ["r3", "r4"], seed
        assert team.reprojection_rms_px < 1e-6
        _assert_exact(team, scene, ["r1", "r2"])


def _ambiguous_scenes(count):
    """r1 is tied to r0 by exactly three observations (r0 sees three of its
    markers: several exact poses), r2 by two of its markers seen by r0, two
    others seen by r1 and one view of r1's: later observations tell r1's
    exact poses apart."""
    core = {"r0", "r3", "r4"}
    extra = {("r0", "r1"): [0, 1, 2], ("r0", "r2"): [0, 1], ("r1", "r2"): [2, 3], ("r2", "r1"): [3]}
    return _scenes(5, core, extra, count, range(400))


def test_a_wrong_exact_pose_is_not_the_answer():
    """r1's three observations fit several exact poses and the first start
    often takes a wrong one (r2's observations, placed later, tell them
    apart): whichever start, the solver reaches the truth."""
    wrong_first = 0
    for seed, scene, obs in _ambiguous_scenes(6):
        problem, names, _ = team_problem(scene.rig, obs)
        truth = scene.truth()
        record = []
        Rs, ts, placed = initial_poses(problem, 0, record=record)
        assert record == [1], seed
        wrong_first += np.linalg.norm(ts[1] - truth["r1"].t) > 0.01
        k = 0
        while True:  # every exact pose of r1 as the start
            try:
                start = initial_poses(problem, 0, choices={1: k})
            except _NoSuchChoice:
                break
            k += 1
            sol = solve_team(problem, 0, initial=start)
            assert sol.localized.all() and sol.cost < 1e-12, (seed, k)
            assert np.abs(sol.ts[1] - truth["r1"].t).max() < TOL_T, (seed, k)
        assert k >= 2, seed  # r1 had several exact poses
        team = mutloc.localize_team(scene.rig, obs)
        assert team.unlocalized == [] and team.unverified == [], seed
        _assert_exact(team, scene)
    assert wrong_first >= 2


def _tag_scene(seed, index):
    """The ``index``-th scene of bench/team_exact.py --kind tags --seed ``seed``."""
    rng = np.random.default_rng(seed)
    for _ in range(index + 1):
        scene = random_team(int(rng.integers(3, 9)), rng, kind="tags")
    return scene


def test_tag_teams_that_failed_are_exact():
    """Tag teams (two points per robot) from the benchmark: scene 115 (a
    robot's start in a wrong basin that fit its four ties within the noise:
    the joint optimum passed its test 6 m off), scenes 5, 27, 34 (the
    reference tied only through observations spread over other robots:
    TooFewObservationsError before)."""
    for index in (5, 27, 34, 115):
        scene = _tag_scene(2, index)
        team = mutloc.localize_team(scene.rig, scene.observations())
        # scene 115: the wrong basin still fits r1's four ties within 1 px
        # (5.5 px^2, 6 m off): r1 is solved exactly but left unverified, the
        # other pose among its candidates (issue 36, test_team_ambiguity.py)
        assert set(team.unverified) <= set(team.ambiguous), index
        assert index == 115 or team.unverified == [], index
        _assert_exact(team, scene, list(team.poses))
        assert len(team.poses) >= 3


def test_a_robot_seen_at_two_points_only_stays_unlocalized():
    """Tag scene 177 of seed 1: r1 is seen by r0 and r2 at the same two
    points (its two tags) and sees nothing: free to turn about their line,
    it is left unlocalized (not placed by the generalized solver into a
    team that would then be degenerate)."""
    scene = _tag_scene(1, 177)
    team = mutloc.localize_team(scene.rig, scene.observations())
    assert team.unlocalized == ["r1"]
    _assert_exact(team, scene, ["r0", "r2"])


def test_loops_without_a_rigid_sub_group_are_solved_exactly():
    """Tag scenes 88 and 190 of seed 2024: no robot shares more than two
    observations with the reference and no group is tied to it by three
    (TooFewObservationsError before): only the loops through several robots
    hold the poses, isolated and with redundancy.  Drawn starts on the
    two-point rays, refined jointly, give the truth, verified by the spare
    observations."""
    for index in (88, 190):
        scene = _tag_scene(2024, index)
        obs = scene.observations()
        problem, names, _ = _observations_of(scene, obs)
        C = problem.counts()
        assert (C[0] + C[:, 0]).max() <= 2, index  # nobody tied to the reference by three
        team = mutloc.localize_team(scene.rig, obs)
        assert team.unlocalized == [] and team.unverified == [], index
        assert team.consistency.dof > 0
        _assert_exact(team, scene)


def test_a_robot_held_only_through_a_free_turning_one_is_localized_with_honest_covariance():
    """Tag scene 76 of seed 2024: r1 is seen at its two tags by r0 and r2 and
    sees nothing, so it turns freely about their line; r2 sees r0 and r1, and
    only through r1 is it held (TooFewObservationsError before).  r1 is
    solved along and reported unlocalized, r2 is the truth on exact pixels;
    under 1 px noise r2's covariance (r1 marginalised out) is consistent:
    mean NEES/6 near 1 over 200 draws (a refusal -- no start within the
    noise at 99.9% -- allowed in at most 2% of them), and the chi-square
    test has the one spare equation."""
    from mutloc.core.geometry import so3_log

    scene = _tag_scene(2024, 76)
    obs = scene.observations()
    team = mutloc.localize_team(scene.rig, obs)
    assert team.unlocalized == ["r1"] and set(team.poses) == {"r0", "r2"}
    _assert_exact(team, scene, ["r2"])
    assert team.consistency.dof == 1
    truth = scene.truth(team.reference)["r2"]
    rng = np.random.default_rng(5)
    nees, refused = [], 0
    for _ in range(200):
        noisy = {a: {m: (np.asarray(uv) + rng.normal(size=2)).tolist() for m, uv in seen.items()}
                 for a, seen in obs.to_dict().items()}
        try:
            est = mutloc.localize_team(scene.rig, noisy, confidence=1.0)
        except mutloc.errors.TooFewObservationsError:
            refused += 1
            continue
        T = est.poses["r2"]
        e = np.r_[so3_log(T.R @ truth.R.T), T.t - truth.t]
        nees.append(e @ np.linalg.solve(est.covariance("r2"), e) / 6)
    assert refused <= 4
    assert 0.75 < np.mean(nees) < 1.35, np.mean(nees)
