"""Minimal solvers: the relative pose from three marker observations.

Every split of three observations between the two cameras (3-0, 2-1, 1-2,
0-3) is one algebraic problem.  Observation ``k`` is a marker whose position
``X_k`` is known in its owner's frame and whose range ``s_k`` along the
observer's unit bearing ``b_k`` is unknown.  The rigid motion preserves the
three pairwise distances (paper, eq. solvescale), giving three quadrics

    f_kl(s_k, s_l) = A s_k^2 + B s_l^2 + C s_k s_l + D s_k + E s_l + F = 0,

with Bezout number 8.  Two Sylvester resultants (first in ``s_1``, then a
division by the monic quadric in ``s_0``) give a degree-8 polynomial in
``s_2`` with no extraneous factor.

Which range to keep is the numerical crux.  In the usual mounting (markers
left and right of each camera, cameras facing each other) the paper's choice
of eliminating down to ``s_1`` meets solutions in pairs with *equal* ``s_1``
and ``s_2``: a double root that noise or rounding splits into a complex pair,
silently losing the true pose.  Those pairs differ in the range measured by
the *other* camera, so for mixed splits we keep that one.  As a second line of
defence the root finder also reports numerically merged double roots
(critical points where the polynomial vanishes to rounding level) and every
candidate is back-substituted without division and polished by Newton's
method on the original three quadrics, so a solution is never dropped merely
because the univariate projection is ill-conditioned.

With the ranges known, both frames hold the same three points, and the
absolute orientation (Arun/Horn; closed form here because the two triangles
are congruent by construction) gives ``T_qp``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .p3p import p3p_kernel
from .polynomial import WORK_SIZE as _ROOT_WORK, real_roots_ws

MAX_SOLUTIONS = 8
# Relative residual of the distance equations for an accepted solution.
_ACCEPT_TOL = 1e-7
# Critical points with |p| below this relative level are merged double roots.
_NEAR_TOL = 1e-9
# Largest range searched, in units of the marker scale.
_MAX_RANGE = 1e4


@njit(cache=True)
def _pair_coeffs(side, b, X, k, l, out):
    """Coefficients (A, B, C, D, E, F) of f_kl = |Y^p_k - Y^p_l|^2 - |Y^q_k - Y^q_l|^2.

    In the frame of its observer, point k is ``s_k b_k`` (unknown range); in
    the other frame it is the known marker position ``X_k``.
    """
    for i in range(6):
        out[i] = 0.0
    for frame in range(2):
        sg = 1.0 if frame == 0 else -1.0
        uk = side[k] == frame
        ul = side[l] == frame
        if uk and ul:
            c = b[k, 0] * b[l, 0] + b[k, 1] * b[l, 1] + b[k, 2] * b[l, 2]
            out[0] += sg
            out[1] += sg
            out[2] -= 2.0 * sg * c
        elif uk:
            bx = b[k, 0] * X[l, 0] + b[k, 1] * X[l, 1] + b[k, 2] * X[l, 2]
            out[0] += sg
            out[3] -= 2.0 * sg * bx
            out[5] += sg * (X[l, 0] ** 2 + X[l, 1] ** 2 + X[l, 2] ** 2)
        elif ul:
            bx = b[l, 0] * X[k, 0] + b[l, 1] * X[k, 1] + b[l, 2] * X[k, 2]
            out[1] += sg
            out[4] -= 2.0 * sg * bx
            out[5] += sg * (X[k, 0] ** 2 + X[k, 1] ** 2 + X[k, 2] ** 2)
        else:
            d = (X[k, 0] - X[l, 0]) ** 2 + (X[k, 1] - X[l, 1]) ** 2 + (X[k, 2] - X[l, 2]) ** 2
            out[5] += sg * d


@njit(cache=True, inline="always")
def _feval(c, x, y):
    return c[0] * x * x + c[1] * y * y + c[2] * x * y + c[3] * x + c[4] * y + c[5]


@njit(cache=True, inline="always")
def _fscale(c, x, y):
    return (
        abs(c[0]) * x * x + abs(c[1]) * y * y + abs(c[2] * x * y) + abs(c[3] * x) + abs(c[4] * y) + abs(c[5])
    )


@njit(cache=True)
def _quad_roots(a, b, c, out):
    """Real roots of a x^2 + b x + c (a != 0); a slightly negative discriminant
    is clamped because it is rounding of a double root.  Returns the count."""
    disc = b * b - 4.0 * a * c
    scale = b * b + abs(4.0 * a * c)
    if disc < 0.0:
        if disc < -1e-7 * scale:
            return 0
        disc = 0.0
    sq = np.sqrt(disc)
    q = -0.5 * (b + sq) if b >= 0.0 else -0.5 * (b - sq)
    if q == 0.0:
        out[0] = 0.0
        return 1
    out[0] = q / a
    out[1] = c / q
    return 2


@njit(cache=True)
def _univariate(f01, f02, f12, poly, ws):
    """Degree-8 polynomial in s2 whose roots are the s2 of all solutions."""
    A01, B01, C01, D01, E01, F01 = f01[0], f01[1], f01[2], f01[3], f01[4], f01[5]
    A02, B02, C02, D02, E02, F02 = f02[0], f02[1], f02[2], f02[3], f02[4], f02[5]
    A12, B12, C12, D12, E12, F12 = f12[0], f12[1], f12[2], f12[3], f12[4], f12[5]
    # Resultant in s1 of f01 (quadratic in s1: a2, a1(s0), a0(s0)) and f12
    # (quadratic in s1: b2, b1(s2), b0(s2)):  g = u^2 - v w  with
    # u = a2 b0 - b2 a0, v = a2 b1 - b2 a1, w = a1 b0 - b1 a0.
    # Bivariate arrays are indexed [power of s0, power of s2].
    U = ws[0:9].reshape((3, 3))
    U[:, :] = 0.0
    U[0, 2] = B01 * B12
    U[0, 1] = B01 * E12
    U[0, 0] = B01 * F12 - A12 * F01
    U[2, 0] = -A12 * A01
    U[1, 0] = -A12 * D01
    V = ws[9:13].reshape((2, 2))
    V[:, :] = 0.0
    V[0, 1] = B01 * C12
    V[0, 0] = B01 * D12 - A12 * E01
    V[1, 0] = -A12 * C01
    W = ws[13:29].reshape((4, 4))
    W[:, :] = 0.0
    W[1, 2] += C01 * B12
    W[1, 1] += C01 * E12
    W[1, 0] += C01 * F12
    W[0, 2] += E01 * B12
    W[0, 1] += E01 * E12
    W[0, 0] += E01 * F12
    W[2, 1] -= C12 * A01
    W[1, 1] -= C12 * D01
    W[0, 1] -= C12 * F01
    W[2, 0] -= D12 * A01
    W[1, 0] -= D12 * D01
    W[0, 0] -= D12 * F01
    G = ws[29:54].reshape((5, 5))
    G[:, :] = 0.0
    for i in range(3):
        for j in range(3):
            if U[i, j] != 0.0:
                for k in range(3):
                    for m in range(3 - k):
                        G[i + k, j + m] += U[i, j] * U[k, m]
    for i in range(2):
        for j in range(2 - i):
            if V[i, j] != 0.0:
                for k in range(4):
                    for m in range(4 - k):
                        if i + k < 5 and j + m < 5:
                            G[i + k, j + m] -= V[i, j] * W[k, m]
    # Reduce g (quartic in s0) modulo f02 = A02 s0^2 + e1(s2) s0 + e0(s2).
    e1 = ws[54:56]
    e1[0] = D02
    e1[1] = C02
    e0 = ws[56:59]
    e0[0] = F02
    e0[1] = E02
    e0[2] = B02
    for i in range(4, 1, -1):
        for j in range(5 - i):
            cf = G[i, j] / A02
            if cf == 0.0:
                continue
            for m in range(2):
                if j + m < 5:
                    G[i - 1, j + m] -= cf * e1[m]
            for m in range(3):
                if j + m < 5:
                    G[i - 2, j + m] -= cf * e0[m]
            G[i, j] = 0.0
    # Resultant of f02 and the linear remainder r1 s0 + r0:
    # A02 r0^2 - e1 r0 r1 + e0 r1^2.
    for i in range(9):
        poly[i] = 0.0
    for i in range(5):
        for j in range(5):
            poly[i + j] += A02 * G[0, i] * G[0, j]
    for i in range(2):
        for j in range(5):
            for k in range(4):
                if i + j + k < 9:
                    poly[i + j + k] -= e1[i] * G[0, j] * G[1, k]
    for i in range(3):
        for j in range(4):
            for k in range(4):
                if i + j + k < 9:
                    poly[i + j + k] += e0[i] * G[1, j] * G[1, k]


@njit(cache=True)
def _newton_polish(f01, f02, f12, s, iters):
    """Newton on the three quadrics; returns the max relative residual."""
    for _ in range(iters):
        r0 = _feval(f01, s[0], s[1])
        r1 = _feval(f02, s[0], s[2])
        r2 = _feval(f12, s[1], s[2])
        j00 = 2 * f01[0] * s[0] + f01[2] * s[1] + f01[3]
        j01 = 2 * f01[1] * s[1] + f01[2] * s[0] + f01[4]
        j10 = 2 * f02[0] * s[0] + f02[2] * s[2] + f02[3]
        j12 = 2 * f02[1] * s[2] + f02[2] * s[0] + f02[4]
        j21 = 2 * f12[0] * s[1] + f12[2] * s[2] + f12[3]
        j22 = 2 * f12[1] * s[2] + f12[2] * s[1] + f12[4]
        # J = [[j00, j01, 0], [j10, 0, j12], [0, j21, j22]]
        det = j00 * (0.0 - j12 * j21) - j01 * (j10 * j22 - 0.0)
        if det == 0.0 or not np.isfinite(det):
            break
        # Cramer's rule for J d = r
        d0 = (r0 * (0.0 - j12 * j21) - j01 * (r1 * j22 - j12 * r2)) / det
        d1 = (j00 * (r1 * j22 - j12 * r2) - r0 * (j10 * j22)) / det
        d2 = (j00 * (0.0 - r1 * j21) - j01 * (j10 * r2) + r0 * (j10 * j21)) / det
        s[0] -= d0
        s[1] -= d1
        s[2] -= d2
        if abs(d0) + abs(d1) + abs(d2) <= 1e-15 * (abs(s[0]) + abs(s[1]) + abs(s[2])):
            break
    e0 = abs(_feval(f01, s[0], s[1])) / (_fscale(f01, s[0], s[1]) + 1e-300)
    e1 = abs(_feval(f02, s[0], s[2])) / (_fscale(f02, s[0], s[2]) + 1e-300)
    e2 = abs(_feval(f12, s[1], s[2])) / (_fscale(f12, s[1], s[2]) + 1e-300)
    return max(e0, max(e1, e2))


@njit(cache=True)
def _frame(P, F):
    """Orthonormal frame (columns of F) of the triangle whose vertices are the
    rows of P, built on its longest edge.  False if the triangle is degenerate."""
    best = -1.0
    ia = 0
    ib = 1
    for a in range(3):
        bb = (a + 1) % 3
        d = (P[a, 0] - P[bb, 0]) ** 2 + (P[a, 1] - P[bb, 1]) ** 2 + (P[a, 2] - P[bb, 2]) ** 2
        if d > best:
            best = d
            ia = a
            ib = bb
    ic = 3 - ia - ib
    ln = np.sqrt(best)
    if not ln > 0.0:
        return False
    ex = (P[ib, 0] - P[ia, 0]) / ln
    ey = (P[ib, 1] - P[ia, 1]) / ln
    ez = (P[ib, 2] - P[ia, 2]) / ln
    vx = P[ic, 0] - P[ia, 0]
    vy = P[ic, 1] - P[ia, 1]
    vz = P[ic, 2] - P[ia, 2]
    nx = ey * vz - ez * vy
    ny = ez * vx - ex * vz
    nz = ex * vy - ey * vx
    nn = np.sqrt(nx * nx + ny * ny + nz * nz)
    if nn <= 1e-10 * ln:
        return False
    nx /= nn
    ny /= nn
    nz /= nn
    F[0, 0] = ex
    F[1, 0] = ey
    F[2, 0] = ez
    F[0, 1] = ny * ez - nz * ey
    F[1, 1] = nz * ex - nx * ez
    F[2, 1] = nx * ey - ny * ex
    F[0, 2] = nx
    F[1, 2] = ny
    F[2, 2] = nz
    return True


@njit(cache=True)
def _absolute_orientation(Pp, Pq, Fp, Fq, R, t):
    """Rigid motion with Pq[i] = R Pp[i] + t for congruent triangles (the
    closed form Arun's SVD method reduces to when the data are exact)."""
    if not _frame(Pp, Fp) or not _frame(Pq, Fq):
        return False
    for i in range(3):
        for j in range(3):
            R[i, j] = Fq[i, 0] * Fp[j, 0] + Fq[i, 1] * Fp[j, 1] + Fq[i, 2] * Fp[j, 2]
    for i in range(3):
        cp0 = (Pp[0, 0] + Pp[1, 0] + Pp[2, 0]) / 3.0
        cp1 = (Pp[0, 1] + Pp[1, 1] + Pp[2, 1]) / 3.0
        cp2 = (Pp[0, 2] + Pp[1, 2] + Pp[2, 2]) / 3.0
        t[i] = (Pq[0, i] + Pq[1, i] + Pq[2, i]) / 3.0 - (R[i, 0] * cp0 + R[i, 1] * cp1 + R[i, 2] * cp2)
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


# Scratch layout of solve_minimal_ws (floats).
_WS_UNI = 0  # 59 for _univariate
_WS_ROOT = 64  # root finder
_WS_MAIN = _WS_ROOT + _ROOT_WORK
WORK_SIZE = _WS_MAIN + 256


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
    cameras along their rays) are returned.
    """
    n0 = 0
    for k in range(3):
        if side[k] == 0:
            n0 += 1
    if n0 == 0 or n0 == 3:
        return _p3p_mutual(n0 == 3, bearings, points, Rs, ts, ranges)
    # Canonical order: the target range (index 2) is the lone observation of
    # a mixed split, so the usual mounting's solution pairs stay apart.
    order = iws[0:3]
    order[0] = 0
    order[1] = 1
    order[2] = 2
    if n0 == 1 or n0 == 2:
        lone = 0 if n0 == 1 else 1
        j = 0
        for k in range(3):
            if side[k] == lone:
                order[2] = k
            else:
                order[j] = k
                j += 1
    sd = iws[3:6]
    o = _WS_MAIN
    b = ws[o : o + 9].reshape((3, 3))
    X = ws[o + 9 : o + 18].reshape((3, 3))
    for i in range(3):
        sd[i] = side[order[i]]
        nb = 0.0
        for j in range(3):
            nb += bearings[order[i], j] ** 2
        nb = np.sqrt(nb)
        if not nb > 0.0:
            return 0
        for j in range(3):
            b[i, j] = bearings[order[i], j] / nb
            X[i, j] = points[order[i], j]
    # Normalise lengths to the marker scale.
    L = 0.0
    for i in range(3):
        L = max(L, np.sqrt(X[i, 0] ** 2 + X[i, 1] ** 2 + X[i, 2] ** 2))
        for j in range(i + 1, 3):
            if sd[i] == sd[j]:
                d = np.sqrt((X[i, 0] - X[j, 0]) ** 2 + (X[i, 1] - X[j, 1]) ** 2 + (X[i, 2] - X[j, 2]) ** 2)
                L = max(L, d)
    if not L > 0.0 or not np.isfinite(L):
        return 0
    Xn = ws[o + 18 : o + 27].reshape((3, 3))
    for i in range(3):
        for j in range(3):
            Xn[i, j] = X[i, j] / L
    f01 = ws[o + 27 : o + 33]
    f02 = ws[o + 33 : o + 39]
    f12 = ws[o + 39 : o + 45]
    _pair_coeffs(sd, b, Xn, 0, 1, f01)
    _pair_coeffs(sd, b, Xn, 0, 2, f02)
    _pair_coeffs(sd, b, Xn, 1, 2, f12)
    poly = ws[o + 45 : o + 54]
    _univariate(f01, f02, f12, poly, ws[_WS_UNI:_WS_ROOT])
    cand = ws[o + 54 : o + 70]
    # Roots need only ~1e-9: Newton on the three quadrics polishes them.
    nr, nn = real_roots_ws(poly, 1e-12, _MAX_RANGE, cand, _NEAR_TOL, 1e-9, 1e-7, ws[_WS_ROOT:_WS_MAIN])
    sols = ws[o + 70 : o + 142].reshape((24, 3))
    nsol = 0
    q0 = ws[o + 142 : o + 144]
    q1 = ws[o + 144 : o + 146]
    s = ws[o + 146 : o + 149]
    tmp = ws[o + 149 : o + 161].reshape((4, 3))
    res = ws[o + 161 : o + 165]
    for ir in range(nr + nn):
        s2 = cand[ir]
        # s0 from f02 (quadratic in s0 given s2), s1 from f01 given s0; the
        # pair that best satisfies f12 is the common root.  No division by
        # a resultant coefficient, so merged projections cannot blow up.
        m0 = _quad_roots(f02[0], f02[2] * s2 + f02[3], f02[1] * s2 * s2 + f02[4] * s2 + f02[5], q0)
        best = np.inf
        ntmp = 0
        for i0 in range(m0):
            s0 = q0[i0]
            m1 = _quad_roots(f01[1], f01[2] * s0 + f01[4], f01[0] * s0 * s0 + f01[3] * s0 + f01[5], q1)
            for i1 in range(m1):
                s1 = q1[i1]
                r = abs(_feval(f12, s1, s2)) / (_fscale(f12, s1, s2) + 1e-300)
                tmp[ntmp, 0] = s0
                tmp[ntmp, 1] = s1
                tmp[ntmp, 2] = s2
                res[ntmp] = r
                ntmp += 1
                best = min(best, r)
        for i in range(ntmp):
            if res[i] > max(1e3 * best, 1e-6):
                continue
            s[0] = tmp[i, 0]
            s[1] = tmp[i, 1]
            s[2] = tmp[i, 2]
            err = _newton_polish(f01, f02, f12, s, 12)
            if err > _ACCEPT_TOL or s[0] <= 0.0 or s[1] <= 0.0 or s[2] <= 0.0:
                continue
            dup = False
            for j in range(nsol):
                if (
                    abs(sols[j, 0] - s[0]) + abs(sols[j, 1] - s[1]) + abs(sols[j, 2] - s[2])
                    <= 1e-7 * (s[0] + s[1] + s[2])
                ):
                    dup = True
                    break
            if not dup and nsol < 24:
                sols[nsol] = s
                nsol += 1
    # Poses from the three point pairs.
    Pp = ws[o + 165 : o + 174].reshape((3, 3))
    Pq = ws[o + 174 : o + 183].reshape((3, 3))
    Fp = ws[o + 183 : o + 192].reshape((3, 3))
    Fq = ws[o + 192 : o + 201].reshape((3, 3))
    nout = 0
    for j in range(nsol):
        if nout >= Rs.shape[0]:
            break
        for i in range(3):
            rng = sols[j, i] * L
            for j2 in range(3):
                if sd[i] == 0:
                    Pp[i, j2] = rng * b[i, j2]
                    Pq[i, j2] = X[i, j2]
                else:
                    Pp[i, j2] = X[i, j2]
                    Pq[i, j2] = rng * b[i, j2]
        if not _absolute_orientation(Pp, Pq, Fp, Fq, Rs[nout], ts[nout]):
            continue
        for i in range(3):
            ranges[nout, order[i]] = sols[j, i] * L
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
