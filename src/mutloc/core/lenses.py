"""Wide-angle lens models behind the interface of :class:`~.camera.Camera`.

One class per model, all with the same public interface (:class:`Lens`, in
the manner of basalt's or PoseLib's camera models: project / unproject and
the projection's Jacobian behind one interface):

* :class:`~.camera.Camera` (``model = "pinhole"``): OpenCV pinhole with
  rational + tangential distortion;
* :class:`FisheyeCamera` (``"fisheye"``): OpenCV's fisheye model, i.e.
  Kannala-Brandt, ROS ``equidistant``, Kalibr ``pinhole-equi``; images
  directions beyond 90 degrees off the axis;
* :class:`OmniCamera` (``"omni"``): Mei's unified model, i.e. OpenCV's
  ``cv::omnidir``, Kalibr ``omni-radtan``.

Conventions are those of :mod:`.camera` (OpenCV): camera optical frame x
right, y down, z forward; pixel ``(0, 0)`` is the *centre* of the top-left
pixel; ``K`` is upper triangular with skew ``K[0, 1]`` (OpenCV's
``alpha * fx``) allowed.  A point's *angle off the axis* is
``theta = atan2(hypot(x, y), z)`` in ``[0, pi]``.

:func:`make_camera` and :func:`lens_from_dict` build the right class from a
rig file's camera entry (key ``model``, default ``pinhole``).

The ``*_scalar`` functions are allocation-free numba kernels over a tuple of
floats (``lens.params``), for other compiled code; the classes loop them.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping
from typing import Any, Protocol, runtime_checkable

import numba
import numpy as np

from ..errors import InputError, RigError
from .camera import (
    Camera,
    as_points,
    distort_terms,
    image_size,
    intrinsic_matrix,
    intrinsics_repr,
    pixels_in_image,
    readonly_copy,
    undistort_normalized,
)

__all__ = [
    "Lens",
    "FisheyeCamera",
    "OmniCamera",
    "MODELS",
    "make_camera",
    "lens_from_dict",
    "fisheye_project_scalar",
    "fisheye_project_jac_scalar",
    "fisheye_unproject_scalar",
    "omni_project_scalar",
    "omni_project_jac_scalar",
    "omni_unproject_scalar",
]

#: Lens models by their name in rig files (``model`` key).
MODELS = ("pinhole", "fisheye", "omni")

#: Other names of these models (ROS ``distortion_model``, Kalibr), for error messages only.
_OTHER_NAMES = {
    "equidistant": "fisheye", "kannala_brandt": "fisheye", "kannala-brandt": "fisheye", "pinhole-equi": "fisheye",
    "equi": "fisheye", "mei": "omni", "omnidir": "omni", "omni-radtan": "omni", "unified": "omni",
    "plumb_bob": "pinhole", "rational_polynomial": "pinhole", "pinhole-radtan": "pinhole", "radtan": "pinhole",
}

_NEWTON_MAXIT = 200
_NEWTON_TOL = 1e-15
# Below this distance from the axis (unit vector) the fisheye Jacobian uses
# its series limit instead of a difference of two terms of order 1 / r^2.
_AXIS_R = 1e-8


@runtime_checkable
class Lens(Protocol):
    """The interface every lens model implements (:class:`~.camera.Camera`,
    :class:`FisheyeCamera`, :class:`OmniCamera`).

    * ``project(X)``: camera-frame points (n, 3) or (3,) to pixels (n, 2) /
      (2,), NaN where the point cannot be imaged (angle off the axis not
      below ``max_angle``, or the origin);
    * ``project_jacobian(X)``: pixels and d(u, v)/dX (n, 2, 3) (NaN likewise);
    * ``bearings_to_pixels(b)``: ``project`` of directions (need not be unit);
    * ``pixels_to_bearings(uv)``: unit rays of pixels.  The wide-angle models
      give NaN rows where a pixel has no pre-image; ``Camera`` raises
      InputError there (its historical behaviour);
    * ``in_image(uv)``: mask of pixels in ``[-0.5, w - 0.5] x [-0.5, h - 0.5]``;
    * ``to_dict()``: rig-file form, read back by :func:`lens_from_dict`;
    * ``max_angle``: directions strictly less than this angle (radians) off
      the optical axis are imaged, others are not (pinhole: ``pi / 2``).
    """

    @property
    def model(self) -> str: ...

    @property
    def K(self) -> np.ndarray: ...

    @property
    def dist(self) -> np.ndarray: ...

    @property
    def n_dist(self) -> int: ...

    @property
    def size(self) -> tuple[int, int] | None: ...

    @property
    def max_angle(self) -> float: ...

    def project(self, X: Any) -> np.ndarray: ...

    def project_jacobian(self, X: Any) -> tuple[np.ndarray, np.ndarray]: ...

    def bearings_to_pixels(self, b: Any) -> np.ndarray: ...

    def pixels_to_bearings(self, uv: Any) -> np.ndarray: ...

    def in_image(self, uv: Any) -> np.ndarray | bool: ...

    def to_dict(self) -> dict[str, Any]: ...


# ---------------------------------------------------------------------------
# numba kernels
# ---------------------------------------------------------------------------

_FAIL_JAC = (False, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan)


@numba.njit(cache=True, fastmath=False)
def _unit(X0, X1, X2):
    """``(ok, x, y, z, norm)``: the direction of ``X`` as a unit vector
    (scaled first, so that neither huge nor tiny points over/underflow)."""
    m = max(abs(X0), abs(X1), abs(X2))
    if not (m > 0.0 and m < np.inf):
        return False, np.nan, np.nan, np.nan, np.nan
    x = X0 / m
    y = X1 / m
    z = X2 / m
    n = math.sqrt(x * x + y * y + z * z)
    return True, x / n, y / n, z / n, m * n


@numba.njit(cache=True, fastmath=False)
def _pixel_jac(c, mx, my, row0, row1, scale):
    """``(ok, u, v, J00, ..., J12)``: pixel ``K (mx, my, 1)`` of the distorted
    normalized point and d(u, v)/dX from d(mx, my)/dX given as its two rows
    (3-tuples) evaluated at the unit vector, times ``scale`` = 1 / |X|."""
    fx = c[0]
    s = c[1]
    fy = c[3]
    u = fx * mx + s * my + c[2]
    v = fy * my + c[4]
    return (math.isfinite(u) and math.isfinite(v), u, v,
            (fx * row0[0] + s * row1[0]) * scale, (fx * row0[1] + s * row1[1]) * scale,
            (fx * row0[2] + s * row1[2]) * scale, fy * row1[0] * scale, fy * row1[1] * scale, fy * row1[2] * scale)


@numba.njit(cache=True, fastmath=False)
def _normalized(c, u, v):
    """Normalized (distorted) image coordinates of pixel ``(u, v)``: ``K^-1``."""
    yd = (v - c[4]) / c[3]
    xd = (u - c[2] - c[1] * yd) / c[0]
    return xd, yd


@numba.njit(cache=True, fastmath=False)
def _fisheye_theta_d(c, theta):
    """``theta_d(theta) = theta (1 + k1 t^2 + k2 t^4 + k3 t^6 + k4 t^8)`` and its derivative."""
    k1 = c[5]
    k2 = c[6]
    k3 = c[7]
    k4 = c[8]
    t2 = theta * theta
    td = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    dtd = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
    return td, dtd


@numba.njit(cache=True, fastmath=False)
def fisheye_project_jac_scalar(c, X0, X1, X2):
    """``(ok, u, v, J00, J01, J02, J10, J11, J12)``: pixel of camera-frame
    point ``X`` for the fisheye camera ``c`` (:attr:`FisheyeCamera.params`)
    and d(u, v)/dX row by row; not ok (all NaN) if ``X`` is the origin or
    ``theta >= max_theta``."""
    ok, x, y, z, norm = _unit(X0, X1, X2)
    if not ok:
        return _FAIL_JAC
    r = math.sqrt(x * x + y * y)
    theta = math.atan2(r, z)
    if not (theta < c[9]):
        return _FAIL_JAC
    td, dtd = _fisheye_theta_d(c, theta)
    # m = s (x, y) with s = theta_d / r; on a unit vector d theta/dx = z x / r,
    # d theta/dz = -r, so dm/dX = [[s + x^2 A, x y A, -x dtd], [x y A, s + y^2 A, -y dtd]]
    # with A = dtd z / r^2 - theta_d / r^3 (-> (2 k1 - 2/3) / z^3 on the axis).
    if r > _AXIS_R:
        s = td / r
        A = (dtd * z - s) / (r * r)
    else:
        s = td / r if r > 0.0 else 1.0 / z
        A = (2.0 * c[5] - 2.0 / 3.0) / (z * z * z)
    xyA = x * y * A
    return _pixel_jac(c, s * x, s * y, (s + x * x * A, xyA, -x * dtd), (xyA, s + y * y * A, -y * dtd), 1.0 / norm)


@numba.njit(cache=True, fastmath=False)
def fisheye_project_scalar(c, X0, X1, X2):
    """``(ok, u, v)`` of :func:`fisheye_project_jac_scalar`."""
    res = fisheye_project_jac_scalar(c, X0, X1, X2)
    return res[0], res[1], res[2]


@numba.njit(cache=True, fastmath=False)
def fisheye_unproject_scalar(c, u, v):
    """``(ok, bx, by, bz)``: unit bearing of pixel ``(u, v)`` for the fisheye
    camera ``c``; not ok (NaN) beyond the image of ``max_theta``.  Solves
    ``theta_d(theta) = |x_d|`` by Newton's method safeguarded by bisection
    on ``[0, max_theta]``, where ``theta_d`` is increasing."""
    xd, yd = _normalized(c, u, v)
    rd = math.sqrt(xd * xd + yd * yd)
    if rd == 0.0:
        return True, 0.0, 0.0, 1.0
    if not (rd < c[10]):
        return False, np.nan, np.nan, np.nan
    lo = 0.0
    hi = c[9]
    theta = rd if rd < hi else 0.5 * hi
    converged = False
    for _ in range(_NEWTON_MAXIT):
        td, dtd = _fisheye_theta_d(c, theta)
        f = td - rd
        if f == 0.0:
            converged = True
            break
        if f > 0.0:
            hi = theta
        else:
            lo = theta
        nxt = theta - f / dtd
        if not (lo < nxt < hi):
            nxt = 0.5 * (lo + hi)
        if abs(nxt - theta) <= _NEWTON_TOL * theta or nxt == lo or nxt == hi:
            theta = nxt
            converged = True
            break
        theta = nxt
    if not converged:
        return False, np.nan, np.nan, np.nan
    sn = math.sin(theta) / rd
    return True, sn * xd, sn * yd, math.cos(theta)


@numba.njit(cache=True, fastmath=False)
def omni_project_jac_scalar(c, X0, X1, X2):
    """``(ok, u, v, J00, ..., J12)``: pixel of ``X`` for the omni camera ``c``
    (:attr:`OmniCamera.params`) and d(u, v)/dX; not ok (NaN) unless the unit
    vector's ``z_s > z_min = -min(xi, 1/xi)`` (the sphere's part that
    projects one-to-one)."""
    ok, x, y, z, norm = _unit(X0, X1, X2)
    if not (ok and z > c[10]):
        return _FAIL_JAC
    xi = c[9]
    iden = 1.0 / (z + xi)
    mx = x * iden
    my = y * iden
    # dm/dX_s = [[1/d, 0, -x/d^2], [0, 1/d, -y/d^2]], times dX_s/dX = (I - X_s X_s^T) / |X|;
    # row i of the product: M_i - (M_i . X_s) X_s^T with M_0 . X_s = x xi / d^2.
    i2 = iden * iden
    q0 = x * xi * i2
    q1 = y * xi * i2
    m00 = iden - q0 * x
    m01 = -q0 * y
    m02 = -x * i2 - q0 * z
    m10 = -q1 * x
    m11 = iden - q1 * y
    m12 = -y * i2 - q1 * z
    xd, yd, a, b, cc, d, _ = distort_terms(c[5], c[6], c[7], c[8], 0.0, 0.0, 0.0, 0.0, mx, my)
    return _pixel_jac(c, xd, yd, (a * m00 + b * m10, a * m01 + b * m11, a * m02 + b * m12),
                      (cc * m00 + d * m10, cc * m01 + d * m11, cc * m02 + d * m12), 1.0 / norm)


@numba.njit(cache=True, fastmath=False)
def omni_project_scalar(c, X0, X1, X2):
    """``(ok, u, v)`` of :func:`omni_project_jac_scalar`."""
    res = omni_project_jac_scalar(c, X0, X1, X2)
    return res[0], res[1], res[2]


@numba.njit(cache=True, fastmath=False)
def omni_unproject_scalar(c, dist, u, v):
    """``(ok, bx, by, bz)``: unit bearing of pixel ``(u, v)`` for the omni
    camera ``c`` with ``dist`` its (8,) radial-tangential coefficients
    (:attr:`OmniCamera.dist8`): undistorted by Newton's method as
    :class:`~.camera.Camera` does, then lifted to the sphere in closed form.
    Not ok (NaN) where the distortion cannot be inverted or the lift leaves
    the one-to-one part of the sphere."""
    xd, yd = _normalized(c, u, v)
    ok, mx, my = undistort_normalized(dist, xd, yd)
    if not ok:
        return False, np.nan, np.nan, np.nan
    xi = c[9]
    r2 = mx * mx + my * my
    disc = 1.0 + (1.0 - xi * xi) * r2
    if not (disc >= 0.0):
        return False, np.nan, np.nan, np.nan
    f = (xi + math.sqrt(disc)) / (r2 + 1.0)
    bz = f - xi
    if not (bz > c[10]):
        return False, np.nan, np.nan, np.nan
    return True, f * mx, f * my, bz


@numba.njit(cache=True, fastmath=False)
def _store(i, u, v, j00, j01, j02, j10, j11, j12, out, J):
    out[i, 0] = u
    out[i, 1] = v
    J[i, 0, 0] = j00
    J[i, 0, 1] = j01
    J[i, 0, 2] = j02
    J[i, 1, 0] = j10
    J[i, 1, 1] = j11
    J[i, 1, 2] = j12


@numba.njit(cache=True, fastmath=False)
def _fisheye_project_many(c, X, out, J):
    for i in range(X.shape[0]):
        _, u, v, j00, j01, j02, j10, j11, j12 = fisheye_project_jac_scalar(c, X[i, 0], X[i, 1], X[i, 2])
        _store(i, u, v, j00, j01, j02, j10, j11, j12, out, J)


@numba.njit(cache=True, fastmath=False)
def _omni_project_many(c, X, out, J):
    for i in range(X.shape[0]):
        _, u, v, j00, j01, j02, j10, j11, j12 = omni_project_jac_scalar(c, X[i, 0], X[i, 1], X[i, 2])
        _store(i, u, v, j00, j01, j02, j10, j11, j12, out, J)


@numba.njit(cache=True, fastmath=False)
def _fisheye_unproject_many(c, uv, out):
    for i in range(uv.shape[0]):
        _, bx, by, bz = fisheye_unproject_scalar(c, uv[i, 0], uv[i, 1])
        out[i, 0] = bx
        out[i, 1] = by
        out[i, 2] = bz


@numba.njit(cache=True, fastmath=False)
def _omni_unproject_many(c, dist, uv, out):
    for i in range(uv.shape[0]):
        _, bx, by, bz = omni_unproject_scalar(c, dist, uv[i, 0], uv[i, 1])
        out[i, 0] = bx
        out[i, 1] = by
        out[i, 2] = bz


# ---------------------------------------------------------------------------
# classes
# ---------------------------------------------------------------------------


def _coefficients(dist: Any, model: str, names: str) -> tuple[np.ndarray, int]:
    """``dist`` as 4 float64 coefficients (zeros if none given) and how many were given."""
    if dist is None:
        d = np.zeros(0)
    else:
        try:
            d = np.asarray(dist, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise RigError("camera dist must be a list of numbers") from None
        if d.ndim == 2 and 1 in d.shape:  # OpenCV's (1, n) / (n, 1)
            d = d.ravel()
        if d.ndim != 1:
            raise RigError(f"camera dist must be a flat list, got shape {d.shape}")
    if d.size not in (0, 4):
        raise RigError(f"camera dist must have 4 coefficients ({names}) for the {model} model (or none), "
                       f"got {d.size}")
    if not np.all(np.isfinite(d)):
        raise RigError("camera dist contains NaN or inf")
    d4 = np.zeros(4)
    d4[: d.size] = d
    return d4, int(d.size)


class _WideLens:
    """What the wide-angle models share: parameters, immutability, the
    NumPy-facing loops over the scalar kernels, ``in_image``."""

    __slots__ = ("_K", "_dist", "_n_dist", "_size", "_params")

    model = ""  # overridden

    _K: np.ndarray
    _dist: np.ndarray
    _n_dist: int
    _size: tuple[int, int] | None
    _params: tuple[float, ...]

    def _init(self, K: Any, dist: np.ndarray, n_dist: int, size: Any, extra: tuple[float, ...]) -> None:
        Kf = intrinsic_matrix(K)
        sz = image_size(size)
        object.__setattr__(self, "_K", readonly_copy(Kf))
        object.__setattr__(self, "_dist", readonly_copy(dist))
        object.__setattr__(self, "_n_dist", n_dist)
        object.__setattr__(self, "_size", sz)
        params = (float(Kf[0, 0]), float(Kf[0, 1]), float(Kf[0, 2]), float(Kf[1, 1]), float(Kf[1, 2]),
                  *(float(k) for k in dist), *extra)
        object.__setattr__(self, "_params", params)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"{type(self).__name__} is immutable")

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"{type(self).__name__} is immutable")

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix (read-only float64, C-contiguous)."""
        return self._K

    @property
    def dist(self) -> np.ndarray:
        """The 4 distortion coefficients (read-only float64; zeros if none were given)."""
        return self._dist

    @property
    def n_dist(self) -> int:
        """Number of distortion coefficients originally given (0 or 4)."""
        return self._n_dist

    @property
    def size(self) -> tuple[int, int] | None:
        """Image ``(width, height)`` in pixels, or None if unknown."""
        return self._size

    @property
    def params(self) -> tuple[float, ...]:
        """The camera as one tuple of floats, what the ``*_scalar`` kernels take."""
        return self._params

    def _repr_parts(self) -> list[str]:
        return intrinsics_repr(self._K, self._dist[: self._n_dist], self._size)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(" + ", ".join(self._repr_parts()) + ")"

    def to_dict(self) -> dict[str, Any]:
        """Rig-file form ``{"model", "K", "dist", ("xi",) ("size")}``, read back by :func:`lens_from_dict`."""
        d: dict[str, Any] = {"model": self.model, "K": self._K.tolist(),
                             "dist": self._dist[: self._n_dist].tolist()}
        d.update(self._extra_dict())
        if self._size is not None:
            d["size"] = [self._size[0], self._size[1]]
        return d

    def _extra_dict(self) -> dict[str, Any]:
        return {}

    def _project_many(self, P: np.ndarray, out: np.ndarray, J: np.ndarray) -> None:
        raise NotImplementedError

    def _unproject_many(self, U: np.ndarray, out: np.ndarray) -> None:
        raise NotImplementedError

    def project(self, X: Any) -> np.ndarray:
        """Pixels (n, 2) of camera-frame points ``X`` (n, 3); NaN rows for
        points not imaged (``max_angle``).  A single point (3,) gives (2,)."""
        uv, _ = self.project_jacobian(X)
        return uv

    def project_jacobian(self, X: Any) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (n, 2) and Jacobians d(u, v)/dX (n, 2, 3); NaN for points not imaged."""
        P, single = as_points(X, 3, "points")
        out = np.empty((P.shape[0], 2))
        J = np.empty((P.shape[0], 2, 3))
        self._project_many(P, out, J)
        return (out[0], J[0]) if single else (out, J)

    def bearings_to_pixels(self, b: Any) -> np.ndarray:
        """Pixels of camera-frame directions ``b`` (need not be unit); NaN for directions not imaged."""
        return self.project(b)

    def pixels_to_bearings(self, uv: Any) -> np.ndarray:
        """Unit bearings (n, 3) of pixels ``uv`` (n, 2); NaN rows for pixels
        with no pre-image (outside the lens's image).  (2,) gives (3,)."""
        U, single = as_points(uv, 2, "pixels")
        out = np.empty((U.shape[0], 3))
        self._unproject_many(U, out)
        return out[0] if single else out

    def in_image(self, uv: Any) -> np.ndarray | bool:
        """Mask of pixels inside the image, ``u`` in ``[-0.5, w - 0.5]`` (pixel-centre origin).

        Non-finite pixels are outside; every finite pixel is inside when
        ``size`` is None.  A single pixel (2,) gives a scalar bool.
        """
        return pixels_in_image(self._size, uv)


def _fisheye_max_theta(k: np.ndarray) -> float:
    """Largest ``theta`` (capped at pi) up to which ``theta_d`` increases:
    the first positive root ``s = theta^2`` of
    ``d theta_d / d theta = 1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3 + 9 k4 s^4``."""
    coeffs = np.array([1.0, 3.0 * k[0], 5.0 * k[1], 7.0 * k[2], 9.0 * k[3]])
    deriv = np.polynomial.Polynomial(coeffs)
    s_max = math.pi**2
    nz = np.flatnonzero(coeffs)
    if nz[-1] > 0:
        for root in np.polynomial.Polynomial(coeffs[: nz[-1] + 1]).roots():
            if abs(root.imag) <= 1e-9 * max(1.0, abs(root)) and root.real > 0.0:
                s = float(root.real)
                for _ in range(3):  # polish
                    dv = deriv.deriv()(s)
                    if dv != 0.0:
                        s -= deriv(s) / dv
                s_max = min(s_max, s)
    # Belt and braces: the derivative must be positive on [0, s_max).
    grid = np.linspace(0.0, s_max, 4097)[:-1]
    bad = np.flatnonzero(deriv(grid) <= 0.0)
    if bad.size:
        s_max = float(grid[bad[0]])
    return math.sqrt(s_max)


class FisheyeCamera(_WideLens):
    """OpenCV's fisheye camera (immutable): Kannala-Brandt, ROS ``equidistant``,
    Kalibr ``pinhole-equi``.

    A camera-frame point at ``theta = atan2(r, z)`` off the axis (``r =
    hypot(x, y)``) is imaged at ``K (theta_d / r) (x, y, 1)`` with
    ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``,
    ``dist = (k1, k2, k3, k4)``.  Directions more than 90 degrees off the
    axis are fine: any with ``theta < max_angle`` is imaged, where
    ``max_angle`` is the largest ``theta`` (at most pi) up to which
    ``theta_d`` increases, so that each pixel has one pre-image.
    """

    __slots__ = ()

    model = "fisheye"

    def __init__(self, K: Any, dist: Any = None, size: Any = None) -> None:
        d4, n = _coefficients(dist, "fisheye", "k1, k2, k3, k4")
        max_theta = _fisheye_max_theta(d4)
        theta_d_max = max_theta * (1.0 + sum(k * max_theta ** (2 * i + 2) for i, k in enumerate(d4)))
        self._init(K, d4, n, size, (max_theta, theta_d_max))

    @property
    def max_angle(self) -> float:
        """Directions strictly less than this angle (radians) off the axis are
        imaged: where ``theta_d`` stops increasing, at most pi."""
        return self._params[9]

    def _project_many(self, P: np.ndarray, out: np.ndarray, J: np.ndarray) -> None:
        _fisheye_project_many(self._params, P, out, J)

    def _unproject_many(self, U: np.ndarray, out: np.ndarray) -> None:
        _fisheye_unproject_many(self._params, U, out)


def _omni_radial_z_min(k1: float, k2: float, xi: float) -> float:
    """The unit vector's smallest ``z_s`` whose radial distortion is still one-to-one: past the radius where
    ``r (1 + k1 r^2 + k2 r^4)`` stops increasing (2 % inside it) a pixel has two directions; -1 when it never
    stops.  ``r = sin(theta) / (cos(theta) + xi)`` grows with the angle off the axis on the imaged part."""
    roots = np.roots([5.0 * k2, 3.0 * k1, 1.0]) if k2 != 0.0 else (np.array([-1.0 / (3.0 * k1)]) if k1 else [])
    s2 = [float(r.real) for r in np.atleast_1d(roots) if abs(r.imag) < 1e-12 and r.real > 0.0]
    if not s2:
        return -1.0
    r_max = 0.98 * math.sqrt(min(s2))
    # solve sin(th) / (cos(th) + xi) = r_max for th by bisection on [0, the geometric limit]
    lo, hi = 0.0, math.pi if xi <= 0.0 else math.acos(max(-min(xi, 1.0 / xi), -1.0))
    den = math.cos(hi) + xi
    if den > 1e-12 and math.sin(hi) / den <= r_max:
        return -1.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if math.sin(mid) / (math.cos(mid) + xi) < r_max:
            lo = mid
        else:
            hi = mid
    return math.cos(lo)


class OmniCamera(_WideLens):
    """Mei's unified (omnidirectional) camera (immutable): OpenCV's
    ``cv::omnidir``, Kalibr ``omni-radtan``.

    A camera-frame point ``X`` goes to the unit sphere, ``X_s = X / |X|``,
    then is projected from ``(0, 0, -xi)``: ``m = (x_s, y_s) / (z_s + xi)``;
    ``m`` gets OpenCV's radial-tangential distortion with ``dist = (k1, k2,
    p1, p2)`` and then ``K``.  ``xi >= 0`` (``xi = 0`` is the pinhole
    model).  Imaged are the directions with ``z_s > -min(xi, 1/xi)``:
    ``z_s + xi > 0``, and for ``xi > 1`` the part of the sphere that projects
    one-to-one.
    """

    __slots__ = ("_dist8",)

    model = "omni"

    _dist8: np.ndarray

    def __init__(self, K: Any, dist: Any = None, xi: Any = None, size: Any = None) -> None:
        d4, n = _coefficients(dist, "omni", "k1, k2, p1, p2")
        if xi is None:
            raise RigError("camera xi is missing: the omni model needs its mirror parameter xi")
        if isinstance(xi, bool):
            raise RigError(f"camera xi must be a number, got {xi!r}")
        try:
            xif = float(xi)
        except (TypeError, ValueError, OverflowError):
            raise RigError(f"camera xi must be a number, got {xi!r}") from None
        if not math.isfinite(xif):
            raise RigError(f"camera xi must be finite, got {xif}")
        if xif < 0.0:
            raise RigError(f"camera xi must be >= 0, got {xif:g}")
        z_min = -min(xif, 1.0 / xif) if xif > 0.0 else 0.0
        z_min = max(z_min, _omni_radial_z_min(float(d4[0]), float(d4[1]), xif))
        self._init(K, d4, n, size, (xif, z_min))
        d8 = np.zeros(8)
        d8[:4] = d4
        object.__setattr__(self, "_dist8", readonly_copy(d8))

    @property
    def xi(self) -> float:
        """Mei's mirror parameter: the projection centre is ``(0, 0, -xi)`` on the unit sphere's axis."""
        return self._params[9]

    @property
    def dist8(self) -> np.ndarray:
        """``dist`` padded to OpenCV's 8 coefficients (as ``Camera.dist``), for the kernels."""
        return self._dist8

    @property
    def max_angle(self) -> float:
        """Directions strictly less than this angle (radians) off the axis are
        imaged: ``acos(-min(xi, 1/xi))`` (pi/2 for xi = 0, pi for xi = 1)."""
        return math.acos(self._params[10])

    def _repr_parts(self) -> list[str]:
        parts = super()._repr_parts()
        parts.insert(4 + (self._K[0, 1] != 0.0), f"xi={self.xi:g}")
        return parts

    def _extra_dict(self) -> dict[str, Any]:
        return {"xi": self.xi}

    def _project_many(self, P: np.ndarray, out: np.ndarray, J: np.ndarray) -> None:
        _omni_project_many(self._params, P, out, J)

    def _unproject_many(self, U: np.ndarray, out: np.ndarray) -> None:
        _omni_unproject_many(self._params, self._dist8, U, out)


# ---------------------------------------------------------------------------
# factory
# ---------------------------------------------------------------------------

_KEYS = ("model", "K", "dist", "size", "xi")


def _model_name(model: Any, where: str) -> str:
    if model is None:
        return "pinhole"
    if not isinstance(model, str):
        raise RigError(f"{where}: model must be a string ({', '.join(MODELS)}), got {model!r}")
    name = model.strip().lower()
    if name in MODELS:
        return name
    if name in _OTHER_NAMES:
        hint = f"; {model!r} is model {_OTHER_NAMES[name]!r} here"
    else:
        close = difflib.get_close_matches(name, MODELS, n=1, cutoff=0.5)
        hint = f"; did you mean {close[0]!r}?" if close else ""
    raise RigError(f"{where}: unknown camera model {model!r} (one of {', '.join(MODELS)}){hint}")


def make_camera(model: Any, K: Any, dist: Any = None, size: Any = None, xi: Any = None,
                where: str = "") -> Lens:
    """The camera of lens ``model`` (``"pinhole"`` (also for None) |
    ``"fisheye"`` | ``"omni"``): :class:`~.camera.Camera`,
    :class:`FisheyeCamera` or :class:`OmniCamera`.

    Raises RigError, one line, starting with ``where`` when given: unknown
    model (with the nearest name), wrong number of distortion coefficients
    for the model (pinhole 0/4/5/8, fisheye 4, omni 4), ``xi`` missing or
    invalid for omni (or given for another model), non-finite numbers.
    """
    w = where or "camera"
    name = _model_name(model, w)
    if xi is not None and name != "omni":
        raise RigError(f"{w}: xi is a parameter of the omni model only, not of {name!r}")
    try:
        if name == "pinhole":
            return Camera(K, dist=dist, size=size)
        if name == "fisheye":
            return FisheyeCamera(K, dist=dist, size=size)
        return OmniCamera(K, dist=dist, xi=xi, size=size)
    except InputError as exc:
        if not where:
            raise
        msg = str(exc)
        msg = msg[len("camera "):] if msg.startswith("camera ") else msg
        raise type(exc)(f"{where}: {msg}") from None


def lens_from_dict(d: Any, where: str = "camera") -> Lens:
    """The camera of a rig file's entry ``{model?, K, dist?, size?, xi?}``
    (the form ``to_dict`` writes; ``model`` defaults to ``pinhole``, so old
    rig files read as before).  Errors as :func:`make_camera`, plus unknown
    or missing keys."""
    if not isinstance(d, Mapping):
        raise RigError(f"{where}: must be a mapping {{model?, K, dist?, size?, xi?}}, got {type(d).__name__}")
    for key in d:
        if key not in _KEYS:
            close = difflib.get_close_matches(str(key), _KEYS, n=1, cutoff=0.5)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise RigError(f"{where}: unknown key {key!r} (known: {', '.join(_KEYS)}){hint}")
    if "K" not in d:
        raise RigError(f"{where}: missing key 'K'")
    if _model_name(d.get("model"), where) == "omni" and "xi" not in d:
        raise RigError(f"{where}: missing key 'xi' (the omni model's mirror parameter)")
    return make_camera(d.get("model"), d["K"], d.get("dist"), d.get("size"), d.get("xi"), where=where)
