"""Perspective-three-point (P3P) pose, Lambda Twist style, as a Numba kernel.

Method (Persson & Nordberg, "Lambda Twist: An Accurate Fast Robust
Perspective Three Point (P3P) Solver", ECCV 2018), written from the paper's
description:

* With unit bearings ``y_i``, depths ``lambda_i`` and object distances
  ``a_ij = |x_i - x_j|^2`` the three constraints are
  ``lambda_i^2 + lambda_j^2 - 2 b_ij lambda_i lambda_j = a_ij`` with
  ``b_ij = y_i . y_j``, i.e. ``Lambda^T M_ij Lambda = a_ij``.
* Eliminating the ``a``'s gives two homogeneous conics
  ``D1 = a23 M12 - a12 M23`` and ``D2 = a23 M13 - a13 M23``; every member
  ``D1 + gamma D2`` of their pencil passes through the solutions.
* A real root ``gamma`` of the cubic ``det(D1 + gamma D2) = 0`` makes
  ``D0 = D1 + gamma D2`` a degenerate conic: a pair of planes through the
  origin.  Intersecting each plane with ``D1`` or ``D2`` is a homogeneous
  quadratic in two unknowns, whose roots fix the direction of ``Lambda``;
  the scale follows from the distance equations.
* The depths are then polished by Newton's method on the three original
  equations, written as ``(l_i - l_j)^2 + 2 c_ij l_i l_j = a_ij`` with
  ``c_ij = 1 - b_ij = |y_i - y_j|^2 / 2``: every term is then of the size of
  ``a_ij`` instead of ``lambda^2``, which is what keeps the far, small
  triangle case accurate.
* The pose maps the object triangle frame ``[x1-x2, x1-x3, (x1-x2)x(x1-x3)]``
  onto the same frame built from the camera points ``lambda_i y_i``.

Deviations from the paper, for robustness:

* the correspondences are relabelled so that the pivot side ``a23`` is the
  longest (a short pivot makes ``D1`` and ``D2`` nearly proportional);
* the cubic is solved in closed form in ``gamma`` or ``1/gamma`` (whichever
  keeps the leading coefficient dominant) and polished by Newton; with three
  real roots the one whose plane pair is best separated is used;
* the plane pair and the per-plane quadratics are both found as zero
  directions of 2x2 symmetric forms (no division by a coefficient that may
  vanish); discriminants within rounding of zero count as double roots and
  are left for the final Newton step to split;
* the final Newton step stops on its step length, not the residual, which
  is unreliable when the rays are nearly coplanar (ill-conditioned Jacobian).

``R`` is built from the refined depths without re-orthonormalisation; it is
orthonormal to rounding (measured <= 2e-12) because the depths are.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["p3p_kernel", "p3p"]

_NEWTON_ITERS = 8
# Relative residual of the distance equations above which a polished
# candidate is not a solution (a complex pair that rounding made look real).
_RESIDUAL_TOL = 1e-7
# Discriminants down to -_DISC_TOL (relative) are rounding noise of a double root.
_DISC_TOL = 1e-10


@njit(cache=True, error_model="numpy")
def _d2(a0, a1, a2, b0, b1, b2):
    """Squared distance between two 3-vectors."""
    d0 = a0 - b0
    d1 = a1 - b1
    d2 = a2 - b2
    return d0 * d0 + d1 * d1 + d2 * d2


@njit(cache=True, error_model="numpy")
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True, error_model="numpy")
def _cof(m00, m01, m02, m11, m12, m22):
    """Cofactors (adjugate) of a symmetric 3x3 matrix, in the same 6-entry order."""
    return (
        m11 * m22 - m12 * m12,
        m02 * m12 - m01 * m22,
        m01 * m12 - m02 * m11,
        m00 * m22 - m02 * m02,
        m01 * m02 - m00 * m12,
        m00 * m11 - m01 * m01,
    )


@njit(cache=True, error_model="numpy")
def _quad(m00, m01, m02, m11, m12, m22, u0, u1, u2, v0, v1, v2):
    """u^T M v for symmetric M."""
    return (
        u0 * (m00 * v0 + m01 * v1 + m02 * v2)
        + u1 * (m01 * v0 + m11 * v1 + m12 * v2)
        + u2 * (m02 * v0 + m12 * v1 + m22 * v2)
    )


@njit(cache=True, error_model="numpy")
def _cubic_roots(b, c, d):
    """Real roots of x^3 + b x^2 + c x + d, each polished by Newton.

    Returns (n, r0, r1, r2).  Closed form is only the starting point: the
    Newton polish against the undepressed cubic removes the cancellation of
    the depressed form.
    """
    b3 = b / 3.0
    p = c - b * b3
    q = (2.0 * b3 * b3 - c) * b3 + d
    hq = 0.5 * q
    tp = p / 3.0
    disc = hq * hq + tp * tp * tp
    n = 1
    r0 = r1 = r2 = 0.0
    if disc > 0.0:
        s = math.sqrt(disc)
        # Same signs in -hq - sign(q) s: no cancellation.
        u = np.cbrt(-hq - s if hq >= 0.0 else -hq + s)
        r0 = (u - tp / u if u != 0.0 else 0.0) - b3
    elif tp < 0.0:
        r = math.sqrt(-tp)
        ca = -hq / (r * r * r)
        ca = min(1.0, max(-1.0, ca))
        phi = math.acos(ca) / 3.0
        r0 = 2.0 * r * math.cos(phi) - b3
        r1 = 2.0 * r * math.cos(phi - 2.0943951023931957) - b3
        r2 = 2.0 * r * math.cos(phi + 2.0943951023931957) - b3
        n = 3
    else:
        r0 = -b3
    for k in range(n):
        x = r0 if k == 0 else (r1 if k == 1 else r2)
        for _ in range(2):
            f = ((x + b) * x + c) * x + d
            df = (3.0 * x + 2.0 * b) * x + c
            if df == 0.0:
                break
            x -= f / df
        if k == 0:
            r0 = x
        elif k == 1:
            r1 = x
        else:
            r2 = x
    return n, r0, r1, r2


@njit(cache=True, error_model="numpy")
def _zero_dirs(p, r, s):
    """Unit directions (a, b) with p a^2 + 2 r a b + s b^2 = 0.

    Returns (n, a1, b1, a2, b2) with n in {0, 1, 2}.  Solved through the
    eigen-decomposition of [[p, r], [r, s]]: the zero directions are
    sqrt(-mu_min) f_max +- sqrt(mu_max) f_min, free of divisions by a
    leading coefficient that may vanish.
    """
    h = 0.5 * (p - s)
    mean = 0.5 * (p + s)
    rad = math.sqrt(h * h + r * r)
    scale = abs(p) + abs(s) + 2.0 * abs(r)
    if not (scale > 0.0):
        return 0, 0.0, 0.0, 0.0, 0.0
    disc = r * r - p * s  # = -mu_max * mu_min
    if disc < 0.0:
        if disc < -_DISC_TOL * scale * scale:
            return 0, 0.0, 0.0, 0.0, 0.0
        disc = 0.0
    big = mean + rad if mean >= 0.0 else mean - rad
    small = -disc / big if big != 0.0 else 0.0
    mu_max = max(big, small)
    mu_min = min(big, small)
    # Eigenvector of mu_max: the better-conditioned of two equivalent forms.
    e0, e1 = h + rad, r
    g0, g1 = r, rad - h
    if e0 * e0 + e1 * e1 < g0 * g0 + g1 * g1:
        e0, e1 = g0, g1
    ne = math.sqrt(e0 * e0 + e1 * e1)
    if ne == 0.0:
        e0, e1 = 1.0, 0.0
    else:
        e0 /= ne
        e1 /= ne
    wa = math.sqrt(max(-mu_min, 0.0))
    wb = math.sqrt(max(mu_max, 0.0))
    # f_min = (-e1, e0)
    a1 = wa * e0 - wb * e1
    b1 = wa * e1 + wb * e0
    a2 = wa * e0 + wb * e1
    b2 = wa * e1 - wb * e0
    n1 = math.sqrt(a1 * a1 + b1 * b1)
    if not (n1 > 0.0):
        return 0, 0.0, 0.0, 0.0, 0.0
    if wb <= 1e-8 * wa or wa <= 1e-8 * wb:
        # Double root (or a vanishing eigenvalue): one direction only.
        return 1, a1 / n1, b1 / n1, 0.0, 0.0
    n2 = math.sqrt(a2 * a2 + b2 * b2)
    return 2, a1 / n1, b1 / n1, a2 / n2, b2 / n2


@njit(cache=True, error_model="numpy")
def _residuals(l1, l2, l3, c12, c13, c23, a12, a13, a23):
    d12 = l1 - l2
    d13 = l1 - l3
    d23 = l2 - l3
    return (
        d12 * d12 + 2.0 * c12 * l1 * l2 - a12,
        d13 * d13 + 2.0 * c13 * l1 * l3 - a13,
        d23 * d23 + 2.0 * c23 * l2 * l3 - a23,
    )


@njit(cache=True, error_model="numpy")
def _newton(l1, l2, l3, c12, c13, c23, a12, a13, a23):
    """Newton on the three distance equations.

    Returns (l1, l2, l3, max relative residual).  Termination is on the
    step, not the residual: when the rays are nearly coplanar the Jacobian
    is ill-conditioned, a full step may raise a 1e-12 residual before it
    collapses, and a tiny residual can still hide a 1e-5 depth error.
    """
    prev = np.inf
    for _ in range(_NEWTON_ITERS):
        f1, f2, f3 = _residuals(l1, l2, l3, c12, c13, c23, a12, a13, a23)
        d12 = l1 - l2
        d13 = l1 - l3
        d23 = l2 - l3
        # d f_ij / d l_i = 2 (l_i - l_j) + 2 c_ij l_j, and symmetrically.
        j11 = 2.0 * (d12 + c12 * l2)
        j12 = 2.0 * (-d12 + c12 * l1)
        j21 = 2.0 * (d13 + c13 * l3)
        j23 = 2.0 * (-d13 + c13 * l1)
        j32 = 2.0 * (d23 + c23 * l3)
        j33 = 2.0 * (-d23 + c23 * l2)
        # J = [[j11, j12, 0], [j21, 0, j23], [0, j32, j33]], solved by its adjugate.
        det = -j11 * j23 * j32 - j12 * j21 * j33
        if det == 0.0 or det != det:
            break
        k1 = (-j23 * j32 * f1 - j12 * j33 * f2 + j12 * j23 * f3) / det
        k2 = (-j21 * j33 * f1 + j11 * j33 * f2 - j11 * j23 * f3) / det
        k3 = (j21 * j32 * f1 - j11 * j32 * f2 - j12 * j21 * f3) / det
        step = max(abs(k1), abs(k2), abs(k3))
        if not (step < prev):
            break  # at the rounding floor (or diverging): keep the last iterate
        l1 -= k1
        l2 -= k2
        l3 -= k3
        if step <= 1e-15 * max(abs(l1), abs(l2), abs(l3)):
            break
        prev = step
    f1, f2, f3 = _residuals(l1, l2, l3, c12, c13, c23, a12, a13, a23)
    return l1, l2, l3, max(abs(f1) / a12, abs(f2) / a13, abs(f3) / a23)


# error_model="numpy": a division by zero must give inf/NaN (caught by the
# checks), never raise from inside a hot loop.
@njit(cache=True, error_model="numpy")
def p3p_kernel(bearings: np.ndarray, points: np.ndarray, Rs: np.ndarray, ts: np.ndarray) -> int:
    """All P3P poses ``X_cam = R @ X_obj + t`` with positive depths.

    bearings: (3, 3) rays in the camera frame (rows; normalised here);
    points: (3, 3) object points (rows).  Writes up to four solutions into
    ``Rs`` (>= 4, 3, 3) and ``ts`` (>= 4, 3) and returns their number.
    Degenerate or non-finite input returns 0.  No heap allocation.
    """
    # --- input, normalisation and degeneracy checks -------------------------
    tot = 0.0
    for i in range(3):
        for j in range(3):
            tot += bearings[i, j] + points[i, j]
    if tot - tot != 0.0:  # NaN or inf anywhere
        return 0
    # Relabel so that the pair (2, 3) is the farthest apart: D1 and D2 below
    # both contain -a_1j M23 terms, and a short pivot side a23 would make them
    # nearly proportional (a degenerate pencil, most digits lost).
    e01 = _d2(points[0, 0], points[0, 1], points[0, 2], points[1, 0], points[1, 1], points[1, 2])
    e02 = _d2(points[0, 0], points[0, 1], points[0, 2], points[2, 0], points[2, 1], points[2, 2])
    e12 = _d2(points[1, 0], points[1, 1], points[1, 2], points[2, 0], points[2, 1], points[2, 2])
    if e12 >= e01 and e12 >= e02:
        i1, i2, i3 = 0, 1, 2
    elif e02 >= e01:
        i1, i2, i3 = 1, 2, 0
    else:
        i1, i2, i3 = 2, 0, 1
    n1 = math.sqrt(_d2(bearings[i1, 0], bearings[i1, 1], bearings[i1, 2], 0.0, 0.0, 0.0))
    n2 = math.sqrt(_d2(bearings[i2, 0], bearings[i2, 1], bearings[i2, 2], 0.0, 0.0, 0.0))
    n3 = math.sqrt(_d2(bearings[i3, 0], bearings[i3, 1], bearings[i3, 2], 0.0, 0.0, 0.0))
    if not (n1 > 0.0 and n2 > 0.0 and n3 > 0.0):
        return 0
    y10, y11, y12 = bearings[i1, 0] / n1, bearings[i1, 1] / n1, bearings[i1, 2] / n1
    y20, y21, y22 = bearings[i2, 0] / n2, bearings[i2, 1] / n2, bearings[i2, 2] / n2
    y30, y31, y32 = bearings[i3, 0] / n3, bearings[i3, 1] / n3, bearings[i3, 2] / n3

    # c_ij = 1 - cos(angle) from the chord: exact even for nearly parallel rays.
    c12 = 0.5 * _d2(y10, y11, y12, y20, y21, y22)
    c13 = 0.5 * _d2(y10, y11, y12, y30, y31, y32)
    c23 = 0.5 * _d2(y20, y21, y22, y30, y31, y32)
    if not (c12 > 1e-18 and c13 > 1e-18 and c23 > 1e-18):
        return 0  # coincident rays

    x10, x11, x12 = points[i1, 0], points[i1, 1], points[i1, 2]
    x20, x21, x22 = points[i2, 0], points[i2, 1], points[i2, 2]
    x30, x31, x32 = points[i3, 0], points[i3, 1], points[i3, 2]
    u0, u1, u2 = x10 - x20, x11 - x21, x12 - x22  # x1 - x2
    v0, v1, v2 = x10 - x30, x11 - x31, x12 - x32  # x1 - x3
    w0, w1, w2 = x20 - x30, x21 - x31, x22 - x32  # x2 - x3
    a12 = u0 * u0 + u1 * u1 + u2 * u2
    a13 = v0 * v0 + v1 * v1 + v2 * v2
    a23 = w0 * w0 + w1 * w1 + w2 * w2
    m0, m1, m2 = _cross(u0, u1, u2, v0, v1, v2)
    area2 = m0 * m0 + m1 * m1 + m2 * m2  # = det of [u, v, u x v]
    if not (area2 > 1e-20 * a12 * a13 and a12 > 0.0 and a13 > 0.0 and a23 > 0.0):
        return 0  # collinear or coincident points

    # Dimensionless distances keep the cubic well scaled whatever the units.
    abar = (a12 + a13 + a23) / 3.0
    s12 = a12 / abar
    s13 = a13 / abar
    s23 = a23 / abar
    b12 = 1.0 - c12
    b13 = 1.0 - c13
    b23 = 1.0 - c23

    # --- the two eliminated conics (symmetric, 6 entries: 00 01 02 11 12 22) --
    p00, p01, p02, p11, p12, p22 = s23, -s23 * b12, 0.0, s23 - s12, s12 * b23, -s12
    q00, q01, q02, q11, q12, q22 = s23, 0.0, -s23 * b13, -s13, s13 * b23, s23 - s13

    # det(D1 + g D2) = det D1 + g tr(adj D1 D2) + g^2 tr(adj D2 D1) + g^3 det D2
    P0, P1, P2, P3, P4, P5 = _cof(p00, p01, p02, p11, p12, p22)
    Q0, Q1, Q2, Q3, Q4, Q5 = _cof(q00, q01, q02, q11, q12, q22)
    k0 = p00 * P0 + p01 * P1 + p02 * P2
    k3 = q00 * Q0 + q01 * Q1 + q02 * Q2
    k1 = P0 * q00 + P3 * q11 + P5 * q22 + 2.0 * (P1 * q01 + P2 * q02 + P4 * q12)
    k2 = Q0 * p00 + Q3 * p11 + Q5 * p22 + 2.0 * (Q1 * p01 + Q2 * p02 + Q4 * p12)

    # Roots as (alpha, beta) with D0 = alpha D1 + beta D2, solved in the
    # variable that keeps the leading coefficient the larger one.
    inv = abs(k0) > abs(k3)
    if inv:
        nr, r0, r1, r2 = _cubic_roots(k1 / k0, k2 / k0, k3 / k0)  # nu = 1/gamma
    elif k3 != 0.0:
        nr, r0, r1, r2 = _cubic_roots(k2 / k3, k1 / k3, k0 / k3)
    else:
        nr, r0, r1, r2 = 1, 0.0, 0.0, 0.0  # det D1 = det D2 = 0: D1 is degenerate

    # Pick the root whose plane pair is best separated: q = sin^2(angle)/4.
    best_q = -np.inf
    al = 1.0
    be = 0.0
    for k in range(nr):
        r = r0 if k == 0 else (r1 if k == 1 else r2)
        ka, kb = (r, 1.0) if inv else (1.0, r)
        e00 = ka * p00 + kb * q00
        e01 = ka * p01 + kb * q01
        e02 = ka * p02 + kb * q02
        e11 = ka * p11 + kb * q11
        e12 = ka * p12 + kb * q12
        e22 = ka * p22 + kb * q22
        C0, C1, C2, C3, C4, C5 = _cof(e00, e01, e02, e11, e12, e22)
        mm = C0 + C3 + C5
        tr = e00 + e11 + e22
        den = tr * tr - 4.0 * mm
        qq = -mm / den if den > 0.0 else -np.inf
        if qq > best_q or k == 0:
            best_q = qq
            al, be = ka, kb
    d00 = al * p00 + be * q00
    d01 = al * p01 + be * q01
    d02 = al * p02 + be * q02
    d11 = al * p11 + be * q11
    d12 = al * p12 + be * q12
    d22 = al * p22 + be * q22
    # Restrict to the planes the pencil member farther from D0 (less cancellation).
    if abs(al) >= abs(be):
        f00, f01, f02, f11, f12, f22 = q00, q01, q02, q11, q12, q22
    else:
        f00, f01, f02, f11, f12, f22 = p00, p01, p02, p11, p12, p22

    # --- null vector of D0: the line shared by both planes -----------------
    ca0, ca1, ca2 = _cross(d00, d01, d02, d01, d11, d12)
    cb0, cb1, cb2 = _cross(d00, d01, d02, d02, d12, d22)
    cc0, cc1, cc2 = _cross(d01, d11, d12, d02, d12, d22)
    na = ca0 * ca0 + ca1 * ca1 + ca2 * ca2
    nb = cb0 * cb0 + cb1 * cb1 + cb2 * cb2
    nc = cc0 * cc0 + cc1 * cc1 + cc2 * cc2
    if nb > na and nb >= nc:
        ca0, ca1, ca2, na = cb0, cb1, cb2, nb
    elif nc > na:
        ca0, ca1, ca2, na = cc0, cc1, cc2, nc
    if not (na > 0.0):
        return 0
    nn = math.sqrt(na)
    z0, z1, z2 = ca0 / nn, ca1 / nn, ca2 / nn
    # Orthonormal basis (g, h) of the plane orthogonal to z.
    if abs(z0) <= abs(z1) and abs(z0) <= abs(z2):
        g0, g1, g2 = 0.0, z2, -z1
    elif abs(z1) <= abs(z2):
        g0, g1, g2 = -z2, 0.0, z0
    else:
        g0, g1, g2 = z1, -z0, 0.0
    ng = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
    g0, g1, g2 = g0 / ng, g1 / ng, g2 / ng
    h0, h1, h2 = _cross(z0, z1, z2, g0, g1, g2)
    # D0 restricted to z-perp: its zero directions span the planes with z.
    npl, pa1, pb1, pa2, pb2 = _zero_dirs(
        _quad(d00, d01, d02, d11, d12, d22, g0, g1, g2, g0, g1, g2),
        _quad(d00, d01, d02, d11, d12, d22, g0, g1, g2, h0, h1, h2),
        _quad(d00, d01, d02, d11, d12, d22, h0, h1, h2, h0, h1, h2),
    )

    # --- pose frame of the object triangle: inverse of [u, v, u x v] -------
    # Rows of the inverse: (v x m, m x u, u x v) / |m|^2.
    iA0, iA1, iA2 = _cross(v0, v1, v2, m0, m1, m2)
    iB0, iB1, iB2 = _cross(m0, m1, m2, u0, u1, u2)
    inv_det = 1.0 / area2
    iA0 *= inv_det
    iA1 *= inv_det
    iA2 *= inv_det
    iB0 *= inv_det
    iB1 *= inv_det
    iB2 *= inv_det
    iC0, iC1, iC2 = m0 * inv_det, m1 * inv_det, m2 * inv_det
    xc0 = (x10 + x20 + x30) / 3.0
    xc1 = (x11 + x21 + x31) / 3.0
    xc2 = (x12 + x22 + x32) / 3.0

    sum_a = s12 + s13 + s23
    lscale = math.sqrt(abar)
    count = 0
    for ip in range(npl):
        wa, wb = (pa1, pb1) if ip == 0 else (pa2, pb2)
        # In-plane direction orthogonal to z; the plane is span{z, w}.
        w0_ = wa * g0 + wb * h0
        w1_ = wa * g1 + wb * h1
        w2_ = wa * g2 + wb * h2
        nd, ea1, eb1, ea2, eb2 = _zero_dirs(
            _quad(f00, f01, f02, f11, f12, f22, z0, z1, z2, z0, z1, z2),
            _quad(f00, f01, f02, f11, f12, f22, z0, z1, z2, w0_, w1_, w2_),
            _quad(f00, f01, f02, f11, f12, f22, w0_, w1_, w2_, w0_, w1_, w2_),
        )
        for idir in range(nd):
            ea, eb = (ea1, eb1) if idir == 0 else (ea2, eb2)
            L1 = ea * z0 + eb * w0_
            L2 = ea * z1 + eb * w1_
            L3 = ea * z2 + eb * w2_
            # Scale from the sum of the three (dimensionless) distance equations.
            S = (
                (L1 - L2) * (L1 - L2)
                + (L1 - L3) * (L1 - L3)
                + (L2 - L3) * (L2 - L3)
                + 2.0 * (c12 * L1 * L2 + c13 * L1 * L3 + c23 * L2 * L3)
            )
            if not (S > 0.0):
                continue
            sc = math.sqrt(sum_a / S)
            if L1 + L2 + L3 < 0.0:
                sc = -sc
            l1, l2, l3, err = _newton(L1 * sc, L2 * sc, L3 * sc, c12, c13, c23, s12, s13, s23)
            if not (l1 > 0.0 and l2 > 0.0 and l3 > 0.0 and err < _RESIDUAL_TOL):
                continue
            l1 *= lscale
            l2 *= lscale
            l3 *= lscale
            Y10, Y11, Y12 = l1 * y10, l1 * y11, l1 * y12
            Y20, Y21, Y22 = l2 * y20, l2 * y21, l2 * y22
            Y30, Y31, Y32 = l3 * y30, l3 * y31, l3 * y32
            e0, e1, e2 = Y10 - Y20, Y11 - Y21, Y12 - Y22
            f0, f1, f2 = Y10 - Y30, Y11 - Y31, Y12 - Y32
            k0_, k1_, k2_ = _cross(e0, e1, e2, f0, f1, f2)
            # R = [e, f, e x f] [u, v, u x v]^-1
            R00 = e0 * iA0 + f0 * iB0 + k0_ * iC0
            R01 = e0 * iA1 + f0 * iB1 + k0_ * iC1
            R02 = e0 * iA2 + f0 * iB2 + k0_ * iC2
            R10 = e1 * iA0 + f1 * iB0 + k1_ * iC0
            R11 = e1 * iA1 + f1 * iB1 + k1_ * iC1
            R12 = e1 * iA2 + f1 * iB2 + k1_ * iC2
            R20 = e2 * iA0 + f2 * iB0 + k2_ * iC0
            R21 = e2 * iA1 + f2 * iB1 + k2_ * iC1
            R22 = e2 * iA2 + f2 * iB2 + k2_ * iC2
            t0 = (Y10 + Y20 + Y30) / 3.0 - (R00 * xc0 + R01 * xc1 + R02 * xc2)
            t1 = (Y11 + Y21 + Y31) / 3.0 - (R10 * xc0 + R11 * xc1 + R12 * xc2)
            t2 = (Y12 + Y22 + Y32) / 3.0 - (R20 * xc0 + R21 * xc1 + R22 * xc2)
            # A point on the line shared by both planes, or both halves of a
            # split double root, can reach the same solution twice.
            dup = False
            for k in range(count):
                dd = abs(ts[k, 0] - t0) + abs(ts[k, 1] - t1) + abs(ts[k, 2] - t2)
                dd += abs(Rs[k, 0, 0] - R00) + abs(Rs[k, 1, 1] - R11) + abs(Rs[k, 2, 2] - R22)
                dd += abs(Rs[k, 0, 1] - R01) + abs(Rs[k, 1, 2] - R12) + abs(Rs[k, 2, 0] - R20)
                if dd <= 1e-12 * (lscale + abs(t0) + abs(t1) + abs(t2)):
                    dup = True
            if dup:
                continue
            Rs[count, 0, 0] = R00
            Rs[count, 0, 1] = R01
            Rs[count, 0, 2] = R02
            Rs[count, 1, 0] = R10
            Rs[count, 1, 1] = R11
            Rs[count, 1, 2] = R12
            Rs[count, 2, 0] = R20
            Rs[count, 2, 1] = R21
            Rs[count, 2, 2] = R22
            ts[count, 0] = t0
            ts[count, 1] = t1
            ts[count, 2] = t2
            count += 1
    return count


def p3p(bearings: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All P3P poses for three bearings (rows, camera frame) and three object
    points (rows): ``R`` (k, 3, 3) and ``t`` (k, 3) with ``X_cam = R X_obj + t``."""
    b = np.ascontiguousarray(bearings, dtype=np.float64).reshape(3, 3)
    x = np.ascontiguousarray(points, dtype=np.float64).reshape(3, 3)
    Rs = np.empty((4, 3, 3))
    ts = np.empty((4, 3))
    n = p3p_kernel(b, x, Rs, ts)
    return Rs[:n].copy(), ts[:n].copy()
