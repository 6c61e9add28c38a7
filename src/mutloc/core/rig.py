"""The rig model: robots, each a camera plus markers in its camera frame, or
a body: several cameras (any lens), each with its pose in the robot's frame,
plus markers in that frame (SPEC "Robots with several cameras, any lens").

Observations name their observer ``ROBOT`` (a robot with one camera) or
``ROBOT/CAMERA``; :meth:`Rig.observer` resolves either to the robot and the
camera.  Pure data and validation; reading rig files lives in
:mod:`mutloc.io.rig`.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from functools import cached_property
from enum import Enum
from typing import Any, Mapping

import numpy as np

from ..errors import ObservationError, RigError, UnknownMarkerError
from .camera import Camera
from .pose import Pose

__all__ = ["Marker", "MarkerKind", "Mount", "Robot", "Rig", "PairTable", "DETECTED_KINDS", "CAMERA_SEPARATOR"]

#: Between a robot's and a camera's name in an observer key: ``p/front``.
CAMERA_SEPARATOR = "/"
# A pose's rotation may be off orthonormal by this much (rounding in a file).
_ROTATION_TOL = 1e-6

# Markers closer than this (metres) on one robot cannot be told apart.
COINCIDENT_TOL_M = 1e-6
# A marker farther than this from its own camera is a unit mistake
# (millimetres or centimetres given for metres), not a robot.
MAX_MARKER_DISTANCE_M = 5.0


class MarkerKind(str, Enum):
    """How a marker is seen: the closed set of kinds, decided by
    :attr:`Marker.kind` and nowhere else."""

    BALL = "ball"                    # a coloured ball, found by its colour (``color``)
    LIGHT = "light"                  # a blinking light, found by its blink (``blink_hz``), never by colour
    TAG = "tag"                      # a printed tag (``tag: {family, id, size}``)
    CYLINDER = "cylinder"            # a banded cylinder (``cylinder: {radius, height, code}``)
    TAG_CORNER = "tag_corner"        # a corner of an oriented tag (derived, ``NAME#k``)
    CYLINDER_BAND = "cylinder_band"  # a band centre of a cylinder (derived, ``NAME#bk``)
    POINT = "point"                  # a known point without a detector: pixels are given


#: Kinds a detector looks for in images (derived points come with their parent).
DETECTED_KINDS = (MarkerKind.BALL, MarkerKind.LIGHT, MarkerKind.TAG, MarkerKind.CYLINDER)


@dataclass(frozen=True, eq=False)
class Marker:
    """A fiducial marker; ``position`` is its centre in its robot's frame (the camera's optical frame for a
    robot with one camera given with ``camera:``)."""

    name: str
    robot: str
    position: np.ndarray
    color: tuple[int, int, int] | None = None
    blink_hz: float | None = None
    tag: Mapping[str, Any] | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        pos = np.asarray(self.position, dtype=float)
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise RigError(f"marker {self.name!r} of robot {self.robot!r}: position must be 3 finite numbers")
        d = float(np.linalg.norm(pos))
        if d > MAX_MARKER_DISTANCE_M:
            raise RigError(f"marker {self.name!r} of robot {self.robot!r} is {d:g} m from its camera: positions are "
                           "in metres (millimetres given?)")
        object.__setattr__(self, "position", pos)

    @property
    def kind(self) -> MarkerKind:
        """The marker's kind; a blinking light is a light even when it has a colour."""
        if "tag_of" in self.extra:
            return MarkerKind.TAG_CORNER
        if "cylinder_of" in self.extra:
            return MarkerKind.CYLINDER_BAND
        if self.tag is not None:
            return MarkerKind.TAG
        if self.extra.get("cylinder") is not None:
            return MarkerKind.CYLINDER
        if self.blink_hz is not None:
            return MarkerKind.LIGHT
        if self.color is not None:
            return MarkerKind.BALL
        return MarkerKind.POINT

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"position": self.position.tolist()}
        if self.color is not None:
            d["color"] = list(self.color)
        if self.blink_hz is not None:
            d["blink_hz"] = self.blink_hz
        if self.tag is not None:
            d["tag"] = dict(self.tag)
        d.update(self.extra)
        return d


@dataclass(frozen=True, eq=False)
class Mount:
    """A camera on a robot: its lens model and ``pose`` = ``T_robot_camera``
    (``x_robot = R @ x_camera + t``, the camera frame its OpenCV optical frame)."""

    name: str
    camera: Any  # Camera, FisheyeCamera or OmniCamera: one interface (project, pixels_to_bearings, ...)
    pose: Pose

    def __post_init__(self) -> None:
        R, t = np.asarray(self.pose.R, dtype=float), np.asarray(self.pose.t, dtype=float)
        if R.shape != (3, 3) or t.shape != (3,) or not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
            raise RigError(f"camera {self.name!r}: pose must be one rotation and translation of finite numbers")
        if np.abs(R.T @ R - np.eye(3)).max() > _ROTATION_TOL or np.linalg.det(R) < 0.0:
            raise RigError(f"camera {self.name!r}: pose R is not a rotation (orthonormal, determinant +1)")

    @property
    def is_identity(self) -> bool:
        """Whether the camera's frame is the robot's."""
        return bool(np.array_equal(self.pose.R, np.eye(3)) and not np.any(self.pose.t))


@dataclass(frozen=True, eq=False)
class Robot:
    """A robot: its camera and the markers it carries, or (``cameras``) a body
    with several cameras posed in its frame.

    ``camera`` is the one camera of a robot whose frame is that camera's
    optical frame (rig ``camera:``), None for a body; ``cameras`` the body's
    cameras by name (rig ``cameras:``), None otherwise.  :attr:`mounts` gives
    either as mounts.
    """

    name: str
    camera: Any
    markers: Mapping[str, Marker]
    #: Pose of the camera in the robot's base frame (``x_base = R @ x_camera + t``), if the rig gives it.
    base_from_camera: Pose | None = None
    cameras: Mapping[str, Mount] | None = None

    def __post_init__(self) -> None:
        if (self.camera is None) == (self.cameras is None):
            raise RigError(f"robot {self.name!r}: give either one camera or several cameras, not "
                           f"{'both' if self.camera is not None else 'neither'}")
        if self.cameras is not None:
            if not self.cameras:
                raise RigError(f"robot {self.name!r}: cameras is empty")
            for cname in self.cameras:
                if not cname or CAMERA_SEPARATOR in cname:
                    raise RigError(f"robot {self.name!r}: camera name {cname!r} must be non-empty and without "
                                   f"{CAMERA_SEPARATOR!r}")
            if self.base_from_camera is not None:
                raise RigError(f"robot {self.name!r}: base_from_camera is for a robot with one camera; a body's "
                               "cameras have their poses")

    @property
    def mounts(self) -> dict[str, Mount]:
        """The robot's cameras by name; a robot given with one ``camera`` has one, named ``""``, at the identity."""
        if self.cameras is not None:
            return dict(self.cameras)
        return {"": Mount("", self.camera, Pose.identity())}

    @property
    def is_body(self) -> bool:
        """Whether the robot's frame is a body frame (``cameras``), not its one camera's optical frame."""
        return self.cameras is not None

    @property
    def central_pinhole(self) -> bool:
        """Whether the robot is one pinhole camera whose frame is the robot's (what every path of mutloc
        handles; the others need the ray solvers of :mod:`mutloc.core.rays`)."""
        return self.cameras is None and getattr(self.camera, "model", "pinhole") == "pinhole"

    def observer_key(self, camera: str) -> str:
        """The observation key of this robot's camera ``camera`` (``ROBOT`` for a robot given with one camera)."""
        return self.name if camera == "" else f"{self.name}{CAMERA_SEPARATOR}{camera}"

    def marker_positions(self, names: list[str] | None = None) -> np.ndarray:
        names = list(self.markers) if names is None else names
        return np.array([self.markers[n].position for n in names], dtype=float).reshape(-1, 3)


@dataclass(frozen=True)
class PairTable:
    """A pair's markers for the solver: ``index[name] = (side, row)`` where
    side 0 marks target's markers (seen by source's camera), 1 source's;
    ``points[row]`` is the marker in its owner's frame; cameras per side."""

    source: str
    target: str
    marker_names: tuple[str, ...]
    index: dict[str, tuple[int, int]]
    points: np.ndarray
    K: tuple[np.ndarray, np.ndarray] | None
    dist: tuple[np.ndarray, np.ndarray] | None
    sizes: tuple[tuple[int, int] | None, tuple[int, int] | None]
    #: Rays (robots that are not one pinhole camera): each observation key of either robot -> (side, its camera).
    mounts: dict[str, tuple[int, Mount]] | None = None

    def names(self, rows: np.ndarray) -> list[str]:
        """The markers at ``rows`` of :attr:`points`."""
        return [self.marker_names[i] for i in rows.tolist()]

    @cached_property
    def observers(self) -> dict[str, tuple[int, np.ndarray, tuple[int, int] | None]]:
        """Each observation key of the pair -> (side, its camera's K, its image size)."""
        if self.mounts is not None:
            return {k: (s, m.camera.K, m.camera.size) for k, (s, m) in self.mounts.items()}
        return {self.source: (0, self.K[0], self.sizes[0]), self.target: (1, self.K[1], self.sizes[1])}

    @cached_property
    def lenses(self) -> Any:
        """:attr:`mounts` as the compiled ray builder reads them (:class:`mutloc.core.rays.LensTable`)."""
        from .rays import lens_table

        return None if self.mounts is None else lens_table(self.mounts)


class Rig:
    """Several robots; marker names are unique over the whole rig."""

    def __init__(self, robots: Mapping[str, Robot]):
        if len(robots) < 1:
            raise RigError("rig has no robots")
        self.robots: dict[str, Robot] = dict(robots)
        self._owner: dict[str, str] = {}
        self._pairs: dict[tuple[str, str], PairTable] = {}
        for rname, robot in self.robots.items():
            for mname in robot.markers:
                if mname in self._owner:
                    raise RigError(
                        f"duplicate marker name {mname!r} (robots {self._owner[mname]!r} and {rname!r})"
                    )
                self._owner[mname] = rname
            names = list(robot.markers)
            pos = robot.marker_positions(names)
            parent = [robot.markers[n].extra.get("cylinder_of") or robot.markers[n].extra.get("tag_of")
                      for n in names]
            for i in range(len(names)):
                for j in range(i + 1, len(names)):
                    if parent[i] == names[j] or parent[j] == names[i]:
                        continue  # a derived point on its own marker (the middle band of an odd count)
                    if np.linalg.norm(pos[i] - pos[j]) < COINCIDENT_TOL_M:
                        raise RigError(f"robot {rname!r}: markers {names[i]!r} and {names[j]!r} coincide")

    def __repr__(self) -> str:
        parts = ", ".join(f"{r}: {list(rb.markers)}" for r, rb in self.robots.items())
        return f"Rig({parts})"

    def robot(self, name: str) -> Robot:
        try:
            return self.robots[name]
        except KeyError:
            raise ObservationError(f"unknown robot {name!r} (rig has {sorted(self.robots)})") from None

    def owner(self, marker: str) -> str:
        """Name of the robot carrying ``marker``."""
        try:
            return self._owner[marker]
        except KeyError:
            names = sorted(self._owner)
            lower = {n.lower(): n for n in reversed(names)}
            near = difflib.get_close_matches(str(marker).lower(), list(lower), n=1)
            hint = (f": did you mean {lower[near[0]]!r}?" if near else
                    f" (the rig's markers: {', '.join(names[:8])}{', ...' if len(names) > 8 else ''})")
            raise UnknownMarkerError(f"unknown marker {marker!r}{hint}") from None

    def marker(self, name: str) -> Marker:
        return self.robots[self.owner(name)].markers[name]

    @property
    def central_pinhole(self) -> bool:
        """Whether every robot is one pinhole camera whose frame is the robot's."""
        return all(r.central_pinhole for r in self.robots.values())

    def observer(self, key: str) -> tuple[str, str]:
        """``(robot, camera)`` of an observation key: ``ROBOT/CAMERA``, or ``ROBOT`` for a robot with one camera
        (the camera then ``""`` for a robot given with ``camera:``).  ObservationError naming the key otherwise."""
        robot = self.robots.get(key)
        if robot is not None:
            if robot.cameras is None:
                return key, ""
            if len(robot.cameras) == 1:
                return key, next(iter(robot.cameras))
            raise ObservationError(f"observations: robot {key!r} has cameras {', '.join(robot.cameras)}: key its "
                                   f"observations by camera ({key}{CAMERA_SEPARATOR}{next(iter(robot.cameras))}, ...)")
        rname, sep, cname = str(key).rpartition(CAMERA_SEPARATOR)
        robot = self.robots.get(rname) if sep else None
        if robot is None:
            raise ObservationError(f"observations: unknown robot {key!r} (rig has {sorted(self.robots)})")
        if robot.cameras is None or cname not in robot.cameras:
            has = (f"cameras {', '.join(robot.cameras)}" if robot.cameras is not None else
                   f"one camera: key its observations {rname!r}")
            raise ObservationError(f"observations: unknown camera {key!r} (robot {rname!r} has {has})")
        return rname, cname

    def mount(self, key: str) -> Mount:
        """The camera an observation key names (see :meth:`observer`)."""
        rname, cname = self.observer(key)
        return self.robots[rname].mounts[cname]

    def observer_keys(self) -> list[str]:
        """Every camera's observation key, robot by robot in rig order."""
        return [r.observer_key(c) for r in self.robots.values() for c in r.mounts]

    def require_central(self, what: str) -> None:
        """RigError (one line) unless every robot is one pinhole camera whose frame is the robot's: for the
        paths that do not yet handle robots with several cameras or wide-angle lenses."""
        for r in self.robots.values():
            if not r.central_pinhole:
                has = (f"cameras {', '.join(r.cameras)}" if r.cameras is not None
                       else f"a {r.camera.model} lens")
                raise RigError(f"robot {r.name!r} has {has}: {what} handles only robots with one pinhole camera "
                               "so far")

    def pair_table(self, source: str, target: str) -> "PairTable":
        """What the solver needs of the pair (source p, target q), built once per rig.  For robots that are
        not one pinhole camera (see :attr:`Robot.central_pinhole`) ``K``/``dist``/``sizes`` are None: their
        observations are rays (:mod:`mutloc.core.rays`)."""
        key = (source, target)
        table = self._pairs.get(key)
        if table is None:
            p, q = self.robot(source), self.robot(target)
            if not (p.central_pinhole and q.central_pinhole):
                names = list(q.markers) + list(p.markers)
                index = {n: (0 if i < len(q.markers) else 1, i) for i, n in enumerate(names)}
                points = np.ascontiguousarray(np.vstack([q.marker_positions(), p.marker_positions()]).reshape(-1, 3))
                mounts: dict[str, tuple[int, Mount]] = {}
                for side, robot in enumerate((p, q)):
                    for cname, mount in robot.mounts.items():
                        mounts[robot.observer_key(cname)] = (side, mount)
                    if len(robot.mounts) == 1:  # a robot with one camera may be named alone
                        mounts[robot.name] = (side, next(iter(robot.mounts.values())))
                table = PairTable(source, target, tuple(names), index, points, None, None, (None, None), mounts)
                self._pairs[key] = table
                return table
            names = list(q.markers) + list(p.markers)
            index = {n: (0 if i < len(q.markers) else 1, i) for i, n in enumerate(names)}
            points = np.ascontiguousarray(np.vstack([q.marker_positions(), p.marker_positions()]).reshape(-1, 3))
            table = PairTable(source, target, tuple(names), index, points, (p.camera.K, q.camera.K),
                              (p.camera.dist, q.camera.dist), (p.camera.size, q.camera.size))
            self._pairs[key] = table
        return table

    def default_pair(self, source: str | None = None, target: str | None = None) -> tuple[str, str]:
        """Resolve ``(source, target)``; both may be omitted for a two-robot rig."""
        if source is None and target is None and len(self.robots) == 2:
            first, second = self.robots
            return first, second
        for what, value in (("source", source), ("target", target)):
            if value is not None and not isinstance(value, str):
                raise ObservationError(f"{what} must be a robot name (a string), got {value!r}")
        names = list(self.robots)
        if source is None and target is None:
            if len(names) != 2:
                raise ObservationError(
                    f"rig has {len(names)} robot{'s' if len(names) != 1 else ''} ({', '.join(names)}): "
                    + ("a relative pose needs two" if len(names) < 2 else "name the pair (source and target)")
                )
            return names[0], names[1]
        if source is None or target is None:
            known = target if source is None else source
            self.robot(known)
            others = [n for n in names if n != known]
            if len(others) != 1:
                raise ObservationError("rig has more than two robots: give both source and target")
            return (others[0], known) if source is None else (known, others[0])
        self.robot(source)
        self.robot(target)
        if source == target:
            raise ObservationError(f"source and target are the same robot {source!r}")
        return source, target

    def to_dict(self) -> dict[str, Any]:
        """The rig in rig-file form (cameras inline)."""
        return {
            "robots": {
                rname: {
                    **({"camera": robot.camera.to_dict()} if robot.cameras is None else
                       {"cameras": {c: {**m.camera.to_dict(), "pose": {"R": m.pose.R.tolist(), "t": m.pose.t.tolist()}}
                                    for c, m in robot.cameras.items()}}),
                    **({} if robot.base_from_camera is None else
                       {"base_from_camera": {"R": robot.base_from_camera.R.tolist(),
                                             "t": robot.base_from_camera.t.tolist()}}),
                    "markers": {m.name: m.to_dict() for m in robot.markers.values()},
                }
                for rname, robot in self.robots.items()
            }
        }
