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
from typing import Any

import numpy as np

from ..core.camera import Camera
from ..core.pose import Pose
from ..core.rig import Robot
from ..errors import InputError
from .world import Room, World, WorldRobot, camera_to_world_facing

__all__ = ["walkaround_poses", "render_view", "inside_room"]

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
