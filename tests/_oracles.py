"""Independent references for the tests: small, plain NumPy, written for the
tests and sharing no code with the library's filter (only the SO(3)
exponential and logarithm of mutloc.core.geometry, tested on their own).

- :func:`cv_transition`: the constant-velocity model's error-state
  transition (12x12) over ``dt``;
- :func:`rts_smooth`: the Rauch-Tung-Striebel smoother of one robot's track
  on SE(3) (error state ``(dtheta, dt, dw, dv)``, ``R <- exp(dtheta) R``,
  ``t <- t + dt``), with the rule for a filter whose gain weighed measured
  noise below the stated one (the gains from the filter's own covariances;
  the reported covariance the smaller, by the trace of its pose block, of the
  filter's and the smoothed own one times ``noise_scale``);
- :func:`kb_project`: the Kannala-Brandt (OpenCV fisheye) projection, any
  angle off the axis, written from its formula.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mutloc.core.geometry import so3_exp, so3_log

DIM = 12


def _left_jacobian(phi: np.ndarray) -> np.ndarray:
    """SO(3) left Jacobian, ``sum_k [phi]x^k / (k+1)!`` summed as a series (no closed form)."""
    X = np.array([[0.0, -phi[2], phi[1]], [phi[2], 0.0, -phi[0]], [-phi[1], phi[0], 0.0]])
    out, term = np.eye(3), np.eye(3)
    for k in range(1, 30):
        term = term @ X / (k + 1)
        out = out + term
    return out


def cv_transition(vel: np.ndarray, dt: float) -> np.ndarray:
    """``d(error after dt) / d(error before)`` for ``R <- exp(w dt) R``, ``t <- t + v dt``."""
    F = np.eye(DIM)
    phi = np.asarray(vel[:3], float) * dt
    F[:3, :3] = so3_exp(phi)
    F[:3, 6:9] = _left_jacobian(phi) * dt
    F[3:6, 9:12] = dt * np.eye(3)
    return F


@dataclass
class State:
    """One robot's filter state: pose, velocity, 12x12 covariance under the
    stated noise, and (``Pg``) the filter's own where it differs, with
    ``noise_scale`` = (stated / measured noise)^2."""

    time: float
    R: np.ndarray
    t: np.ndarray
    vel: np.ndarray
    P: np.ndarray
    Pg: np.ndarray | None = None
    noise_scale: float = 1.0

    @property
    def own(self) -> np.ndarray:
        return self.P if self.Pg is None else self.Pg


def rts_smooth(priors: list[State], posts: list[State]) -> list[State]:
    """``priors[k]``: the prediction to record k (``priors[0]`` unused);
    ``posts[k]``: the state after record k.  Returns the smoothed states."""
    out = [posts[-1]] * len(posts)
    for k in range(len(posts) - 2, -1, -1):
        post, prior, nxt = posts[k], priors[k + 1], out[k + 1]
        F = cv_transition(post.vel, prior.time - post.time)
        G = post.own @ F.T @ np.linalg.inv(prior.own)
        d = np.r_[so3_log(nxt.R @ prior.R.T), nxt.t - prior.t, nxt.vel - prior.vel]
        e = G @ d
        Pg = post.own + G @ (nxt.own - prior.own) @ G.T
        if post.Pg is None and prior.Pg is None and nxt.Pg is None:
            P, Pg = Pg, None
        else:
            Pg = 0.5 * (Pg + Pg.T)
            scaled = post.noise_scale * Pg
            P = scaled if np.trace(scaled[:6, :6]) < np.trace(post.P[:6, :6]) else post.P
        out[k] = State(post.time, so3_exp(e[:3]) @ post.R, post.t + e[3:6], post.vel + e[6:], 0.5 * (P + P.T), Pg,
                       post.noise_scale)
    return out


def kb_project(K: np.ndarray, k: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Kannala-Brandt (OpenCV fisheye) projection of camera-frame points (n, 3), any angle off the axis."""
    X = np.atleast_2d(np.asarray(X, float))
    r = np.hypot(X[:, 0], X[:, 1])
    th = np.arctan2(r, X[:, 2])
    thd = th * (1 + k[0] * th**2 + k[1] * th**4 + k[2] * th**6 + k[3] * th**8)
    s = np.where(r > 0, thd / np.where(r > 0, r, 1.0), 0.0)
    return np.stack([K[0, 0] * s * X[:, 0] + K[0, 2], K[1, 1] * s * X[:, 1] + K[1, 2]], axis=1)
