"""The compiled generalized P3P (core/generalized.py, generalized_p3p_kernel)
on random non-central problems of every split, against ground truth and
against the NumPy implementation it replaced (kept below, verbatim, as an
independent oracle: np.roots on the companion matrix, SVD absolute
orientation); its central special cases against P3P and the mutual minimal
solver; its use from another compiled function."""

import numpy as np
import pytest
from numba import njit

from mutloc.core.generalized import (GP3P_MAX_SOLUTIONS, GP3P_WORK_SIZE, KIND_U_RAY, generalized_p3p,
                                     generalized_p3p_kernel)
from mutloc.core.minimal import solve_minimal
from mutloc.core.p3p import p3p

SPLITS = [(0, 0, 0), (0, 0, 1), (0, 1, 1), (1, 1, 1)]
_MAX_RANGE = 1e4
_RESIDUAL_TOL = 1e-8


def random_rotation(rng):
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def random_problem(rng, kinds, central=False):
    """Two robots 1-5 m apart, any orientation; markers and camera centres
    within +-0.3 m of each robot's origin; each ray from its own centre
    (``central``: one centre per robot).  Returns R, t, origins, directions
    (any length), points."""
    R = random_rotation(rng)
    u = rng.normal(size=3)
    t = u / np.linalg.norm(u) * rng.uniform(1.0, 5.0)
    cu, cw = rng.uniform(-0.3, 0.3, 3), rng.uniform(-0.3, 0.3, 3)
    o, d, X = np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3))
    for k, kind in enumerate(kinds):
        X[k] = rng.uniform(-0.3, 0.3, 3)
        if kind == KIND_U_RAY:  # a camera of U sees a marker of W
            o[k] = cu if central else rng.uniform(-0.3, 0.3, 3)
            d[k] = R.T @ (X[k] - t) - o[k]
        else:  # a camera of W sees a marker of U
            o[k] = cw if central else rng.uniform(-0.3, 0.3, 3)
            d[k] = R @ X[k] + t - o[k]
        d[k] *= rng.uniform(0.5, 2.0)
    return R, t, o, d, X


def pose_errors(R, t, Rs, ts):
    """(rotation error in degrees, translation error relative to |t|) of the candidate closest to (R, t)."""
    if len(Rs) == 0:
        return np.inf, np.inf
    er = np.degrees(2.0 * np.arcsin(np.clip(np.linalg.norm(Rs - R, axis=(1, 2)) / np.sqrt(8.0), 0.0, 1.0)))
    et = np.linalg.norm(ts - t, axis=1) / np.linalg.norm(t)
    i = int(np.argmin(er / 1e-6 + et / 1e-8))
    return er[i], et[i]


def same_set(Ra, ta, Rb, tb, tol=1e-6):
    """Every pose of a is in b and vice versa."""
    def inside(Rx, tx, Ry, ty):
        return all(len(Ry) and np.min(np.abs(Ry - Ri).max(axis=(1, 2)) + np.abs(ty - ti).max(axis=1)) < tol
                   for Ri, ti in zip(Rx, tx))
    return inside(Ra, ta, Rb, tb) and inside(Rb, tb, Ra, ta)


@pytest.mark.parametrize("kinds", SPLITS)
def test_true_pose_found_in_random_non_central_problems(kinds):
    """2000 problems per split; the true pose within 1e-6 deg and 1e-8 of |t|.
    Required >= 99.9 %; measured 100 % on every split (bench/bench_gp3p.py: 60 000 problems)."""
    rng = np.random.default_rng([2024, *kinds])
    Rs, ts, ws = np.empty((GP3P_MAX_SOLUTIONS, 3, 3)), np.empty((GP3P_MAX_SOLUTIONS, 3)), np.empty(GP3P_WORK_SIZE)
    kinds_a = np.array(kinds, dtype=np.int64)
    missed = []
    for i in range(2000):
        R, t, o, d, X = random_problem(rng, kinds)
        n = generalized_p3p_kernel(kinds_a, o, d, X, Rs, ts, ws)
        assert 0 <= n <= GP3P_MAX_SOLUTIONS
        er, et = pose_errors(R, t, Rs[:n], ts[:n])
        if not (er < 1e-6 and et < 1e-8):
            missed.append((i, n, er, et))
    assert len(missed) <= 2, missed


@pytest.mark.parametrize("kinds", SPLITS)
def test_every_solution_is_exact(kinds):
    """Each returned pose fits the three correspondences (point on its ray,
    ahead of the origin) and is a rotation."""
    rng = np.random.default_rng([7, *kinds])
    for _ in range(300):
        R, t, o, d, X = random_problem(rng, kinds)
        Rs, ts = generalized_p3p(kinds, o, d, X)
        for Rk, tk in zip(Rs, ts):
            np.testing.assert_allclose(Rk @ Rk.T, np.eye(3), atol=1e-12)
            assert np.linalg.det(Rk) > 0
            for k, kind in enumerate(kinds):
                p = Rk.T @ (X[k] - tk) if kind == KIND_U_RAY else Rk @ X[k] + tk
                u = d[k] / np.linalg.norm(d[k])
                s = (p - o[k]) @ u
                assert s > 0 and np.linalg.norm(p - o[k] - s * u) < 1e-9


def misfit(kinds, o, d, X, R, t):
    """Largest distance of a correspondence's point from its ray (inf if behind its origin)."""
    worst = 0.0
    for k, kind in enumerate(kinds):
        p = R.T @ (X[k] - t) if kind == KIND_U_RAY else R @ X[k] + t
        u = d[k] / np.linalg.norm(d[k])
        s = (p - o[k]) @ u
        if s <= 0:
            return np.inf
        worst = max(worst, np.linalg.norm(p - o[k] - s * u))
    return worst


def _dist(Rs, ts, R, t):
    return np.min(np.abs(Rs - R).max(axis=(1, 2)) + np.abs(ts - t).max(axis=1)) if len(Rs) else np.inf


@pytest.mark.parametrize("kinds", SPLITS)
def test_same_solutions_as_the_numpy_implementation(kinds):
    """The same solution set as the NumPy implementation, up to its
    imprecise copies: near two close solutions its Newton step stopped
    early, and up to 2 % of its sets (0-3) hold a second copy of an exact
    solution 1e-5..3e-3 off it, fitting to only 1e-9..1e-6 m (polished
    further, it lands on the exact one; the kernel polishes to convergence
    and keeps one).  Every exact (1e-10 m) solution of either is in the
    other's set, to 1e-6."""
    rng = np.random.default_rng([11, *kinds])
    copies = 0
    for i in range(400):
        R, t, o, d, X = random_problem(rng, kinds)
        Rs, ts = generalized_p3p(kinds, o, d, X)
        Ro, to = oracle_gp3p(kinds, o, d, X)
        for Ri, ti in zip(Rs, ts):
            assert misfit(kinds, o, d, X, Ri, ti) < 1e-10 and _dist(Ro, to, Ri, ti) < 1e-3, i
        for Ri, ti in zip(Ro, to):
            if _dist(Rs, ts, Ri, ti) > 1e-6:
                assert misfit(kinds, o, d, X, Ri, ti) > 1e-10 and _dist(Rs, ts, Ri, ti) < 1e-2, i
                copies += 1
    assert copies <= 16, copies


@pytest.mark.parametrize("kinds", SPLITS)
def test_central_cases_match_p3p_and_the_mutual_minimal_solver(kinds):
    """Rays sharing one centre per robot (anywhere, not at its origin): 3-0
    is P3P from U's camera, 0-3 P3P from W's, 2-1 and 1-2 the mutual minimal
    problem; the same solution set, and the true pose among it."""
    rng = np.random.default_rng([13, *kinds])
    for _ in range(300):
        R, t, o, d, X = random_problem(rng, kinds, central=True)
        Rs, ts = generalized_p3p(kinds, o, d, X)
        assert pose_errors(R, t, Rs, ts)[0] < 1e-6
        cu, cw = o[kinds.index(0)] if 0 in kinds else None, o[kinds.index(1)] if 1 in kinds else None
        if kinds == (0, 0, 0):  # X_cam = Rp X_W + tp, X_cam = x_U - cu
            Rp, tp = p3p(d, X)
            Rr = np.transpose(Rp, (0, 2, 1))
            tr = -np.einsum("kij,kj->ki", Rr, tp + cu)
        elif kinds == (1, 1, 1):  # x_W - cw = Rp x_U + tp
            Rr, tr = p3p(d, X)
            tr = tr + cw
        else:  # p = U with its camera at cu, q = W with its camera at cw (both cameras axis-aligned)
            # marker positions relative to the owner's camera: x_q' = R x_p' + t', t' = R cu + t - cw
            Xc = np.where(np.array(kinds)[:, None] == KIND_U_RAY, X - cw, X - cu)
            Rr, tc = solve_minimal(np.array(kinds, dtype=np.int64), d, Xc)
            tr = tc - np.einsum("kij,j->ki", Rr, cu) + cw
        assert same_set(Rs, ts, Rr, tr), (len(Rs), len(Rr))


def test_scratch_size_and_capacity():
    """Only len(Rs) poses are written; nothing past GP3P_WORK_SIZE is touched."""
    rng = np.random.default_rng(3)
    kinds = np.array([0, 0, 0], dtype=np.int64)
    for _ in range(200):
        R, t, o, d, X = random_problem(rng, (0, 0, 0))
        full = generalized_p3p_kernel(kinds, o, d, X, np.empty((8, 3, 3)), np.empty((8, 3)), np.empty(GP3P_WORK_SIZE))
        if full >= 2:
            break
    ws = np.full(GP3P_WORK_SIZE + 16, 7.0)
    Rs, ts = np.full((9, 3, 3), 5.0), np.full((9, 3), 5.0)
    assert generalized_p3p_kernel(kinds, o, d, X, Rs[:1], ts[:1], ws[:GP3P_WORK_SIZE]) == 1
    assert np.all(Rs[1:] == 5.0) and np.all(ts[1:] == 5.0) and np.all(ws[GP3P_WORK_SIZE:] == 7.0)


def test_degenerate_and_non_finite_input_give_no_pose():
    Rs, ts, ws = np.empty((8, 3, 3)), np.empty((8, 3)), np.empty(GP3P_WORK_SIZE)
    k = np.zeros(3, dtype=np.int64)
    X = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [0.0, 0.0, 3.0]])
    assert generalized_p3p_kernel(k, np.zeros((3, 3)), np.zeros((3, 3)), X, Rs, ts, ws) == 0  # no directions
    bad = X.copy()
    bad[1, 2] = np.nan
    assert generalized_p3p_kernel(k, np.zeros((3, 3)), X, bad, Rs, ts, ws) == 0
    assert generalized_p3p_kernel(k, np.zeros((3, 3)), X, np.zeros((3, 3)), Rs, ts, ws) == 0  # one point, one centre


@njit(cache=True)
def _solve_many(kinds, o, d, X, Rs, ts, ws, counts):
    for i in range(o.shape[0]):
        counts[i] = generalized_p3p_kernel(kinds, o[i], d[i], X[i], Rs[i], ts[i], ws)


def test_callable_from_a_compiled_loop():
    """As the pair solver calls it: from another njit function, one scratch for all problems."""
    rng = np.random.default_rng(5)
    probs = [random_problem(rng, (0, 1, 1)) for _ in range(20)]
    o, d, X = (np.array([p[i] for p in probs]) for i in (2, 3, 4))
    Rs, ts = np.empty((20, 8, 3, 3)), np.empty((20, 8, 3))
    counts = np.empty(20, dtype=np.int64)
    kinds = np.array([0, 1, 1], dtype=np.int64)
    _solve_many(kinds, o, d, X, Rs, ts, np.empty(GP3P_WORK_SIZE), counts)
    for i, (R, t, *_rest) in enumerate(probs):
        er, et = pose_errors(R, t, Rs[i, :counts[i]], ts[i, :counts[i]])
        assert er < 1e-6 and et < 1e-8


# --- the NumPy implementation the kernel replaced (the oracle) ---------------

def _quadric(oU, uU, oW, uW, k, l):
    """F (3, 3): coefficient of ``s_k^i s_l^j`` in f_kl."""
    dU = oU[k] - oU[l]
    dW = oW[k] - oW[l]
    F = np.zeros((3, 3))
    F[0, 0] = dU @ dU - dW @ dW
    F[2, 0] = uU[k] @ uU[k] - uW[k] @ uW[k]
    F[0, 2] = uU[l] @ uU[l] - uW[l] @ uW[l]
    F[1, 0] = 2.0 * (dU @ uU[k] - dW @ uW[k])
    F[0, 1] = -2.0 * (dU @ uU[l] - dW @ uW[l])
    F[1, 1] = -2.0 * (uU[k] @ uU[l] - uW[k] @ uW[l])
    return F


def _mul(a, b):
    """Product of polynomials in one or two variables (coefficient arrays, ascending)."""
    a = np.atleast_1d(a)
    b = np.atleast_1d(b)
    if a.ndim == 1 and b.ndim == 1:
        return np.convolve(a, b)
    a = a.reshape(a.shape[0], -1)
    b = b.reshape(b.shape[0], -1)
    out = np.zeros((a.shape[0] + b.shape[0] - 1, a.shape[1] + b.shape[1] - 1))
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            if a[i, j] != 0.0:
                out[i:i + b.shape[0], j:j + b.shape[1]] += a[i, j] * b
    return out


def _add(*polys):
    """Sum of polynomials (arrays of any shapes, ascending, same number of dimensions)."""
    shape = tuple(max(p.shape[d] for p in polys) for d in range(polys[0].ndim))
    out = np.zeros(shape)
    for p in polys:
        out[tuple(slice(0, n) for n in p.shape)] += p
    return out


def _univariate(F01, F02, F12):
    """Degree-8 polynomial (ascending) in s2 whose roots are the s2 of all solutions."""
    # f01 = a s0^2 + B1(s1) s0 + C1(s1), f02 = a s0^2 + B2(s2) s0 + C2(s2), the
    # same a = +-1; as bivariate arrays [i, j] = coefficient of s1^i s2^j
    B1 = np.array([[F01[1, 0]], [F01[1, 1]]])
    C1 = F01[0, :].reshape(3, 1)
    B2 = np.array([[F02[1, 0], F02[1, 1]]])
    C2 = F02[0, :].reshape(1, 3)
    a = F01[2, 0]
    # resultant of two quadratics in s0 with the same leading coefficient a
    dC = _add(C2, -C1)
    dB = _add(B2, -B1)
    g = _add(a * a * _mul(dC, dC), -a * _mul(dB, _add(_mul(B1, C2), -_mul(B2, C1))), np.zeros((5, 5)))[:5, :5]
    # reduce g modulo f12 = a1 s1^2 + beta(s2) s1 + gamma(s2) (a1 = +-1)
    a1 = F12[2, 0]
    beta = np.array([F12[1, 0], F12[1, 1]]) / a1
    gamma = F12[0, :] / a1
    rows = [g[i, :5 - i].copy() for i in range(5)]  # row i: degree 4 - i in s2
    for i in range(4, 1, -1):
        rows[i - 1] = _add(rows[i - 1], -_mul(rows[i], beta))
        rows[i - 2] = _add(rows[i - 2], -_mul(rows[i], gamma))
    r0, r1 = rows[0], rows[1]
    # resultant of the monic quadratic and r1 s1 + r0
    out = _add(_mul(_mul(r1, r1), gamma), -_mul(_mul(r0, r1), beta), _mul(r0, r0), np.zeros(9))
    return out[:9], r0, r1


def _quad_roots(a, b, c):
    """Real roots of a x^2 + b x + c (a slightly negative discriminant counts as zero)."""
    if a == 0.0:
        return [-c / b] if b != 0.0 else []
    disc = b * b - 4.0 * a * c
    if disc < 0.0:
        if disc < -1e-6 * (b * b + abs(4.0 * a * c)):
            return []
        disc = 0.0
    q = -0.5 * (b + np.copysign(np.sqrt(disc), b))
    if q == 0.0:
        return [0.0]
    return [q / a, c / q]


def _feval(F, x, y):
    return (F[0, 0] + F[1, 0] * x + F[0, 1] * y + F[2, 0] * x * x + F[0, 2] * y * y + F[1, 1] * x * y)


def _residual(F01, F02, F12, s):
    """Largest quadric residual at s relative to the size of s."""
    r = max(abs(_feval(F01, s[0], s[1])), abs(_feval(F02, s[0], s[2])), abs(_feval(F12, s[1], s[2])))
    return r / (1.0 + s[0] * s[0] + s[1] * s[1] + s[2] * s[2])


def _newton(F01, F02, F12, s, iters=8):
    """Newton's method on the three quadrics from s (3,); the polished s and its relative residual."""
    s = s.copy()

    def resid(s):
        return np.array([_feval(F01, s[0], s[1]), _feval(F02, s[0], s[2]), _feval(F12, s[1], s[2])])

    def grad(F, x, y):
        return (F[1, 0] + 2 * F[2, 0] * x + F[1, 1] * y, F[0, 1] + 2 * F[0, 2] * y + F[1, 1] * x)

    r = resid(s)
    for _ in range(iters):
        if np.max(np.abs(r)) <= 1e-15 * (1.0 + s @ s):
            break
        J = np.zeros((3, 3))
        J[0, 0], J[0, 1] = grad(F01, s[0], s[1])
        J[1, 0], J[1, 2] = grad(F02, s[0], s[2])
        J[2, 1], J[2, 2] = grad(F12, s[1], s[2])
        try:
            step = np.linalg.solve(J, -r)
        except np.linalg.LinAlgError:
            break
        s1 = s + step
        r1 = resid(s1)
        if not np.all(np.isfinite(r1)) or np.abs(r1).sum() >= np.abs(r).sum():
            break
        s, r = s1, r1
    scale = 1.0 + np.sum(s * s)
    return s, float(np.max(np.abs(r)) / scale)


def _rigid(P, Q):
    """R, t with Q ~ R P + t (Kabsch) for point sets (3, 3); None if P is degenerate."""
    cp, cq = P.mean(axis=0), Q.mean(axis=0)
    A, B = P - cp, Q - cq
    if np.linalg.norm(np.cross(A[1] - A[0], A[2] - A[0])) <= 1e-12 * max(np.sum(A * A), 1e-300):
        return None
    U, _, Vt = np.linalg.svd(B.T @ A)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    return R, cq - R @ cp


def oracle_gp3p(kinds, origins, directions, points) -> tuple[np.ndarray, np.ndarray]:
    """The NumPy implementation before the kernel (np.roots, SVD), unchanged."""
    kinds = np.asarray(kinds, dtype=np.int64).reshape(3)
    o = np.asarray(origins, dtype=float).reshape(3, 3)
    d = np.asarray(directions, dtype=float).reshape(3, 3)
    X = np.asarray(points, dtype=float).reshape(3, 3)
    d = d / np.linalg.norm(d, axis=1)[:, None]
    ray_u = (kinds == KIND_U_RAY)[:, None]
    # U side: origin + s * direction (kind 0) or the fixed point (kind 1); W alike
    oU = np.where(ray_u, o, X)
    uU = np.where(ray_u, d, 0.0)
    oW = np.where(ray_u, X, o)
    uW = np.where(ray_u, 0.0, d)
    # scale: ranges and coordinates in units of the largest distance between
    # the fixed parts (distances are translation invariant in each frame)
    L = max(np.max(np.linalg.norm(oU[:, None] - oU[None], axis=2)),
            np.max(np.linalg.norm(oW[:, None] - oW[None], axis=2)), 1e-300)
    oU, oW = oU / L, oW / L
    F01 = _quadric(oU, uU, oW, uW, 0, 1)
    F02 = _quadric(oU, uU, oW, uW, 0, 2)
    F12 = _quadric(oU, uU, oW, uW, 1, 2)
    poly, r0, r1 = _univariate(F01, F02, F12)
    c = np.trim_zeros(poly, "b")
    if c.size < 2 or not np.all(np.isfinite(c)):
        return np.zeros((0, 3, 3)), np.zeros((0, 3))
    roots = np.roots(c[::-1] / np.max(np.abs(c)))
    near = np.abs(roots.imag) <= 1e-3 * (1.0 + np.abs(roots.real))
    s2s = roots.real[near]
    sols: list[np.ndarray] = []
    for s2 in s2s:
        if not (-1e-6 < s2 < _MAX_RANGE):
            continue
        starts = []
        # linear back-substitution: s1 = -r0/r1 (g mod f12), s0 from f01 - f02
        v1 = np.polynomial.polynomial.polyval(s2, r1)
        if v1 != 0.0:
            s1 = -np.polynomial.polynomial.polyval(s2, r0) / v1
            den = (F01[1, 0] + F01[1, 1] * s1) - (F02[1, 0] + F02[1, 1] * s2)
            num = (F02[0, 0] + F02[0, 1] * s2 + F02[0, 2] * s2 * s2) - (F01[0, 0] + F01[0, 1] * s1
                                                                         + F01[0, 2] * s1 * s1)
            if den != 0.0:
                starts.append(np.array([num / den, s1, s2]))
        # both roots of each quadratic (solutions sharing s2)
        for s1 in _quad_roots(F12[2, 0], F12[1, 0] + F12[1, 1] * s2, F12[0, 0] + F12[0, 1] * s2 + F12[0, 2] * s2 * s2):
            for s0 in _quad_roots(F02[2, 0], F02[1, 0] + F02[1, 1] * s2,
                                  F02[0, 0] + F02[0, 1] * s2 + F02[0, 2] * s2 * s2):
                starts.append(np.array([s0, s1, s2]))
        for s in starts:
            if _residual(F01, F02, F12, s) > 1e-2 or any(np.max(np.abs(s - q)) <= 1e-7 * (1.0 + np.max(np.abs(q)))
                                                          for q in sols):
                continue  # not near a solution, or one found already
            s, err = _newton(F01, F02, F12, s)
            if err > _RESIDUAL_TOL or not np.all(s > 0.0) or not np.all(s < _MAX_RANGE):
                continue
            if any(np.max(np.abs(s - q)) <= 1e-7 * (1.0 + np.max(np.abs(q))) for q in sols):
                continue
            sols.append(s)
    Rs, ts = [], []
    for s in sols:
        P = oU + s[:, None] * uU
        Q = oW + s[:, None] * uW
        fit = _rigid(P, Q)
        if fit is None:
            continue
        R, t = fit
        Rs.append(R)
        ts.append(t * L)
    if not Rs:
        return np.zeros((0, 3, 3)), np.zeros((0, 3))
    return np.array(Rs), np.array(ts)
