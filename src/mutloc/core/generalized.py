"""Generalized absolute pose from three point-on-ray correspondences, both
directions mixed (generalized P3P).

Unknown: the rigid motion ``T = (R, t)`` of a frame ``U`` into a frame ``W``
(``x_W = R @ x_U + t``).  Each of three correspondences ``k`` is a ray and a
known point, one in each frame:

* kind 0 -- a ray of ``U`` (origin ``c_k``, unit direction ``d_k``, both in
  ``U``) passes through the known point ``X_k`` of ``W``:
  ``X_k = R (c_k + s_k d_k) + t``;
* kind 1 -- a ray of ``W`` passes through the known point ``X_k`` of ``U``:
  ``R X_k + t = c_k + s_k d_k``;

with ranges ``s_k > 0``.  In a team: ``U`` is a robot (or a rigid group of
robots solved among themselves), ``W`` the robots already placed; kind 0 is
a camera of the group seeing a placed robot's marker, kind 1 a placed camera
seeing a marker of the group.  Three kind-0 rays from one origin are plain
P3P, three kind-1 rays from one origin the inverse P3P; rays from several
origins are the non-central (multi-camera) problem.

The rigid motion preserves the three pairwise distances, so the ranges
satisfy three quadrics ``f_kl(s_k, s_l) = |p_k - p_l|^2 - |q_k - q_l|^2 = 0``
(``p`` the points in ``U``, ``q`` in ``W``), each ``s_k^2`` with the constant
coefficient ``+-1``: Bezout number 8.  ``s0`` is eliminated by the resultant
of two quadratics (``f01``, ``f02``), ``s1`` by reducing that quartic modulo
the monic (in ``s1``) ``f12``: a univariate of degree 8 in ``s2`` with no
extraneous factor.  Every (near-)real root is back-substituted both ways
(the linear elimination and the two roots of each quadratic, so solutions
sharing an ``s2`` -- a double root split into a complex pair by rounding --
are not lost) and polished by Newton's method on the three quadrics; the
pose is then the absolute orientation of the two congruent triangles.

Compiled with Numba (:func:`generalized_p3p_kernel`): the pair solver
calls it in its inner loop for minimal subsets whose rays leave different
camera centres, thousands of times per call, so it is allocation-free (a
caller-owned scratch array of :data:`GP3P_WORK_SIZE` floats) and written, like
:mod:`.minimal`, with scalars and tuples instead of small arrays.  The
univariate's real roots come from the project's root finder
(:func:`.polynomial.positive_roots_ws`), which also reports numerically
merged double roots.  For mixed splits the correspondences are first put in
the order "majority kind, majority kind, lone kind", so that ``s2`` is the
lone ray's range: in the central mutual problem that is the range that
separates the usual mounting's solution pairs (see :mod:`.minimal`); the
order does not change the solution set.  :func:`generalized_p3p` is the
NumPy convenience wrapper.  Per call (bench/bench_gp3p.py, one loaded AMD
EPYC core): 2.8 us for 2-1 / 1-2, 5-6 us for 3-0 / 0-3 (the root finder's
derivative chain), against 1-1.7 us for the central ``solve_minimal_kernel``.

At most :data:`GP3P_MAX_SOLUTIONS` = 8 poses: the three quadrics have Bezout
number 8, so a non-degenerate problem has at most 8 isolated solutions
(complex ones and those with a non-positive range are not returned).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .minimal import triangle_frame
from .polynomial import WORK_SIZE as _ROOT_WORK, positive_roots_ws, real_roots_ws
from .vec3 import row as _row, dot as _dot, sub as _sub, scale as _scale, axpy as _axpy, cross as _cross

__all__ = ["generalized_p3p", "generalized_p3p_kernel", "GP3P_MAX_SOLUTIONS", "GP3P_WORK_SIZE", "KIND_U_RAY",
           "KIND_W_RAY"]

#: A ray of the unknown frame U through a known point of W.
KIND_U_RAY = 0
#: A ray of the known frame W through a known point of U.
KIND_W_RAY = 1
#: Most poses one problem can have (the Bezout number of the three quadrics).
GP3P_MAX_SOLUTIONS = 8
# Largest range searched, in units of the problem's scale L.
_MAX_RANGE = 1e4
# Relative residual (to the size of the quadric's terms) of an accepted
# solution (Newton reaches ~1e-16; an ill-conditioned solution -- two nearby
# ones -- polished to only 1e-9 can still be 1e-7 off).
_ACCEPT_TOL = 1e-11
# Newton iterations at most (linear convergence near a double root).
_NEWTON_ITERS = 30
# Relative residual of a back-substituted start worth polishing.
_START_TOL = 1e-2
# Critical points of the univariate with |p| below this relative level are
# numerically merged double roots (polished like the others).
_NEAR_TOL = 1e-7
# Most distinct range triples kept (more than 8 only if rounding duplicates).
_MAX_SOLS = 16

# Scratch layout of generalized_p3p_kernel (floats).
_WS_ROOT = 0  # the root finder's scratch
_WS_POLY = _WS_ROOT + _ROOT_WORK  # 13 slots of 9: the univariate and its ingredients (_univariate)
_WS_CAND = _WS_POLY + 13 * 9  # 16: the univariate's roots
_WS_SOLS = _WS_CAND + 16  # _MAX_SOLS x 4: distinct polished ranges and their residuals
#: Size of the scratch array ``ws`` of :func:`generalized_p3p_kernel` (floats).
GP3P_WORK_SIZE = _WS_SOLS + 4 * _MAX_SOLS


@njit(cache=True)
def _quadric(oUk, uUk, oWk, uWk, ak, oUl, uUl, oWl, uWl, al):
    """Coefficients ``(c00, c10, c01, c20, c02, c11)`` of
    ``f_kl = |p_k - p_l|^2 - |q_k - q_l|^2``, ``c_ij`` multiplying
    ``s_k^i s_l^j``; the point of correspondence k is ``oU + s uU`` in U and
    ``oW + s uW`` in W (one of the two directions zero), ``ak`` = +-1 its
    ``s_k^2`` coefficient."""
    dU = _sub(oUk, oUl)
    dW = _sub(oWk, oWl)
    return (_dot(dU, dU) - _dot(dW, dW),
            2.0 * (_dot(dU, uUk) - _dot(dW, uWk)),
            -2.0 * (_dot(dU, uUl) - _dot(dW, uWl)),
            ak,
            al,
            -2.0 * (_dot(uUk, uUl) - _dot(uWk, uWl)))


@njit(cache=True, inline="always")
def _feval(c, x, y):
    return c[0] + c[1] * x + c[2] * y + c[3] * x * x + c[4] * y * y + c[5] * x * y


@njit(cache=True, inline="always")
def _fscale(c, x, y):
    return (abs(c[0]) + abs(c[1] * x) + abs(c[2] * y) + abs(c[3]) * x * x + abs(c[4]) * y * y
            + abs(c[5] * x * y))


@njit(cache=True, inline="always")
def _rel(c, x, y):
    """|f(x, y)| relative to the size of its terms."""
    return abs(_feval(c, x, y)) / (_fscale(c, x, y) + 1e-300)


@njit(cache=True, inline="always")
def _quad_roots(a, b, c):
    """Real roots (count, x1, x2) of a x^2 + b x + c (a = +-1); a slightly
    negative discriminant is a double root split by rounding and counts as zero."""
    disc = b * b - 4.0 * a * c
    if disc < 0.0:
        if disc < -1e-6 * (b * b + abs(4.0 * a * c)):
            return 0, 0.0, 0.0
        disc = 0.0
    sq = np.sqrt(disc)
    q = -0.5 * (b + sq) if b >= 0.0 else -0.5 * (b - sq)
    if q == 0.0:
        return 1, 0.0, 0.0
    return 2, q / a, c / q


@njit(cache=True, inline="always")
def _pmac(ws, out, a, na, b, nb, c):
    """ws[out:] += c * (ws[a:] * ws[b:]): polynomials (ascending) of degrees na, nb."""
    for i in range(na + 1):
        ai = c * ws[a + i]
        for j in range(nb + 1):
            ws[out + i + j] += ai * ws[b + j]


@njit(cache=True, inline="always")
def _put(ws, at, c0, c1, c2):
    ws[at] = c0
    ws[at + 1] = c1
    ws[at + 2] = c2


@njit(cache=True)
def _univariate(f01, f02, f12, ws, o):
    """Degree-8 polynomial in s2 whose roots are the s2 of all solutions,
    into ws[o + 108 : o + 117]; the coefficients of 1 and s1 of ``g mod f12``
    (r0 of degree 4, r1 of degree 3) stay at ws[o + 18], ws[o + 27].

    f01 = a s0^2 + B1(s1) s0 + C1(s1) and f02 = a s0^2 + B2(s2) s0 + C2(s2)
    share a = +-1; their resultant in s0,

        g = a^2 (C2 - C1)^2 - a (B2 - B1) (B1 C2 - B2 C1),

    is a polynomial of total degree 4 in (s1, s2), stored as rows g_i(s2)
    (the coefficients of s1^i).  Reducing it modulo f12 / a1 = s1^2 + beta
    s1 + gamma leaves r1 s1 + r0, and the resultant of that with the monic
    quadratic is ``r1^2 gamma - r0 r1 beta + r0^2``.  Slots of 9 floats from
    o: 0 c2' = C2 - c00(f01), 1 b2' = B2 - c10(f01), 2..6 g_0..g_4,
    7 E0, 8 E1, 9 E2 (E = B1 C2 - B2 C1 by powers of s1), 10 beta, 11 gamma,
    12 the univariate.
    """
    for i in range(13 * 9):
        ws[o + i] = 0.0
    p00, p10, p01, a, p02, p11 = f01
    q00, q10, q01, _, q02, q11 = f02
    A2 = a * a
    C2P, B2P, G, E0, E1, E2, BE, GA, OUT = o, o + 9, o + 18, o + 63, o + 72, o + 81, o + 90, o + 99, o + 108
    _put(ws, C2P, q00 - p00, q01, q02)
    _put(ws, B2P, q10 - p10, q11, 0.0)
    _put(ws, E0, p10 * q00 - p00 * q10, p10 * q01 - p00 * q11, p10 * q02)
    _put(ws, E1, p11 * q00 - p01 * q10, p11 * q01 - p01 * q11, p11 * q02)
    _put(ws, E2, -p02 * q10, -p02 * q11, 0.0)
    G0, G1, G2, G3, G4 = G, G + 9, G + 18, G + 27, G + 36
    # a^2 (C2 - C1)^2, C2 - C1 = c2' - p01 s1 - p02 s1^2
    _pmac(ws, G0, C2P, 2, C2P, 2, A2)
    for j in range(3):
        ws[G1 + j] += -2.0 * A2 * p01 * ws[C2P + j]
        ws[G2 + j] += -2.0 * A2 * p02 * ws[C2P + j]
    ws[G2] += A2 * p01 * p01
    ws[G3] += 2.0 * A2 * p01 * p02
    ws[G4] += A2 * p02 * p02
    # - a (B2 - B1) E, B2 - B1 = b2' - p11 s1
    _pmac(ws, G0, B2P, 1, E0, 2, -a)
    _pmac(ws, G1, B2P, 1, E1, 2, -a)
    _pmac(ws, G2, B2P, 1, E2, 1, -a)
    for j in range(3):
        ws[G1 + j] += a * p11 * ws[E0 + j]
        ws[G2 + j] += a * p11 * ws[E1 + j]
        ws[G3 + j] += a * p11 * ws[E2 + j]
    # reduce modulo f12 / a1: s1^2 = -(beta s1 + gamma)
    r00, r10, r01, a1, r02, r11 = f12
    _put(ws, BE, r10 / a1, r11 / a1, 0.0)
    _put(ws, GA, r00 / a1, r01 / a1, r02 / a1)
    for i in range(4, 1, -1):
        gi = G + 9 * i
        _pmac(ws, gi - 9, gi, 4 - i, BE, 1, -1.0)  # g_i has degree 4 - i here
        _pmac(ws, gi - 18, gi, 4 - i, GA, 2, -1.0)
    # r1^2 gamma - r0 r1 beta + r0^2 with r0 = g_0 (degree 4), r1 = g_1
    # (degree 3); the products go to slots 7-8 (E0, E1 are done with)
    b0, b1 = ws[BE], ws[BE + 1]
    T = E0
    for j in range(18):
        ws[T + j] = 0.0
    _pmac(ws, T, G1, 3, G1, 3, 1.0)
    _pmac(ws, OUT, T, 6, GA, 2, 1.0)
    for j in range(18):
        ws[T + j] = 0.0
    _pmac(ws, T, G0, 4, G1, 3, 1.0)  # r0 r1 (degree 7)
    for j in range(8):
        ws[OUT + j] -= b0 * ws[T + j]
        ws[OUT + j + 1] -= b1 * ws[T + j]
    _pmac(ws, OUT, G0, 4, G0, 4, 1.0)


@njit(cache=True)
def _newton(f01, f02, f12, s0, s1, s2, iters):
    """Newton's method on the three quadrics from (s0, s1, s2); the polished
    ranges and the largest relative residual."""
    prev = np.inf
    for _ in range(iters):
        r0 = _feval(f01, s0, s1)
        r1 = _feval(f02, s0, s2)
        r2 = _feval(f12, s1, s2)
        j00 = f01[1] + 2.0 * f01[3] * s0 + f01[5] * s1
        j01 = f01[2] + 2.0 * f01[4] * s1 + f01[5] * s0
        j10 = f02[1] + 2.0 * f02[3] * s0 + f02[5] * s2
        j12 = f02[2] + 2.0 * f02[4] * s2 + f02[5] * s0
        j21 = f12[1] + 2.0 * f12[3] * s1 + f12[5] * s2
        j22 = f12[2] + 2.0 * f12[4] * s2 + f12[5] * s1
        # J = [[j00, j01, 0], [j10, 0, j12], [0, j21, j22]]; Cramer's rule for J d = r
        det = -j00 * j12 * j21 - j01 * j10 * j22
        if det == 0.0 or not np.isfinite(det):
            break
        d0 = (-r0 * j12 * j21 - j01 * (r1 * j22 - j12 * r2)) / det
        d1 = (j00 * (r1 * j22 - j12 * r2) - r0 * j10 * j22) / det
        d2 = (-j00 * r1 * j21 - j01 * j10 * r2 + r0 * j10 * j21) / det
        s0 -= d0
        s1 -= d1
        s2 -= d2
        # Quadratic convergence: after a step this small the error is far
        # below it.  Near a double root convergence is linear and rounding
        # keeps the steps at ~1e-13 (relative) for ever: stop when they no
        # longer shrink.
        step = abs(d0) + abs(d1) + abs(d2)
        size = abs(s0) + abs(s1) + abs(s2)
        if step <= 1e-14 * size or (step >= prev and step <= 1e-9 * size):
            break
        prev = step
    err = max(_rel(f01, s0, s1), max(_rel(f02, s0, s2), _rel(f12, s1, s2)))
    return s0, s1, s2, err


@njit(cache=True)
def _try_start(f01, f02, f12, s0, s1, s2, sols, nsol):
    """Polish the start (s0, s1, s2) if it is near a solution with positive
    ranges, and add it to the list ``sols`` (rows s0, s1, s2, residual) unless
    that solution is there already (then the more accurate of the two is
    kept); the new count."""
    if not (np.isfinite(s0) and np.isfinite(s1)):
        return nsol
    big = max(abs(s0), max(abs(s1), abs(s2)))
    if min(s0, s1) < -1e-3 * big:
        return nsol  # polishing does not make a clearly negative range positive
    if max(_rel(f01, s0, s1), max(_rel(f02, s0, s2), _rel(f12, s1, s2))) > _START_TOL:
        return nsol
    for k in range(nsol):
        if abs(sols[4 * k] - s0) + abs(sols[4 * k + 1] - s1) + abs(sols[4 * k + 2] - s2) <= 1e-9 * big:
            return nsol  # found already (and polished to convergence)
    p0, p1, p2, err = _newton(f01, f02, f12, s0, s1, s2, _NEWTON_ITERS)
    if not (err <= _ACCEPT_TOL and p0 > 0.0 and p1 > 0.0 and p2 > 0.0 and max(p0, max(p1, p2)) < _MAX_RANGE):
        return nsol
    for k in range(nsol):
        if abs(sols[4 * k] - p0) + abs(sols[4 * k + 1] - p1) + abs(sols[4 * k + 2] - p2) <= 1e-7 * (p0 + p1 + p2):
            if err < sols[4 * k + 3]:
                sols[4 * k] = p0
                sols[4 * k + 1] = p1
                sols[4 * k + 2] = p2
                sols[4 * k + 3] = err
            return nsol
    if 4 * nsol + 4 > sols.shape[0]:
        return nsol
    sols[4 * nsol] = p0
    sols[4 * nsol + 1] = p1
    sols[4 * nsol + 2] = p2
    sols[4 * nsol + 3] = err
    return nsol + 1


@njit(cache=True)
def _absolute_orientation(P0, P1, P2, Q0, Q1, Q2, Rs, ts, k):
    """Rigid motion with Q_i = R P_i + t for congruent triangles (what Arun's
    SVD method reduces to for exact data) into Rs[k], ts[k]; False if a
    triangle is degenerate.  As :mod:`.minimal`'s, with the centroids taken
    relative to the first points (rays from camera centres far from the
    robot's origin)."""
    okp, p1, p2, p3 = triangle_frame(P0, P1, P2)
    okq, q1, q2, q3 = triangle_frame(Q0, Q1, Q2)
    if not (okp and okq):
        return False
    for i in range(3):
        for j in range(3):
            Rs[k, i, j] = q1[i] * p1[j] + q2[i] * p2[j] + q3[i] * p3[j]
    # centroids relative to P0, Q0 (coordinates may be far from the origin)
    cp = _axpy(P0, 1.0 / 3.0, _axpy(_sub(P1, P0), 1.0, _sub(P2, P0)))
    cq = _axpy(Q0, 1.0 / 3.0, _axpy(_sub(Q1, Q0), 1.0, _sub(Q2, Q0)))
    for i in range(3):
        ts[k, i] = cq[i] - (Rs[k, i, 0] * cp[0] + Rs[k, i, 1] * cp[1] + Rs[k, i, 2] * cp[2])
    return True


@njit(cache=True)
def _roots(poly, cand, work, fast):
    """Positive roots of the univariate into ``cand`` (sign changes, then
    merged double roots): ``(n_roots, n_near)``.

    Roots need only ~1e-9: Newton on the three quadrics polishes them.  The
    root finder's fast path (Laguerre from above, deflating) is tried for
    mixed splits only: for 3-0 and 0-3 the univariate is nearly even (exactly
    in the central case), its complex roots near the positive axis defeat the
    fast path's certificate almost always (98 % of random problems), and the
    derivative chain alone is then faster.  The fast path's roots are
    checked on the univariate itself: deflating from the largest root is
    unstable when the roots' sizes spread over many orders (a few 1e4 beside
    a few 1), and a root that is none sends us to the derivative chain.
    """
    if fast:
        nr, nn = positive_roots_ws(poly, 1e-12, _MAX_RANGE, cand, _NEAR_TOL, 1e-9, 1e-7, work)
        ok = True
        for i in range(nr + nn):
            x = cand[i]
            p = poly[8]
            a = abs(poly[8])
            for j in range(7, -1, -1):
                p = p * x + poly[j]
                a = a * x + abs(poly[j])
            if not abs(p) <= 1e-6 * a:
                ok = False
        if ok:
            return nr, nn
    return real_roots_ws(poly, 1e-12, _MAX_RANGE, cand, _NEAR_TOL, 1e-9, 1e-7, work)


@njit(cache=True, inline="always")
def _sides(kind, o, u, X):
    """(oU, uU, oW, uW, a): the correspondence's point is oU + s uU in U and
    oW + s uW in W; a = +-1 the coefficient of s^2 in its quadrics."""
    zero = (0.0, 0.0, 0.0)
    if kind == KIND_U_RAY:
        return o, u, X, zero, 1.0
    return X, zero, o, u, -1.0


@njit(cache=True)
def generalized_p3p_kernel(kinds, origins, directions, points, Rs, ts, ws):
    """Every pose ``(R, t)`` (``x_W = R x_U + t``) fitting three
    correspondences exactly with positive ranges (module docstring).

    ``kinds`` (3,) integers: :data:`KIND_U_RAY` (0) or :data:`KIND_W_RAY`
    (any other value); ``origins``, ``directions`` (3, 3): each ray (in ``U``
    for kind 0, in ``W`` for kind 1; directions need not be unit);
    ``points`` (3, 3): the known point of each correspondence (in ``W`` for
    kind 0, in ``U`` for kind 1).  Writes up to ``min(8, len(Rs))`` poses
    into ``Rs`` (k, 3, 3), ``ts`` (k, 3) and returns their count (0 for
    degenerate or non-finite input).  ``ws``: scratch of at least
    :data:`GP3P_WORK_SIZE` floats; nothing is allocated.
    """
    n0 = 0
    for k in range(3):
        if kinds[k] == KIND_U_RAY:
            n0 += 1
    # Mixed splits: the lone kind last, so s2 is its range (module docstring).
    lone = 1 if n0 == 2 else (0 if n0 == 1 else -1)
    i0, i1, i2 = 0, 1, 2
    if lone >= 0:
        for k in range(3):
            if (kinds[k] == KIND_U_RAY) == (lone == KIND_U_RAY):
                i2 = k
        i0 = 1 if i2 == 0 else 0
        i1 = 3 - i0 - i2
    D0, D1, D2 = _row(directions, i0), _row(directions, i1), _row(directions, i2)
    n_0, n_1, n_2 = np.sqrt(_dot(D0, D0)), np.sqrt(_dot(D1, D1)), np.sqrt(_dot(D2, D2))
    if not (0.0 < n_0 < np.inf and 0.0 < n_1 < np.inf and 0.0 < n_2 < np.inf):
        return 0
    oU0, uU0, oW0, uW0, a0 = _sides(kinds[i0], _row(origins, i0), _scale(D0, 1.0 / n_0), _row(points, i0))
    oU1, uU1, oW1, uW1, a1 = _sides(kinds[i1], _row(origins, i1), _scale(D1, 1.0 / n_1), _row(points, i1))
    oU2, uU2, oW2, uW2, a2 = _sides(kinds[i2], _row(origins, i2), _scale(D2, 1.0 / n_2), _row(points, i2))
    # Scale: lengths in units of the largest distance between the fixed parts
    # (distances are translation invariant in each frame).
    L2 = 0.0
    for d in (_sub(oU0, oU1), _sub(oU0, oU2), _sub(oU1, oU2), _sub(oW0, oW1), _sub(oW0, oW2), _sub(oW1, oW2)):
        L2 = max(L2, _dot(d, d))
    L = np.sqrt(L2)
    if not (0.0 < L < np.inf):
        return 0
    iL = 1.0 / L
    sU0, sU1, sU2 = _scale(oU0, iL), _scale(oU1, iL), _scale(oU2, iL)
    sW0, sW1, sW2 = _scale(oW0, iL), _scale(oW1, iL), _scale(oW2, iL)
    f01 = _quadric(sU0, uU0, sW0, uW0, a0, sU1, uU1, sW1, uW1, a1)
    f02 = _quadric(sU0, uU0, sW0, uW0, a0, sU2, uU2, sW2, uW2, a2)
    f12 = _quadric(sU1, uU1, sW1, uW1, a1, sU2, uU2, sW2, uW2, a2)
    for c in (f01, f02, f12):
        for v in c:
            if not np.isfinite(v):
                return 0
    o = _WS_POLY
    _univariate(f01, f02, f12, ws, o)
    cand = ws[_WS_CAND:_WS_CAND + 16]
    nr, nn = _roots(ws[o + 108:o + 117], cand, ws[_WS_ROOT:_WS_POLY], lone >= 0)
    sols = ws[_WS_SOLS:_WS_SOLS + 4 * _MAX_SOLS]
    nsol = 0
    R0, R1 = o + 18, o + 27  # g mod f12 = r1(s2) s1 + r0(s2)
    for ir in range(nr + nn):
        s2 = cand[ir]
        # the linear back-substitution: s1 = -r0 / r1, s0 from f01 - f02 (linear in s0)
        v0 = ws[R0 + 4]
        for j in range(3, -1, -1):
            v0 = v0 * s2 + ws[R0 + j]
        v1 = ws[R1 + 3]
        for j in range(2, -1, -1):
            v1 = v1 * s2 + ws[R1 + j]
        if v1 != 0.0:
            s1 = -v0 / v1
            den = (f01[1] + f01[5] * s1) - (f02[1] + f02[5] * s2)
            num = (f02[0] + f02[2] * s2 + f02[4] * s2 * s2) - (f01[0] + f01[2] * s1 + f01[4] * s1 * s1)
            if den != 0.0:
                nsol = _try_start(f01, f02, f12, num / den, s1, s2, sols, nsol)
        # both roots of f12 (in s1) and of f02 (in s0): solutions sharing s2
        m1, x1, x2 = _quad_roots(f12[3], f12[1] + f12[5] * s2, f12[0] + f12[2] * s2 + f12[4] * s2 * s2)
        m0, y1, y2 = _quad_roots(f02[3], f02[1] + f02[5] * s2, f02[0] + f02[2] * s2 + f02[4] * s2 * s2)
        for j1 in range(m1):
            for j0 in range(m0):
                nsol = _try_start(f01, f02, f12, y1 if j0 == 0 else y2, x1 if j1 == 0 else x2, s2, sols, nsol)
    # Poses from the two congruent triangles (unscaled ranges).
    nout = 0
    for k in range(nsol):
        if nout >= min(Rs.shape[0], GP3P_MAX_SOLUTIONS):
            break
        r0, r1, r2 = sols[4 * k] * L, sols[4 * k + 1] * L, sols[4 * k + 2] * L
        if _absolute_orientation(_axpy(oU0, r0, uU0), _axpy(oU1, r1, uU1), _axpy(oU2, r2, uU2),
                                 _axpy(oW0, r0, uW0), _axpy(oW1, r1, uW1), _axpy(oW2, r2, uW2), Rs, ts, nout):
            nout += 1
    return nout


def generalized_p3p(kinds, origins, directions, points) -> tuple[np.ndarray, np.ndarray]:
    """Every pose ``(R, t)`` (``x_W = R x_U + t``) fitting three
    correspondences exactly with positive ranges (module docstring); the
    NumPy convenience wrapper of :func:`generalized_p3p_kernel`.

    ``kinds`` (3,): :data:`KIND_U_RAY` or :data:`KIND_W_RAY`; ``origins``,
    ``directions`` (3, 3): each ray (in ``U`` for kind 0, in ``W`` for kind
    1; directions need not be unit); ``points`` (3, 3): the known point of
    each correspondence (in ``W`` for kind 0, in ``U`` for kind 1).  Returns
    ``Rs`` (m, 3, 3) and ``ts`` (m, 3), m <= 8, possibly zero.
    """
    kinds = np.ascontiguousarray(kinds, dtype=np.int64).reshape(3)
    o = np.ascontiguousarray(origins, dtype=float).reshape(3, 3)
    d = np.ascontiguousarray(directions, dtype=float).reshape(3, 3)
    X = np.ascontiguousarray(points, dtype=float).reshape(3, 3)
    Rs = np.empty((GP3P_MAX_SOLUTIONS, 3, 3))
    ts = np.empty((GP3P_MAX_SOLUTIONS, 3))
    n = generalized_p3p_kernel(kinds, o, d, X, Rs, ts, np.empty(GP3P_WORK_SIZE))
    return Rs[:n].copy(), ts[:n].copy()
