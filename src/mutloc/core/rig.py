"""The rig model: robots, each a camera plus markers in its camera frame.

Pure data and validation; reading rig files lives in :mod:`mutloc.io.rig`.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Mapping

import numpy as np

from ..errors import ObservationError, RigError, UnknownMarkerError
from .camera import Camera
from .pose import Pose

__all__ = ["Marker", "MarkerKind", "Robot", "Rig", "PairTable", "DETECTED_KINDS"]

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
    """A fiducial marker; ``position`` is its centre in its robot's camera frame."""

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
class Robot:
    """A robot: its camera and the markers it carries."""

    name: str
    camera: Camera
    markers: Mapping[str, Marker]
    #: Pose of the camera in the robot's base frame (``x_base = R @ x_camera + t``), if the rig gives it.
    base_from_camera: Pose | None = None

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
    K: tuple[np.ndarray, np.ndarray]
    dist: tuple[np.ndarray, np.ndarray]
    sizes: tuple[tuple[int, int] | None, tuple[int, int] | None]

    def names(self, rows: np.ndarray) -> list[str]:
        """The markers at ``rows`` of :attr:`points`."""
        return [self.marker_names[i] for i in rows.tolist()]


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

    def pair_table(self, source: str, target: str) -> "PairTable":
        """What the solver needs of the pair (source p, target q), built once per rig."""
        key = (source, target)
        table = self._pairs.get(key)
        if table is None:
            p, q = self.robot(source), self.robot(target)
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
                    "camera": robot.camera.to_dict(),
                    **({} if robot.base_from_camera is None else
                       {"base_from_camera": {"R": robot.base_from_camera.R.tolist(),
                                             "t": robot.base_from_camera.t.tolist()}}),
                    "markers": {m.name: m.to_dict() for m in robot.markers.values()},
                }
                for rname, robot in self.robots.items()
            }
        }
