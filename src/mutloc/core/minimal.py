"""Minimal solvers: the relative pose from three marker observations.

Every split of three observations between the two cameras (3-0, 2-1, 1-2,
0-3) is one algebraic problem.  Observation ``k`` is a marker whose position
``X_k`` is known in its owner's frame and whose range ``s_k`` along the
observer's unit bearing ``b_k`` is unknown.  The rigid motion preserves the
three pairwise distances (paper, eq. solvescale), giving three quadrics

    f_kl(s_k, s_l) = A s_k^2 + B s_l^2 + C s_k s_l + D s_k + E s_l + F = 0,

with Bezout number 8.  3-0 and 0-3 are P3P (Lambda Twist, :mod:`.p3p`).

Mixed splits (2-1, 1-2) are ordered so that observations 0 and 1 come from
one camera (the *pair observer*) and 2 from the other (the *lone observer*).
Then f02 and f12 have no cross term and read u^2 = H0(s2), v^2 = H1(s2) in
the shifted ranges u = s0 - g0, v = s1 - g1 (g_k = b_k . X2: the pair
observer's own marker, the one the lone observer sees, projected on ray k),
while f01 becomes bilinear in u and v.
Eliminating u and v (:func:`_univariate`) leaves a degree-8 polynomial in
``s2`` with no extraneous factor.

Which range to keep is the numerical crux.  In the usual mounting (markers
left and right of each camera, cameras facing each other) the paper's choice
of eliminating down to ``s_1`` meets solutions in pairs with *equal* ``s_1``
and ``s_2``: a double root that noise or rounding splits into a complex pair,
silently losing the true pose.  Those pairs differ in the range measured by
the *other* camera, so for mixed splits we keep that one, ``s2``.  As a
second line of defence the root finder also reports numerically merged
double roots (:func:`.polynomial.positive_roots_ws`: its fast Laguerre path
only returns when it can certify that none exist near the positive axis,
else the derivative chain reports them), and every candidate is
back-substituted without division and polished by Newton's method on the
original three quadrics, so a solution is never dropped merely because the
univariate projection is ill-conditioned.

With the ranges known, both frames hold the same three points, and the
absolute orientation (Arun/Horn; closed form here because the two triangles
are congruent by construction) gives ``T_qp``.

The mixed-split path is written with scalars and 3-tuples rather than small
reshaped array views (about 15 ns each in Numba, a few percent of a whole
solve): this solver runs millions of times in RANSAC and Monte Carlo loops.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .p3p import p3p_kernel
from .polynomial import WORK_SIZE as _ROOT_WORK, positive_roots_ws
from .vec3 import row as _row, dot as _dot, sub as _sub, scale as _scale, cross as _cross

MAX_SOLUTIONS = 8
# Relative residual of the distance equations for an accepted solution.
_ACCEPT_TOL = 1e-7
# Critical points with |p| below this relative level are merged double roots.
_NEAR_TOL = 1e-9
# Largest range searched, in units of the marker scale.
_MAX_RANGE = 1e4


@njit(cache=True)
def _mixed_quadrics(b0, b1, b2, X0, X1, X2):
    """Coefficients (A, B, C, D, E, F) of the three distance equations of a
    mixed split in canonical order (see :func:`solve_minimal_ws`).

    ``b0``, ``b1`` are unit rays of the pair observer, ``b2`` of the lone
    observer; ``X0``, ``X1`` are in the lone observer's frame, ``X2`` in the
    pair observer's.  Then

        f01 = |s0 b0 - s1 b1|^2 - |X0 - X1|^2
        f02 = |s0 b0 - X2|^2 - |X0 - s2 b2|^2
        f12 = |s1 b1 - X2|^2 - |X1 - s2 b2|^2,

    so A = 1 everywhere, B = +-1, and only f01 has a cross term.
    """
    n2 = _dot(X2, X2)
    d = _sub(X0, X1)
    f01 = (1.0, 1.0, -2.0 * _dot(b0, b1), 0.0, 0.0, -_dot(d, d))
    f02 = (1.0, -1.0, 0.0, -2.0 * _dot(b0, X2), 2.0 * _dot(b2, X0), n2 - _dot(X0, X0))
    f12 = (1.0, -1.0, 0.0, -2.0 * _dot(b1, X2), 2.0 * _dot(b2, X1), n2 - _dot(X1, X1))
    return f01, f02, f12


@njit(cache=True, inline="always")
def _feval(c, x, y):
    return c[0] * x * x + c[1] * y * y + c[2] * x * y + c[3] * x + c[4] * y + c[5]


@njit(cache=True, inline="always")
def _fscale(c, x, y):
    return (
        abs(c[0]) * x * x + abs(c[1]) * y * y + abs(c[2] * x * y) + abs(c[3] * x) + abs(c[4] * y) + abs(c[5])
    )


@njit(cache=True, inline="always")
def _quad_roots(a, b, c):
    """Real roots (count, x1, x2) of a x^2 + b x + c (a != 0); a slightly
    negative discriminant is clamped because it is rounding of a double root."""
    disc = b * b - 4.0 * a * c
    if disc < 0.0:
        if disc < -1e-7 * (b * b + abs(4.0 * a * c)):
            return 0, 0.0, 0.0
        disc = 0.0
    sq = np.sqrt(disc)
    q = -0.5 * (b + sq) if b >= 0.0 else -0.5 * (b - sq)
    if q == 0.0:
        return 1, 0.0, 0.0
    return 2, q / a, c / q


@njit(cache=True, inline="always")
def _mul22(a0, a1, a2, b0, b1, b2):
    """Product of two quadratics (ascending coefficients)."""
    return a0 * b0, a0 * b1 + a1 * b0, a0 * b2 + a1 * b1 + a2 * b0, a1 * b2 + a2 * b1, a2 * b2


@njit(cache=True)
def _univariate(f01, f02, f12, poly):
    """Degree-8 polynomial in s2 whose roots are the s2 of all solutions.

    With a = D02 / 2 and b = D12 / 2, the shifted ranges u = s0 + a and
    v = s1 + b turn f02 and f12 into u^2 = H0(s2), v^2 = H1(s2) (monic
    quadratics), and f01, with u^2 and v^2 replaced, into

        C uv + alpha u + beta v = W(s2),   W = -(H0 + H1 + K).

    Writing u (C v + alpha) = W - beta v, squaring (u^2 = H0) and collecting
    the odd powers of v gives 2 S v = T with

        T = W^2 + beta^2 H1 - H0 (C^2 H1 + alpha^2),   S = C alpha H0 + beta W,

    and squaring once more (v^2 = H1) the resultant  T^2 - 4 H1 S^2.  Each
    squaring only merges the two signs of u or v, and all four sign choices
    are genuine solutions of the three quadrics, so no root is extraneous;
    the leading coefficient 16 (1 - c^2)^2 (c = b0 . b1) never vanishes for
    distinct rays.
    """
    C = f01[2]
    a = 0.5 * f02[3]
    b = 0.5 * f12[3]
    # H0 = s2^2 + h01 s2 + h00, H1 = s2^2 + h11 s2 + h10.
    h00 = a * a - f02[5]
    h01 = -f02[4]
    h10 = b * b - f12[5]
    h11 = -f12[4]
    alpha = -2.0 * a - C * b
    beta = -2.0 * b - C * a
    K = a * a + b * b + C * a * b + f01[5]
    # T = (H0 - H1)^2 + (4 - C^2) H0 H1 + 2 K (H0 + H1) + K^2 + beta^2 H1 - alpha^2 H0,
    # i.e. the definition with W expanded, so that the large, nearly equal
    # parts of W^2 and C^2 H0 H1 (C is close to -2 for distant markers)
    # cancel exactly instead of in rounding.
    e0 = h00 - h10
    e1 = h01 - h11
    g = 4.0 - C * C
    p0, p1, p2, p3, p4 = _mul22(h00, h01, 1.0, h10, h11, 1.0)
    t0 = e0 * e0 + g * p0 + 2.0 * K * (h00 + h10) + K * K + beta * beta * h10 - alpha * alpha * h00
    t1 = 2.0 * e0 * e1 + g * p1 + 2.0 * K * (h01 + h11) + beta * beta * h11 - alpha * alpha * h01
    t2 = e1 * e1 + g * p2 + 4.0 * K + beta * beta - alpha * alpha
    t3 = g * p3
    t4 = g * p4
    # S = C alpha H0 - beta (H0 + H1 + K), and S^2.
    ca = C * alpha
    S0 = ca * h00 - beta * (h00 + h10 + K)
    S1 = ca * h01 - beta * (h01 + h11)
    S2 = ca - 2.0 * beta
    q0, q1, q2, q3, q4 = _mul22(S0, S1, S2, S0, S1, S2)
    # T^2 - 4 H1 S^2, with 4 H1 = m0 + m1 s2 + 4 s2^2.
    m0 = 4.0 * h10
    m1 = 4.0 * h11
    poly[0] = t0 * t0 - m0 * q0
    poly[1] = 2.0 * t0 * t1 - (m0 * q1 + m1 * q0)
    poly[2] = 2.0 * t0 * t2 + t1 * t1 - (m0 * q2 + m1 * q1 + 4.0 * q0)
    poly[3] = 2.0 * (t0 * t3 + t1 * t2) - (m0 * q3 + m1 * q2 + 4.0 * q1)
    poly[4] = 2.0 * (t0 * t4 + t1 * t3) + t2 * t2 - (m0 * q4 + m1 * q3 + 4.0 * q2)
    poly[5] = 2.0 * (t1 * t4 + t2 * t3) - (m1 * q4 + 4.0 * q3)
    poly[6] = 2.0 * t2 * t4 + t3 * t3 - 4.0 * q4
    poly[7] = 2.0 * t3 * t4
    poly[8] = t4 * t4


@njit(cache=True)
def _newton_polish(f01, f02, f12, s0, s1, s2, iters):
    """Newton on the three quadrics from (s0, s1, s2); returns the polished
    ranges and the max relative residual."""
    for _ in range(iters):
        r0 = _feval(f01, s0, s1)
        r1 = _feval(f02, s0, s2)
        r2 = _feval(f12, s1, s2)
        j00 = 2 * f01[0] * s0 + f01[2] * s1 + f01[3]
        j01 = 2 * f01[1] * s1 + f01[2] * s0 + f01[4]
        j10 = 2 * f02[0] * s0 + f02[2] * s2 + f02[3]
        j12 = 2 * f02[1] * s2 + f02[2] * s0 + f02[4]
        j21 = 2 * f12[0] * s1 + f12[2] * s2 + f12[3]
        j22 = 2 * f12[1] * s2 + f12[2] * s1 + f12[4]
        # J = [[j00, j01, 0], [j10, 0, j12], [0, j21, j22]]
        det = -j00 * j12 * j21 - j01 * j10 * j22
        if det == 0.0 or not np.isfinite(det):
            break
        # Cramer's rule for J d = r
        d0 = (-r0 * j12 * j21 - j01 * (r1 * j22 - j12 * r2)) / det
        d1 = (j00 * (r1 * j22 - j12 * r2) - r0 * j10 * j22) / det
        d2 = (-j00 * r1 * j21 - j01 * j10 * r2 + r0 * j10 * j21) / det
        s0 -= d0
        s1 -= d1
        s2 -= d2
        # Quadratic convergence: after a step this small the error is far
        # below it.  (A stricter test only chases rounding noise, up to the
        # iteration limit, whenever the Jacobian is moderately conditioned.)
        if abs(d0) + abs(d1) + abs(d2) <= 1e-12 * (abs(s0) + abs(s1) + abs(s2)):
            break
    e0 = abs(_feval(f01, s0, s1)) / (_fscale(f01, s0, s1) + 1e-300)
    e1 = abs(_feval(f02, s0, s2)) / (_fscale(f02, s0, s2) + 1e-300)
    e2 = abs(_feval(f12, s1, s2)) / (_fscale(f12, s1, s2) + 1e-300)
    return s0, s1, s2, max(e0, max(e1, e2))


@njit(cache=True)
def triangle_frame(P0, P1, P2):
    """Orthonormal frame (columns e1, e2, e3) of the triangle P0 P1 P2,
    built on its longest edge; ``ok`` is False if the triangle is degenerate."""
    d01 = _sub(P1, P0)
    d12 = _sub(P2, P1)
    d20 = _sub(P0, P2)
    l01 = _dot(d01, d01)
    l12 = _dot(d12, d12)
    l20 = _dot(d20, d20)
    if l01 >= l12 and l01 >= l20:
        A, B, Cc, best = P0, P1, P2, l01
    elif l12 >= l20:
        A, B, Cc, best = P1, P2, P0, l12
    else:
        A, B, Cc, best = P2, P0, P1, l20
    ln = np.sqrt(best)
    zero = (0.0, 0.0, 0.0)
    if not ln > 0.0:
        return False, zero, zero, zero
    ex = _scale(_sub(B, A), 1.0 / ln)
    n = _cross(ex, _sub(Cc, A))
    nn = np.sqrt(_dot(n, n))
    if nn <= 1e-10 * ln:
        return False, zero, zero, zero
    n = _scale(n, 1.0 / nn)
    return True, ex, _cross(n, ex), n


@njit(cache=True)
def _absolute_orientation(P0, P1, P2, Q0, Q1, Q2, Rs, ts, k):
    """Rigid motion with Q_i = R P_i + t for congruent triangles (the closed
    form Arun's SVD method reduces to when the data are exact), written to
    Rs[k], ts[k].  False if a triangle is degenerate."""
    okp, p1, p2, p3 = triangle_frame(P0, P1, P2)
    okq, q1, q2, q3 = triangle_frame(Q0, Q1, Q2)
    if not (okp and okq):
        return False
    # R maps p's frame onto q's: R = sum_k q_k p_k^T.
    for i in range(3):
        for j in range(3):
            Rs[k, i, j] = q1[i] * p1[j] + q2[i] * p2[j] + q3[i] * p3[j]
    cp = _scale((P0[0] + P1[0] + P2[0], P0[1] + P1[1] + P2[1], P0[2] + P1[2] + P2[2]), 1.0 / 3.0)
    cq = _scale((Q0[0] + Q1[0] + Q2[0], Q0[1] + Q1[1] + Q2[1], Q0[2] + Q1[2] + Q2[2]), 1.0 / 3.0)
    for i in range(3):
        ts[k, i] = cq[i] - (Rs[k, i, 0] * cp[0] + Rs[k, i, 1] * cp[1] + Rs[k, i, 2] * cp[2])
    return True


@njit(cache=True)
def _orthonormalize(R):
    """Gram-Schmidt on the rows: removes the 1e-12-level drift of a rotation
    built from noisy-free but rounded depths (the paper's arccos rotation
    error amplifies it to 1e-5 degrees)."""
    n0 = np.sqrt(R[0, 0] ** 2 + R[0, 1] ** 2 + R[0, 2] ** 2)
    for j in range(3):
        R[0, j] /= n0
    d = R[0, 0] * R[1, 0] + R[0, 1] * R[1, 1] + R[0, 2] * R[1, 2]
    for j in range(3):
        R[1, j] -= d * R[0, j]
    n1 = np.sqrt(R[1, 0] ** 2 + R[1, 1] ** 2 + R[1, 2] ** 2)
    for j in range(3):
        R[1, j] /= n1
    R[2, 0] = R[0, 1] * R[1, 2] - R[0, 2] * R[1, 1]
    R[2, 1] = R[0, 2] * R[1, 0] - R[0, 0] * R[1, 2]
    R[2, 2] = R[0, 0] * R[1, 1] - R[0, 1] * R[1, 0]


@njit(cache=True)
def _p3p_mutual(seen_by_p, bearings, points, Rs, ts, ranges):
    """3-0 and 0-3: one camera sees three markers of the other robot, plain
    P3P (Lambda Twist, :mod:`.p3p`).  P3P gives the observed robot's frame in
    the observer's; for p observing, T_qp is its inverse."""
    n = p3p_kernel(bearings, points, Rs, ts)
    for i in range(n):
        _orthonormalize(Rs[i])
        for k in range(3):
            x0 = Rs[i, 0, 0] * points[k, 0] + Rs[i, 0, 1] * points[k, 1] + Rs[i, 0, 2] * points[k, 2] + ts[i, 0]
            x1 = Rs[i, 1, 0] * points[k, 0] + Rs[i, 1, 1] * points[k, 1] + Rs[i, 1, 2] * points[k, 2] + ts[i, 1]
            x2 = Rs[i, 2, 0] * points[k, 0] + Rs[i, 2, 1] * points[k, 1] + Rs[i, 2, 2] * points[k, 2] + ts[i, 2]
            ranges[i, k] = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
        if seen_by_p:
            t0, t1, t2 = ts[i, 0], ts[i, 1], ts[i, 2]
            for a in range(3):
                for b in range(a + 1, 3):
                    tmp = Rs[i, a, b]
                    Rs[i, a, b] = Rs[i, b, a]
                    Rs[i, b, a] = tmp
            for a in range(3):
                ts[i, a] = -(Rs[i, a, 0] * t0 + Rs[i, a, 1] * t1 + Rs[i, a, 2] * t2)
    return n


@njit(cache=True, inline="always")
def _push(tmp, res, n, s0, s1, r):
    tmp[2 * n] = s0
    tmp[2 * n + 1] = s1
    res[n] = r
    return n + 1


@njit(cache=True)
def _back_substitute(f01, f02, f12, s2, tmp, res):
    """Candidate (s0, s1) for a root s2 into ``tmp``, with the relative
    residual of the remaining equation into ``res``; returns their count.

    Two of the quadrics are solved for s0 and s1 (two signs each) and the
    third one judges the combinations.  No division by a resultant
    coefficient, so merged projections cannot blow up.  By default s0 and s1
    come from f02 and f12, which read (s_k + a_k)^2 = H_k(s2) (see
    :func:`_univariate`).  A slightly negative H is rounding of a double
    root and is clamped; a clearly negative one can still be the error of an
    ill-conditioned s2 (the solution then lies near H = 0, s_k = -a_k, where
    the square root magnifies it), so that range is taken from f01 instead.
    """
    a0 = 0.5 * f02[3]
    a1 = 0.5 * f12[3]
    g0 = s2 * s2 - f02[4] * s2 - f02[5]
    g1 = s2 * s2 - f12[4] * s2 - f12[5]
    h0 = a0 * a0 + g0
    h1 = a1 * a1 + g1
    ok0 = h0 >= -1e-7 * (a0 * a0 + abs(g0))
    ok1 = h1 >= -1e-7 * (a1 * a1 + abs(g1))
    u = np.sqrt(max(h0, 0.0))
    v = np.sqrt(max(h1, 0.0))
    n = 0
    if ok0:
        for i0 in range(2 if u > 0.0 else 1):
            s0 = (u if i0 == 0 else -u) - a0
            if ok1:
                for i1 in range(2 if v > 0.0 else 1):
                    s1 = (v if i1 == 0 else -v) - a1
                    r = abs(_feval(f01, s0, s1)) / (_fscale(f01, s0, s1) + 1e-300)
                    n = _push(tmp, res, n, s0, s1, r)
            else:
                m, x1, x2 = _quad_roots(1.0, f01[2] * s0, s0 * s0 + f01[5])
                for i1 in range(m):
                    s1 = x1 if i1 == 0 else x2
                    r = abs(_feval(f12, s1, s2)) / (_fscale(f12, s1, s2) + 1e-300)
                    n = _push(tmp, res, n, s0, s1, r)
    elif ok1:
        for i1 in range(2 if v > 0.0 else 1):
            s1 = (v if i1 == 0 else -v) - a1
            m, x1, x2 = _quad_roots(1.0, f01[2] * s1, s1 * s1 + f01[5])
            for i0 in range(m):
                s0 = x1 if i0 == 0 else x2
                r = abs(_feval(f02, s0, s2)) / (_fscale(f02, s0, s2) + 1e-300)
                n = _push(tmp, res, n, s0, s1, r)
    return n


@njit(cache=True, inline="always")
def _add_unique(sols, nsol, s0, s1, s2):
    """Append (s0, s1, s2) to the flat solution list unless already there
    (to 1e-7, relative); returns the new count."""
    for k in range(nsol):
        if abs(sols[3 * k] - s0) + abs(sols[3 * k + 1] - s1) + abs(sols[3 * k + 2] - s2) <= 1e-7 * (s0 + s1 + s2):
            return nsol
    if 3 * nsol + 3 > sols.shape[0]:
        return nsol
    sols[3 * nsol] = s0
    sols[3 * nsol + 1] = s1
    sols[3 * nsol + 2] = s2
    return nsol + 1


@njit(cache=True)
def _pose(pair, b0, b1, b2, X0, X1, X2, r0, r1, r2, Rs, ts, k):
    """T_qp of a mixed split with ranges (r0, r1, r2) into Rs[k], ts[k].

    The pair observer holds r0 b0, r1 b1 and its own marker X2; the lone
    observer X0, X1 and r2 b2.  ``pair`` is 0 when p is the pair observer.
    """
    A0 = _scale(b0, r0)
    A1 = _scale(b1, r1)
    B2 = _scale(b2, r2)
    if pair == 0:
        return _absolute_orientation(A0, A1, X2, X0, X1, B2, Rs, ts, k)
    return _absolute_orientation(X0, X1, B2, A0, A1, X2, Rs, ts, k)


# Scratch layout of solve_minimal_ws (floats).
_WS_ROOT = 0  # root finder
_WS_MAIN = _WS_ROOT + _ROOT_WORK
WORK_SIZE = _WS_MAIN + 128


@njit(cache=True)
def solve_minimal_kernel(side, bearings, points, Rs, ts, ranges):
    """All poses T_qp consistent with three observations (allocating wrapper
    of :func:`solve_minimal_ws`)."""
    ws = np.empty(WORK_SIZE)
    iws = np.empty(6, dtype=np.int64)
    return solve_minimal_ws(side, bearings, points, Rs, ts, ranges, ws, iws)


@njit(cache=True)
def solve_minimal_ws(side, bearings, points, Rs, ts, ranges, ws, iws):
    """All poses T_qp consistent with three observations.

    side[k] is 0 when p observed marker k (bearing in p's frame, marker
    position in q's frame) and 1 when q observed it.  Writes up to 8 poses
    into Rs (8,3,3), ts (8,3) and their ranges (8,3); returns the count.
    Only solutions with positive ranges (markers in front of the observing
    cameras along their rays) are returned.  ``ws`` (WORK_SIZE floats) and
    ``iws`` (6 ints) are scratch space, so batches allocate nothing.
    """
    n0 = 0
    for k in range(3):
        if side[k] == 0:
            n0 += 1
    if n0 == 0 or n0 == 3:
        return _p3p_mutual(n0 == 3, bearings, points, Rs, ts, ranges)
    # Canonical order: the pair observer's two observations first, the lone
    # observation last, so the kept range s2 keeps the usual mounting's
    # solution pairs apart.
    pair = 0 if n0 == 2 else 1
    order = iws[0:3]
    j = 0
    for k in range(3):
        if side[k] == pair:
            order[j] = k
            j += 1
        else:
            order[2] = k
    B0 = _row(bearings, order[0])
    B1 = _row(bearings, order[1])
    B2 = _row(bearings, order[2])
    nb0 = np.sqrt(_dot(B0, B0))
    nb1 = np.sqrt(_dot(B1, B1))
    nb2 = np.sqrt(_dot(B2, B2))
    if not (nb0 > 0.0 and nb1 > 0.0 and nb2 > 0.0):
        return 0
    b0 = (B0[0] / nb0, B0[1] / nb0, B0[2] / nb0)
    b1 = (B1[0] / nb1, B1[1] / nb1, B1[2] / nb1)
    b2 = (B2[0] / nb2, B2[1] / nb2, B2[2] / nb2)
    X0 = _row(points, order[0])
    X1 = _row(points, order[1])
    X2 = _row(points, order[2])
    # Normalise lengths to the marker scale.
    d01 = _sub(X0, X1)
    L = max(max(np.sqrt(_dot(X0, X0)), np.sqrt(_dot(X1, X1))), max(np.sqrt(_dot(X2, X2)), np.sqrt(_dot(d01, d01))))
    if not L > 0.0 or not np.isfinite(L):
        return 0
    f01, f02, f12 = _mixed_quadrics(b0, b1, b2, _scale(X0, 1.0 / L), _scale(X1, 1.0 / L), _scale(X2, 1.0 / L))
    o = _WS_MAIN
    poly = ws[o : o + 9]
    _univariate(f01, f02, f12, poly)
    cand = ws[o + 9 : o + 25]
    # Roots need only ~1e-9: Newton on the three quadrics polishes them.
    nr, nn = positive_roots_ws(poly, 1e-12, _MAX_RANGE, cand, _NEAR_TOL, 1e-9, 1e-7, ws[_WS_ROOT:_WS_MAIN])
    sols = ws[o + 25 : o + 97]  # up to 24 solutions (s0, s1, s2)
    tmp = ws[o + 97 : o + 105]  # candidates (s0, s1) of one root
    res = ws[o + 105 : o + 109]  # and their residuals
    nsol = 0
    for ir in range(nr + nn):
        s2 = cand[ir]
        ntmp = _back_substitute(f01, f02, f12, s2, tmp, res)
        best = np.inf
        for i in range(ntmp):
            best = min(best, res[i])
        for i in range(ntmp):
            s0 = tmp[2 * i]
            s1 = tmp[2 * i + 1]
            if res[i] > max(1e3 * best, 1e-6):
                continue
            # Typically three of the four roots put a marker behind a camera;
            # polishing cannot make a clearly negative range positive.
            if s0 < -1e-6 * s2 or s1 < -1e-6 * s2:
                continue
            p0, p1, p2, err = _newton_polish(f01, f02, f12, s0, s1, s2, 12)
            if err <= _ACCEPT_TOL and p0 > 0.0 and p1 > 0.0 and p2 > 0.0:
                nsol = _add_unique(sols, nsol, p0, p1, p2)
    # Poses from the three point pairs.
    nout = 0
    for k in range(nsol):
        if nout >= Rs.shape[0]:
            break
        r0 = sols[3 * k] * L
        r1 = sols[3 * k + 1] * L
        r2 = sols[3 * k + 2] * L
        if _pose(pair, b0, b1, b2, X0, X1, X2, r0, r1, r2, Rs, ts, nout):
            ranges[nout, order[0]] = r0
            ranges[nout, order[1]] = r1
            ranges[nout, order[2]] = r2
            nout += 1
    return nout


def solve_minimal(side, bearings, points) -> tuple[np.ndarray, np.ndarray]:
    """Every pose T_qp (x_q = R x_p + t) consistent with three observations.

    ``side`` (3,): 0 if p saw the marker, 1 if q did; ``bearings`` (3, 3):
    rays in the observer's frame; ``points`` (3, 3): the markers in their
    owner's frame.  Returns ``R`` (k, 3, 3) and ``t`` (k, 3), k <= 8; only
    poses that put each marker in front of its observer along its ray.
    """
    Rs = np.empty((16, 3, 3))
    ts = np.empty((16, 3))
    rg = np.empty((16, 3))
    n = solve_minimal_kernel(np.asarray(side, dtype=np.int64), np.ascontiguousarray(bearings, dtype=float),
                             np.ascontiguousarray(points, dtype=float), Rs, ts, rg)
    return Rs[:n], ts[:n]
