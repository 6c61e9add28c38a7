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

NumPy only (no compilation): the team initialisation calls it when the
central pair solvers do not apply, a few times per team at most.
"""

from __future__ import annotations

import numpy as np

__all__ = ["generalized_p3p", "KIND_U_RAY", "KIND_W_RAY"]

#: A ray of the unknown frame U through a known point of W.
KIND_U_RAY = 0
#: A ray of the known frame W through a known point of U.
KIND_W_RAY = 1
_MAX_RANGE = 1e4
_RESIDUAL_TOL = 1e-8


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


def generalized_p3p(kinds, origins, directions, points) -> tuple[np.ndarray, np.ndarray]:
    """Every pose ``(R, t)`` (``x_W = R x_U + t``) fitting three
    correspondences exactly with positive ranges (module docstring).

    ``kinds`` (3,): :data:`KIND_U_RAY` or :data:`KIND_W_RAY`; ``origins``,
    ``directions`` (3, 3): each ray (in ``U`` for kind 0, in ``W`` for kind
    1; directions need not be unit); ``points`` (3, 3): the known point of
    each correspondence (in ``W`` for kind 0, in ``U`` for kind 1).  Returns
    ``Rs`` (m, 3, 3) and ``ts`` (m, 3), m <= 8, possibly zero.
    """
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
