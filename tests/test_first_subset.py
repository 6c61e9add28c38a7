"""The shortcut of ``estimate(accept=...)`` (what ``localize`` uses): one
well-chosen minimal subset solved first, the others only when its optimum
fails the consistency gate or could be ambiguous.

Ground truth is the full search of the same code path without the shortcut
(every minimal subset, ranking, refinement of the best starts) on synthetic
scenes of known pose, and the synthetic pose itself: the shortcut must give
the same optimum, the same candidates (computed when first read), and fall
back whenever it cannot vouch for its answer.
"""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

import mutloc
from mutloc.core.camera import Camera
from mutloc.core.consistency import chi2_quantile
from mutloc.core.estimate import PairProblem, estimate
from mutloc.core.rig import Marker, Rig, Robot
from mutloc.sim.synthetic import batch_scenes

K = np.array([[800.0, 0.0, 479.5], [0.0, 800.0, 269.5], [0.0, 0.0, 1.0]])
CAM = Camera(K, None, None)


def _rig(mp: np.ndarray, mq: np.ndarray) -> Rig:
    return Rig({"p": Robot("p", CAM, {f"P{i}": Marker(f"P{i}", "p", x) for i, x in enumerate(mp)}),
                "q": Robot("q", CAM, {f"Q{i}": Marker(f"Q{i}", "q", x) for i, x in enumerate(mq)})})


def _pixels(R, t, mp, mq, rng, sigma):
    up = CAM.project((mq - t) @ R) + rng.normal(scale=sigma, size=(len(mq), 2))
    uq = CAM.project(mp @ R.T + t) + rng.normal(scale=sigma, size=(len(mp), 2))
    return up, uq


def _problem(mp, mq, up, uq) -> PairProblem:
    """p saw q's markers (side 0), q saw p's (side 1), pixel objective."""
    return PairProblem.trusted(np.r_[np.zeros(len(mq), np.int64), np.ones(len(mp), np.int64)],
                               np.ascontiguousarray(np.vstack([mq, mp])), None,
                               np.ascontiguousarray(np.vstack([up, uq])), (K, K), (CAM.dist, CAM.dist))


def _gate(n: int) -> float:
    return chi2_quantile(0.99, 2 * n - 6)


@pytest.mark.parametrize("kind", ["usual", "random", "facing"])
@pytest.mark.parametrize("n_p,n_q", [(2, 2), (1, 3), (3, 3)])
def test_shortcut_finds_the_full_search_optimum_and_candidates(kind, n_p, n_q):
    rng = np.random.default_rng(7)
    R, t, mp, mq = batch_scenes(rng, 80, kind, n_p, n_q, distance=(1.0, 3.0))
    taken = 0
    for i in range(80):
        up, uq = _pixels(R[i], t[i], mp[i], mq[i], rng, 1.0)
        full = estimate(_problem(mp[i], mq[i], up, uq))
        fast = estimate(_problem(mp[i], mq[i], up, uq), accept=_gate(n_p + n_q))
        if fast.extra.get("first_subset"):
            taken += 1
            assert fast.cost <= _gate(n_p + n_q)
        np.testing.assert_allclose(fast.pose.R, full.pose.R, atol=1e-7)
        np.testing.assert_allclose(fast.pose.t, full.pose.t, atol=1e-7 * (1 + np.linalg.norm(full.pose.t)))
        np.testing.assert_allclose(fast.information_inv, full.information_inv, rtol=1e-5, atol=1e-12)
        # candidates: solved for when read, the same stack as the full search's
        assert fast.candidates.R.shape == full.candidates.R.shape
        np.testing.assert_allclose(fast.candidates.R, full.candidates.R, atol=1e-12)
        np.testing.assert_allclose(fast.candidate_costs, full.candidate_costs, rtol=1e-9, atol=1e-12)
    # about 1% of sigma = 1 px draws fail the 99% gate and take the full search
    assert taken >= 0.9 * 80


def test_noise_free_shortcut_recovers_truth():
    rng = np.random.default_rng(3)
    R, t, mp, mq = batch_scenes(rng, 300, "random", 2, 2, distance=(0.5, 5.0))
    for i in range(300):
        up, uq = _pixels(R[i], t[i], mp[i], mq[i], rng, 0.0)
        sol = estimate(_problem(mp[i], mq[i], up, uq), accept=_gate(4))
        assert sol.extra.get("first_subset")
        np.testing.assert_allclose(sol.pose.R, R[i], atol=1e-8)
        np.testing.assert_allclose(sol.pose.t, t[i], atol=1e-8 * (1 + np.linalg.norm(t[i])))


def test_one_camera_only_takes_the_full_search():
    # Four markers seen by one camera: a PnP problem, where nearly coplanar
    # markers leave two poses that fit; the shortcut does not try it.
    rng = np.random.default_rng(5)
    R, t, mp, mq = batch_scenes(rng, 20, "usual", 0, 4, distance=(1.0, 3.0))
    for i in range(20):
        up, _ = _pixels(R[i], t[i], mp[i], mq[i], rng, 1.0)
        prob = PairProblem.trusted(np.zeros(4, np.int64), np.ascontiguousarray(mq[i]), None,
                                   np.ascontiguousarray(up), (K, K), (CAM.dist, CAM.dist))
        assert not estimate(prob, accept=_gate(4)).extra.get("first_subset")


def test_a_wrong_pixel_falls_back_to_the_full_search():
    rng = np.random.default_rng(11)
    R, t, mp, mq = batch_scenes(rng, 50, "usual", 2, 2, distance=(1.0, 3.0))
    for i in range(50):
        up, uq = _pixels(R[i], t[i], mp[i], mq[i], rng, 1.0)
        uq[1] += (40.0, -30.0)  # 50 px off: no pose fits all four within the noise
        full = estimate(_problem(mp[i], mq[i], up, uq))
        fast = estimate(_problem(mp[i], mq[i], up, uq), accept=_gate(4))
        assert not fast.extra.get("first_subset")
        np.testing.assert_allclose(fast.pose.R, full.pose.R, atol=1e-12)
        np.testing.assert_allclose(fast.pose.t, full.pose.t, atol=1e-12)


def test_localize_candidates_are_read_lazily_and_survive_replace():
    rng = np.random.default_rng(2)
    R, t, mp, mq = batch_scenes(rng, 10, "usual", 2, 2, distance=(1.0, 3.0))
    for i in range(10):
        rig = _rig(mp[i], mq[i])
        up, uq = _pixels(R[i], t[i], mp[i], mq[i], rng, 0.5)
        obs = {"p": {f"Q{k}": up[k] for k in range(2)}, "q": {f"P{k}": uq[k] for k in range(2)}}
        est = mutloc.localize(rig, obs)
        full = estimate(_problem(mp[i], mq[i], up, uq))
        cand = est.candidates
        assert isinstance(cand, mutloc.Pose)
        np.testing.assert_allclose(cand.R, full.candidates.R, atol=1e-12)
        assert est.candidates is cand  # solved once
        # the true pose is among the candidates' basins: the best one is near it
        assert np.min(cand.translation_error(mutloc.Pose(R[i], t[i]))) < 0.05
        moved = dataclasses.replace(est, source="p2")
        assert moved.candidates is cand
        inv = est.inverse()
        np.testing.assert_allclose(inv.candidates.inverse().R, cand.R, atol=1e-12)
        again = pickle.loads(pickle.dumps(est))
        np.testing.assert_allclose(again.candidates.R, cand.R, atol=0)
        np.testing.assert_allclose(again.R, est.R, atol=0)
        d = est.to_dict()
        assert d["status"] == "solved" and d["markers_used"] == ["Q0", "Q1", "P0", "P1"]
