"""Extra views of a rendered scene: the photos a structure-from-motion user takes.

A Bundler/COLMAP user does not rely on the robots' frames alone: they walk
around the room with a camera.  :func:`walkaround_poses` places such views on
a circle around the area of interest, looking inwards across it (each view
overlaps its neighbours, and views from either side see what each robot sees);
:func:`render_view` renders the world from any camera pose, under the world's
own light, without adding a body to the scene.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Hashable, Mapping

import numpy as np

from ..core.camera import Camera
from ..core.pose import Pose
from ..core.rig import Robot
from ..errors import InputError
from .world import Room, World, WorldRobot, camera_to_world_facing

__all__ = ["walkaround_poses", "render_view", "inside_room", "view_overlap", "robot_points"]

VIEWER = "_viewer"


def inside_room(room: Room, xy: Any, margin: float) -> np.ndarray:
    """Whether world points ``xy`` (n, 2) are at least ``margin`` m inside the room's walls."""
    P = np.asarray(xy, float).reshape(-1, 2)
    half = 0.5 * np.asarray(room.size, float) - margin
    return np.all(np.abs(P - np.asarray(room.center, float)) <= half, axis=1)


def walkaround_poses(centre: Any, n: int, *, radius: float = 2.0, height: float = 0.9, pitch_deg: float = -8.0,
                     room: Room | None = None, margin: float = 0.4, phase: float = 0.0) -> list[Pose]:
    """Camera -> world poses of ``n`` upright views on a circle of ``radius``
    around ``centre`` (world xy), at ``height`` m, each looking at the centre
    (pitched by ``pitch_deg``); with ``room``, views are pulled in to stay
    ``margin`` m inside its walls."""
    if n < 1 or not (radius > 0):
        raise InputError("walk-around needs n >= 1 views and a positive radius")
    c = np.asarray(centre, float)[:2]
    poses = []
    for k in range(int(n)):
        a = phase + 2.0 * math.pi * k / n
        d = np.array([math.cos(a), math.sin(a)])
        r = float(radius)
        if room is not None:
            while r > 0.2 and not inside_room(room, c + r * d, margin)[0]:
                r *= 0.9
        pos = c + r * d
        yaw = math.atan2(-d[1], -d[0])
        poses.append(camera_to_world_facing((pos[0], pos[1], height), yaw=yaw, pitch=math.radians(pitch_deg)))
    return poses


def render_view(world: World, camera: Camera, T_wc: Pose, *, seed: int = 0, noise_sigma: float = 0.0) -> np.ndarray:
    """``world`` seen by ``camera`` at camera -> world pose ``T_wc`` (uint8 BGR).

    The world's light stays where it is (its default position depends on the
    robots, so it is fixed first), and the viewer has no body.
    """
    from .render import render

    light = world.light if world.light.position is not None else replace(
        world.light, position=tuple(float(x) for x in world.light_position()))
    robots = dict(world.robots)
    robots[VIEWER] = WorldRobot(Robot(VIEWER, camera, {}), T_wc, body=False)
    w = World(robots=robots, room=world.room, light=light, sensor=world.sensor, background=world.background)
    return render(w, VIEWER, seed=seed, noise_sigma=noise_sigma)


def view_overlap(room: Room, views: Mapping[str, tuple[Camera, Pose]], *,
                 objects: Mapping[str, Mapping[Hashable, Any]] | None = None, grid: tuple[int, int] = (32, 18),
                 margin: float = 0.1) -> dict[tuple[str, str], float]:
    """How much of what view ``a`` sees view ``b`` can see: ``{(a, b): fraction}``.

    ``views[name] = (camera, T_wc)``.  A grid of ``grid`` rays through view
    ``a``'s image is cast to the room's walls, floor and ceiling; the samples
    are those surface points plus, with ``objects[a] = {object: world points
    (m, 3)}`` (the things besides the room in ``a``'s world, e.g. a robot's
    markers), the object points inside ``a``'s image.  The fraction is the
    share of the samples inside view ``b``'s image (grown by ``margin`` of its
    extent on every side), in front of it -- object points only when the same
    object (same key) is in ``b``'s world too.  Occlusion is ignored, so this
    is an upper bound: a pair with fraction 0 shares no point of the scene.
    Pairs ``a == b`` are left out.
    """
    names = list(views)
    objects = objects or {}
    lo = np.array([room.center[0] - room.size[0] / 2, room.center[1] - room.size[1] / 2, 0.0])
    hi = np.array([room.center[0] + room.size[0] / 2, room.center[1] + room.size[1] / 2, room.height])
    bounds = {n: _normalized_extent(views[n][0], n, margin) for n in names}
    samples: dict[str, np.ndarray] = {}
    owner: dict[str, list[Any]] = {}  # None for a room sample, else the object's key
    for n in names:
        cam, T = views[n]
        w, h = _size(cam, n)
        u, v = np.meshgrid((np.arange(grid[0]) + 0.5) * w / grid[0] - 0.5,
                           (np.arange(grid[1]) + 0.5) * h / grid[1] - 0.5)
        d = cam.pixels_to_bearings(np.column_stack([u.ravel(), v.ravel()])) @ T.R.T
        o = T.t
        if not (np.all(o > lo) and np.all(o < hi)):
            raise InputError(f"view {n!r} is not inside the room")
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d > 0, (hi - o) / d, np.where(d < 0, (lo - o) / d, np.inf))
        pts, keys = [o + t.min(axis=1, keepdims=True) * d], [None] * len(d)  # where each ray leaves the box
        for key, P in objects.get(n, {}).items():
            P = np.asarray(P, float).reshape(-1, 3)
            P = P[_in_view(P, T, bounds[n])]
            pts.append(P)
            keys += [key] * len(P)
        samples[n], owner[n] = np.concatenate(pts), keys
    out: dict[tuple[str, str], float] = {}
    for b in names:
        _cam, T = views[b]
        here = set(objects.get(b, {}))
        for a in names:
            if a == b:
                continue
            shared = np.array([k is None or k in here for k in owner[a]], bool)
            out[(a, b)] = float(np.mean(shared & _in_view(samples[a], T, bounds[b])))
    return out


def robot_points(robot: Robot, T_wc: Pose) -> np.ndarray:
    """World points (m, 3) on ``robot`` with its camera at ``T_wc``: the
    camera, the markers and a column of its body down to the floor (for the
    ``objects`` of :func:`view_overlap`)."""
    body = [(x, y, 0.0) for x in (-0.15, 0.0, 0.15) for y in np.linspace(0.0, float(T_wc.t[2]), 5)]  # y is down
    P = np.array(body + [m.position for m in robot.markers.values()], float).reshape(-1, 3)
    return P @ T_wc.R.T + T_wc.t


def _normalized_extent(camera: Camera, name: str, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """The image's extent in normalized coordinates (x/z, y/z), from its
    border pixels (no projection of far-off points through the distortion
    polynomial, which can fold them back into the image), grown by ``margin``."""
    w, h = _size(camera, name)
    x, y = np.linspace(-0.5, w - 0.5, 16), np.linspace(-0.5, h - 0.5, 16)
    border = np.concatenate([np.column_stack([x, np.full(16, -0.5)]), np.column_stack([x, np.full(16, h - 0.5)]),
                             np.column_stack([np.full(16, -0.5), y]), np.column_stack([np.full(16, w - 0.5), y])])
    nb = camera.pixels_to_bearings(border)
    nb = nb[:, :2] / nb[:, 2:]
    span = nb.max(axis=0) - nb.min(axis=0)
    return nb.min(axis=0) - margin * span, nb.max(axis=0) + margin * span


def _in_view(P: np.ndarray, T_wc: Pose, extent: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Which world points ``P`` are in front of the camera at ``T_wc`` and within ``extent``."""
    Xc = (P - T_wc.t) @ T_wc.R
    front = Xc[:, 2] > 1e-6
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = Xc[:, :2] / Xc[:, 2:]
    return front & np.all((xy >= extent[0]) & (xy <= extent[1]), axis=1)


def _size(camera: Camera, name: str) -> tuple[int, int]:
    if camera.size is None:
        raise InputError(f"the camera of view {name!r} has no image size")
    return camera.size
