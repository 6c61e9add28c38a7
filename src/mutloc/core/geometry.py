"""SO(3)/SE(3) helpers and the paper's error measures.

Conventions (SPEC): a pose ``(R, t)`` maps ``x_b = R @ x_a + t``.  Rotation
perturbations are rotation vectors applied on the left: ``R' = exp(w) @ R``.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "skew",
    "so3_exp",
    "so3_log",
    "so3_left_jacobian",
    "se3_exp",
    "se3_log",
    "rotation_error_deg",
    "translation_error",
    "quaternion_xyzw_from_matrix",
    "matrix_from_quaternion_xyzw",
]


def skew(w: np.ndarray) -> np.ndarray:
    """The 3x3 cross-product matrix ``[w]x`` with ``[w]x @ v == cross(w, v)``."""
    x, y, z = np.asarray(w, dtype=float)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``w`` (Rodrigues)."""
    w = np.asarray(w, dtype=float)
    th = float(np.linalg.norm(w))
    W = skew(w)
    if th < 1e-8:
        return np.eye(3) + W + 0.5 * W @ W
    return np.eye(3) + (np.sin(th) / th) * W + ((1.0 - np.cos(th)) / th**2) * W @ W


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector of ``R``; accurate near 0 and near 180 degrees."""
    R = np.asarray(R, dtype=float)
    c = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    s = 0.5 * np.linalg.norm(v)
    th = np.arctan2(s, c)
    if th < 1e-6:
        return 0.5 * v * (1.0 + th**2 / 6.0)
    if th < np.pi - 1e-3:
        return th / (2.0 * np.sin(th)) * v
    # Near pi the antisymmetric part vanishes: read the axis off R + R^T.
    B = 0.5 * (R + R.T) - c * np.eye(3)
    k = int(np.argmax(np.diag(B)))
    axis = B[:, k] / np.sqrt(max(B[k, k], 1e-300))
    axis /= np.linalg.norm(axis)
    if axis @ v < 0:
        axis = -axis
    return th * axis


def so3_left_jacobian(w: np.ndarray, inverse: bool = False) -> np.ndarray:
    """The left Jacobian ``J_l(w) = I + (1-cos th)/th^2 [w]x + (th-sin th)/th^3 [w]x^2``
    of SO(3) (``so3_exp(w + dw) ~= so3_exp(J_l(w) @ dw) @ so3_exp(w)``), or its inverse."""
    w = np.asarray(w, dtype=float)
    th2 = float(w @ w)
    th = np.sqrt(th2)
    W = skew(w)
    if inverse:
        if th < 1e-6:
            c = 1.0 / 12.0 + th2 / 720.0
        else:
            c = (1.0 - th * np.sin(th) / (2.0 * (1.0 - np.cos(th)))) / th2
        return np.eye(3) - 0.5 * W + c * W @ W
    if th < 1e-6:
        a, b = 0.5 - th2 / 24.0, 1.0 / 6.0 - th2 / 120.0
    else:
        a, b = (1.0 - np.cos(th)) / th2, (th - np.sin(th)) / (th2 * th)
    return np.eye(3) + a * W + b * W @ W


def se3_exp(xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` of the twist ``xi = (w, v)`` (rotation first, as the SPEC's
    covariances): the pose reached moving with constant angular velocity
    ``w`` and body-fixed linear velocity ``v`` for unit time (a screw motion);
    ``R = so3_exp(w)``, ``t = J_l(w) @ v``."""
    xi = np.asarray(xi, dtype=float).reshape(6)
    return so3_exp(xi[:3]), so3_left_jacobian(xi[:3]) @ xi[3:]


def se3_log(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The twist ``(w, v)`` with ``se3_exp((w, v)) == (R, t)`` (the inverse of :func:`se3_exp`)."""
    w = so3_log(R)
    return np.concatenate([w, so3_left_jacobian(w, inverse=True) @ np.asarray(t, dtype=float)])


def rotation_error_deg(R_est: np.ndarray, R_gt: np.ndarray) -> float:
    """The paper's rotation error (eq. roterr) in degrees, argument clipped."""
    c = (np.trace(np.asarray(R_gt).T @ np.asarray(R_est)) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def translation_error(t_est: np.ndarray, t_gt: np.ndarray) -> float:
    """Euclidean distance between two translations."""
    return float(np.linalg.norm(np.asarray(t_est, float) - np.asarray(t_gt, float)))


def quaternion_xyzw_from_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(x, y, z, w)`` with ``w >= 0`` of a rotation matrix."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = np.array([(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s])
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(max(1.0 + R[i, i] - R[j, j] - R[k, k], 1e-300))
        q = np.empty(4)
        q[i] = 0.25 * s
        q[j] = (R[j, i] + R[i, j]) / s
        q[k] = (R[k, i] + R[i, k]) / s
        q[3] = (R[k, j] - R[j, k]) / s
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def matrix_from_quaternion_xyzw(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a (not necessarily unit) quaternion ``(x, y, z, w)``."""
    x, y, z, w = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
