"""Pinhole camera with OpenCV's rational + tangential distortion model.

Conventions (OpenCV): camera optical frame x right, y down, z forward; pixel
``(0, 0)`` is the *centre* of the top-left pixel, so an image of width ``w``
covers ``u`` in ``[-0.5, w - 0.5]``.  Distortion coefficients are in OpenCV
order ``(k1, k2, p1, p2[, k3[, k4, k5, k6]])``; missing ones are zero.

The ``*_kernel`` functions are scalar, allocation-free numba kernels meant to
be called from other ``njit`` code (the pose solvers' inner loops).  They take
``K`` (3, 3) and ``dist`` (8,) float64 arrays, e.g. ``Camera.K`` and
``Camera.dist``.
"""

from __future__ import annotations

import math
from numbers import Integral, Real
from typing import Any

import numba
import numpy as np

from ..errors import InputError, RigError

__all__ = [
    "Camera",
    "intrinsics",
    "project_scalar",
    "project_jac_scalar",
    "project_kernel",
    "project_jac_kernel",
    "undistort_kernel",
    "project_many",
    "project_jac_many",
    "undistort_many",
    "VALID_DIST_LENGTHS",
    "distort_terms",
    "undistort_normalized",
    "intrinsic_matrix",
    "image_size",
    "as_points",
    "readonly_copy",
    "pixels_in_image",
    "intrinsics_repr",
]

VALID_DIST_LENGTHS = (0, 4, 5, 8)

# Newton stops once its step is below this (relative to 1 + |x| + |y|) in
# normalized coordinates; a stalled iteration is still accepted if its last
# Newton step is below the looser floor, since with the full rational model
# residual round-off can prevent reaching the tight tolerance.
_UNDIST_TOL = 1e-14
_UNDIST_ACCEPT = 1e-12
_UNDIST_MAXIT = 60
_UNDIST_MAX_HALVINGS = 40


# ---------------------------------------------------------------------------
# numba kernels
# ---------------------------------------------------------------------------


@numba.njit(cache=True, fastmath=False)
def intrinsics(K, dist):
    """``K`` and ``dist`` as one tuple of 13 floats ``(fx, skew, cx, fy, cy,
    k1, k2, p1, p2, k3, k4, k5, k6)``: what the ``*_scalar`` kernels take.
    A tuple of floats costs nothing to pass to a compiled function, where
    every array argument costs reference counting: inner loops that project
    thousands of points read their cameras once with this."""
    return (K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2], dist[0], dist[1], dist[2], dist[3], dist[4], dist[5],
            dist[6], dist[7])


@numba.njit(cache=True, fastmath=False)
def distort_terms(k1, k2, p1, p2, k3, k4, k5, k6, x, y):
    """Distorted point, its 2x2 Jacobian (a b; c d) wrt (x, y), and the radial factor."""
    x2 = x * x
    y2 = y * y
    xy = x * y
    r2 = x2 + y2
    num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    dnum = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    dden = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)
    radial = num / den
    # d radial / d r2, then chain through d r2 / dx = 2x.
    drad = (dnum - radial * dden) / den
    xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2)
    yd = y * radial + p1 * (r2 + 2.0 * y2) + 2.0 * p2 * xy
    cross = 2.0 * xy * drad + 2.0 * p1 * x + 2.0 * p2 * y
    a = radial + 2.0 * x2 * drad + 2.0 * p1 * y + 6.0 * p2 * x
    d = radial + 2.0 * y2 * drad + 6.0 * p1 * y + 2.0 * p2 * x
    return xd, yd, a, cross, cross, d, radial


@numba.njit(cache=True, fastmath=False)
def _distort(dist, x, y):
    """Distorted normalized point of the undistorted normalized (x, y)."""
    xd, yd, _, _, _, _, _ = _distort_jac(dist, x, y)
    return xd, yd


@numba.njit(cache=True, fastmath=False)
def _distort_jac(dist, x, y):
    """Distorted point, its 2x2 Jacobian (a b; c d) wrt (x, y), and the radial factor."""
    return distort_terms(dist[0], dist[1], dist[2], dist[3], dist[4], dist[5], dist[6], dist[7], x, y)


@numba.njit(cache=True, fastmath=False)
def project_scalar(c, X0, X1, X2):
    """``(ok, u, v)``: distorted pixel of camera-frame point ``(X0, X1, X2)``
    for the camera ``c`` (:func:`intrinsics`); not ok (NaN pixel) if the
    point is not strictly in front of the camera, or the pixel not finite."""
    if not (X2 > 0.0):
        return False, np.nan, np.nan
    x = X0 / X2
    y = X1 / X2
    xd, yd, _, _, _, _, _ = distort_terms(c[5], c[6], c[7], c[8], c[9], c[10], c[11], c[12], x, y)
    u = c[0] * xd + c[1] * yd + c[2]
    v = c[3] * yd + c[4]
    return math.isfinite(u) and math.isfinite(v), u, v


@numba.njit(cache=True, fastmath=False)
def project_jac_scalar(c, X0, X1, X2):
    """As :func:`project_scalar`, plus d(u, v)/dX row by row:
    ``(ok, u, v, J00, J01, J02, J10, J11, J12)`` (NaN on failure)."""
    if not (X2 > 0.0):
        return False, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan
    iz = 1.0 / X2
    x = X0 * iz
    y = X1 * iz
    xd, yd, a, b, cc, d, _ = distort_terms(c[5], c[6], c[7], c[8], c[9], c[10], c[11], c[12], x, y)
    fx = c[0]
    s = c[1]
    fy = c[3]
    u = fx * xd + s * yd + c[2]
    v = fy * yd + c[4]
    # d(u,v)/d(x,y) = [[fx, s], [0, fy]] @ [[a, b], [c, d]]
    dux = fx * a + s * cc
    duy = fx * b + s * d
    dvx = fy * cc
    dvy = fy * d
    # d(x,y)/dX = [[1/z, 0, -x/z], [0, 1/z, -y/z]]
    return (math.isfinite(u) and math.isfinite(v), u, v, dux * iz, duy * iz, -(dux * x + duy * y) * iz,
            dvx * iz, dvy * iz, -(dvx * x + dvy * y) * iz)


@numba.njit(cache=True, fastmath=False)
def project_kernel(K, dist, X, uv) -> bool:
    """Distorted pixel of camera-frame point ``X`` into ``uv``.

    Returns False (``uv`` = NaN) if ``X`` is not strictly in front of the
    camera or the projection is not finite.
    """
    ok, u, v = project_scalar(intrinsics(K, dist), X[0], X[1], X[2])
    uv[0] = u
    uv[1] = v
    return ok


@numba.njit(cache=True, fastmath=False)
def project_jac_kernel(K, dist, X, uv, J) -> bool:
    """As :func:`project_kernel`, plus ``J`` (2, 3) = d(u, v)/dX (NaN on failure)."""
    ok, u, v, j00, j01, j02, j10, j11, j12 = project_jac_scalar(intrinsics(K, dist), X[0], X[1], X[2])
    uv[0] = u
    uv[1] = v
    J[0, 0] = j00
    J[0, 1] = j01
    J[0, 2] = j02
    J[1, 0] = j10
    J[1, 1] = j11
    J[1, 2] = j12
    return ok


@numba.njit(cache=True, fastmath=False)
def undistort_normalized(dist, xd, yd):
    """Invert the distortion: (ok, x, y) with distort(x, y) == (xd, yd)."""
    # One OpenCV-style fixed-point step as the start: for barrel distortion
    # it undershoots the radius, which keeps Newton on the branch connected
    # to the optical axis instead of the folded one beyond the critical radius.
    x = xd
    y = yd
    fxd, fyd, _, _, _, _, radial = _distort_jac(dist, x, y)
    if radial > 0.0 and math.isfinite(radial):
        tx = fxd - x * radial
        ty = fyd - y * radial
        gx = (xd - tx) / radial
        gy = (yd - ty) / radial
        if math.isfinite(gx) and math.isfinite(gy):
            x = gx
            y = gy

    converged = False
    for _ in range(_UNDIST_MAXIT):
        px, py, a, b, c, d, radial = _distort_jac(dist, x, y)
        rx = px - xd
        ry = py - yd
        res = rx * rx + ry * ry
        if not math.isfinite(res):
            return False, np.nan, np.nan
        if res == 0.0:
            converged = True
            break
        det = a * d - b * c
        if det == 0.0 or not math.isfinite(det):
            return False, np.nan, np.nan
        sx = -(d * rx - b * ry) / det
        sy = -(a * ry - c * rx) / det
        tol = _UNDIST_TOL * (1.0 + abs(x) + abs(y))
        if abs(sx) <= tol and abs(sy) <= tol:
            x += sx
            y += sy
            converged = True
            break
        # Backtrack so the residual never grows: a full step near the fold can
        # jump onto the other branch.
        t = 1.0
        stepped = False
        for _h in range(_UNDIST_MAX_HALVINGS):
            nx = x + t * sx
            ny = y + t * sy
            qx, qy = _distort(dist, nx, ny)
            ex = qx - xd
            ey = qy - yd
            if ex * ex + ey * ey < res:
                x = nx
                y = ny
                stepped = True
                break
            t *= 0.5
        if not stepped:
            # Residual at round-off level: accept only if Newton says we are close.
            acc = _UNDIST_ACCEPT * (1.0 + abs(x) + abs(y))
            converged = abs(sx) <= acc and abs(sy) <= acc
            break

    if not converged:
        return False, np.nan, np.nan
    # A root where the map folds over (det <= 0) or flips the point through
    # the axis (radial <= 0) is not the physical pre-image of the pixel.
    px, py, a, b, c, d, radial = _distort_jac(dist, x, y)
    if not (radial > 0.0 and a * d - b * c > 0.0):
        return False, np.nan, np.nan
    if not (math.isfinite(x) and math.isfinite(y)):
        return False, np.nan, np.nan
    return True, x, y


@numba.njit(cache=True, fastmath=False)
def undistort_kernel(K, dist, uv, b) -> bool:
    """Unit bearing ``b`` (3,) (z > 0) of distorted pixel ``uv``.

    Returns False (``b`` = NaN) when the distortion cannot be inverted at
    ``uv`` (outside the invertible region, or no convergence).
    """
    fy = K[1, 1]
    yd = (uv[1] - K[1, 2]) / fy
    xd = (uv[0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    ok, x, y = undistort_normalized(dist, xd, yd)
    if not ok:
        b[0] = np.nan
        b[1] = np.nan
        b[2] = np.nan
        return False
    inv = 1.0 / math.sqrt(x * x + y * y + 1.0)
    b[0] = x * inv
    b[1] = y * inv
    b[2] = inv
    return True


@numba.njit(cache=True, fastmath=False)
def project_many(K, dist, X, out) -> None:
    """Project points ``X`` (n, 3) into ``out`` (n, 2) (compiled; no checks)."""
    for i in range(X.shape[0]):
        project_kernel(K, dist, X[i], out[i])


@numba.njit(cache=True, fastmath=False)
def project_jac_many(K, dist, X, out, J) -> None:
    """Project ``X`` (n, 3) into ``out`` with Jacobians ``J`` (n, 2, 3) (compiled; no checks)."""
    for i in range(X.shape[0]):
        project_jac_kernel(K, dist, X[i], out[i], J[i])


@numba.njit(cache=True, fastmath=False)
def undistort_many(K, dist, uv, out) -> int:
    """Index of the first pixel that cannot be undistorted, or -1."""
    for i in range(uv.shape[0]):
        if not undistort_kernel(K, dist, uv[i], out[i]):
            return i
    return -1


# ---------------------------------------------------------------------------
# Camera
# ---------------------------------------------------------------------------


def as_points(a: Any, dim: int, what: str, allow_nonfinite: bool = False) -> tuple[np.ndarray, bool]:
    """``a`` as a C-contiguous float64 (n, dim) array, and whether it was 1-D."""
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"{what}: cannot convert to a float array ({exc})") from None
    single = arr.ndim == 1
    if single:
        arr = arr.reshape(1, -1)
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise InputError(f"{what}: expected shape ({dim},) or (n, {dim}), got {np.shape(a)}")
    if not allow_nonfinite and not np.all(np.isfinite(arr)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(arr), axis=1))[0])
        raise InputError(f"{what}: row {bad} is not finite: {arr[bad].tolist()}")
    return np.ascontiguousarray(arr), single


def readonly(a: np.ndarray) -> np.ndarray:
    """``a`` itself if read-only, else a read-only view of it (no copy).

    Numba compiles a kernel once per argument type, and whether an array is
    writable is part of its type: the solvers' camera arrays (``K``, ``dist``)
    are always passed read-only, so that each kernel is compiled once."""
    if not a.flags.writeable:
        return a
    v = a.view()
    v.flags.writeable = False
    return v


def readonly_copy(a: np.ndarray) -> np.ndarray:
    """A read-only, C-contiguous float64 copy of ``a``."""
    a = np.ascontiguousarray(a, dtype=np.float64).copy()
    a.flags.writeable = False
    return a


def intrinsic_matrix(K: Any) -> np.ndarray:
    """``K`` checked as a camera's 3x3 intrinsic matrix: finite, positive
    focal lengths, ``K[1, 0] = 0`` and bottom row ``[0, 0, 1]`` (skew
    ``K[0, 1]`` allowed).  Raises RigError (message starting "camera ")."""
    try:
        Kf = np.asarray(K, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise RigError("camera K must be a 3x3 matrix of numbers") from None
    if Kf.shape != (3, 3):
        raise RigError(f"camera K must be 3x3, got shape {Kf.shape}")
    if not np.all(np.isfinite(Kf)):
        raise RigError("camera K contains NaN or inf")
    if not (Kf[0, 0] > 0.0 and Kf[1, 1] > 0.0):
        raise RigError(f"camera focal lengths must be positive, got fx={Kf[0, 0]}, fy={Kf[1, 1]}")
    if Kf[1, 0] != 0.0 or Kf[2, 0] != 0.0 or Kf[2, 1] != 0.0 or Kf[2, 2] != 1.0:
        raise RigError(
            f"camera K must have K[1,0] = 0 and bottom row [0, 0, 1], got K[1,0]={Kf[1, 0]}, "
            f"bottom row {Kf[2].tolist()}"
        )
    return Kf


def image_size(size: Any) -> tuple[int, int] | None:
    """``size`` checked as an image ``(width, height)`` of positive integers, or None."""
    if size is None:
        return None
    try:
        items = list(size)
    except TypeError:
        raise RigError(f"camera size must be [width, height], got {size!r}") from None
    if len(items) != 2 or not all(_is_int(s) and int(s) > 0 for s in items):
        raise RigError(f"camera size must be two positive integers [width, height], got {size!r}")
    return (int(items[0]), int(items[1]))


def pixels_in_image(size: tuple[int, int] | None, uv: Any) -> np.ndarray | bool:
    """Mask of pixels ``uv`` inside an image of ``size`` (see :meth:`Camera.in_image`)."""
    U, single = as_points(uv, 2, "pixels", allow_nonfinite=True)
    mask = np.all(np.isfinite(U), axis=1)
    if size is not None:
        w, h = size
        u = U[:, 0]
        v = U[:, 1]
        with np.errstate(invalid="ignore"):
            mask &= (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5)
    return bool(mask[0]) if single else mask


class Camera:
    """An intrinsically calibrated camera (immutable).

    ``K`` is the 3x3 intrinsic matrix (skew ``K[0, 1]`` allowed), ``dist``
    the distortion coefficients padded to 8, ``n_dist`` how many were given,
    ``size`` the image ``(width, height)`` in pixels or None.
    """

    __slots__ = ("_K", "_dist", "_n_dist", "_size")

    _K: np.ndarray
    _dist: np.ndarray
    _n_dist: int
    _size: tuple[int, int] | None

    def __init__(self, K: Any, dist: Any = None, size: Any = None) -> None:
        Kf = intrinsic_matrix(K)

        if dist is None:
            d = np.zeros(0)
        else:
            try:
                d = np.asarray(dist, dtype=np.float64)
            except (TypeError, ValueError, OverflowError):
                raise RigError("camera dist must be a list of numbers") from None
            # OpenCV hands out (1, n) / (n, 1) arrays; accept those too.
            if d.ndim == 2 and 1 in d.shape:
                d = d.ravel()
            if d.ndim != 1:
                raise RigError(f"camera dist must be a flat list, got shape {d.shape}")
        if d.size not in VALID_DIST_LENGTHS:
            raise RigError(
                f"camera dist must have {', '.join(map(str, VALID_DIST_LENGTHS))} coefficients "
                f"(k1, k2, p1, p2[, k3[, k4, k5, k6]]), got {d.size}"
            )
        if not np.all(np.isfinite(d)):
            raise RigError("camera dist contains NaN or inf")
        d8 = np.zeros(8)
        d8[: d.size] = d

        sz = image_size(size)

        object.__setattr__(self, "_K", readonly_copy(Kf))
        object.__setattr__(self, "_dist", readonly_copy(d8))
        object.__setattr__(self, "_n_dist", int(d.size))
        object.__setattr__(self, "_size", sz)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("Camera is immutable")

    def __delattr__(self, name: str) -> None:
        raise AttributeError("Camera is immutable")

    # -- parameters -------------------------------------------------------

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix (read-only float64, C-contiguous)."""
        return self._K

    @property
    def dist(self) -> np.ndarray:
        """Distortion coefficients padded to 8 (read-only float64)."""
        return self._dist

    @property
    def n_dist(self) -> int:
        """Number of distortion coefficients originally given (0, 4, 5 or 8)."""
        return self._n_dist

    @property
    def size(self) -> tuple[int, int] | None:
        """Image ``(width, height)`` in pixels, or None if unknown."""
        return self._size

    @property
    def model(self) -> str:
        """The lens model's name in rig files: ``"pinhole"``."""
        return "pinhole"

    @property
    def max_angle(self) -> float:
        """Bound on the angle (radians) off the optical axis of the directions
        the lens images: only those strictly inside it (z > 0) are, so ``pi/2``."""
        return math.pi / 2.0

    def __repr__(self) -> str:
        return "Camera(" + ", ".join(intrinsics_repr(self._K, self._dist[: self._n_dist], self._size)) + ")"

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form ``{"K", "dist", "size"}`` accepted back by ``Camera(**d)``."""
        d: dict[str, Any] = {
            "K": self._K.tolist(),
            "dist": self._dist[: self._n_dist].tolist(),
        }
        if self._size is not None:
            d["size"] = [self._size[0], self._size[1]]
        return d

    # -- geometry -----------------------------------------------------------

    def project(self, X: Any) -> np.ndarray:
        """Pixels (n, 2) of camera-frame points ``X`` (n, 3); NaN rows where z <= 0.

        A single point (3,) gives a (2,) result.
        """
        P, single = as_points(X, 3, "points")
        out = np.empty((P.shape[0], 2))
        project_many(self._K, self._dist, P, out)
        return out[0] if single else out

    def project_jacobian(self, X: Any) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (n, 2) and Jacobians d(u, v)/dX (n, 2, 3); NaN where z <= 0."""
        P, single = as_points(X, 3, "points")
        out = np.empty((P.shape[0], 2))
        J = np.empty((P.shape[0], 2, 3))
        project_jac_many(self._K, self._dist, P, out, J)
        return (out[0], J[0]) if single else (out, J)

    def bearings_to_pixels(self, b: Any) -> np.ndarray:
        """Pixels of camera-frame directions ``b`` (need not be unit); NaN where b_z <= 0."""
        return self.project(b)

    def pixels_to_bearings(self, uv: Any) -> np.ndarray:
        """Unit bearings (n, 3), z > 0, of distorted pixels ``uv`` (n, 2).

        A single pixel (2,) gives a (3,) result.  Raises InputError if a pixel
        lies where the distortion cannot be inverted.
        """
        U, single = as_points(uv, 2, "pixels")
        out = np.empty((U.shape[0], 3))
        bad = undistort_many(self._K, self._dist, U, out)
        if bad >= 0:
            u, v = U[bad]
            raise InputError(
                f"pixel ({u:.6g}, {v:.6g}) (row {bad}) cannot be undistorted: "
                f"outside the region where the lens distortion is invertible"
            )
        return out[0] if single else out

    def in_image(self, uv: Any) -> np.ndarray | bool:
        """Mask of pixels inside the image, ``u`` in ``[-0.5, w - 0.5]`` (pixel-centre origin).

        Non-finite pixels (e.g. from points behind the camera) are outside;
        every finite pixel is inside when ``size`` is None.  A single pixel
        (2,) gives a scalar bool.
        """
        return pixels_in_image(self._size, uv)


def intrinsics_repr(K: np.ndarray, dist: np.ndarray, size: tuple[int, int] | None) -> list[str]:
    """``["fx=..", "fy=..", "cx=..", "cy=..", ("skew=..",) ("dist=[..]",) ("size=..")]`` for a ``__repr__``."""
    parts = [f"fx={K[0, 0]:g}", f"fy={K[1, 1]:g}", f"cx={K[0, 2]:g}", f"cy={K[1, 2]:g}"]
    if K[0, 1] != 0.0:
        parts.append(f"skew={K[0, 1]:g}")
    if dist.size:
        parts.append("dist=[" + ", ".join(f"{c:g}" for c in dist) + "]")
    if size is not None:
        parts.append(f"size={size}")
    return parts


def _is_int(s: Any) -> bool:
    if isinstance(s, bool):
        return False
    if isinstance(s, Integral):
        return True
    # YAML/JSON writers sometimes emit 640.0 for an integer width.
    return isinstance(s, Real) and float(s).is_integer()
