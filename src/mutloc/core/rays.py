"""Observations as rays from several centres: robots with several cameras, any lens.

A camera of a robot (a :class:`~mutloc.core.rig.Mount`: a lens and its pose
``T_robot_camera``) turns a raw pixel into a ray of the robot's frame: its
origin is the camera's centre, its direction the lens's unprojection rotated
into the robot frame.  The pair and team solvers then work on rays alone
(:data:`mutloc.core.refine.MODE_RAY`), whatever the lens.

Each ray carries a *frame* (4, 3): two tangent directions, the ray direction
and the origin.  The residual of a predicted point ``X`` (observer's frame)
is ``(e_k . (X - o)) / (b . (X - o))`` for the two tangent rows ``e_k``: the
gnomonic coordinates of the predicted ray around the observed one.  The
tangent rows are the unit tangent basis ``E`` (2, 3) at the observed ray
premultiplied by ``A = J E^T`` (2, 2), ``J`` the lens's Jacobian
``d(u, v)/dX`` at the observed ray: then the residual is the pixel error of
the prediction to first order, so costs, the chi-square test and the
covariance are in pixels exactly as for a pinhole camera, and the weighted
least squares is the maximum-likelihood estimate of isotropic pixel noise to
first order (on the Cramér-Rao bound).
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from ..errors import ObservationError
from .refine import tangent_bases

__all__ = ["ray_frames", "pair_rays"]


def ray_frames(mount: Any, uv: Any, label: Callable[[int], str] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(bearings (n, 3), frames (n, 4, 3))`` of raw pixels ``uv`` (n, 2) seen by
    the camera ``mount``, in its robot's frame.  ObservationError naming the
    row (``label(i)``) for a pixel the lens cannot unproject."""
    uv = np.ascontiguousarray(uv, dtype=float).reshape(-1, 2)
    n = len(uv)
    cam = mount.camera
    b = np.asarray(cam.pixels_to_bearings(uv), dtype=float).reshape(n, 3)
    bad = ~np.all(np.isfinite(b), axis=1)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        where = label(i) if label is not None else f"observation {i}"
        raise ObservationError(f"{where}: pixel ({uv[i, 0]:.2f}, {uv[i, 1]:.2f}) is outside what the "
                               f"{getattr(cam, 'model', 'pinhole')} lens images")
    b /= np.linalg.norm(b, axis=1)[:, None]
    basis = np.empty((n, 3, 3))
    tangent_bases(np.ascontiguousarray(b), basis)
    _, J = cam.project_jacobian(b)
    J = np.asarray(J, dtype=float).reshape(n, 2, 3)
    E = basis[:, :2, :]
    A = np.einsum("nij,nkj->nik", J, E)  # d(u, v) / d(gnomonic coordinates): columns J e_k
    if not np.all(np.isfinite(A)):
        i = int(np.flatnonzero(~np.all(np.isfinite(A), axis=(1, 2)))[0])
        where = label(i) if label is not None else f"observation {i}"
        raise ObservationError(f"{where}: pixel ({uv[i, 0]:.2f}, {uv[i, 1]:.2f}): the lens has no finite "
                               "Jacobian there")
    W = np.einsum("nij,njk->nik", A, E)
    R, t = mount.pose.R, mount.pose.t
    frames = np.empty((n, 4, 3))
    frames[:, :2] = W @ R.T
    frames[:, 2] = b @ R.T
    frames[:, 3] = t
    return np.ascontiguousarray(frames[:, 2]), frames


def pair_rays(mounts: dict, keys: Sequence[str], uv: np.ndarray,
              label: Callable[[int], str] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ray_frames` of rows seen by several cameras: ``keys[i]`` is row i's
    observer key in ``mounts`` (key -> (side, Mount), a pair table's)."""
    n = len(keys)
    bearings = np.empty((n, 3))
    frames = np.empty((n, 4, 3))
    groups: dict[str, list[int]] = {}
    for i, k in enumerate(keys):
        groups.setdefault(k, []).append(i)
    for k, idx in groups.items():
        ix = np.asarray(idx)
        b, f = ray_frames(mounts[k][1], uv[ix], None if label is None else (lambda j, ix=ix: label(int(ix[j]))))
        bearings[ix] = b
        frames[ix] = f
    return bearings, frames
