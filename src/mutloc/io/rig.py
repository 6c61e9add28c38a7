"""Reading and writing rig files (YAML or JSON), see SPEC "Rig file".

A camera is given inline (``{model?, K, dist?, size?, xi?}``) or as a path,
relative to the rig file's folder, to a calibration file: a ROS
``camera_info`` YAML (ROS 1 ``camera_matrix: {rows, cols, data}`` form or the
ROS 2 message form ``k``/``d``/``width``/``height``; ``distortion_model``
``equidistant`` is the fisheye model) or an OpenCV ``FileStorage`` calibration
(YAML or XML, read with :class:`cv2.FileStorage`).

A robot has one ``camera`` (its frame is that camera's optical frame) or
``cameras``: a body with cameras by name, each with its ``pose``
(``T_robot_camera``), inline, in a camera file, or a Kalibr camera chain
(``cameras: {kalibr: FILE, pose?: T_robot_cam0}``, :mod:`.kalibr`).

Every problem raises a one-line error that says where it is (file, robot,
key, marker): an unreadable or unparsable file raises FileFormatError, a
well-formed file with wrong content raises RigError.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from ..core.geometry import so3_exp, so3_log
from ..core.lenses import MODELS, Lens, make_camera
from ..core.pose import Pose
from ..core.rig import CAMERA_SEPARATOR, MAX_MARKER_DISTANCE_M, Marker, Mount, Rig, Robot
from ..errors import FileFormatError, MutlocError, RigError
from ._files import (
    PathLike,
    as_float_array,
    as_rotation,
    is_number,
    is_path,
    load_file,
    named_items,
    one_line,
    parse_text,
    read_text,
    short,
    to_builtin,
)
from .kalibr import load_kalibr_camchain

__all__ = ["load_rig", "save_rig", "load_camera_file", "rig_from_dict"]

# Marker keys with a meaning of their own; EXTRA_MARKER_KEYS are kept in
# Marker.extra.  Any other key is a mistake (a misspelt key would otherwise
# silently change how a marker is found).
MARKER_KEYS = ("position", "color", "blink_hz", "tag", "frame")
EXTRA_MARKER_KEYS = ("radius", "phase", "intensity", "cylinder", "position_sigma",
                     "tag_of", "tag_corner", "cylinder_of", "band")  # the last four: derived points
# Keys of the user's own (kept in Marker.extra, never interpreted) start with this.
USER_KEY_PREFIX = "x_"
TAG_KEYS = ("family", "id", "size", "rotation", "rotation_sigma")
ROBOT_KEYS = ("camera", "cameras", "markers", "base_from_camera")
# A pose (base_from_camera, a camera's pose): t and one of R, rotation, quaternion_xyzw.
BASE_KEYS = ("R", "rotation", "quaternion_xyzw", "t")
# A camera under a robot's cameras: inline, or a camera file with its pose beside it.
CAMERA_KEYS = ("model", "K", "dist", "size", "xi", "pose")
CAMERA_FILE_KEYS = ("file", "pose")
# cameras: {kalibr: FILE, pose?}: a Kalibr camera chain, pose = T_robot_cam0.
KALIBR_KEYS = ("kalibr", "pose")
# A quaternion's norm may be off 1 by this much (rounding); it is then normalised.
QUATERNION_TOL = 1e-6
# Where a marker's position (and a tag's rotation) is given: the camera's optical frame or the robot's base.
MARKER_FRAMES = ("camera", "base")
RIG_KEYS = ("robots",)
# A tag larger than this (metres) is a unit mistake (millimetres?).
MAX_TAG_SIZE_M = 2.0

# Calibration-file key aliases, in order of preference.
_K_KEYS = ("K", "camera_matrix", "cameraMatrix", "k", "intrinsic_matrix")
_DIST_KEYS = ("dist", "distortion_coefficients", "dist_coeffs", "distCoeffs", "D", "d", "distortion")
_SIZE_KEYS = ("size", "image_size", "imageSize")
_WH_KEYS = (("image_width", "image_height"), ("width", "height"))
# ROS camera_info distortion models (and their like in calibration files) -> lens model:
# OpenCV's pinhole (k1, k2, p1, p2[, k3[, k4, k5, k6]]) or fisheye (k1..k4).
_DISTORTION_MODELS = {"plumb_bob": "pinhole", "rational_polynomial": "pinhole", "pinhole": "pinhole",
                      "radtan": "pinhole", "none": "pinhole", "": "pinhole", "equidistant": "fisheye",
                      "fisheye": "fisheye"}


# ---------------------------------------------------------------------------
# public API
# ---------------------------------------------------------------------------


def load_rig(source: PathLike | Mapping[str, Any] | Rig, *, base_dir: PathLike | None = None) -> Rig:
    """Load a rig from a YAML/JSON file path or from a dict in rig-file form.

    Camera paths are resolved against the rig file's folder (for a dict:
    ``base_dir``, default the current directory).  A :class:`Rig` is returned
    unchanged.  Raises FileFormatError (unreadable/unparsable file) or RigError
    (invalid content), each with a one-line message naming file, robot and key.
    """
    if isinstance(source, Rig):
        return source
    if is_path(source):
        path = Path(source).expanduser()
        where = str(source)
        data = load_file(path, where, duplicate_error=RigError)
        base = path.parent if base_dir is None else Path(base_dir)
        return rig_from_dict(data, where=where, base_dir=base)
    if isinstance(source, Mapping):
        return rig_from_dict(source, where="rig", base_dir=Path.cwd() if base_dir is None else Path(base_dir))
    raise RigError(f"rig must be a file path or a mapping with key 'robots' (rig-file form), got {type(source).__name__}")


def save_rig(rig: Rig | Mapping[str, Any], path: PathLike) -> None:
    """Write ``rig`` (cameras inline) to ``path``: JSON if it ends in ``.json``,
    else YAML.  The file loads back with :func:`load_rig` to an equal rig."""
    data = to_builtin(rig.to_dict() if isinstance(rig, Rig) else rig)
    path = Path(path).expanduser()
    if path.suffix.lower() == ".json":
        text = json.dumps(data, indent=2) + "\n"
    else:
        text = yaml.safe_dump(data, sort_keys=False, default_flow_style=None, allow_unicode=True)
    path.write_text(text, encoding="utf-8")


def load_camera_file(path: PathLike, *, where: str | None = None) -> Lens:
    """A camera from a calibration file: ROS ``camera_info`` YAML, OpenCV
    ``FileStorage`` (YAML/XML/JSON), or a YAML/JSON ``{model?, K, dist?, size?, xi?}``.

    The lens model is the file's ``model`` (``pinhole``, ``fisheye``, ``omni``),
    else its ``distortion_model`` (ROS: ``plumb_bob``, ``rational_polynomial`` ->
    pinhole :class:`~mutloc.core.camera.Camera`; ``equidistant`` ->
    :class:`~mutloc.core.lenses.FisheyeCamera`), else OpenCV's
    ``fisheye_model: 1`` (fisheye) or an ``xi`` entry (omnidir:
    :class:`~mutloc.core.lenses.OmniCamera`); pinhole without any.  A ``pose``
    in the file is not read here (see rig files' ``cameras``)."""
    where = where if where is not None else f"camera file {str(path)!r}"
    return _camera_from_mapping(_read_camera_file(Path(path).expanduser(), where), where, in_file=True)


def _read_camera_file(p: Path, where: str) -> Mapping[str, Any]:
    """A calibration file's entries as a mapping."""
    name = p.name.lower()
    if name.endswith(".gz"):
        if not p.is_file():
            raise FileFormatError(f"{where}: cannot read file: No such file")
        return _read_filestorage(p, where)
    text = read_text(p, where)
    head = text.lstrip()[:256]
    opencv = (
        name.endswith(".xml")
        or head.startswith("%YAML:")
        or head.startswith("<")
        or "opencv-matrix" in text
        or "opencv_storage" in head
    )
    if opencv:
        data = _read_filestorage(p, where)
    else:
        data = parse_text(text, where, as_json=name.endswith(".json"), duplicate_error=FileFormatError)
        if not isinstance(data, Mapping):
            raise FileFormatError(
                f"{where}: expected a camera calibration mapping (ROS camera_info or {{K, dist, size}}), "
                f"got {type(data).__name__}"
            )
    return data


def check_keys(spec: Mapping, known: tuple[str, ...], w: str) -> None:
    """RigError naming the first unknown key and the nearest known one (keys
    starting with ``x_`` are the user's own and always allowed)."""
    import difflib

    for k in spec:
        if not isinstance(k, str):
            raise RigError(f"{w}: key {k!r} must be a string")
        if k not in known and not k.startswith(USER_KEY_PREFIX):
            near = difflib.get_close_matches(k, known, n=1, cutoff=0.5)
            hint = f" (did you mean {near[0]!r}?)" if near else f" (known keys: {', '.join(known)})"
            raise RigError(f"{w}: unknown key {k!r}{hint}")


def rig_from_dict(data: Any, *, where: str = "rig", base_dir: PathLike | None = None) -> Rig:
    """Build a :class:`Rig` from parsed rig-file data; ``where`` prefixes errors."""
    base = Path.cwd() if base_dir is None else Path(base_dir)
    if data is None:
        raise RigError(f"{where}: empty rig (expected a mapping with key 'robots')")
    if not isinstance(data, Mapping):
        raise RigError(f"{where}: expected a mapping with key 'robots', got {type(data).__name__}")
    check_keys(data, RIG_KEYS, where)
    if "robots" not in data:
        raise RigError(f"{where}: missing key 'robots'")
    robots_spec = data["robots"]
    if not isinstance(robots_spec, Mapping):
        raise RigError(f"{where}: 'robots' must be a mapping of robot name to {{camera, markers}}, "
                       f"got {short(robots_spec)}")
    if not robots_spec:
        raise RigError(f"{where}: 'robots' is empty")

    robots: dict[str, Robot] = {}
    for rname, rspec in named_items(robots_spec, "robot", f"{where}: robots", RigError):
        robots[rname] = _robot(rname, rspec, where, base)

    try:
        return Rig(robots)
    except MutlocError as exc:
        raise type(exc)(f"{where}: {exc}") from None


# ---------------------------------------------------------------------------
# robots and markers
# ---------------------------------------------------------------------------


def _robot(name: str, spec: Any, where: str, base: Path) -> Robot:
    w = f"{where}: robot {name!r}"
    if not isinstance(spec, Mapping):
        raise RigError(f"{w}: must be a mapping with keys 'camera' and 'markers', got {short(spec)}")
    check_keys(spec, ROBOT_KEYS, w)
    if "camera" in spec and "cameras" in spec:
        raise RigError(f"{w}: give either 'camera' (one camera, whose optical frame is the robot's) or 'cameras' "
                       "(several, each with its pose in the robot frame), not both")
    if "camera" not in spec and "cameras" not in spec:
        raise RigError(f"{w}: missing key 'camera' (or 'cameras' for several)")
    if "markers" not in spec:
        raise RigError(f"{w}: missing key 'markers'")
    body = "cameras" in spec
    if body:
        if spec.get("base_from_camera") is not None:
            raise RigError(f"{w}: base_from_camera is for a robot with one camera: with 'cameras', give each "
                           "camera's pose in the robot frame")
        camera, mounts, bfc = None, _cameras(spec["cameras"], f"{w}: cameras", base), None
    else:
        camera, mounts = _camera(spec["camera"], f"{w}: camera", base), None
        bfc = _base_from_camera(spec.get("base_from_camera"), f"{w}: base_from_camera")

    mspec = spec["markers"]
    if not isinstance(mspec, Mapping):
        raise RigError(f"{w}: 'markers' must be a mapping of marker name to {{position, ...}}, got {short(mspec)}")
    markers: dict[str, Marker] = {}
    for mname, mval in named_items(mspec, "marker", f"{w}: markers", RigError):
        markers[mname] = _marker(mname, name, mval, f"{w}: marker {mname!r}", bfc, body=body)
    try:
        return Robot(name=name, camera=camera, markers=markers, base_from_camera=bfc, cameras=mounts)
    except MutlocError as exc:
        raise type(exc)(f"{where}: {exc}") from None


def _base_from_camera(spec: Any, w: str) -> Pose | None:
    """The camera's pose in the robot's base frame (see :func:`_pose`); None if not given."""
    return None if spec is None else _pose(spec, w)


def _pose(spec: Any, w: str) -> Pose:
    """A pose ``{t, R | rotation | quaternion_xyzw}``: ``x_to = R @ x_from + t``
    (``rotation`` a rotation vector in radians).  A rotation off by rounding
    (1e-6) is made exact, a quaternion normalised; more is a one-line RigError."""
    if not isinstance(spec, Mapping):
        raise RigError(f"{w}: must be a mapping {{R or rotation or quaternion_xyzw, t}}, got {short(spec)}")
    check_keys(spec, BASE_KEYS, w)
    given = [k for k in ("R", "rotation", "quaternion_xyzw") if k in spec]
    if len(given) != 1 or "t" not in spec:
        raise RigError(f"{w}: needs 't' (metres) and exactly one of 'R' (3x3), 'rotation' (rotation vector, "
                       f"radians) or 'quaternion_xyzw', got keys {sorted(spec)}")
    t = as_float_array(spec["t"])
    if t is None or t.shape != (3,) or not np.all(np.isfinite(t)):
        raise RigError(f"{w}: t must be 3 finite numbers (metres), got {short(spec['t'])}")
    if float(np.linalg.norm(t)) > MAX_MARKER_DISTANCE_M:
        raise RigError(f"{w}: t is {float(np.linalg.norm(t)):g} m long: positions are in metres "
                       "(millimetres given?)")
    key = given[0]
    v = as_float_array(spec[key])
    shape = {"R": (3, 3), "rotation": (3,), "quaternion_xyzw": (4,)}[key]
    if v is None or v.shape != shape or not np.all(np.isfinite(v)):
        raise RigError(f"{w}: {key} must be {'a 3x3 matrix' if key == 'R' else f'{shape[0]} finite numbers'}, "
                       f"got {short(spec[key])}")
    if key == "R":
        R = as_rotation(v)
        if R is None:
            raise RigError(f"{w}: R is not a rotation matrix (orthonormal, determinant +1)")
        return Pose(R, t)
    if key == "rotation":
        return Pose.from_rotvec(v, t)
    norm = float(np.linalg.norm(v))
    if not abs(norm - 1.0) <= QUATERNION_TOL:
        raise RigError(f"{w}: quaternion_xyzw must be a unit quaternion [x, y, z, w], its norm is {norm:.9g}")
    return Pose.from_quaternion_xyzw(v / norm, t)


def _marker(name: str, robot: str, spec: Any, w: str, base_from_camera: Pose | None = None, *,
            body: bool = False) -> Marker:
    if not isinstance(spec, Mapping):
        raise RigError(f"{w}: must be a mapping with at least 'position', got {short(spec)}")
    check_keys(spec, MARKER_KEYS + EXTRA_MARKER_KEYS, w)
    if "position" not in spec:
        raise RigError(f"{w}: missing key 'position'")
    pos = as_float_array(spec["position"])
    if pos is None or pos.shape != (3,):
        raise RigError(f"{w}: position must be 3 numbers [x, y, z] (metres), got {short(spec['position'])}")
    if not np.all(np.isfinite(pos)):
        raise RigError(f"{w}: position must be finite, got {short(spec['position'])}")

    color = _color(spec.get("color"), w)
    blink = _blink(spec.get("blink_hz"), w)
    tag = _tag(spec.get("tag"), w)
    frame = spec.get("frame", "base" if body else "camera")
    if frame not in MARKER_FRAMES:
        raise RigError(f"{w}: frame must be 'camera' or 'base', got {short(frame)}")
    if body and frame == "camera":
        raise RigError(f"{w}: a robot with 'cameras' has its markers in its robot (base) frame: frame 'camera' is "
                       "for a robot given with one 'camera'")
    if frame == "base" and not body:
        # Stored in the camera frame like every marker: the solvers never see the base.
        if base_from_camera is None:
            raise RigError(f"{w}: frame 'base' needs the robot's base_from_camera")
        if spec.get("cylinder") is not None:
            raise RigError(f"{w}: a banded cylinder's axis is the camera's y: give it in the camera frame")
        cam_from_base = base_from_camera.inverse()
        pos = cam_from_base.apply(pos)
        if tag is not None and "rotation" in tag:
            rot = as_float_array(tag["rotation"])
            if rot is None or rot.shape != (3,):
                raise RigError(f"{w}: tag: rotation must be 3 numbers (rotation vector, radians)")
            tag = dict(tag, rotation=so3_log(cam_from_base.R @ so3_exp(rot)).tolist())

    extra: dict[str, Any] = {}
    for k, v in spec.items():
        if k not in MARKER_KEYS:
            extra[k] = to_builtin(v)
    try:
        return Marker(name=name, robot=robot, position=pos, color=color, blink_hz=blink, tag=tag, extra=extra)
    except MutlocError as exc:
        raise type(exc)(f"{w}: {exc}") from None


def _integral(x: Any) -> int | None:
    """``x`` as an int if it is an integer (or an integral float), else None."""
    if not is_number(x):
        return None
    if isinstance(x, (int, np.integer)):
        return int(x)
    f = float(x)
    return int(f) if math.isfinite(f) and f.is_integer() else None


def _color(value: Any, w: str) -> tuple[int, int, int] | None:
    if value is None:
        return None
    items = list(value) if isinstance(value, (list, tuple, np.ndarray)) else None
    ints = [_integral(x) for x in items] if items is not None else None
    if ints is None or len(ints) != 3 or any(c is None or not 0 <= c <= 255 for c in ints):
        raise RigError(f"{w}: color must be 3 integers [r, g, b] in 0..255, got {short(value)}")
    return (ints[0], ints[1], ints[2])


def _blink(value: Any, w: str) -> float | None:
    if value is None:
        return None
    if not is_number(value) or not math.isfinite(float(value)) or not float(value) > 0:
        raise RigError(f"{w}: blink_hz must be a finite number > 0, got {short(value)}")
    return float(value)


def _tag(value: Any, w: str) -> dict[str, Any] | None:
    if value is None:
        return None
    if not isinstance(value, Mapping):
        raise RigError(f"{w}: tag must be a mapping {{family, id, size}}, got {short(value)}")
    check_keys(value, TAG_KEYS, f"{w}: tag")
    for key in ("family", "id", "size"):
        if key not in value:
            raise RigError(f"{w}: tag: missing key {key!r}")
    family = value["family"]
    if not isinstance(family, str) or not family.strip():
        raise RigError(f"{w}: tag: family must be a non-empty string (e.g. tag36h11), got {short(family)}")
    tid = value["id"]
    if not isinstance(tid, (int, np.integer)) or isinstance(tid, (bool, np.bool_)) or tid < 0:
        raise RigError(f"{w}: tag: id must be a non-negative integer, got {short(tid)}")
    size = value["size"]
    if not is_number(size) or not math.isfinite(float(size)) or not float(size) > 0:
        raise RigError(f"{w}: tag: size must be a finite number > 0 (metres), got {short(size)}")
    if float(size) > MAX_TAG_SIZE_M:
        raise RigError(f"{w}: tag: size {float(size):g} m is not plausible: sizes are in metres (millimetres given?)")
    out: dict[str, Any] = {"family": family, "id": int(tid), "size": float(size)}
    for k, v in value.items():
        if k not in out:
            out[str(k)] = to_builtin(v)
    return out


# ---------------------------------------------------------------------------
# cameras
# ---------------------------------------------------------------------------


def _camera(spec: Any, w: str, base: Path) -> Lens:
    """A robot's one ``camera``: inline or a file; its frame is the robot's, so no pose."""
    if isinstance(spec, str):
        path, cw = _file_path(spec, w, base)
        data = _read_camera_file(path, cw)
        if "pose" in data:
            raise RigError(f"{cw}: has a pose: a robot given with 'camera' has that camera's frame (its pose in a "
                           "base frame is the robot's base_from_camera; several posed cameras are 'cameras')")
        return _camera_from_mapping(data, cw, in_file=True)
    if isinstance(spec, Mapping):
        if "pose" in spec:
            raise RigError(f"{w}: pose is for the cameras of a robot given with 'cameras': a robot's one 'camera' "
                           "has the robot's frame (its pose in a base frame is base_from_camera)")
        return _camera_from_mapping(spec, w, in_file=False)
    raise RigError(
        f"{w}: must be a mapping {{model?, K, dist?, size?, xi?}} or a calibration file path, got {short(spec)}"
    )


def _file_path(spec: str, w: str, base: Path) -> tuple[Path, str]:
    """A file named in the rig, resolved against the rig's folder, and how errors name it."""
    if not spec.strip():
        raise RigError(f"{w}: file path is empty")
    ref = Path(spec).expanduser()
    path = ref if ref.is_absolute() else base / ref
    return path, f"{w}: file {spec!r}" + ("" if ref.is_absolute() else f" ({path})")


def _cameras(spec: Any, w: str, base: Path) -> dict[str, Mount]:
    """A robot's ``cameras``: name -> camera with its pose (inline, a camera file, ``{file, pose}``), or
    ``{kalibr: FILE, pose?}``."""
    if isinstance(spec, Mapping) and not spec:
        raise RigError(f"{w}: is empty (give at least one camera)")
    if not isinstance(spec, Mapping):
        raise RigError(f"{w}: must be a mapping of camera name to camera (inline, a file, or {{file, pose}}), or "
                       f"{{kalibr: FILE}}, got {short(spec)}")
    if "kalibr" in spec:
        check_keys(spec, KALIBR_KEYS, f"{w} (a Kalibr camera chain)")
        if not isinstance(spec["kalibr"], str):
            raise RigError(f"{w}: kalibr must be the path of a Kalibr camchain file, got {short(spec['kalibr'])}")
        path, cw = _file_path(spec["kalibr"], f"{w}: kalibr", base)
        pose = _pose(spec["pose"], f"{w}: pose") if "pose" in spec else None
        return load_kalibr_camchain(path, pose=pose, where=cw)
    mounts: dict[str, Mount] = {}
    for cname, cspec in named_items(spec, "camera", w, RigError):
        cw = f"{w}: camera {cname!r}"
        if CAMERA_SEPARATOR in cname:
            raise RigError(f"{cw}: a camera name must not contain {CAMERA_SEPARATOR!r} (observations name it "
                           f"ROBOT{CAMERA_SEPARATOR}CAMERA)")
        pose_spec: Any = None
        if isinstance(cspec, str) or (isinstance(cspec, Mapping) and "file" in cspec):
            if isinstance(cspec, Mapping):
                check_keys(cspec, CAMERA_FILE_KEYS, cw)
                if not isinstance(cspec["file"], str):
                    raise RigError(f"{cw}: file must be a calibration file path, got {short(cspec['file'])}")
                path, fw = _file_path(cspec["file"], cw, base)
                pose_spec = cspec.get("pose")
            else:
                path, fw = _file_path(cspec, cw, base)
            data = _read_camera_file(path, fw)
            if "pose" in data:
                if pose_spec is not None:
                    raise RigError(f"{cw}: pose given both in the file {path.name!r} and beside it: give one")
                pose_spec, pw = data["pose"], f"{fw}: pose"
            else:
                pw = f"{cw}: pose"
            camera = _camera_from_mapping(data, fw, in_file=True)
        elif isinstance(cspec, Mapping):
            check_keys(cspec, CAMERA_KEYS, cw)
            camera = _camera_from_mapping({k: v for k, v in cspec.items() if k != "pose"}, cw, in_file=False)
            pose_spec, pw = cspec.get("pose"), f"{cw}: pose"
        else:
            raise RigError(f"{cw}: must be a mapping {{model?, K, dist?, size?, xi?, pose?}}, a calibration file "
                           f"path or {{file, pose}}, got {short(cspec)}")
        pose = Pose.identity() if pose_spec is None else _pose(_plain_pose(pose_spec), pw)
        try:
            mounts[cname] = Mount(cname, camera, pose)
        except MutlocError as exc:
            raise type(exc)(f"{cw}: {exc}") from None
    return mounts


def _plain_pose(spec: Any) -> Any:
    """A pose read from an OpenCV FileStorage file: its (3, 1) / (1, 3) matrices flattened."""
    if not isinstance(spec, Mapping):
        return spec
    return {k: (v.ravel() if isinstance(v, np.ndarray) and v.ndim == 2 and 1 in v.shape else v)
            for k, v in spec.items()}


def _first(d: Mapping[str, Any], keys: tuple[str, ...]) -> tuple[str | None, Any]:
    for k in keys:
        if k in d and d[k] is not None:
            return k, d[k]
    return None, None


def _matrix(value: Any, w: str, what: str) -> np.ndarray:
    """A numeric array from a list, nested list, ndarray, or a ``{rows, cols,
    data}`` mapping (ROS camera_info / OpenCV JSON matrices)."""
    if isinstance(value, Mapping):
        if "data" not in value:
            raise RigError(f"{w}: {what} must be a list or a {{rows, cols, data}} mapping, got keys {sorted(map(str, value))}")
        arr = as_float_array(value["data"])
        if arr is None:
            raise RigError(f"{w}: {what}: data must be a list of numbers, got {short(value['data'])}")
        arr = arr.ravel()
        rows, cols = value.get("rows"), value.get("cols")
        if rows is not None or cols is not None:
            r, c = _integral(rows), _integral(cols)
            if r is None or c is None or r < 0 or c < 0:
                raise RigError(f"{w}: {what}: rows and cols must be integers, got rows={short(rows)}, cols={short(cols)}")
            if r * c != arr.size:
                raise RigError(f"{w}: {what}: rows x cols = {r} x {c} but data has {arr.size} numbers")
            arr = arr.reshape(r, c)
        return arr
    arr = as_float_array(value)
    if arr is None:
        raise RigError(f"{w}: {what} must be numbers, got {short(value)}")
    return arr


def _lens_model(d: Mapping[str, Any], w: str, *, in_file: bool) -> tuple[Any, str]:
    """The camera's lens model (as given, for :func:`make_camera`, which names the nearest on a misspelling)
    and how it was said, for error messages: ``model``, a ROS ``distortion_model``, and in a file OpenCV's
    ``fisheye_model: 1`` or an omnidir ``xi``."""
    import difflib

    said: list[tuple[str, str]] = []  # (lens model, how it was said)
    dmodel = d.get("distortion_model")
    if dmodel is not None:
        name = dmodel.strip().lower() if isinstance(dmodel, str) else None
        if name not in _DISTORTION_MODELS:
            known = [k for k in _DISTORTION_MODELS if k]
            near = difflib.get_close_matches(name or "", known, n=1, cutoff=0.5)
            hint = f"; did you mean {near[0]!r}?" if near else ""
            raise RigError(f"{w}: distortion_model {dmodel!r} is not supported (plumb_bob, rational_polynomial: "
                           f"pinhole; equidistant: fisheye){hint}")
        said.append((_DISTORTION_MODELS[name], f"distortion_model {dmodel!r}"))
    if in_file and "model" not in d:
        fisheye = d.get("fisheye_model")
        if is_number(fisheye) and float(fisheye) == 1.0:
            said.append(("fisheye", "fisheye_model 1"))
        elif "xi" in d and not said:
            said.append(("omni", "xi (omnidir)"))
    model = d.get("model")
    if model is not None:
        name = model.strip().lower() if isinstance(model, str) else None
        for other, how in said:
            if name in MODELS and name != other:
                raise RigError(f"{w}: model {model!r} but {how} (model {other!r}): give one")
        return model, f"model {model!r}"
    if said:
        return said[0]
    return None, "pinhole"


def _camera_from_mapping(d: Mapping[str, Any], w: str, *, in_file: bool) -> Lens:
    model, said = _lens_model(d, w, in_file=in_file)

    kkey, kval = _first(d, _K_KEYS)
    if kkey is None:
        if in_file:
            raise FileFormatError(
                f"{w}: no camera matrix found (looked for keys {', '.join(_K_KEYS)})"
            )
        raise RigError(f"{w}: missing key 'K'")
    K = _matrix(kval, w, kkey)
    if K.size == 9 and K.ndim <= 2 and K.shape in ((9,), (1, 9), (9, 1), (3, 3)):
        K = K.reshape(3, 3)
    else:
        raise RigError(f"{w}: {kkey} must be a 3x3 matrix (or 9 numbers row by row), got {short(kval)}")
    if not np.all(np.isfinite(K)):
        raise RigError(f"{w}: {kkey} must be finite, got {short(K)}")

    dkey, dval = _first(d, _DIST_KEYS)
    dist: np.ndarray | None = None
    if dkey is not None:
        arr = _matrix(dval, w, dkey)
        if arr.ndim == 2 and 1 in arr.shape:
            arr = arr.ravel()
        if arr.ndim != 1:
            raise RigError(f"{w}: {dkey} must be a flat list of numbers, got {short(dval)}")
        if not np.all(np.isfinite(arr)):
            raise RigError(f"{w}: {dkey} must be finite, got {short(dval)}")
        dist = arr if arr.size else None

    size = _size(d, w)
    xi = d.get("xi")
    if isinstance(xi, np.ndarray) and xi.size == 1:  # OpenCV omnidir writes xi as a 1x1 matrix
        xi = float(xi.ravel()[0])

    try:
        return make_camera(model, K, dist, size, xi, where=w if model is None or said.startswith("model") else
                           f"{w} ({said})")
    except MutlocError:
        raise
    except (ValueError, TypeError) as exc:  # defensive: keep it one line and typed
        raise RigError(f"{w}: {one_line(exc)}") from None


def _size(d: Mapping[str, Any], w: str) -> tuple[int, int] | None:
    skey, sval = _first(d, _SIZE_KEYS)
    if skey is not None:
        arr = _matrix(sval, w, skey).ravel()
        wh = [_integral(x) for x in arr.tolist()]
        if len(wh) != 2 or any(x is None or x <= 0 for x in wh):
            raise RigError(f"{w}: {skey} must be two positive integers [width, height], got {short(sval)}")
        return (wh[0], wh[1])
    for wk, hk in _WH_KEYS:
        if wk in d or hk in d:
            if wk not in d or hk not in d:
                raise RigError(f"{w}: {wk!r} and {hk!r} must be given together")
            wv, hv = _integral(d[wk]), _integral(d[hk])
            if wv is None or hv is None or wv < 0 or hv < 0:
                raise RigError(
                    f"{w}: {wk}/{hk} must be non-negative integers, got {short(d[wk])}/{short(d[hk])}"
                )
            if wv == 0 and hv == 0:  # ROS writes 0 x 0 when the size is unknown
                return None
            if wv == 0 or hv == 0:
                raise RigError(f"{w}: image size must be positive, got {wv} x {hv}")
            return (wv, hv)
    return None


def _read_filestorage(path: Path, where: str) -> dict[str, Any]:
    """Top-level entries of an OpenCV FileStorage file as plain Python data."""
    import cv2

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:
        cause = exc.__cause__ if isinstance(exc, SystemError) and exc.__cause__ is not None else exc
        raise FileFormatError(f"{where}: not a valid OpenCV FileStorage file: {_cv_message(cause)}") from None
    try:
        if not fs.isOpened():
            raise FileFormatError(f"{where}: cannot open as an OpenCV FileStorage file")
        root = fs.root()
        out: dict[str, Any] = {}
        try:
            for key in root.keys():
                out[key] = _fs_value(root.getNode(key))
        except (cv2.error, SystemError) as exc:
            raise FileFormatError(f"{where}: cannot read OpenCV FileStorage entry: {_cv_message(exc)}") from None
        return out
    finally:
        fs.release()


def _fs_value(node: Any) -> Any:
    if node.isMap():
        keys = list(node.keys())
        if {"rows", "cols", "data"} <= set(keys):
            import cv2

            try:
                mat = node.mat()
            except (cv2.error, SystemError):
                mat = None
            if mat is not None:
                return np.asarray(mat)
        return {k: _fs_value(node.getNode(k)) for k in keys}
    if node.isSeq():
        return [_fs_value(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    return None


def _cv_message(exc: BaseException) -> str:
    msg = one_line(exc)
    # "OpenCV(5.0.0) /path/file.cpp:681: error: (-212:Parsing error) parseValue in function '...'"
    if "error:" in msg:
        msg = msg.split("error:", 1)[1].strip()
    return msg
