"""Numba kernels of the team filter (:mod:`mutloc.core.team_filter`): its
prediction and its iterated update, written to touch only what they must.

- :func:`team_predict` moves every tracked robot by its constant velocity
  and propagates the joint covariance ``F P F^T + Q`` using the transition's
  structure (per robot ``F`` is the identity but for ``exp(w dt)`` and
  ``J_l dt`` in the rotation rows and ``dt I`` in the translation rows), in
  place, with no ``12k x 12k`` temporary.
- :func:`team_iekf` is the iterated EKF update on the pixel residuals of
  one set of observations (pixel mode, or ray mode with ``frames``: robots
  with several cameras, any lens, see :func:`mutloc.core.team.team_residuals_any`): the Jacobian only over the six pose columns of
  each robot involved, the innovation covariance from their block of ``P``,
  the state step through those columns of ``P``, and the posterior
  ``P - K S K^T`` as one symmetric low-rank update of rank ``min(2m, 6q)``
  (``m`` observations, ``q`` robots involved).
- :func:`team_ls_residual` is the residual of one update's observations
  fitted on their own (the detections' noise, whatever the prior).

The arithmetic is that of the NumPy formulation it replaces (same
linearisation points, iterations and stopping rule); only the order of
floating-point sums differs.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .filter import STATE_DIM, cv_transition
from .refine import so3_exp_left
from .team import team_residuals_any

__all__ = ["team_predict", "team_iekf", "team_ls_residual"]


@njit(cache=True)
def _rows_by_f(P, E, G, dt):
    """In place ``P <- F P`` for the block-diagonal transition whose block
    ``x`` is the identity but for rows ``0:3`` (``E[x]`` on columns ``0:3``,
    ``G[x]`` on ``6:9``) and rows ``3:6`` (``dt I`` on ``9:12``)."""
    tmp = np.empty(3)
    for x in range(E.shape[0]):
        o = STATE_DIM * x
        for c in range(P.shape[1]):
            for a in range(3):
                s = 0.0
                for b in range(3):
                    s += E[x, a, b] * P[o + b, c] + G[x, a, b] * P[o + 6 + b, c]
                tmp[a] = s
            for a in range(3):
                P[o + a, c] = tmp[a]
                P[o + 3 + a, c] += dt * P[o + 9 + a, c]


@njit(cache=True)
def team_predict(tracked, R, t, vel, P, dt, qa, ql):
    """In place: each tracked robot ``tracked[x]`` (state block ``x``)
    moved over ``dt`` by its velocity; ``P <- F P F^T + Q``, symmetrised."""
    k = tracked.shape[0]
    N = STATE_DIM * k
    E = np.empty((k, 3, 3))
    G = np.empty((k, 3, 3))
    phi = np.empty(3)
    Rn = np.empty((3, 3))
    F = np.empty((STATE_DIM, STATE_DIM))
    for x in range(k):
        i = tracked[x]
        for c in range(3):
            phi[c] = vel[i, c] * dt
        cv_transition(vel[i], dt, F)
        for a in range(3):
            for b in range(3):
                E[x, a, b] = F[a, b]
                G[x, a, b] = F[a, 6 + b]
        so3_exp_left(phi, R[i], Rn)
        R[i, :, :] = Rn
        for c in range(3):
            t[i, c] = t[i, c] + vel[i, 3 + c] * dt
    _rows_by_f(P, E, G, dt)  # F P
    _rows_by_f(P.T, E, G, dt)  # (F (F P)^T)^T = F P F^T, in place through the transposed view
    d3 = dt**3 / 3.0
    d2 = dt**2 / 2.0
    for x in range(k):
        o = STATE_DIM * x
        for a in range(6):
            q = qa if a < 3 else ql
            P[o + a, o + a] += q * d3
            P[o + a, o + a + 6] += q * d2
            P[o + a + 6, o + a] += q * d2
            P[o + a + 6, o + a + 6] += q * dt
    for r in range(N):
        for c in range(r + 1, N):
            v = 0.5 * (P[r, c] + P[c, r])
            P[r, c] = v
            P[c, r] = v


@njit(cache=True)
def _cholesky(A, L):
    """Lower ``L`` with ``L L^T = A``; False if ``A`` is not positive definite."""
    n = A.shape[0]
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return False
        d = np.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / d
        for i in range(j):
            L[i, j] = 0.0
    return True


@njit(cache=True)
def _forward(L, B):
    """In place ``B <- L^-1 B`` (``B``: n x cols)."""
    n = L.shape[0]
    for i in range(n):
        for k in range(i):
            f = L[i, k]
            if f != 0.0:
                for c in range(B.shape[1]):
                    B[i, c] -= f * B[k, c]
        d = 1.0 / L[i, i]
        for c in range(B.shape[1]):
            B[i, c] *= d


@njit(cache=True)
def _sparse_rows(cam, own, ref, slot, Ja, Jb, hv, hc):
    """The Jacobian's rows in sparse form: row ``2j + k`` is ``hv[row]`` on
    columns ``hc[row]`` -- the observer's six pose columns, then the
    owner's (zeros on column 0 for the reference, which has none)."""
    for j in range(cam.shape[0]):
        for side in range(2):
            i = cam[j] if side == 0 else own[j]
            for k in range(2):
                for a in range(6):
                    z = 6 * side + a
                    if i == ref:
                        hv[2 * j + k, z] = 0.0
                        hc[2 * j + k, z] = 0
                    else:
                        hv[2 * j + k, z] = Ja[j, k, a] if side == 0 else Jb[j, k, a]
                        hc[2 * j + k, z] = 6 * slot[i] + a


@njit(cache=True)
def _retract(i, o, e, R0, t0, Rs, ts):
    """Robot ``i``'s pose moved by the error state's entries ``o:o+6``."""
    so3_exp_left(e[o:o + 3], R0[i], Rs[i])
    for k in range(3):
        ts[i, k] = t0[i, k] + e[o + 3 + k]


@njit(cache=True)
def team_iekf(cam, own, pts, meas, wt, Ks, ds, frames, pos, ref, R0, t0, vel0, P0, s2, max_iter, Rs, ts, vel, P, res,
              H_lin, r_lin, innov_lin):
    """The iterated update with the observations given (all of tracked
    robots or the reference ``ref``; ``pos[i]``: robot ``i``'s state block
    or -1).  Writes the posterior robots' ``Rs``, ``ts``, ``vel``, ``P`` and
    each row's reprojection error at it (``res``, px).  Returns ``(ok,
    chi2)``; not ok when a marker is behind its camera or the innovation
    covariance is not positive definite.

    At the last linearisation it also writes the Jacobian ``H_lin`` (``2m x
    6q``: the pose columns of the ``q`` robots involved, in ascending robot
    index), the residuals ``r_lin`` and the innovation ``innov_lin`` (``-r +
    H e``) -- what the caller needs for the same gain's covariance under
    another noise and for the residual no pose explains."""
    m = cam.shape[0]
    n = R0.shape[0]
    N = P0.shape[0]
    # the robots involved (ascending index) and their pose columns in P
    slot = np.full(n, -1, np.int64)
    for j in range(m):
        if cam[j] != ref:
            slot[cam[j]] = 0
        if own[j] != ref:
            slot[own[j]] = 0
    q = 0
    for i in range(n):
        if slot[i] >= 0:
            slot[i] = q
            q += 1
    invol = np.empty(q, np.int64)
    for i in range(n):
        if slot[i] >= 0:
            invol[slot[i]] = i
    c = 6 * q
    cols = np.empty(c, np.int64)
    for x in range(q):
        for a in range(6):
            cols[6 * x + a] = STATE_DIM * pos[invol[x]] + a
    PHc = np.empty((N, c))
    for r in range(N):
        for a in range(c):
            PHc[r, a] = P0[r, cols[a]]
    Pcc = np.empty((c, c))
    for a in range(c):
        for b in range(c):
            Pcc[a, b] = PHc[cols[a], b]
    Rs[:, :, :] = R0
    ts[:, :] = t0
    e = np.zeros(N)
    e_new = np.empty(N)
    r = np.empty(2 * m)
    Ja = np.empty((m, 2, 6))
    Jb = np.empty((m, 2, 6))
    hv = np.empty((2 * m, 12))
    hc = np.empty((2 * m, 12), np.int64)
    HP = np.empty((2 * m, c))
    S = np.empty((2 * m, 2 * m))
    L = np.empty((2 * m, 2 * m))
    innov = np.empty((2 * m, 1))
    g = np.empty(c)
    chi2 = np.inf
    iters = max_iter if m >= 3 else 1
    for _ in range(iters):
        if not team_residuals_any(cam, own, pts, meas, wt, Ks, ds, frames, Rs, ts, r, Ja, Jb, np.bool_(True)):
            return False, chi2
        _sparse_rows(cam, own, ref, slot, Ja, Jb, hv, hc)
        HP[:, :] = 0.0  # H Pcc
        for row in range(2 * m):
            for z in range(12):
                h = hv[row, z]
                o = hc[row, z]
                for b in range(c):
                    HP[row, b] += h * Pcc[o, b]
        for col in range(2 * m):  # S = (H Pcc) H^T + s2 I, and the innovation -r + H e
            he = 0.0
            for a in range(2 * m):
                S[a, col] = 0.0
            for z in range(12):
                h = hv[col, z]
                o = hc[col, z]
                he += h * e[cols[o]]
                for row in range(2 * m):
                    S[row, col] += HP[row, o] * h
            innov[col, 0] = -r[col] + he
            innov_lin[col] = innov[col, 0]
            r_lin[col] = r[col]
        for a in range(2 * m):
            S[a, a] += s2
        for a in range(2 * m):
            for b in range(a):
                v = 0.5 * (S[a, b] + S[b, a])
                S[a, b] = v
                S[b, a] = v
        if not _cholesky(S, L):
            return False, chi2
        w = innov.copy()
        _forward(L, w)  # w = L^-1 innov; chi2 = |w|^2, y = L^-T w
        chi2 = 0.0
        for a in range(2 * m):
            chi2 += w[a, 0] * w[a, 0]
        for a in range(2 * m - 1, -1, -1):
            s = w[a, 0]
            for b in range(a + 1, 2 * m):
                s -= L[b, a] * w[b, 0]
            w[a, 0] = s / L[a, a]
        g[:] = 0.0  # H^T y
        for row in range(2 * m):
            for z in range(12):
                g[hc[row, z]] += hv[row, z] * w[row, 0]
        step = 0.0
        for row in range(N):
            s = 0.0
            for b in range(c):
                s += PHc[row, b] * g[b]
            e_new[row] = s
            d = abs(s - e[row])
            if d > step:
                step = d
        e[:] = e_new
        for x in range(q):  # the residuals see only the robots involved
            _retract(invol[x], STATE_DIM * pos[invol[x]], e, R0, t0, Rs, ts)
        if step < 1e-7:  # (rad, m, rad/s, m/s): far below any noise
            break
    vel[:, :] = vel0
    for i in range(n):  # the others move through their correlations; velocities all
        if pos[i] < 0:
            continue
        o = STATE_DIM * pos[i]
        if slot[i] < 0:
            _retract(i, o, e, R0, t0, Rs, ts)
        for k in range(6):
            vel[i, k] = vel0[i, k] + e[o + 6 + k]
    # Posterior with the last linearisation: P0 - K S K^T = P0 - W W^T, of
    # rank min(2m, c): W = P0[:, cols] H^T L^-T, or P0[:, cols] (H^T S^-1 H)
    # P0[cols, :] when fewer columns than rows.
    B = np.zeros((2 * m, c))  # H, dense
    for row in range(2 * m):
        for z in range(12):
            B[row, hc[row, z]] += hv[row, z]
    H_lin[:, :] = B
    _forward(L, B)  # B = L^-1 H (2m x c)
    if 2 * m <= c:
        Wl = PHc @ B.T  # (N, 2m)
        Wr = Wl
    else:
        Wl = PHc @ (B.T @ B)  # B^T B = H^T S^-1 H (c x c)
        Wr = PHc
    # the upper triangle of Wl Wr^T, by row blocks (symmetric: the rest is not needed)
    WW = np.empty((N, N))
    step = max(64, (N + 3) // 4)
    for s0 in range(0, N, step):
        s1 = min(N, s0 + step)
        WW[s0:s1, s0:] = Wl[s0:s1] @ Wr[s0:].T
    for a in range(N):
        for b in range(a, N):
            v = 0.5 * (P0[a, b] + P0[b, a]) - WW[a, b]
            P[a, b] = v
            P[b, a] = v
    if not team_residuals_any(cam, own, pts, meas, wt, Ks, ds, frames, Rs, ts, r, Ja, Jb, np.bool_(False)):
        return False, chi2
    for j in range(m):
        res[j] = np.hypot(r[2 * j], r[2 * j + 1])
    return True, chi2


@njit(cache=True)
def team_ls_residual(H, r, blocks):
    """The squared residual (px^2) of observations fitted on their own and
    its degrees of freedom: ``|r|^2`` less its part in the span of the
    Jacobian ``H`` (``2m`` rows, six pose columns per robot involved; row
    ``2j + k`` touches only observation ``j``'s ``blocks[j]``: its
    observer's and marker owner's column blocks, -1 for the reference),
    ``2m - 6q`` degrees of freedom for the ``q`` robots the observations
    fix.  A robot in three observations or fewer fits them exactly whatever
    the others' poses (six rows or fewer, six unknowns): it and its
    observations are left out, which changes neither the residual nor its
    degrees of freedom.  Returns ``(chi2, dof)``; ``(nan, 0)`` with no
    degree of freedom or singular normal equations."""
    m = blocks.shape[0]
    q = H.shape[1] // 6
    keep = np.ones(m, np.bool_)
    weak = np.zeros(q, np.bool_)
    count = np.empty(q, np.int64)
    while True:
        count[:] = 0
        for j in range(m):
            if keep[j]:
                for s in range(2):
                    if blocks[j, s] >= 0 and not (s == 1 and blocks[j, 1] == blocks[j, 0]):
                        count[blocks[j, s]] += 1
        changed = False
        for x in range(q):
            if not weak[x] and count[x] <= 3:
                weak[x] = True
                changed = True
        if not changed:
            break
        for j in range(m):
            for s in range(2):
                if blocks[j, s] >= 0 and weak[blocks[j, s]]:
                    keep[j] = False
    cmap = np.full(q, -1, np.int64)
    k = 0
    for x in range(q):
        if not weak[x]:
            cmap[x] = k
            k += 1
    c = 6 * k
    n_rows = 0
    for j in range(m):
        if keep[j]:
            n_rows += 2
    dof = n_rows - c
    if dof <= 0:
        return np.nan, 0
    N = np.zeros((c, c))
    g = np.zeros((c, 1))
    rr = 0.0
    for j in range(m):
        if not keep[j]:
            continue
        blocks_j1 = -1 if blocks[j, 1] == blocks[j, 0] else blocks[j, 1]  # its own marker: one block
        for i in range(2):
            row = 2 * j + i
            ri = r[row]
            rr += ri * ri
            for s in range(2):
                b = blocks[j, 0] if s == 0 else blocks_j1
                if b < 0:
                    continue
                for a in range(6):
                    h = H[row, 6 * b + a]
                    ia = 6 * cmap[b] + a
                    g[ia, 0] += h * ri
                    for s2 in range(2):
                        b2 = blocks[j, 0] if s2 == 0 else blocks_j1
                        if b2 < 0:
                            continue
                        for a2 in range(6):
                            N[ia, 6 * cmap[b2] + a2] += h * H[row, 6 * b2 + a2]
    d = np.empty(c)
    for a in range(c):
        if not N[a, a] > 0.0:
            return np.nan, 0
        d[a] = np.sqrt(N[a, a])
    for a in range(c):
        g[a, 0] /= d[a]
        for b in range(c):
            N[a, b] /= d[a] * d[b]
    L = np.empty((c, c))
    if not _cholesky(N, L):
        return np.nan, 0
    _forward(L, g)  # g = L^-1 D^-1 H^T r: |g|^2 is the part of |r|^2 the poses explain
    for a in range(c):
        rr -= g[a, 0] * g[a, 0]
    return max(rr, 0.0), dof
