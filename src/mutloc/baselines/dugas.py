"""Closed-form relative pose for two lights beside each camera.

The setting of Dugas, Giguere and Rekleitis (ISRR 2013) and Giguere et al.
(IROS 2012): each robot carries two lights placed symmetrically about its
camera's optical centre, ``c +- h e``; each camera measures the bearings of
the other robot's two lights.  This is our derivation for that geometry (not
their code):

1. The direction to the other camera is the bisector of the two light
   bearings (exact when the light pair is seen square-on; the error is of
   order ``h / r`` times the obliquity).
2. The angle ``alpha`` a light pair of half-length ``h`` subtends at a
   viewer at range ``r`` and angle ``psi`` from the pair's axis obeys
   ``cos alpha = (r^2 - h^2) / sqrt((r^2 + h^2)^2 - 4 h^2 r^2 cos^2 psi)``, a
   quadratic in ``r^2``; ``psi`` is known from the *other* camera's bisector.
   Each camera gives one range; their mean is used.
3. With the ranges, each light's distance follows, so the other robot's
   light axis is known in the viewer's frame; the rotation is the
   least-squares (SVD) fit of three direction pairs: the baseline seen from
   both ends and both light axes.
4. Steps 1-3 are repeated with the exact midpoint directions from the ranges
   of step 3 (``corrections`` times), removing the bisector's bias.
"""

from __future__ import annotations

import numpy as np

from ..core.pose import Pose
from ..errors import DegenerateGeometryError, InputError, NoSolutionError

__all__ = ["dugas_pose", "subtended_range"]


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v)
    if not n > 0:
        raise DegenerateGeometryError("a zero-length direction in the closed form")
    return v / n


def subtended_range(cos_alpha: float, h: float, cos_psi: float) -> float:
    """Range ``r`` of a viewer that sees a light pair of half-length ``h``
    under the angle ``alpha``, at angle ``psi`` from the pair's axis."""
    c2 = cos_alpha * cos_alpha
    a = 1.0 - c2
    if not a > 1e-15 or cos_alpha <= 0:
        raise NoSolutionError("the two lights subtend no angle (or more than 90 degrees): range unobservable")
    b = 2.0 * h * h * (1.0 + c2 * (1.0 - 2.0 * cos_psi * cos_psi))
    disc = b * b - 4.0 * a * a * h ** 4
    if disc < 0:
        disc = 0.0
    return float(np.sqrt((b + np.sqrt(disc)) / (2.0 * a)))


def _check(lights: np.ndarray, who: str) -> tuple[float, np.ndarray]:
    lights = np.asarray(lights, float)
    if lights.shape != (2, 3) or not np.all(np.isfinite(lights)):
        raise InputError(f"{who}: two light positions (2, 3) expected")
    h = 0.5 * float(np.linalg.norm(lights[0] - lights[1]))
    if not h > 0:
        raise DegenerateGeometryError(f"{who}: the two lights coincide")
    if np.linalg.norm(lights[0] + lights[1]) > 1e-3 * h:
        raise DegenerateGeometryError(f"{who}: the closed form needs the camera midway between its two lights")
    return h, _unit(lights[0])


def _bearings(b: np.ndarray, who: str) -> np.ndarray:
    b = np.asarray(b, float)
    if b.shape != (2, 3) or not np.all(np.isfinite(b)):
        raise InputError(f"{who}: two bearings (2, 3) expected")
    return b / np.linalg.norm(b, axis=1, keepdims=True)


def dugas_pose(bearings_p: np.ndarray, bearings_q: np.ndarray, lights_p: np.ndarray, lights_q: np.ndarray,
               *, corrections: int = 2) -> Pose:
    """``T_qp`` from the bearings of the other robot's two lights.

    ``bearings_p`` (2, 3): rays in p's frame towards q's lights
    ``lights_q[0]``, ``lights_q[1]`` (q's frame); likewise ``bearings_q``
    towards ``lights_p``.  Each robot's lights must be symmetric about its
    camera (``lights[1] = -lights[0]``).
    """
    hp, ep = _check(lights_p, "robot p")
    hq, eq = _check(lights_q, "robot q")
    a = _bearings(bearings_p, "bearings of p")
    b = _bearings(bearings_q, "bearings of q")
    cos_a = float(a[0] @ a[1])
    cos_b = float(b[0] @ b[1])
    # Direction to the other camera, first as the bisector.
    u_p = _unit(a[0] + a[1])  # p -> q, p's frame
    u_q = _unit(b[0] + b[1])  # q -> p, q's frame
    for it in range(max(0, int(corrections)) + 1):
        r1 = subtended_range(cos_a, hq, float(u_q @ eq))  # p's view of q's pair; p sits along u_q from q
        r2 = subtended_range(cos_b, hp, float(u_p @ ep))
        r = 0.5 * (r1 + r2)
        # Distances to each light: |r u - h e| for the light at +h e.
        lam = np.array([np.linalg.norm(r * u_q - hq * eq), np.linalg.norm(r * u_q + hq * eq)])
        mu = np.array([np.linalg.norm(r * u_p - hp * ep), np.linalg.norm(r * u_p + hp * ep)])
        if it < corrections:
            u_p = _unit(lam[0] * a[0] + lam[1] * a[1])
            u_q = _unit(mu[0] * b[0] + mu[1] * b[1])
    eq_in_p = _unit(lam[0] * a[0] - lam[1] * a[1])
    ep_in_q = _unit(mu[0] * b[0] - mu[1] * b[1])
    # R maps p-frame directions to q-frame ones.
    x = np.array([u_p, eq_in_p, ep])
    y = np.array([-u_q, eq, ep_in_q])
    w = np.array([2.0, 1.0, 1.0])
    U, _s, Vt = np.linalg.svd((y * w[:, None]).T @ x)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    return Pose(R, r * u_q)
