"""Fixed-lag Rauch-Tung-Striebel smoothing of the joint team filter
(:class:`mutloc.core.team_filter.TeamFilter`).

The filter's state after each record (its posterior) and its prediction to
the record (before any robot entered or left the state there) are kept as
:class:`~mutloc.core.team_filter.TeamSnapshot`; each record's smoothed
state comes from the records after it by the RTS recursion over the joint
state (all tracked robots' poses and velocities with their correlations):

    G_k = P_k F_k' (P_k+1^-)^-1,    x_k^s = x_k (+) G_k (x_k+1^s (-) x_k+1^-),
    P_k^s = P_k + G_k (P_k+1^s - P_k+1^-) G_k'

on the error state (SPEC perturbations: ``R <- exp(dtheta) R``), ``F_k``
each robot's constant-velocity transition, or the prediction's own where
odometry moved it (:attr:`~mutloc.core.team_filter.TeamSnapshot.F`; block
diagonal either way: one block per robot).

Robots entering and leaving the state: a step from record ``k + 1`` back to
``k`` carries only the robots tracked at both on the same track (same
:attr:`~mutloc.core.team_filter.TeamSnapshot.serial`).  The smoothed state
of those at ``k + 1`` is the marginal of the smoothed joint state (a robot
that entered at ``k + 1`` did so independent of the others: leaving it out
is exact); a robot dropped (or started again) at ``k + 1`` is not informed
by what came after -- the records after its track ended say nothing of it
but through the others, which is what the gain over the others carries.
A robot's records before it entered are not smoothed (it has no state there).

Where the filter's gain weighed measured detection noise below the stated
(:attr:`~mutloc.core.team_filter.TeamSnapshot.Pg`), the gains and the
recursion use the filter's own covariances, and the reported covariance is
the smaller (by the trace of the pose blocks) of two bounds of the stated
one: the filter's, and the smoothed own one times ``noise_scale``.

Nothing here reads files or decides statuses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from .filter import STATE_DIM, cv_transition
from .refine import so3_exp_left
from .team_filter import TeamSnapshot

__all__ = ["TeamSmoother", "team_rts_step"]


@dataclass(frozen=True)
class _Gain:
    """One backward step's gain ``G`` and the robots it carries: their
    places in record ``k``'s state (and in the prediction to ``k + 1``:
    the same) and in record ``k + 1``'s posterior."""

    G: np.ndarray | None
    at_post: np.ndarray
    at_next: np.ndarray

    @property
    def post(self) -> np.ndarray:
        return _rows(self.at_post)

    @property
    def nxt(self) -> np.ndarray:
        return _rows(self.at_next)


def _rows(positions) -> np.ndarray:
    return (STATE_DIM * np.asarray(positions, np.int64)[:, None] + np.arange(STATE_DIM)).ravel()


def _gain(post: TeamSnapshot, prior: TeamSnapshot, nxt_post: TeamSnapshot) -> _Gain:
    """The RTS gain from record ``k`` (``post``) to ``k + 1`` (``prior``: the
    prediction to it, ``nxt_post``: its posterior, whose robots decide which
    tracks carry on)."""
    carried = [x for x, (i, s) in enumerate(zip(post.tracked, post.serial))
               if nxt_post.position(i) >= 0 and nxt_post.serial[nxt_post.position(i)] == s
               and prior.position(i) == x]
    if not carried:
        return _Gain(None, np.empty(0, np.int64), np.empty(0, np.int64))
    rows = _rows(carried)
    dt = prior.time - post.time
    F = np.empty((STATE_DIM, STATE_DIM))
    # Cov(x_k, x_k+1^-) = P_k[:, C] F_C' with F block diagonal: F_C P_k[C, :] block by block.
    FP = np.empty((len(rows), post.P.shape[0]))
    for n, x in enumerate(carried):
        if prior.F is not None:  # odometry moved the prediction: its own transition
            F = prior.F[x]
        else:
            cv_transition(post.vel[x], dt, F)
        FP[STATE_DIM * n:STATE_DIM * (n + 1)] = F @ post.own[STATE_DIM * x:STATE_DIM * (x + 1)]
    Pp = prior.own[np.ix_(rows, rows)]
    G = np.linalg.solve(Pp, FP).T
    return _Gain(G, np.asarray(carried, np.int64),
                 np.array([nxt_post.position(post.tracked[x]) for x in carried], np.int64))


@njit(cache=True)
def _so3_log(M, out):
    """``out`` = the rotation vector of ``M`` (as :func:`mutloc.core.geometry.so3_log`)."""
    c = min(max((M[0, 0] + M[1, 1] + M[2, 2] - 1.0) / 2.0, -1.0), 1.0)
    v0, v1, v2 = M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]
    s = 0.5 * np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
    th = np.arctan2(s, c)
    if th < 1e-6:
        f = 0.5 * (1.0 + th * th / 6.0)
        out[0], out[1], out[2] = f * v0, f * v1, f * v2
        return
    if th < np.pi - 1e-3:
        f = th / (2.0 * np.sin(th))
        out[0], out[1], out[2] = f * v0, f * v1, f * v2
        return
    # Near pi the antisymmetric part vanishes: read the axis off R + R^T.
    B = 0.5 * (M + M.T)
    for i in range(3):
        B[i, i] -= c
    k = 0
    for i in range(1, 3):
        if B[i, i] > B[k, k]:
            k = i
    a = B[:, k] / np.sqrt(max(B[k, k], 1e-300))
    a = a / np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    if a[0] * v0 + a[1] * v1 + a[2] * v2 < 0.0:
        a = -a
    out[0], out[1], out[2] = th * a[0], th * a[1], th * a[2]


@njit(cache=True)
def _smoothed_mean(G, at_post, at_next, Rp, tp, vp, Rq, tq, vq, Rn, tn, vn, R_out, t_out, v_out):
    """The RTS step's mean: ``x_k (+) G (x_k+1^s (-) x_k+1^-)`` (``p``: record
    ``k``'s posterior, ``q``: the prediction to ``k + 1``, ``n``: ``k + 1``
    smoothed; ``at_post``/``at_next``: the carried robots' places)."""
    m = at_post.shape[0]
    d = np.empty(STATE_DIM * m)
    M = np.empty((3, 3))
    r = np.empty(3)
    for n in range(m):
        x, y = at_post[n], at_next[n]
        for i in range(3):
            for j in range(3):
                M[i, j] = Rn[y, i, 0] * Rq[x, j, 0] + Rn[y, i, 1] * Rq[x, j, 1] + Rn[y, i, 2] * Rq[x, j, 2]
        _so3_log(M, r)
        o = STATE_DIM * n
        for i in range(3):
            d[o + i] = r[i]
            d[o + 3 + i] = tn[y, i] - tq[x, i]
        for i in range(6):
            d[o + 6 + i] = vn[y, i] - vq[x, i]
    e = G @ d
    w = np.empty(3)
    for x in range(Rp.shape[0]):
        o = STATE_DIM * x
        for i in range(3):
            w[i] = e[o + i]
            t_out[x, i] = tp[x, i] + e[o + 3 + i]
        for i in range(6):
            v_out[x, i] = vp[x, i] + e[o + 6 + i]
        so3_exp_left(w, Rp[x], R_out[x])


def team_rts_step(post: TeamSnapshot, prior: TeamSnapshot, smooth_next: TeamSnapshot,
                  gain: _Gain | None = None, nxt_post: TeamSnapshot | None = None) -> TeamSnapshot:
    """One backward RTS step: record ``k``'s smoothed state from its
    posterior ``post``, the prediction ``prior`` to record ``k + 1`` and
    ``smooth_next``, record ``k + 1``'s smoothed state (over the robots of
    its posterior ``nxt_post``, default ``smooth_next`` itself)."""
    g = gain if gain is not None else _gain(post, prior, nxt_post if nxt_post is not None else smooth_next)
    if g.G is None:
        return post
    R, t, vel = np.empty_like(post.R), np.empty_like(post.t), np.empty_like(post.vel)
    _smoothed_mean(g.G, g.at_post, g.at_next, post.R, post.t, post.vel, prior.R, prior.t, prior.vel,
                   smooth_next.R, smooth_next.t, smooth_next.vel, R, t, vel)
    k = len(post.tracked)
    if len(g.at_post) == k == len(smooth_next.tracked) and (g.at_post == g.at_next).all() \
            and (g.at_post == np.arange(k)).all():
        D = smooth_next.own - prior.own  # every robot carried, in the same order (the common case)
    else:
        post_rows, next_rows = g.post, g.nxt
        D = smooth_next.own[np.ix_(next_rows, next_rows)] - prior.own[np.ix_(post_rows, post_rows)]
    Pg = post.own + (g.G @ D) @ g.G.T
    if post.Pg is None and prior.Pg is None and smooth_next.Pg is None:
        P, Pg = Pg, None
    else:
        Pg = 0.5 * (Pg + Pg.T)
        scaled = post.noise_scale * Pg
        pose = (np.arange(len(Pg)) % STATE_DIM) < 6
        P = scaled if np.diag(scaled)[pose].sum() < np.diag(post.P)[pose].sum() else post.P
    return TeamSnapshot(post.time, post.tracked, post.serial, R, t, vel, 0.5 * (P + P.T), Pg, post.noise_scale)


class TeamSmoother:
    """The last records' predictions and posteriors, and each record's
    fixed-lag smoothed state: :meth:`add` one record (its prediction before
    any robot entered or left, its posterior after), :meth:`smoothed` ``k``
    from the records ``k .. k + lag`` (fewer at the end of the input),
    :meth:`forget` records before ``k``.  Record numbers count every
    :meth:`add`; the gains are computed once (they depend on the filter alone)."""

    def __init__(self, lag: int) -> None:
        self.lag = int(lag)
        self.first = 0  #: number of the oldest record kept
        self._priors: list[TeamSnapshot] = []
        self._posts: list[TeamSnapshot] = []
        self._gains: dict[int, _Gain] = {}

    def __len__(self) -> int:
        return self.first + len(self._posts)

    def add(self, prior: TeamSnapshot, post: TeamSnapshot) -> None:
        self._priors.append(prior)
        self._posts.append(post)

    def posterior(self, k: int) -> TeamSnapshot:
        return self._posts[k - self.first]

    def smoothed(self, k: int) -> TeamSnapshot:
        """Record ``k``'s state smoothed by the ``lag`` records after it (those there are)."""
        end = min(len(self), k + self.lag + 1)
        s = self.posterior(end - 1)
        for j in range(end - 2, k - 1, -1):
            g = self._gains.get(j)
            if g is None:
                g = self._gains[j] = _gain(self.posterior(j), self._priors[j + 1 - self.first], self.posterior(j + 1))
            s = team_rts_step(self.posterior(j), self._priors[j + 1 - self.first], s, g)
        return s

    def truncate(self, k: int) -> None:
        """Drop record ``k`` and those after it (to filter them again)."""
        n = max(k - self.first, 0)
        del self._priors[n:], self._posts[n:]
        for j in [j for j in self._gains if j >= k - 1]:
            del self._gains[j]

    def forget(self, k: int) -> None:
        """Drop the records before ``k``."""
        n = k - self.first
        if n <= 0:
            return
        del self._priors[:n], self._posts[:n]
        self.first = k
        for j in [j for j in self._gains if j < k]:
            del self._gains[j]
