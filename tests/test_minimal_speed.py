"""The fast positive-root path of the mixed (2-1, 1-2) minimal solver.

Its speed is measured by ``bench/bench_solvers.py``, not here (tests must
not depend on how busy the machine is).  Correctness of the solver itself is
``test_minimal.py``'s job; here:

* ``positive_roots_ws`` (Laguerre + deflation, certified by the signs of the
  quotient) finds the same positive roots as the derivative chain, and hands
  over to it whenever a merged double root may be near the positive axis;
* in the usual mounting the fast path is certified almost always (if it were
  not, the solver would be correct but three times slower);
* an ill-conditioned root next to H = 0 (see ``minimal._back_substitute``)
  still yields its solution;
* the batch throughput, in CPU time of the solving thread, meets the target.
"""

from __future__ import annotations


import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from mutloc.core.minimal import solve_minimal
from mutloc.core.polynomial import WORK_SIZE, _positive_roots_certified, positive_roots_ws, real_roots_py
from mutloc.sim.synthetic import batch_minimal_problems, batch_scenes

HI = 1e4


def _fast(c, lo=1e-12, hi=HI):
    """(sign-change roots, merged double roots) from positive_roots_ws."""
    roots = np.empty(16)
    nr, nn = positive_roots_ws(np.ascontiguousarray(c, dtype=float), lo, hi, roots, 1e-9, 1e-9, 1e-7, np.empty(WORK_SIZE))
    return np.sort(roots[:nr]), roots[nr:nr + nn]


def _certified(c, lo=1e-12, hi=HI):
    """Roots from the fast path alone, or None when it declines."""
    roots = np.empty(16)
    n = len(c) - 1
    nr = _positive_roots_certified(np.ascontiguousarray(c, dtype=float), n, lo, hi, roots, np.empty(9), 1e-9)
    return None if nr < 0 else np.sort(roots[:nr])


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 8))
def test_positive_roots_match_derivative_chain(seed, deg):
    """Random real roots of both signs, plus complex pairs: the same positive
    roots.  (When the fast path declines, the chain may add critical points
    of tiny relative |p| as merged double roots; those are not compared.)"""
    rng = np.random.default_rng(seed)
    n_complex = int(rng.integers(0, deg // 2 + 1))
    real = rng.uniform(-20, 20, size=deg - 2 * n_complex)
    cplx = rng.uniform(-20, 20, size=n_complex) + 1j * rng.uniform(0.5, 10, size=n_complex)
    roots = np.concatenate([real, cplx, cplx.conj()])
    c = np.real(np.poly(roots))[::-1] * rng.uniform(0.1, 10)
    pos = np.sort(real[real > 1e-12])
    if len(pos) > 1 and np.min(np.diff(pos)) < 1e-3:
        return  # the reference is ill-conditioned there
    got, _ = _fast(c)
    # Roots with close neighbours are fixed only to ~1e-8 by the rounded
    # coefficients of a degree-8 polynomial, whichever method finds them.
    np.testing.assert_allclose(got, pos, rtol=1e-6, atol=1e-9)
    chain = real_roots_py(c, 1e-12, HI)
    np.testing.assert_allclose(got, chain, rtol=1e-6, atol=1e-9)


def test_no_positive_coefficient_sign_change_means_no_roots():
    c = np.poly([-1.0, -2.0, -3.0 + 1j, -3.0 - 1j, -0.5])[::-1].real
    assert np.all(c > 0)
    assert _certified(c).size == 0
    assert _fast(c)[0].size == 0


def test_merged_double_root_is_handed_to_the_derivative_chain():
    """A double root pushed into the complex plane by rounding: the quotient
    keeps a sign change, the fast path declines, the chain reports the root."""
    c = np.poly([1.0, 1.0, 2.0, 3.0, -4.0, -5.0])[::-1].copy()
    c[0] += 1e-12 * np.abs(c).max()
    assert _certified(c) is None
    got, near = _fast(c)
    assert len(near) >= 1
    assert np.min(np.abs(near - 1.0)) < 1e-5


@pytest.mark.parametrize("k", [2, 1])
def test_fast_path_certified_in_usual_mounting(k):
    """The Laguerre path must carry the usual mounting; its roots match the chain."""
    from mutloc.core import minimal

    rng = np.random.default_rng(11 + k)
    R, t, mp, mq = batch_scenes(rng, 2000, "usual", 3, 3)
    side, b, X = batch_minimal_problems(R, t, mp, mq, k)
    declined = 0
    for i in range(len(b)):
        bb = b[i] if k == 2 else b[i][[1, 2, 0]]  # canonical order: pair observer first
        XX = X[i] if k == 2 else X[i][[1, 2, 0]]
        L = max(np.linalg.norm(XX, axis=1).max(), np.linalg.norm(XX[0] - XX[1]))
        f = minimal._mixed_quadrics(*map(tuple, bb), *map(tuple, XX / L))
        poly = np.empty(9)
        minimal._univariate(*f, poly)
        fast = _certified(poly)
        if fast is None:
            declined += 1
            continue
        np.testing.assert_allclose(fast, real_roots_py(poly, 1e-12, HI), rtol=1e-6)
    assert declined <= 0.01 * len(b), f"fast path declined {declined} of {len(b)} usual-mounting polynomials"


def test_root_next_to_a_vanishing_square_root_is_kept():
    """A genuine solution (ranges 0.33, 0.005, 0.024 m) whose s2 is ill-conditioned: at
    the computed root H1 < 0, so s1 must come from f01 instead of sqrt(H1)."""
    bearings = np.array([[0.40145498524636186, -0.11913312102407964, 0.9080975687093901],
                         [0.42258513178202006, -0.036361003053964024, 0.9055935533414989],
                         [-0.7729239028459688, -0.12326071940899257, 0.6224109859732017]])
    points = np.array([[-0.27697296730909066, -0.12276319570722652, -0.14269863436666877],
                       [-0.00730824901780136, 0.007774905305153124, -0.013476082287489644],
                       [-0.021500148990501122, -0.019160307544863475, 0.015071834937658624]])
    side = [0, 0, 1]
    Rs, ts = solve_minimal(side, bearings, points)
    # The genuine solution, from the distance equations by Newton's method.
    s = np.array([0.331479, 0.005219, 0.023635])
    for _ in range(50):
        Y = [s[0] * bearings[0], s[1] * bearings[1], points[2]]
        Z = [points[0], points[1], s[2] * bearings[2]]
        f = np.array([np.sum((Y[k] - Y[l]) ** 2) - np.sum((Z[k] - Z[l]) ** 2) for k, l in ((0, 1), (0, 2), (1, 2))])
        J = np.zeros((3, 3))
        for n, (k, l) in enumerate(((0, 1), (0, 2), (1, 2))):
            for m, sg in ((k, 1.0), (l, -1.0)):
                J[n, m] += 2 * sg * ((Y[k] - Y[l]) @ bearings[m] if side[m] == 0 else -(Z[k] - Z[l]) @ bearings[m])
        s = s - np.linalg.solve(J, f)
    assert np.max(np.abs(f)) < 1e-14
    # Its pose maps p's three points onto q's.
    Pp = np.array([s[0] * bearings[0], s[1] * bearings[1], points[2]])
    Pq = np.array([points[0], points[1], s[2] * bearings[2]])
    err = [np.max(np.abs(Pp @ R.T + t - Pq)) for R, t in zip(Rs, ts)]
    assert min(err) < 1e-9, f"solution lost; candidates off by {err}"
