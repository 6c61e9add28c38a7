"""Kalibr camera chains (``camchain.yaml``) as a robot's cameras.

Kalibr writes one entry per camera, ``cam0``, ``cam1``, ...::

    cam1:
      camera_model: pinhole            # pinhole | omni
      distortion_model: equidistant    # radtan | equidistant | none
      intrinsics: [fu, fv, pu, pv]     # omni: [xi, fu, fv, pu, pv]
      distortion_coeffs: [k1, k2, k3, k4]
      resolution: [width, height]
      T_cn_cnm1: 4x4                   # x_cam1 = T_cn_cnm1 @ x_cam0 (cam1 and later)
      rostopic: /front/image_raw       # optional

:func:`load_kalibr_camchain` turns them into :class:`~mutloc.core.rig.Mount`
s: lens models ``pinhole-radtan`` / ``pinhole-none`` -> pinhole
:class:`~mutloc.core.camera.Camera`, ``pinhole-equidistant`` ->
:class:`~mutloc.core.lenses.FisheyeCamera`, ``omni-radtan`` / ``omni-none``
-> :class:`~mutloc.core.lenses.OmniCamera`; poses ``T_robot_camN`` by
chaining the inverses of ``T_cn_cnm1`` from cam0, whose pose is the robot
frame's (the identity) unless given.  Pixels and intrinsics are taken as
they are (Kalibr's pixel centres are OpenCV's).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ..core.lenses import make_camera
from ..core.pose import Pose
from ..core.rig import CAMERA_SEPARATOR, Mount
from ..errors import FileFormatError, MutlocError, RigError
from ._files import PathLike, as_float_array, as_rotation, load_file, short

__all__ = ["load_kalibr_camchain", "KALIBR_MODELS"]

#: (camera_model, distortion_model) -> mutloc's lens model.
KALIBR_MODELS = {
    ("pinhole", "radtan"): "pinhole",
    ("pinhole", "none"): "pinhole",
    ("pinhole", "equidistant"): "fisheye",
    ("omni", "radtan"): "omni",
    ("omni", "none"): "omni",
}
# Number of intrinsics per Kalibr camera_model, and their names.
_INTRINSICS = {"pinhole": ("fu", "fv", "pu", "pv"), "omni": ("xi", "fu", "fv", "pu", "pv")}
_N_DIST = {"radtan": 4, "equidistant": 4, "none": 0}
_CAM_KEY = re.compile(r"cam(0|[1-9][0-9]*)")


def load_kalibr_camchain(path: PathLike, *, pose: Pose | None = None, where: str | None = None) -> dict[str, Mount]:
    """The cameras of a Kalibr camera chain, by name, each with its pose
    ``T_robot_camera`` (``x_robot = R @ x_camera + t``).

    ``pose`` is cam0's pose in the robot frame (``T_robot_cam0``); default the
    identity: the robot frame is cam0's optical frame.  Camera ``n``'s pose is
    ``pose @ inv(T_c1_c0) @ ... @ inv(T_cn_cnm1)``.  A camera is named after
    its ``rostopic``'s last-but-one component (``/front/image_raw`` ->
    ``front``); if a camera has no such topic, or two would share a name,
    every camera is named by its key (``cam0``, ``cam1``, ...).

    FileFormatError (unreadable file) or RigError (content), one line naming
    the file and the camera.
    """
    w = where if where is not None else f"Kalibr camchain {str(path)!r}"
    data = load_file(Path(path).expanduser(), w, duplicate_error=FileFormatError)
    if not isinstance(data, Mapping) or not data:
        raise FileFormatError(f"{w}: expected a Kalibr camera chain (cam0, cam1, ...), got {short(data)}")
    for key in data:
        if not (isinstance(key, str) and _CAM_KEY.fullmatch(key)):
            raise RigError(f"{w}: key {key!r} is not a camera of a Kalibr chain (cam0, cam1, ...)")
    n = len(data)
    missing = [f"cam{i}" for i in range(n) if f"cam{i}" not in data]
    if missing:
        raise RigError(f"{w}: cameras must be cam0, cam1, ... without gaps: {missing[0]} is missing "
                       f"(the file has {', '.join(sorted(data, key=lambda k: int(k[3:])))})")

    robot_from_cam = Pose.identity() if pose is None else pose
    cameras: list[tuple[str, Any, Pose]] = []
    for i in range(n):
        key = f"cam{i}"
        spec = data[key]
        cw = f"{w}: camera {key!r}"
        if not isinstance(spec, Mapping):
            raise RigError(f"{cw}: must be a mapping (camera_model, intrinsics, ...), got {short(spec)}")
        camera = _camera(spec, cw)
        if i > 0:
            # x_cn = T_cn_cnm1 @ x_cnm1, so T_robot_cn = T_robot_cnm1 @ inv(T_cn_cnm1)
            robot_from_cam = robot_from_cam @ _rigid(spec, cw).inverse()
            R = as_rotation(robot_from_cam.R)  # exact again after the products
            robot_from_cam = Pose(robot_from_cam.R if R is None else R, robot_from_cam.t)
        cameras.append((key, camera, robot_from_cam))

    names = [_topic_name(data[key].get("rostopic")) for key, _, _ in cameras]
    if any(nm is None for nm in names) or len(set(names)) != len(names):
        names = [key for key, _, _ in cameras]
    try:
        return {nm: Mount(nm, cam, T) for nm, (_, cam, T) in zip(names, cameras)}
    except MutlocError as exc:
        raise type(exc)(f"{w}: {exc}") from None


def _topic_name(topic: Any) -> str | None:
    """``front`` of ``/front/image_raw``; None without a last-but-one component."""
    if not isinstance(topic, str):
        return None
    parts = [p for p in topic.strip().split("/") if p]
    if len(parts) < 2 or CAMERA_SEPARATOR in parts[-2]:
        return None
    return parts[-2]


def _camera(spec: Mapping[str, Any], cw: str) -> Any:
    cmodel, dmodel = spec.get("camera_model"), spec.get("distortion_model", "none")
    for key, value, known in (("camera_model", cmodel, tuple(_INTRINSICS)), ("distortion_model", dmodel, tuple(_N_DIST))):
        if value is None:
            raise RigError(f"{cw}: missing key {key!r} ({' | '.join(known)})")
        if not isinstance(value, str) or value not in known:
            raise RigError(f"{cw}: {key} {value!r} is not supported (mutloc reads Kalibr's "
                           f"{', '.join(f'{c}-{d}' for c, d in KALIBR_MODELS)})")
    model = KALIBR_MODELS.get((cmodel, dmodel))
    if model is None:
        raise RigError(f"{cw}: {cmodel}-{dmodel} is not supported (mutloc reads Kalibr's "
                       f"{', '.join(f'{c}-{d}' for c, d in KALIBR_MODELS)})")

    names = _INTRINSICS[cmodel]
    if "intrinsics" not in spec:
        raise RigError(f"{cw}: missing key 'intrinsics' ({', '.join(names)})")
    intr = as_float_array(spec["intrinsics"])
    if intr is None or intr.shape != (len(names),) or not np.all(np.isfinite(intr)):
        raise RigError(f"{cw}: intrinsics must be {len(names)} finite numbers ({', '.join(names)}) for camera_model "
                       f"{cmodel}, got {short(spec['intrinsics'])}")
    xi = float(intr[0]) if cmodel == "omni" else None
    fu, fv, pu, pv = intr[-4:]
    K = np.array([[fu, 0.0, pu], [0.0, fv, pv], [0.0, 0.0, 1.0]])

    nd = _N_DIST[dmodel]
    dval = spec.get("distortion_coeffs", [] if nd == 0 else None)
    if dval is None:
        raise RigError(f"{cw}: missing key 'distortion_coeffs' ({nd} numbers for distortion_model {dmodel})")
    dist = as_float_array(dval)
    if dist is None or dist.ndim != 1 or dist.size != nd or not np.all(np.isfinite(dist)):
        raise RigError(f"{cw}: distortion_coeffs must be {nd} finite numbers for distortion_model {dmodel}, "
                       f"got {short(dval)}")

    size = spec.get("resolution")
    if size is not None:
        wh = as_float_array(size)
        if wh is None or wh.shape != (2,) or not np.all(wh == np.round(wh)) or not np.all(wh > 0):
            raise RigError(f"{cw}: resolution must be two positive integers [width, height], got {short(size)}")
        size = (int(wh[0]), int(wh[1]))
    return make_camera(model, K, dist if nd else None, size, xi, where=cw)


def _rigid(spec: Mapping[str, Any], cw: str) -> Pose:
    """``T_cn_cnm1`` of a camera after cam0, checked rigid."""
    if "T_cn_cnm1" not in spec:
        raise RigError(f"{cw}: missing key 'T_cn_cnm1' (its pose relative to the previous camera, 4x4)")
    T = as_float_array(spec["T_cn_cnm1"])
    if T is None or T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise RigError(f"{cw}: T_cn_cnm1 must be a 4x4 matrix of finite numbers, got {short(spec['T_cn_cnm1'])}")
    R = as_rotation(T[:3, :3])
    if R is None or np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-9:
        raise RigError(f"{cw}: T_cn_cnm1 is not a rigid transform (rotation block orthonormal with determinant +1, "
                       "last row 0 0 0 1)")
    return Pose(R, T[:3, 3])
