"""The generalized three-correspondence solver (core/generalized.py) against
ground truth: random rigid motions, rays from one to three origins in
either frame, every mix of the two directions; the true pose must be among
the solutions, and every solution must fit the three correspondences
exactly (checked independently of the solver's algebra)."""

import numpy as np
import pytest

from mutloc.core.generalized import KIND_U_RAY, generalized_p3p
from mutloc.core.geometry import so3_exp


def _case(rng, kinds, n_origins):
    R = so3_exp(rng.normal(size=3) * 2.0)
    t = rng.normal(size=3) * 2.0
    centres_u = rng.normal(size=(3, 3)) * 0.5
    centres_w = rng.normal(size=(3, 3)) * 0.5
    o, d, X = np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3))
    for k, kind in enumerate(kinds):
        c = k % n_origins
        if kind == KIND_U_RAY:  # a ray of U through a known point of W
            o[k] = centres_u[c]
            p = o[k] + rng.normal(size=3)
            d[k] = (p - o[k]) * rng.uniform(0.5, 2.0)  # any length
            X[k] = R @ p + t
        else:  # a ray of W through a known point of U
            o[k] = centres_w[c]
            X[k] = rng.normal(size=3)
            d[k] = R @ X[k] + t - o[k]
    return R, t, o, d, X


def _fits(kinds, o, d, X, R, t):
    """Largest distance of a correspondence's point from its ray (ahead of the origin)."""
    worst = 0.0
    for k, kind in enumerate(kinds):
        if kind == KIND_U_RAY:
            p = R.T @ (X[k] - t)  # the W point in U
        else:
            p = R @ X[k] + t  # the U point in W
        u = d[k] / np.linalg.norm(d[k])
        s = (p - o[k]) @ u
        if s <= 0:
            return np.inf
        worst = max(worst, np.linalg.norm(p - o[k] - s * u))
    return worst


@pytest.mark.parametrize("kinds", [(0, 0, 0), (0, 0, 1), (0, 1, 1), (1, 1, 1), (1, 0, 1)])
@pytest.mark.parametrize("n_origins", [1, 2, 3])
def test_true_pose_among_solutions(kinds, n_origins):
    rng = np.random.default_rng([17, n_origins, *kinds])
    missed = 0
    for _ in range(60):
        R, t, o, d, X = _case(rng, kinds, n_origins)
        Rs, ts = generalized_p3p(kinds, o, d, X)
        assert 1 <= len(Rs) <= 8 and Rs.shape == (len(Rs), 3, 3) and ts.shape == (len(Rs), 3)
        for Rk, tk in zip(Rs, ts):
            np.testing.assert_allclose(Rk @ Rk.T, np.eye(3), atol=1e-9)
            assert np.linalg.det(Rk) > 0
            assert _fits(kinds, o, d, X, Rk, tk) < 1e-7
        err = min(np.abs(Rk - R).max() + np.abs(tk - t).max() for Rk, tk in zip(Rs, ts))
        missed += err > 1e-6
    assert missed == 0


@pytest.mark.parametrize("kinds", [(0, 0, 0), (0, 0, 1), (0, 1, 1), (1, 1, 1)])
def test_two_cameras_match_the_pair_minimal_solver(kinds):
    """One camera in each frame, at its origin, is the pair problem: the
    same solution set as the project's minimal solvers (solve_minimal, p = U
    and q = W; side 0 = p saw a marker of q = a ray of U)."""
    from mutloc.core.minimal import solve_minimal

    rng = np.random.default_rng([19, *kinds])
    for _ in range(40):
        R, t, o, d, X = _case(rng, kinds, 1)
        o[:] = 0.0
        for k, kind in enumerate(kinds):  # rays from each frame's origin
            d[k] = R.T @ (X[k] - t) if kind == KIND_U_RAY else R @ X[k] + t
        Rs, ts = generalized_p3p(kinds, o, d, X)
        bear = d / np.linalg.norm(d, axis=1)[:, None]
        Rm, tm = solve_minimal(np.array(kinds, dtype=np.int64), bear, X)
        assert len(Rs) == len(Rm)
        for Rk, tk in zip(Rm, tm):
            assert min(np.abs(Rk - Rj).max() + np.abs(tk - tj).max() for Rj, tj in zip(Rs, ts)) < 1e-6


def test_degenerate_input_gives_no_pose():
    # all three points of W on one line through U's single camera centre
    X = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [0.0, 0.0, 3.0]])
    Rs, ts = generalized_p3p([0, 0, 0], np.zeros((3, 3)), X, X)
    assert len(Rs) == 0 or all(_fits([0, 0, 0], np.zeros((3, 3)), X, X, Rk, tk) < 1e-7 for Rk, tk in zip(Rs, ts))
