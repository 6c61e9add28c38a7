"""The real-root finder against numpy.roots (companion-matrix eigenvalues)."""

import numpy as np
from hypothesis import given, settings, strategies as st

from mutloc.core.polynomial import real_roots_py


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 8))
def test_random_real_roots_found(seed, deg):
    rng = np.random.default_rng(seed)
    roots = np.sort(rng.uniform(-5, 5, size=deg))
    # Keep roots apart so the reference is well conditioned.
    if deg > 1 and np.min(np.diff(roots)) < 1e-3:
        roots = np.linspace(-5, 5, deg) + rng.uniform(-0.1, 0.1, deg)
    c = np.poly(roots)[::-1] * rng.uniform(0.1, 10)
    got = real_roots_py(c, -10, 10)
    np.testing.assert_allclose(got, np.sort(roots), atol=1e-7)


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_agrees_with_numpy_roots_on_random_coefficients(seed):
    rng = np.random.default_rng(seed)
    c = rng.normal(size=9)
    ref = np.roots(c[::-1])
    ref = np.sort(ref[np.abs(ref.imag) < 1e-9].real)
    ref = ref[(ref > -50) & (ref < 50)]
    got = real_roots_py(c, -50, 50)
    # Near-tangent pairs may be reported once or twice; every simple root must appear.
    for r in ref:
        assert np.min(np.abs(got - r)) < 1e-6 * (1 + abs(r))


def test_merged_double_root_is_reported():
    c = np.poly([1.0, 1.0, 2.0, 3.0])[::-1].copy()
    c[0] += 1e-12  # rounding has pushed the double root at 1 into the complex plane
    assert np.sum(np.isreal(np.roots(c[::-1])) & (np.abs(np.roots(c[::-1]) - 1) < 1e-3)) == 0
    got = real_roots_py(c, 0, 10, near_tol=1e-9)
    assert np.min(np.abs(got - 1.0)) < 1e-5


def test_interval_is_respected():
    c = np.poly([-2.0, 0.5, 3.0])[::-1]
    np.testing.assert_allclose(real_roots_py(c, 0.0, 10.0), [0.5, 3.0])
