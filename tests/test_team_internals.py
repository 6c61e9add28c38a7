"""The team solver's fast paths against their plain counterparts: the NumPy
checks of team_problem against the row-by-row ones, the compiled helpers of
the initialisation and the ordering against NumPy and known graphs."""

import numpy as np
import pytest

import mutloc
from mutloc.core.team import _rcm_kernel, _spread
from mutloc.errors import ObservationError
from mutloc.sim.team import random_team
from mutloc.team import _team_problem_rows, team_problem


def _same(a, b):
    pa, na, ma = a
    pb, nb, mb = b
    assert na == nb and ma == mb
    for f in ("cam", "own", "points", "uv", "K", "dist"):
        np.testing.assert_array_equal(getattr(pa, f), getattr(pb, f))


def test_team_problem_matches_the_row_by_row_path():
    rng = np.random.default_rng(11)
    for _ in range(10):
        scene = random_team(int(rng.integers(3, 10)), rng)
        obs = scene.observations(1.0, rng)
        _same(team_problem(scene.rig, obs), _team_problem_rows(scene.rig, obs, list(scene.rig.robots)))


def test_team_problem_keeps_the_best_of_several_candidates():
    rng = np.random.default_rng(12)
    scene = random_team(4, rng)
    obs = scene.observations(1.0, rng)
    # every detection doubled by a worse-scored one 40 px away
    doubled = mutloc.ObservationSet(obs.observer + obs.observer, obs.marker + obs.marker,
                                    np.vstack([obs.uv, obs.uv + 40.0]), None,
                                    np.r_[np.ones(len(obs)), np.full(len(obs), 0.5)])
    _same(team_problem(scene.rig, doubled), team_problem(scene.rig, obs))


def test_team_problem_names_a_pixel_outside_the_image():
    rng = np.random.default_rng(13)
    scene = random_team(3, rng)
    obs = scene.observations(1.0, rng)
    uv = np.array(obs.uv)
    uv[1] = (5000.0, 10.0)
    bad = mutloc.ObservationSet(obs.observer, obs.marker, uv)
    with pytest.raises(ObservationError, match=rf"\[{obs.marker[1]!r}\]: pixel \(5000.00, 10.00\) is outside"):
        team_problem(scene.rig, bad)


def test_spread_is_numpy_rounding_of_linspace():
    for n in range(0, 40):
        rows = np.arange(100, 100 + n, dtype=np.int64)
        for k in (2, 3, 5):
            expected = rows if n <= k else rows[np.round(np.linspace(0, n - 1, k)).astype(np.int64)]
            np.testing.assert_array_equal(_spread(rows, k), expected)


def test_rcm_of_a_shuffled_path_has_bandwidth_one():
    rng = np.random.default_rng(14)
    for k in (3, 10, 57):
        label = rng.permutation(k)
        a, b = label[:-1], label[1:]  # the path label[0] - label[1] - ...
        order = _rcm_kernel(a, b, k)
        assert sorted(order.tolist()) == list(range(k))
        pos = np.empty(k, dtype=np.int64)
        pos[order] = np.arange(k)
        assert np.max(np.abs(pos[a] - pos[b])) == 1


def test_rcm_covers_every_component():
    rng = np.random.default_rng(15)
    a = rng.integers(0, 12, 15)
    b = rng.integers(0, 12, 15)  # some nodes isolated, self-loops ignored
    order = _rcm_kernel(a, b, 20)
    assert sorted(order.tolist()) == list(range(20))
