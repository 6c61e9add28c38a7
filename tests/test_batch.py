"""Batch API: agrees with the single-problem solver, bounded chunks, typed errors."""

import numpy as np
import pytest

from mutloc.core.batch import iter_solve_minimal, solve_minimal_batch
from mutloc.core.estimate import minimal_candidates_kernel
from mutloc.core.minimal import solve_minimal
from mutloc.errors import InputError
from mutloc.sim.synthetic import batch_minimal_problems, batch_scenes


@pytest.mark.parametrize("k", [3, 2, 1, 0])
def test_batch_equals_single_calls_and_contains_truth(k):
    rng = np.random.default_rng(k)
    R, t, mp, mq = batch_scenes(rng, 300, "usual", 3, 3)
    side, b, X = batch_minimal_problems(R, t, mp, mq, k)
    res = solve_minimal_batch(side, b, X, chunk_size=64)
    assert res.R.shape == (300, 8, 3, 3) and res.count.shape == (300,)
    for i in range(0, 300, 37):
        Rs, ts = solve_minimal(side, b[i], X[i])
        assert len(Rs) == res.count[i]
        np.testing.assert_allclose(ts, res.t[i, : res.count[i]], atol=1e-12)
    et = np.linalg.norm(res.t - t[:, None], axis=2)
    assert np.all(np.nanmin(et, axis=1) < 1e-6)


def test_iter_chunks_cover_everything_once():
    rng = np.random.default_rng(0)
    R, t, mp, mq = batch_scenes(rng, 1000, "random", 2, 2)
    side, b, X = batch_minimal_problems(R, t, mp, mq, 2)
    starts = [(c.start, len(c)) for c in iter_solve_minimal(side, b, X, chunk_size=300)]
    assert starts == [(0, 300), (300, 300), (600, 300), (900, 100)]


def test_nonfinite_problem_gets_no_solution_not_an_exception():
    rng = np.random.default_rng(0)
    R, t, mp, mq = batch_scenes(rng, 3, "usual", 2, 2)
    side, b, X = batch_minimal_problems(R, t, mp, mq, 2)
    b[1, 0, 0] = np.nan
    res = solve_minimal_batch(side, b, X)
    assert res.count[1] == 0 and res.count[0] > 0 and res.count[2] > 0


@pytest.mark.parametrize("side,shape", [([0, 1], (4, 3, 3)), ([0, 1, 2], (4, 3, 3)), ([0, 1, 1], (4, 3, 2))])
def test_bad_batch_input_raises_typed_error(side, shape):
    with pytest.raises(InputError):
        solve_minimal_batch(side, np.ones(shape), np.ones(shape))


def test_root_filter_keeps_true_root_in_valid_geometry():
    """Paper Section III-D: observed markers farther than the observer's own
    markers -> the filter never drops the true solution, and drops others."""
    rng = np.random.default_rng(3)
    R, t, mp, mq = batch_scenes(rng, 2000, "usual", 2, 2, distance=(1.0, 5.0))
    kept = total = 0
    for i in range(len(R)):
        side, b, X = batch_minimal_problems(R[i : i + 1], t[i : i + 1], mp[i : i + 1], mq[i : i + 1], 2)
        subsets = np.array([[0, 1, 2]])
        out = []
        for flt in (False, True):
            Rc = np.empty((16, 3, 3))
            tc = np.empty((16, 3))
            n = minimal_candidates_kernel(side, X[0], b[0], np.zeros((3, 3)), subsets, flt, Rc, tc)
            out.append(tc[:n])
        assert np.min(np.linalg.norm(out[1] - t[i], axis=1)) < 1e-6
        kept += len(out[1])
        total += len(out[0])
    assert kept < total  # the filter does remove spurious roots
