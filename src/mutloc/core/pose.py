"""The one pose type: a rigid transform, or a stack of them.

``Pose(R, t)`` maps ``x_to = R @ x_from + t`` (SPEC).  Like SciPy's
``Rotation``/``RigidTransform``, one object holds a single transform
(``R`` (3, 3), ``t`` (3,)) or a stack of any leading shape (``R``
(..., 3, 3), ``t`` (..., 3)): ``inverse``, ``@`` (composition, broadcast),
``apply``, indexing, ``len`` and iteration work on both.  The solvers'
candidates, batch results and tracks are stacks; an estimate's pose is one.
"""

from __future__ import annotations

from typing import Any, Iterator, Sequence

import numpy as np

from ..errors import InputError
from .geometry import (
    matrix_from_quaternion_xyzw,
    skew,
    quaternion_xyzw_from_matrix,
    rotation_error_deg,
    so3_exp,
    so3_log,
    translation_error,
)

__all__ = ["Pose", "sandwich_covariance"]


def _per_matrix(fn: Any, R: np.ndarray, width: int) -> np.ndarray:
    """``fn`` over every 3x3 of a stack, shaped like the stack plus ``width``."""
    if R.ndim == 2:
        return fn(R)
    flat = R.reshape(-1, 3, 3)
    out = np.array([fn(r) for r in flat]).reshape(R.shape[:-2] + (width,))
    return out


class Pose:
    """A rigid transform ``x_to = R @ x_from + t``, or a stack of them."""

    __slots__ = ("R", "t")
    R: np.ndarray
    t: np.ndarray

    def __init__(self, R: Any, t: Any) -> None:
        if not (type(R) is np.ndarray and R.dtype == np.float64):
            R = np.asarray(R, dtype=float)
        if not (type(t) is np.ndarray and t.dtype == np.float64):
            t = np.asarray(t, dtype=float)
        if R.shape == (9,):
            R = R.reshape(3, 3)
        if R.ndim < 2 or R.shape[-2:] != (3, 3) or t.shape[-1:] != (3,) or R.shape[:-2] != t.shape[:-1]:
            raise InputError(f"Pose: R must be (..., 3, 3) and t (..., 3) with the same leading shape, "
                             f"got {R.shape} and {t.shape}")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("Pose is immutable")

    def __reduce__(self) -> tuple:
        return (Pose, (self.R, self.t))

    # -- construction -------------------------------------------------------

    @classmethod
    def trusted(cls, R: np.ndarray, t: np.ndarray) -> "Pose":
        """From float64 arrays already shaped (..., 3, 3) and (..., 3), not
        checked (the solvers' own output)."""
        obj = object.__new__(cls)
        object.__setattr__(obj, "R", R)
        object.__setattr__(obj, "t", t)
        return obj

    @classmethod
    def identity(cls, shape: int | tuple[int, ...] = ()) -> "Pose":
        """The identity (a stack of them when ``shape`` is given)."""
        shape = (shape,) if isinstance(shape, (int, np.integer)) else tuple(shape)
        return cls(np.broadcast_to(np.eye(3), shape + (3, 3)).copy(), np.zeros(shape + (3,)))

    @classmethod
    def from_matrix(cls, T: Any) -> "Pose":
        """From 4x4 homogeneous matrices (..., 4, 4)."""
        T = np.asarray(T, dtype=float)
        return cls(T[..., :3, :3], T[..., :3, 3])

    @classmethod
    def from_rotvec(cls, rotvec: Any, t: Any) -> "Pose":
        """From rotation vectors (..., 3) (radians) and translations (..., 3)."""
        w = np.asarray(rotvec, dtype=float)
        R = so3_exp(w) if w.ndim == 1 else np.array([so3_exp(x) for x in w.reshape(-1, 3)]).reshape(w.shape + (3,))
        return cls(R, t)

    @classmethod
    def from_quaternion_xyzw(cls, q: Any, t: Any) -> "Pose":
        """From quaternions ``(x, y, z, w)`` (..., 4) and translations (..., 3)."""
        q = np.asarray(q, dtype=float)
        if q.ndim == 1:
            return cls(matrix_from_quaternion_xyzw(q), t)
        R = np.array([matrix_from_quaternion_xyzw(x) for x in q.reshape(-1, 4)]).reshape(q.shape[:-1] + (3, 3))
        return cls(R, t)

    @classmethod
    def concatenate(cls, poses: Sequence["Pose"]) -> "Pose":
        """One stack from single poses and 1-D stacks, in order."""
        if not poses:
            return cls(np.empty((0, 3, 3)), np.empty((0, 3)))
        return cls(np.concatenate([p.R.reshape(-1, 3, 3) for p in poses]),
                   np.concatenate([p.t.reshape(-1, 3) for p in poses]))

    # -- a stack ------------------------------------------------------------

    @property
    def shape(self) -> tuple[int, ...]:
        """Leading shape: ``()`` for a single pose."""
        return self.t.shape[:-1]

    @property
    def single(self) -> bool:
        return self.t.ndim == 1

    def __len__(self) -> int:
        if self.single:
            raise TypeError("a single Pose has no len(); it is not a stack")
        return self.t.shape[0]

    def __getitem__(self, index: Any) -> "Pose":
        if self.single:
            raise TypeError("a single Pose cannot be indexed; it is not a stack")
        return Pose(self.R[index], self.t[index])

    def __iter__(self) -> Iterator["Pose"]:
        if self.single:
            raise TypeError("a single Pose is not iterable; it is not a stack")
        for i in range(len(self)):
            yield Pose(self.R[i], self.t[i])

    def isfinite(self) -> np.ndarray | bool:
        """Which poses are finite (padding of batch results is NaN)."""
        ok = np.all(np.isfinite(self.R), axis=(-2, -1)) & np.all(np.isfinite(self.t), axis=-1)
        return bool(ok) if self.single else ok

    # -- algebra ------------------------------------------------------------

    def as_matrix(self) -> np.ndarray:
        """Homogeneous matrices (..., 4, 4)."""
        T = np.zeros(self.shape + (4, 4))
        T[..., :3, :3] = self.R
        T[..., :3, 3] = self.t
        T[..., 3, 3] = 1.0
        return T

    def inverse(self) -> "Pose":
        Rt = np.swapaxes(self.R, -1, -2)
        return Pose(Rt, -np.einsum("...ij,...j->...i", Rt, self.t))

    def __matmul__(self, other: "Pose") -> "Pose":
        """Composition: ``(A @ B).apply(x) == A.apply(B.apply(x))`` (stacks broadcast)."""
        if not isinstance(other, Pose):
            return NotImplemented
        if self.single and other.single:
            return Pose(self.R @ other.R, self.R @ other.t + self.t)
        return Pose(self.R @ other.R, np.einsum("...ij,...j->...i", self.R, other.t) + self.t)

    def apply(self, x: Any) -> np.ndarray:
        """Transform points: ``(3,)`` or ``(n, 3)`` by a single pose; by a stack,
        one point per pose (broadcast)."""
        x = np.asarray(x, dtype=float)
        if self.single:
            return x @ self.R.T + self.t
        return np.einsum("...ij,...j->...i", self.R, x) + self.t

    # -- views --------------------------------------------------------------

    @property
    def quaternion_xyzw(self) -> np.ndarray:
        """Unit quaternions ``(x, y, z, w)`` with ``w >= 0`` (..., 4)."""
        return _per_matrix(quaternion_xyzw_from_matrix, self.R, 4)

    @property
    def rotvec(self) -> np.ndarray:
        """Rotation vectors in radians (..., 3)."""
        return _per_matrix(so3_log, self.R, 3)

    def rotation_error_deg(self, other: "Pose") -> float | np.ndarray:
        """The paper's rotation error to ``other`` (per pose for stacks)."""
        if self.single and other.single:
            return rotation_error_deg(self.R, other.R)
        c = (np.einsum("...ij,...ij->...", other.R, self.R) - 1.0) / 2.0
        return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))

    def translation_error(self, other: "Pose") -> float | np.ndarray:
        """Distance between the translations (per pose for stacks)."""
        if self.single and other.single:
            return translation_error(self.t, other.t)
        return np.linalg.norm(self.t - other.t, axis=-1)

    def to_dict(self) -> dict[str, Any]:
        """``{"R", "t", "quaternion_xyzw"}`` as in the SPEC's result JSON (single pose)."""
        if not self.single:
            return {"poses": [p.to_dict() for p in self]} if self.t.ndim == 2 else {"R": self.R.tolist(),
                                                                                  "t": self.t.tolist()}
        return {"R": self.R.tolist(), "t": self.t.tolist(), "quaternion_xyzw": self.quaternion_xyzw.tolist()}

    def __repr__(self) -> str:
        if self.single:
            return f"Pose(rotvec={np.round(self.rotvec, 6).tolist()}, t={np.round(self.t, 6).tolist()})"
        return f"Pose(stack of shape {self.shape})"


def sandwich_covariance(A: Pose, T: Pose, C: Pose, covariance: np.ndarray) -> np.ndarray:
    """Covariance of ``A @ T @ C`` for exactly known ``A`` and ``C`` (single
    poses), from the 6x6 ``covariance`` of ``T``; both in the SPEC's
    convention (rotation vector on the left, then translation):
    ``dtheta' = R_A dtheta``, ``dt' = R_A (dt - [R_T t_C]x dtheta)``."""
    RA = A.R
    J = np.zeros((6, 6))
    J[:3, :3] = RA
    J[3:, 3:] = RA
    J[3:, :3] = -RA @ skew(T.R @ C.t)
    return J @ np.asarray(covariance, dtype=float) @ J.T
