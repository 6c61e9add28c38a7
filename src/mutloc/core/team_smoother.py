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
each robot's constant-velocity transition (the motion is independent per
robot: ``F`` is block diagonal).

Robots entering and leaving the state: a step from record ``k + 1`` back to
``k`` carries only the robots tracked at both on the same track (same
:attr:`~mutloc.core.team_filter.TeamSnapshot.serial`).  The smoothed state
of those at ``k + 1`` is the marginal of the smoothed joint state (a robot
that entered at ``k + 1`` did so independent of the others: leaving it out
is exact); a robot dropped (or started again) at ``k + 1`` is not informed
by what came after -- the records after its track ended say nothing of it
but through the others, which is what the gain over the others carries.
A robot's records before it entered are not smoothed (it has no state there).

Nothing here reads files or decides statuses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .filter import STATE_DIM, cv_transition
from .geometry import so3_exp, so3_log
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
        cv_transition(post.vel[x], dt, F)
        FP[STATE_DIM * n:STATE_DIM * (n + 1)] = F @ post.P[STATE_DIM * x:STATE_DIM * (x + 1)]
    Pp = prior.P[np.ix_(rows, rows)]
    G = np.linalg.solve(Pp, FP).T
    return _Gain(G, np.asarray(carried, np.int64),
                 np.array([nxt_post.position(post.tracked[x]) for x in carried], np.int64))


def _error(a: TeamSnapshot, ia: np.ndarray, b: TeamSnapshot, ib: np.ndarray) -> np.ndarray:
    """``a (-) b`` on the error state, over robots at positions ``ia`` of ``a`` and ``ib`` of ``b``."""
    out = np.empty((len(ia), STATE_DIM))
    for n, (x, y) in enumerate(zip(ia.tolist(), ib.tolist())):
        out[n, :3] = so3_log(a.R[x] @ b.R[y].T)
        out[n, 3:6] = a.t[x] - b.t[y]
        out[n, 6:] = a.vel[x] - b.vel[y]
    return out.ravel()


def team_rts_step(post: TeamSnapshot, prior: TeamSnapshot, smooth_next: TeamSnapshot,
                  gain: _Gain | None = None, nxt_post: TeamSnapshot | None = None) -> TeamSnapshot:
    """One backward RTS step: record ``k``'s smoothed state from its
    posterior ``post``, the prediction ``prior`` to record ``k + 1`` and
    ``smooth_next``, record ``k + 1``'s smoothed state (over the robots of
    its posterior ``nxt_post``, default ``smooth_next`` itself)."""
    g = gain if gain is not None else _gain(post, prior, nxt_post if nxt_post is not None else smooth_next)
    if g.G is None:
        return post
    d = _error(smooth_next, g.at_next, prior, g.at_post)
    e = (g.G @ d).reshape(-1, STATE_DIM)
    R, t, vel = post.R.copy(), post.t + e[:, 3:6], post.vel + e[:, 6:]
    for x in range(len(R)):
        R[x] = so3_exp(e[x, :3]) @ post.R[x]
    post_rows, next_rows = g.post, g.nxt
    D = smooth_next.P[np.ix_(next_rows, next_rows)] - prior.P[np.ix_(post_rows, post_rows)]
    P = post.P + g.G @ D @ g.G.T
    return TeamSnapshot(post.time, post.tracked, post.serial, R, t, vel, 0.5 * (P + P.T))


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

    def forget(self, k: int) -> None:
        """Drop the records before ``k``."""
        n = k - self.first
        if n <= 0:
            return
        del self._priors[:n], self._posts[:n]
        self.first = k
        for j in [j for j in self._gains if j < k]:
            del self._gains[j]
