"""The two-way reprojection objective, its Levenberg-Marquardt minimiser on
SE(3), and the pose covariance.

Objective (paper, eq. proboptimization): the sum over both cameras of the
squared distance between each observed marker and the projection of that
marker under the pose.  Residuals are either pixels (through each camera's
``K`` and OpenCV distortion, the maximum-likelihood objective for Gaussian
detection noise), or, for ``solve_bearings``, the gnomonic tangent-plane error
around each observed ray (radians to first order), which fits any central
camera model, or (``MODE_RAY``: robots with several cameras, any lens) that
tangent-plane error around rays leaving their own origins in the robot
frames, each row's two tangent directions scaled by its lens's Jacobian at the
observed pixel so that the residual is the pixel error to first order (see
:mod:`mutloc.core.rays`).

Parameters: a rotation vector applied on the *left* of ``R`` and a
translation increment, ``R <- exp(dtheta) R``, ``t <- t + dt`` (SPEC), so the
covariance ``sigma^2 (J^T J)^-1`` is directly in the published convention.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .camera import intrinsics, project_jac_scalar, project_scalar

#: Scratch floats :func:`residuals` needs.
WS_SIZE = 29
MODE_PIXEL = 0
MODE_BEARING = 1
#: Rays from several centres: ``basis[i]`` (4, 3) holds the row's weighted
#: tangent directions (two rows), its ray direction and its origin, in the
#: observing robot's frame.
MODE_RAY = 2


@njit(cache=True)
def tangent_bases(bearings, basis):
    """For each unit bearing b write rows (e1, e2, b) with e1, e2 spanning b's
    orthogonal complement."""
    for i in range(bearings.shape[0]):
        bx, by, bz = bearings[i, 0], bearings[i, 1], bearings[i, 2]
        nb = np.sqrt(bx * bx + by * by + bz * bz)
        bx /= nb
        by /= nb
        bz /= nb
        # Cross with the axis least aligned with b.
        if abs(bx) <= abs(by) and abs(bx) <= abs(bz):
            ax, ay, az = 1.0, 0.0, 0.0
        elif abs(by) <= abs(bz):
            ax, ay, az = 0.0, 1.0, 0.0
        else:
            ax, ay, az = 0.0, 0.0, 1.0
        e1x = by * az - bz * ay
        e1y = bz * ax - bx * az
        e1z = bx * ay - by * ax
        n1 = np.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
        e1x /= n1
        e1y /= n1
        e1z /= n1
        basis[i, 0, 0] = e1x
        basis[i, 0, 1] = e1y
        basis[i, 0, 2] = e1z
        basis[i, 1, 0] = by * e1z - bz * e1y
        basis[i, 1, 1] = bz * e1x - bx * e1z
        basis[i, 1, 2] = bx * e1y - by * e1x
        basis[i, 2, 0] = bx
        basis[i, 2, 1] = by
        basis[i, 2, 2] = bz


@njit(cache=True)
def residuals(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, R, t, r, J, want_jac, ws):
    """Residuals (2N,) and optionally their Jacobian (2N, 6) at (R, t);
    ``ws`` is scratch of at least :data:`WS_SIZE` floats (reused across
    calls: candidate ranking calls this thousands of times).

    Returns False when a marker falls behind the camera observing it.
    """
    Jp = ws[5:11].reshape((2, 3))
    dX = ws[11:29].reshape((3, 6))
    # The cameras as scalars, read once: the loop below then calls no
    # compiled function with array arguments (each costs reference counting).
    cp = intrinsics(Kp, dp)
    cq = intrinsics(Kq, dq)
    n = side.shape[0]
    for i in range(n):
        if side[i] == 0:
            # p sees q's marker Q: X = R^T (Q - t).
            d0 = pts[i, 0] - t[0]
            d1 = pts[i, 1] - t[1]
            d2 = pts[i, 2] - t[2]
            X0 = R[0, 0] * d0 + R[1, 0] * d1 + R[2, 0] * d2
            X1 = R[0, 1] * d0 + R[1, 1] * d1 + R[2, 1] * d2
            X2 = R[0, 2] * d0 + R[1, 2] * d1 + R[2, 2] * d2
            if want_jac:
                # dX/dtheta = R^T [Q - t]x,  dX/dt = -R^T
                for a in range(3):
                    c0 = R[0, a]
                    c1 = R[1, a]
                    c2 = R[2, a]
                    # row a of R^T times skew(d)
                    dX[a, 0] = c1 * d2 - c2 * d1
                    dX[a, 1] = c2 * d0 - c0 * d2
                    dX[a, 2] = c0 * d1 - c1 * d0
                    dX[a, 3] = -c0
                    dX[a, 4] = -c1
                    dX[a, 5] = -c2
            cam = cp
        else:
            # q sees p's marker P: X = R P + t.
            X0 = R[0, 0] * pts[i, 0] + R[0, 1] * pts[i, 1] + R[0, 2] * pts[i, 2] + t[0]
            X1 = R[1, 0] * pts[i, 0] + R[1, 1] * pts[i, 1] + R[1, 2] * pts[i, 2] + t[1]
            X2 = R[2, 0] * pts[i, 0] + R[2, 1] * pts[i, 1] + R[2, 2] * pts[i, 2] + t[2]
            if want_jac:
                # dX/dtheta = -[R P]x, dX/dt = I
                y0 = X0 - t[0]
                y1 = X1 - t[1]
                y2 = X2 - t[2]
                dX[0, 0] = 0.0
                dX[0, 1] = y2
                dX[0, 2] = -y1
                dX[1, 0] = -y2
                dX[1, 1] = 0.0
                dX[1, 2] = y0
                dX[2, 0] = y1
                dX[2, 1] = -y0
                dX[2, 2] = 0.0
                for a in range(3):
                    for c in range(3):
                        dX[a, 3 + c] = 1.0 if a == c else 0.0
            cam = cq
        if mode == MODE_RAY:
            # The ray leaves its own camera's centre, not the robot's origin.
            X0 -= basis[i, 3, 0]
            X1 -= basis[i, 3, 1]
            X2 -= basis[i, 3, 2]
        if mode == MODE_PIXEL:
            if want_jac:
                ok, u, v, Jp[0, 0], Jp[0, 1], Jp[0, 2], Jp[1, 0], Jp[1, 1], Jp[1, 2] = project_jac_scalar(
                    cam, X0, X1, X2)
            else:
                ok, u, v = project_scalar(cam, X0, X1, X2)
            if not ok:
                return False
            r[2 * i] = u - meas[i, 0]
            r[2 * i + 1] = v - meas[i, 1]
        else:
            den = basis[i, 2, 0] * X0 + basis[i, 2, 1] * X1 + basis[i, 2, 2] * X2
            # (a point at the observer's centre, or a right angle off its ray: no residual)
            if not den > 1e-150:
                return False
            for k in range(2):
                num = basis[i, k, 0] * X0 + basis[i, k, 1] * X1 + basis[i, k, 2] * X2
                r[2 * i + k] = num / den
                for a in range(3):
                    Jp[k, a] = (basis[i, k, a] * den - num * basis[i, 2, a]) / (den * den)
        # Each observation's rows in units of its own noise (``wt``: pixel_sigma over its sigma).
        w = wt[i]
        if w != 1.0:
            r[2 * i] *= w
            r[2 * i + 1] *= w
            for k in range(2):
                for a in range(3):
                    Jp[k, a] *= w
        if want_jac:
            for k in range(2):
                for c in range(6):
                    J[2 * i + k, c] = Jp[k, 0] * dX[0, c] + Jp[k, 1] * dX[1, c] + Jp[k, 2] * dX[2, c]
    return True


@njit(cache=True)
def cost_into(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, R, t, r, J, ws):
    """Sum of squared residuals with caller-provided buffers (see :func:`residuals`)."""
    # np.bool_, not a literal False/True: Numba compiles a callee once more for each literal argument
    if not residuals(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, R, t, r, J, np.bool_(False), ws):
        return np.inf
    c = 0.0
    for k in range(r.shape[0]):
        c += r[k] * r[k]
    return c


@njit(cache=True)
def cost(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, R, t):
    """Sum of squared residuals; inf if a marker is behind its observer."""
    n = side.shape[0]
    r = np.empty(2 * n)
    J = np.empty((1, 6))
    return cost_into(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, R, t, r, J, np.empty(WS_SIZE))


@njit(cache=True)
def so3_exp_left(w, R, out):
    """out = exp([w]x) @ R (Rodrigues, written out: no BLAS for 3x3)."""
    th2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    th = np.sqrt(th2)
    if th < 1e-8:
        a = 1.0
        b = 0.5
    else:
        a = np.sin(th) / th
        b = (1.0 - np.cos(th)) / th2
    x, y, z = w[0], w[1], w[2]
    e00 = 1.0 - b * (y * y + z * z)
    e11 = 1.0 - b * (x * x + z * z)
    e22 = 1.0 - b * (x * x + y * y)
    e01 = -a * z + b * x * y
    e10 = a * z + b * x * y
    e02 = a * y + b * x * z
    e20 = -a * y + b * x * z
    e12 = -a * x + b * y * z
    e21 = a * x + b * y * z
    for j in range(3):
        r0 = R[0, j]
        r1 = R[1, j]
        r2 = R[2, j]
        out[0, j] = e00 * r0 + e01 * r1 + e02 * r2
        out[1, j] = e10 * r0 + e11 * r1 + e12 * r2
        out[2, j] = e20 * r0 + e21 * r1 + e22 * r2



@njit(cache=True)
def cholesky(A, L):
    """Lower Cholesky factor of a small SPD ``A`` into ``L``; False if ``A``
    is not positive definite."""
    n = A.shape[0]
    for i in range(n):
        for j in range(i + 1):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if not s > 0.0:
                    return False
                L[i, i] = np.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
        for j in range(i + 1, n):
            L[i, j] = 0.0
    return True


@njit(cache=True)
def solve_spd(A, b, x):
    """Cholesky solve of a small symmetric positive definite system."""
    n = A.shape[0]
    L = np.empty((n, n))
    if not cholesky(A, L):
        return False
    cho_solve(L, b, x)
    return True


@njit(cache=True)
def cho_solve(L, b, x):
    """Solve ``(L L^T) x = b`` given the lower Cholesky factor ``L`` (``x`` may not alias ``b``)."""
    n = L.shape[0]
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * x[k]
        x[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]


@njit(cache=True)
def normal_equations(J, r, H, g):
    """H = J^T J and g = J^T r without a BLAS call (tiny matrices)."""
    m = J.shape[0]
    for a in range(6):
        g[a] = 0.0
        for b in range(a + 1):
            H[a, b] = 0.0
    # Row by row: the 27 sums are independent, so they proceed side by side
    # instead of one dependent chain after another (same order of additions
    # per entry, same result).
    for k in range(m):
        rk = r[k]
        for a in range(6):
            ja = J[k, a]
            g[a] += ja * rk
            for b in range(a + 1):
                H[a, b] += ja * J[k, b]
    for a in range(6):
        for b in range(a):
            H[b, a] = H[a, b]


@njit(cache=True)
def lm_refine(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, R, t, max_iter, H=None):
    """Levenberg-Marquardt on SE(3) from (R, t), updated in place; ``H``
    (6, 6), if given, receives J^T J at the returned pose (what
    :func:`information` computes) when the cost is finite.

    Returns (final cost, iterations used).
    """
    if H is None:
        H = np.empty((6, 6))
    n = side.shape[0]
    r = np.empty(2 * n)
    J = np.empty((2 * n, 6))
    g = np.empty(6)
    A = np.empty((6, 6))
    L = np.empty((6, 6))
    delta = np.empty(6)
    Rn = np.empty((3, 3))
    tn = np.empty(3)
    r2 = np.empty(2 * n)
    J2 = np.empty((2 * n, 6))
    ws = np.empty(WS_SIZE)
    if not residuals(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, R, t, r, J, np.bool_(True), ws):
        return np.inf, 0
    c = 0.0
    for k in range(2 * n):
        c += r[k] * r[k]
    lam = 1e-4
    it = 0
    fresh = False  # whether H is J^T J at the current pose
    for it in range(1, max_iter + 1):
        normal_equations(J, r, H, g)
        fresh = True
        improved = False
        small = False
        scale = 1.0 + np.sqrt(t[0] ** 2 + t[1] ** 2 + t[2] ** 2)
        for _ in range(12):
            A[:, :] = H
            for k in range(6):
                A[k, k] += lam * (H[k, k] + 1e-12)
            if not cholesky(A, L):
                lam *= 10.0
                continue
            # delta = -(A^-1 g): negation is exact, so this is A^-1 (-g).
            cho_solve(L, g, delta)
            for k in range(6):
                delta[k] = -delta[k]
            step = 0.0
            for k in range(3):
                step += delta[k] ** 2 + (delta[3 + k] / scale) ** 2
            # Near the optimum a Gauss-Newton step this small changes
            # nothing measurable: stop instead of probing lambda upwards.
            if np.sqrt(step) < 1e-10:
                small = True
                break
            so3_exp_left(delta[:3], R, Rn)
            for k in range(3):
                tn[k] = t[k] + delta[3 + k]
            # The trial point's Jacobian comes with its residuals: a step is
            # accepted far more often than not, and then it is the next one's.
            cn = np.inf
            if residuals(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, Rn, tn, r2, J2, np.bool_(True), ws):
                cn = 0.0
                for k in range(2 * n):
                    cn += r2[k] * r2[k]
            if cn <= c:
                R[:, :] = Rn
                t[:] = tn
                r, r2 = r2, r
                J, J2 = J2, J
                fresh = False
                dc = c - cn
                c = cn
                lam = max(lam * 0.1, 1e-12)
                improved = True
                small = np.sqrt(step) < 1e-9 or dc <= 1e-14 * c
                break
            if np.sqrt(step) < 1e-8:
                # A step this small that does not lower the cost is rounding
                # at the optimum, not a sign that more damping is needed.
                small = True
                break
            lam *= 10.0
        if not improved or small:
            break
    if not fresh:
        normal_equations(J, r, H, g)
    return c, it


@njit(cache=True)
def information(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, R, t, H):
    """J^T J (6x6) at (R, t) into H; False if a marker is behind a camera."""
    n = side.shape[0]
    r = np.empty(2 * n)
    J = np.empty((2 * n, 6))
    if not residuals(side, pts, meas, basis, Kp, dp, Kq, dq, mode, wt, R, t, r, J, np.bool_(True), np.empty(WS_SIZE)):
        return False
    g = np.empty(6)
    normal_equations(J, r, H, g)
    return True
