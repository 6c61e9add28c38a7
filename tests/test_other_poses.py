"""The search for a second consistent pose (mutloc.core.robust.other_consistent_poses) on robots with several
cameras: the compiled loop against the reference loop written here in NumPy, and the ambiguous scenes where
both robots see each other (few observations), against the simulator's truth."""

from __future__ import annotations

import numpy as np
import pytest

import mutloc
from mutloc import api
from mutloc.core import robust
from mutloc.core.consistency import DEFAULT_CONFIDENCE, chi2_quantile
from mutloc.core.estimate import estimate
from mutloc.core.geometry import so3_exp, so3_log
from mutloc.core.observations import ObservationSet
from mutloc.core.refine import lm_refine
from mutloc.sim.bodies import body_observations, random_pair

# Seeds of :func:`_mutual_scene` whose observations fit two poses (found by searching seeds 0-3000 with every
# minimal subset's candidates): p sees 1 or 3 markers, q the rest, 4 in all.
AMBIGUOUS_MUTUAL = (345, 741, 864, 2867)


def _mutual_scene(seed: int):
    """Robots 1.5-6 m apart, both seeing each other, through 4-8 of the observations their cameras make."""
    rng = np.random.default_rng(seed)
    rig, poses, T = random_pair(rng, 1.5, 6.0)
    truth = body_observations(rig, poses)
    items = [(k, m) for k, v in truth.items() for m in v]
    if len(items) < 4 or len({k.split("/")[0] for k, _ in items}) < 2:
        return None
    noisy = body_observations(rig, poses, sigma=1.0, rng=rng)
    for _ in range(20):
        n = int(rng.integers(4, min(8, len(items)) + 1))
        sel = [items[i] for i in rng.choice(len(items), n, replace=False)]
        if len({k.split("/")[0] for k, _ in sel}) == 2:
            break
    else:
        return None
    obs: dict = {}
    for k, m in sel:
        if k in noisy and m in noisy[k]:
            obs.setdefault(k, {})[m] = noisy[k][m]
    return rig, obs, T


def _solved(rig, obs, accept=True):
    pair = ObservationSet.from_dict(obs).pair(rig, "p", "q")
    problem = api._problem(pair, pair.side, pair.points_index, pair.rows)
    gate = api._accept(len(pair.rows), 1.0, DEFAULT_CONFIDENCE) if accept else None
    return problem, estimate(problem, accept=gate)


def _reference_search(problem, first, sigma, confidence, tries=6):
    """The search as first written (NumPy, every subset's candidates): refine the best-ranked candidates outside
    the 99.9 % ellipsoid of the first pose and of every pose found."""
    n = len(problem.side)
    gate = chi2_quantile(confidence, 2 * n - 6) * sigma**2
    info = first.information / sigma**2
    limit = chi2_quantile(0.999, 6)

    def far(R, t, R0, t0):
        d = np.r_[so3_log(R @ R0.T), t - t0]
        return d @ info @ d > limit

    cand, costs = first.candidates, first.candidate_costs
    found, attempts = [], 0
    for i in np.flatnonzero(costs <= 50.0 * gate):
        if attempts >= tries:
            break
        R, t = cand.R[i].copy(), cand.t[i].copy()
        if not far(R, t, first.pose.R, first.pose.t) or any(not far(R, t, *f) for f in found):
            continue
        attempts += 1
        c, _ = lm_refine(*problem.kernel_args(), R, t, 50)
        if c <= gate and far(R, t, first.pose.R, first.pose.t) and all(far(R, t, *f) for f in found):
            found.append((R, t))
    return found


def test_compiled_search_matches_the_reference_loop():
    """Far robots seen by one camera through four markers (two poses fit more often than not): the compiled
    search finds the same poses as the NumPy loop."""
    rng = np.random.default_rng(5)
    compared = ambiguous = 0
    while compared < 40:
        rig, poses, _ = random_pair(rng, 3.5, 5.0)
        obs = body_observations(rig, poses, sigma=1.0, rng=rng)
        if len(obs) != 1 or sum(len(v) for v in obs.values()) != 4:
            continue
        try:
            problem, sol = _solved(rig, obs, accept=False)
        except mutloc.errors.MutlocError:
            continue
        compared += 1
        ref = _reference_search(problem, sol, 1.0, DEFAULT_CONFIDENCE)
        got = robust.other_consistent_poses(problem, sol, 1.0, DEFAULT_CONFIDENCE)
        assert len(got) == len(ref)
        for p, (R, t) in zip(got, ref):
            np.testing.assert_allclose(p.R, R, atol=1e-9)
            np.testing.assert_allclose(p.t, t, atol=1e-9)
        ambiguous += bool(ref)
    assert ambiguous >= 5


def test_pose_mahalanobis_is_the_rotation_vector_distance():
    rng = np.random.default_rng(6)
    for _ in range(50):
        A = rng.normal(size=(6, 6))
        info = A @ A.T
        Ra, Rb = so3_exp(rng.normal(0, 1.0, 3)), so3_exp(rng.normal(0, 1.0, 3))
        ta, tb = rng.normal(size=3), rng.normal(size=3)
        d = np.r_[so3_log(Ra @ Rb.T), ta - tb]
        if np.linalg.norm(d[:3]) > 3.0:
            continue  # near a half turn the kernel's axis is approximate (enough to tell poses apart)
        assert robust.pose_mahalanobis(Ra, ta, Rb, tb, info) == pytest.approx(d @ info @ d, rel=1e-9)


@pytest.mark.parametrize("seed", AMBIGUOUS_MUTUAL)
def test_robots_seeing_each_other_can_fit_two_poses(seed):
    """Both robots see each other yet the observations fit two poses: `unverified`, the truth's basin among
    the poses given, never `solved` at one of them."""
    rig, obs, T = _mutual_scene(seed)
    assert {k.split("/")[0] for k in obs} == {"p", "q"}
    est = mutloc.localize(rig, obs, "p", "q")
    assert est.status == "unverified" and len(est.alternatives) >= 1
    poses = [est.pose.R] + list(est.alternatives.R)
    off = [np.linalg.norm(so3_log(R @ T.R.T)) for R in poses]
    apart = np.linalg.norm(so3_log(poses[0] @ poses[1].T))
    assert min(off) < 0.5 * apart  # the truth nearer one of them than they are to each other


def test_the_first_subsets_roots_find_the_second_pose(monkeypatch):
    """Started from the first minimal subset's roots alone (the shortcut for robots that see each other), the
    search still finds every second pose of the ambiguous scenes, even allowed on four observations: a pose
    that fits every observation fits the subset's three, so one of its roots lies in that pose's basin (or
    the subset's other roots start too close and the whole search runs)."""
    monkeypatch.setattr(robust, "SUBSET_SEARCH_MIN_OBS", 4)
    monkeypatch.setattr(robust, "SUBSET_SEARCH_MIN_SIDE", 1)
    by_roots = 0
    for seed in AMBIGUOUS_MUTUAL:
        rig, obs, _ = _mutual_scene(seed)
        problem, sol = _solved(rig, obs)
        shortcut = bool(sol.extra.get("first_subset"))
        found = robust.other_consistent_poses(problem, sol, 1.0, DEFAULT_CONFIDENCE)
        assert found
        by_roots += shortcut and not sol.candidates_known
    assert by_roots >= 1  # the roots alone found it, every subset untouched


def test_subset_roots_and_every_subset_agree_on_robots_seeing_each_other(monkeypatch):
    """Scenes where both robots see each other through 4-8 observations: the verdict from the first subset's
    roots is the verdict of every subset's candidates, scene by scene."""
    monkeypatch.setattr(robust, "SUBSET_SEARCH_MIN_OBS", 4)
    monkeypatch.setattr(robust, "SUBSET_SEARCH_MIN_SIDE", 1)
    compared = shortcut = 0
    for seed in list(range(60)) + list(AMBIGUOUS_MUTUAL):
        scene = _mutual_scene(seed)
        if scene is None:
            continue
        rig, obs, _ = scene
        try:
            problem, sol = _solved(rig, obs)
        except mutloc.errors.MutlocError:
            continue
        compared += 1
        fast = robust.other_consistent_poses(problem, sol, 1.0, DEFAULT_CONFIDENCE)
        shortcut += not sol.candidates_known
        sol.candidates  # noqa: B018 -- every subset solved: the full search from here
        full = robust.other_consistent_poses(problem, sol, 1.0, DEFAULT_CONFIDENCE)
        assert len(fast) == len(full)
        for a, b in zip(fast, full):
            assert np.degrees(np.linalg.norm(so3_log(a.R @ b.R.T))) < 1e-3
    assert compared >= 40 and shortcut >= 20
