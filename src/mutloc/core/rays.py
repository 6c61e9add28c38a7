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

import math
import weakref
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from numba import njit

from ..errors import ObservationError
from .camera import intrinsics, project_jac_scalar, undistort_normalized
from .lenses import fisheye_project_jac_scalar, fisheye_unproject_scalar, omni_project_jac_scalar, omni_unproject_scalar
from .refine import tangent_bases

__all__ = ["ray_frames", "pair_rays", "LensTable", "lens_table", "rays_kernel", "past_rim_px", "set_aside_past_rim",
           "RIM_TOLERANCE_PX", "RIM_TOLERANCE_SIGMAS"]

#: Lens codes of :func:`rays_kernel`.
PINHOLE, FISHEYE, OMNI = 0, 1, 2
_CODES = {"pinhole": PINHOLE, "fisheye": FISHEYE, "omni": OMNI}
# A camera as one row of floats: its lens's scalar-kernel parameters [0, 16), the 8 distortion coefficients
# the pinhole and omni unprojections take [16, 24), R_robot_camera row-major [24, 33), its centre [33, 36).
_ROW = 36
_rows: "weakref.WeakKeyDictionary[Any, tuple[int, np.ndarray]]" = weakref.WeakKeyDictionary()


def _mount_row(mount: Any) -> tuple[int, np.ndarray]:
    """``(lens code, row)`` of a camera on a robot (mounts and lenses are immutable: kept per mount)."""
    hit = _rows.get(mount)
    if hit is None:
        cam = mount.camera
        code = _CODES[getattr(cam, "model", "pinhole")]
        row = np.zeros(_ROW)
        if code == PINHOLE:
            params = intrinsics(np.ascontiguousarray(cam.K, dtype=float), np.ascontiguousarray(cam.dist, dtype=float))
            row[16:24] = cam.dist
        else:
            params = cam.params
            if code == OMNI:
                row[16:24] = cam.dist8
        row[:len(params)] = params
        row[24:33] = np.asarray(mount.pose.R, dtype=float).reshape(9)
        row[33:36] = mount.pose.t
        hit = _rows[mount] = (code, row)
    return hit


@dataclass(frozen=True)
class LensTable:
    """Cameras as the compiled ray builder reads them: ``index[key]`` is the row of observer key ``key``."""

    index: dict[str, int]
    codes: np.ndarray
    rows: np.ndarray
    models: tuple[str, ...]


def lens_table(mounts: Mapping[str, Any]) -> LensTable:
    """The :class:`LensTable` of ``mounts`` (key -> Mount, or key -> (side, Mount) as a pair table's)."""
    index: dict[str, int] = {}
    codes, rows, models = [], [], []
    for key, m in mounts.items():
        mount = m[1] if isinstance(m, tuple) else m
        code, row = _mount_row(mount)
        index[key] = len(rows)
        codes.append(code)
        rows.append(row)
        models.append(getattr(mount.camera, "model", "pinhole"))
    return LensTable(index, np.array(codes, dtype=np.int64), np.ascontiguousarray(np.array(rows).reshape(-1, _ROW)),
                     tuple(models))


@njit(cache=True)
def rays_kernel(uv, cam, codes, rows, frames):
    """Ray frames (n, 4, 3) of raw pixels ``uv`` (n, 2), row i seen by camera ``cam[i]`` of the table
    (``codes``, ``rows``: :class:`LensTable`), in the robots' frames: tangent rows ``A E`` (rotated), the
    unit ray, the camera's centre.  Returns ``(-1, 0)``, or the first failing row and why: 1 the lens
    images nothing at that pixel, 2 its Jacobian there is not finite."""
    b = np.empty((1, 3))
    E = np.empty((1, 3, 3))
    W = np.empty((2, 3))
    for i in range(uv.shape[0]):
        j = cam[i]
        c = rows[j]
        code = codes[j]
        u = uv[i, 0]
        v = uv[i, 1]
        if code == PINHOLE:
            yd = (v - c[4]) / c[3]
            xd = (u - c[2] - c[1] * yd) / c[0]
            ok, x, y = undistort_normalized(c[16:24], xd, yd)
            bx, by, bz = x, y, 1.0
        elif code == FISHEYE:
            ok, bx, by, bz = fisheye_unproject_scalar(c, u, v)
        else:
            ok, bx, by, bz = omni_unproject_scalar(c, c[16:24], u, v)
        if not (ok and np.isfinite(bx) and np.isfinite(by) and np.isfinite(bz)):
            return i, 1
        nb = np.sqrt(bx * bx + by * by + bz * bz)
        b[0, 0] = bx / nb
        b[0, 1] = by / nb
        b[0, 2] = bz / nb
        tangent_bases(b, E)
        if code == PINHOLE:
            _, _, _, j00, j01, j02, j10, j11, j12 = project_jac_scalar(c, b[0, 0], b[0, 1], b[0, 2])
        elif code == FISHEYE:
            _, _, _, j00, j01, j02, j10, j11, j12 = fisheye_project_jac_scalar(c, b[0, 0], b[0, 1], b[0, 2])
        else:
            _, _, _, j00, j01, j02, j10, j11, j12 = omni_project_jac_scalar(c, b[0, 0], b[0, 1], b[0, 2])
        # A = J E^T (d(u, v) / d(gnomonic coordinates)), W = A E
        a00 = j00 * E[0, 0, 0] + j01 * E[0, 0, 1] + j02 * E[0, 0, 2]
        a01 = j00 * E[0, 1, 0] + j01 * E[0, 1, 1] + j02 * E[0, 1, 2]
        a10 = j10 * E[0, 0, 0] + j11 * E[0, 0, 1] + j12 * E[0, 0, 2]
        a11 = j10 * E[0, 1, 0] + j11 * E[0, 1, 1] + j12 * E[0, 1, 2]
        if not (np.isfinite(a00) and np.isfinite(a01) and np.isfinite(a10) and np.isfinite(a11)):
            return i, 2
        for k in range(3):
            W[0, k] = a00 * E[0, 0, k] + a01 * E[0, 1, k]
            W[1, k] = a10 * E[0, 0, k] + a11 * E[0, 1, k]
        # into the robot's frame: x_robot = R x_camera + t
        for a in range(3):
            r0 = c[24 + 3 * a]
            r1 = c[25 + 3 * a]
            r2 = c[26 + 3 * a]
            frames[i, 0, a] = r0 * W[0, 0] + r1 * W[0, 1] + r2 * W[0, 2]
            frames[i, 1, a] = r0 * W[1, 0] + r1 * W[1, 1] + r2 * W[1, 2]
            frames[i, 2, a] = r0 * b[0, 0] + r1 * b[0, 1] + r2 * b[0, 2]
            frames[i, 3, a] = c[33 + a]
    return -1, 0


def _raise(table: LensTable, cam: np.ndarray, uv: np.ndarray, i: int, kind: int,
           label: Callable[[int], str] | None) -> None:
    where = label(i) if label is not None else f"observation {i}"
    if kind == 1:
        raise ObservationError(f"{where}: pixel ({uv[i, 0]:.2f}, {uv[i, 1]:.2f}) is outside what the "
                               f"{table.models[int(cam[i])]} lens images")
    raise ObservationError(f"{where}: pixel ({uv[i, 0]:.2f}, {uv[i, 1]:.2f}): the lens has no finite Jacobian there")


def _build(table: LensTable, cam: np.ndarray, uv: Any, label: Callable[[int], str] | None
           ) -> tuple[np.ndarray, np.ndarray]:
    uv = np.ascontiguousarray(uv, dtype=float).reshape(-1, 2)
    frames = np.empty((len(uv), 4, 3))
    i, kind = rays_kernel(uv, cam, table.codes, table.rows, frames)
    if i >= 0:
        _raise(table, cam, uv, i, kind, label)
    return np.ascontiguousarray(frames[:, 2]), frames


def ray_frames(mount: Any, uv: Any, label: Callable[[int], str] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(bearings (n, 3), frames (n, 4, 3))`` of raw pixels ``uv`` (n, 2) seen by
    the camera ``mount``, in its robot's frame.  ObservationError naming the
    row (``label(i)``) for a pixel the lens cannot unproject."""
    table = lens_table({"": mount})
    n = len(np.asarray(uv).reshape(-1, 2))
    return _build(table, np.zeros(n, dtype=np.int64), uv, label)


def pair_rays(mounts: Mapping[str, Any] | LensTable, keys: Sequence[str], uv: np.ndarray,
              label: Callable[[int], str] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ray_frames` of rows seen by several cameras: ``keys[i]`` is row i's
    observer key in ``mounts`` (key -> (side, Mount), a pair table's; or its :class:`LensTable`)."""
    table = mounts if isinstance(mounts, LensTable) else lens_table(mounts)
    index = table.index
    cam = np.array([index[k] for k in keys], dtype=np.int64)
    return _build(table, cam, uv, label)


#: A pixel past its lens's rim (where the lens images nothing: past ``max_angle``, where the lens model stops
#: being one-to-one) by at most this many pixels, or this many of its pixel sigmas, is set aside rather than
#: refused: detection noise puts a marker seen at the very rim of a fisheye there (:func:`set_aside_past_rim`).
RIM_TOLERANCE_PX = 4.0
RIM_TOLERANCE_SIGMAS = 4.0
#: False: nothing is set aside (every such pixel refused, as before; bench/bench_bodies.py --refusals compares).
SET_ASIDE_PAST_RIM = True


def past_rim_px(camera: Any, uv: Any) -> float:
    """How far (pixels, along the line from the principal point) the pixel ``uv`` lies past the rim of what
    ``camera``'s lens images (the image of directions at ``max_angle`` off the axis); NaN when the lens has no
    such rim (a pinhole) or the pixel is not past it."""
    if getattr(camera, "model", "pinhole") == "pinhole":
        return math.nan
    theta = float(camera.max_angle)
    K = np.asarray(camera.K, dtype=float)
    u, v = (float(x) for x in np.asarray(uv, dtype=float).reshape(2))
    y = (v - K[1, 2]) / K[1, 1]
    x = (u - K[0, 2] - K[0, 1] * y) / K[0, 0]
    phi = math.atan2(y, x)
    t = theta * (1.0 - 1e-9)
    rim = np.asarray(camera.project(np.array([math.sin(t) * math.cos(phi), math.sin(t) * math.sin(phi),
                                              math.cos(t)])), dtype=float).reshape(2)
    if not np.all(np.isfinite(rim)):
        return math.nan
    past = math.hypot(u - K[0, 2], v - K[1, 2]) - math.hypot(rim[0] - K[0, 2], rim[1] - K[1, 2])
    return past if past > 0 else math.nan


def set_aside_past_rim(rig: Any, obs: Any, pixel_sigma: float) -> tuple[Any, list[dict[str, Any]]]:
    """The observations (an ObservationSet) without the pixels its lenses cannot unproject that lie at most
    ``max(RIM_TOLERANCE_PX, RIM_TOLERANCE_SIGMAS * sigma)`` past the lens's rim (``sigma`` the row's noise,
    ``pixel_sigma`` times its ``sigma_scale``), and those set aside, each as a result's ``rejected`` entry
    ``{"observer", "marker", "residual_px": None, "at": "lens", "past_rim_px"}``.  Pixels farther past, or
    not unprojectable for another reason, are kept: solving on them raises the usual ObservationError
    naming them.  Nothing is set aside for a rig of one-pinhole robots."""
    if not SET_ASIDE_PAST_RIM or getattr(rig, "central_pinhole", True) or not len(obs):
        return obs, []
    scale = obs.scales_of()
    keep: list[int] = []
    aside: list[dict[str, Any]] = []
    for i, (o, m) in enumerate(zip(obs.observer, obs.marker)):
        try:
            mount = rig.mount(o)
            ray_frames(mount, obs.uv[i])
            keep.append(i)
            continue
        except Exception:  # noqa: BLE001 -- unknown observer, or a pixel the lens cannot unproject: judged below
            pass
        try:
            past = past_rim_px(rig.mount(o).camera, obs.uv[i])
        except Exception:  # noqa: BLE001
            past = math.nan
        sigma = pixel_sigma * (1.0 if scale is None else float(scale[i]))
        if math.isfinite(past) and past <= max(RIM_TOLERANCE_PX, RIM_TOLERANCE_SIGMAS * sigma):
            aside.append({"observer": o, "marker": m, "residual_px": None, "at": "lens", "past_rim_px": past})
        else:
            keep.append(i)
    if not aside:
        return obs, []
    return obs.take(np.array(keep, dtype=np.int64)), aside
