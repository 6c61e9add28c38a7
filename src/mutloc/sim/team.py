"""Synthetic teams with ground truth (no rendering): robots in a room, each a
camera with markers around it; observations are the exact (or noisy) pixels
of every marker a camera sees.  Used by the tests, bench/bench_team.py,
``mutloc experiment team`` and ``mutloc simulate --robots N``.

World frame: y down (like a camera's), the floor plane is x-z.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable

import numpy as np

from ..core.camera import Camera
from ..core.geometry import so3_exp
from ..core.observations import ObservationSet
from ..core.pose import Pose
from ..core.rig import Marker, Rig, Robot

__all__ = ["TeamScene", "team_camera_records", "random_team", "chain_team", "team_rig", "robot_names", "level_pose", "MARKER_RING",
           "TAG_LAYOUT", "TEAM_KINDS", "team_motion", "team_sequence"]

# Markers on each robot (its own camera frame, metres): four balls above and
# beside the camera, not coplanar, seen from any side, never in its own view.
MARKER_RING = np.array([[0.12, -0.10, -0.02], [-0.12, -0.10, -0.02], [0.0, -0.22, 0.04], [0.0, -0.14, -0.14]])


def robot_names(n: int) -> list[str]:
    """``r0``, ``r1``, ... (marker names ``r0_m0`` ... are unique in the rig)."""
    return [f"r{i}" for i in range(n)]


def _colour(i: int, n: int) -> tuple[int, int, int]:
    """Hues spread evenly over the markers of the team."""
    import colorsys

    r, g, b = colorsys.hsv_to_rgb((i / max(n, 1)) % 1.0, 1.0, 1.0)
    return int(round(255 * r)), int(round(255 * g)), int(round(255 * b))


# Printed tags of a team robot (kind "tags"): two cards left and right of
# the camera, facing forward (tag36h11, ids 2i and 2i+1 on robot i).
TAG_LAYOUT = np.array([[-0.16, -0.08, -0.03], [0.16, -0.08, -0.03]])
TAG_SIZE = 0.15
#: Marker kinds a simulated team can carry.
TEAM_KINDS = ("balls", "tags")


def team_rig(names: list[str], *, focal: float = 500.0, size: tuple[int, int] = (960, 540),
             markers: np.ndarray | None = None, k1: float = 0.0, kind: str = "balls") -> Rig:
    """A rig of identical robots (camera ``focal``/``size``, markers
    ``markers`` named ``NAME_mK``): ``kind`` "balls", each ball its own
    colour (positions :data:`MARKER_RING`), or "tags", printed AprilTags
    with distinct ids and their corners as the rig's points (positions
    :data:`TAG_LAYOUT`, side :data:`TAG_SIZE`)."""
    if kind not in TEAM_KINDS:
        from ..errors import InputError

        raise InputError(f"a simulated team carries one of {', '.join(TEAM_KINDS)}, not {kind!r}")
    if markers is None:
        markers = MARKER_RING if kind == "balls" else TAG_LAYOUT
    w, h = size
    K = np.array([[focal, 0.0, (w - 1) / 2], [0.0, focal, (h - 1) / 2], [0.0, 0.0, 1.0]])
    total = len(names) * len(markers)
    robots = {}
    for i, n in enumerate(names):
        ms = {}
        for k, p in enumerate(markers):
            mname = f"{n}_m{k}"
            if kind == "balls":
                ms[mname] = Marker(mname, n, np.asarray(p, float), color=_colour(i * len(markers) + k, total))
            else:
                tag = {"family": "tag36h11", "id": i * len(markers) + k, "size": TAG_SIZE,
                       "rotation": [0.0, float(np.pi), 0.0]}  # facing forward, as sim.world's default
                ms[mname] = Marker(mname, n, np.asarray(p, float), tag=tag)
        robots[n] = Robot(n, Camera(K, [k1, 0.0, 0.0, 0.0, 0.0], size), ms)
    return Rig(robots)


@dataclass
class TeamScene:
    """Ground truth of a team: ``world[r]`` is ``T_world_r``; ``links`` the
    directed (observer, observed) pairs allowed to see each other (None:
    every pair, by field of view alone)."""

    rig: Rig
    world: dict[str, Pose]
    links: set[tuple[str, str]] | None = None
    max_range: float = 8.0
    extra: dict = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        return list(self.rig.robots)

    def truth(self, reference: str | None = None) -> dict[str, Pose]:
        """``T_ref_r`` of every robot (reference: the first robot)."""
        ref = self.world[reference or self.names[0]].inverse()
        return {n: ref @ T for n, T in self.world.items()}

    def visible(self) -> list[tuple[str, str, np.ndarray]]:
        """(observer, marker, exact pixel) of every marker a camera sees:
        in front of it, inside its image, within ``max_range``, along a link."""
        out = []
        for a in self.names:
            cam = self.rig.robots[a].camera
            Ta_inv = self.world[a].inverse()
            for b in self.names:
                if a == b or (self.links is not None and (a, b) not in self.links):
                    continue
                rb = self.rig.robots[b]
                X = (Ta_inv @ self.world[b]).apply(rb.marker_positions())
                for mname, x in zip(rb.markers, X):
                    if not (0.2 < x[2] and np.linalg.norm(x) < self.max_range):
                        continue
                    uv = cam.project(x)
                    if cam.size is not None and not bool(cam.in_image(uv)):
                        continue
                    out.append((a, mname, np.asarray(uv, float)))
        return out

    def observations(self, sigma: float = 0.0, rng: np.random.Generator | None = None,
                     visible: Iterable[tuple[str, str, np.ndarray]] | None = None) -> ObservationSet:
        """The visible markers' pixels, with Gaussian noise ``sigma`` px."""
        vis = list(self.visible() if visible is None else visible)
        uv = np.array([v[2] for v in vis]).reshape(-1, 2)
        if sigma > 0:
            uv = uv + (rng or np.random.default_rng()).normal(0.0, sigma, uv.shape)
        return ObservationSet.trusted([v[0] for v in vis], [v[1] for v in vis], uv)


def level_pose(position: np.ndarray, yaw: float, tilt: np.ndarray) -> Pose:
    """Camera at ``position`` looking along yaw (about the world's y axis),
    with a small extra rotation ``tilt`` (rotation vector)."""
    c, s = np.cos(yaw), np.sin(yaw)
    Ry = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return Pose(Ry @ so3_exp(tilt), position)


def random_team(n: int, rng: np.random.Generator, *, radius: float = 2.5, one_way: float = 0.3, focal: float = 500.0,
                size: tuple[int, int] = (960, 540), yaw_jitter_deg: float = 30.0, k1: float = 0.0,
                kind: str = "balls") -> TeamScene:
    """``n`` robots at random in a disc of ``radius`` metres, each looking
    roughly at the team's centre (+- ``yaw_jitter_deg``), camera heights and
    tilts a little different; of every pair that sees each other both ways,
    one direction is dropped with probability ``one_way``."""
    names = robot_names(n)
    world = {}
    pos = []
    for name in names:
        for _ in range(100):
            r = radius * np.sqrt(rng.uniform(0.15, 1.0))
            a = rng.uniform(0, 2 * np.pi)
            p = np.array([r * np.cos(a), rng.uniform(-0.6, -0.4), r * np.sin(a)])
            if all(np.linalg.norm(p - q) > 0.7 for q in pos):
                break
        pos.append(p)
    centre = np.mean(pos, axis=0)
    for name, p in zip(names, pos):
        d = centre - p
        yaw = np.arctan2(d[0], d[2]) + np.radians(rng.uniform(-yaw_jitter_deg, yaw_jitter_deg))
        world[name] = level_pose(p, yaw, rng.normal(0.0, 0.05, 3))
    scene = TeamScene(team_rig(names, focal=focal, size=size, k1=k1, kind=kind), world)
    seen = {(a, m.rsplit("_m", 1)[0]) for a, m, _ in scene.visible()}
    links = set(seen)
    for a, b in sorted(seen):
        if a < b and (b, a) in seen and rng.uniform() < one_way:
            links.discard((a, b) if rng.uniform() < 0.5 else (b, a))
    scene.links = links
    return scene


def chain_team(n: int, rng: np.random.Generator, *, spacing: float = 1.5, focal: float = 500.0,
               size: tuple[int, int] = (960, 540), skip: bool = True) -> TeamScene:
    """A chain: robots on a line ``spacing`` apart, alternately a little to
    the left and right, all facing along it (z forward); robot ``i`` sees
    robots ``i+1`` and (with ``skip``) ``i+2`` ahead of it, and is seen by
    none behind it: every tie is one-way."""
    names = robot_names(n)
    world = {}
    for i, name in enumerate(names):
        p = np.array([0.35 * (-1) ** i + rng.normal(0, 0.05), -0.5 + rng.normal(0, 0.03), spacing * i])
        world[name] = level_pose(p, np.radians(rng.normal(0, 3.0)), rng.normal(0.0, 0.02, 3))
    links = {(names[i], names[i + 1]) for i in range(n - 1)}
    if skip:
        links |= {(names[i], names[i + 2]) for i in range(n - 2)}
    return TeamScene(team_rig(names, focal=focal, size=size), world, links)


def team_motion(scene: TeamScene, *, amplitude: float = 0.25, yaw_deg: float = 8.0, period: float = 6.0,
                seed: int = 0, speed: float | None = None, turn_rate: float | None = None):
    """``T_world_r(t)`` for every robot of ``scene``: each sways about its
    place in the scene on a smooth loop (``amplitude`` metres, its own phase)
    and turns its heading by up to ``yaw_deg``; periodic in ``period`` s.
    Returns a function ``t -> {robot: Pose}`` (at t = 0 the scene's poses
    moved by the loop's start).

    Fast robots: with ``speed`` (m/s) each robot instead drives a circle of
    radius ``amplitude`` about its place at a constant speed between 0.8 and
    1.2 times ``speed`` (its own, drawn from ``seed``), and with
    ``turn_rate`` (deg/s) its heading swings by ``yaw_deg`` at a peak rate
    between 0.93 and 1.07 times ``turn_rate`` (its own)."""
    from ..errors import positive_number

    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 515])
    phases = {n: rng.uniform(0, 2 * np.pi, 3) for n in scene.names}
    w = 2 * np.pi / period
    if speed is not None:
        positive_number(speed, "speed")
    if turn_rate is not None:
        positive_number(turn_rate, "turn_rate")
    fast = {n: (w if speed is None else speed * rng.uniform(0.8, 1.2) / amplitude,
                w if turn_rate is None else np.radians(turn_rate * rng.uniform(0.93, 1.07)) / np.radians(yaw_deg))
            for n in scene.names}

    def at(t: float) -> dict[str, Pose]:
        out = {}
        for n, T in scene.world.items():
            a, b, c = phases[n]
            wd, wy = fast[n]
            if speed is None:
                d = amplitude * np.array([np.sin(w * t + a), 0.0, 0.6 * np.sin(2 * w * t + b)])
            else:  # a circle at constant speed
                d = amplitude * np.array([np.sin(wd * t + a) - np.sin(a), 0.0, np.cos(wd * t + a) - np.cos(a)])
            yaw = np.radians(yaw_deg) * np.sin(wy * t + c)
            turn = so3_exp([0.0, yaw, 0.0])
            out[n] = Pose(turn @ T.R, T.t + d)
        return out

    return at


def team_sequence(scene: TeamScene, frames: int, fps: float, *, sigma: float = 0.0, seed: int = 0,
                  **motion) -> list[tuple[float, TeamScene, ObservationSet]]:
    """``frames`` snapshots of ``scene`` moving by :func:`team_motion`
    (``motion``: its keywords): per frame the time, the scene at that time
    (same rig and links) and its observations with ``sigma`` px noise,
    stamped with the time."""
    at = team_motion(scene, seed=seed, **motion)
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 516])
    out = []
    for i in range(frames):
        t = i / fps
        snap = TeamScene(scene.rig, at(t), scene.links, scene.max_range, dict(scene.extra))
        obs = snap.observations(sigma, rng)
        out.append((t, snap, ObservationSet.trusted(obs.observer, obs.marker, obs.uv, time=t)))
    return out


def team_camera_records(scene: TeamScene, duration: float, *, fps: float | dict[str, float] = 30.0,
                        offsets: dict[str, float] | None = None, sigma: float = 0.0, seed: int = 0,
                        **motion) -> list[tuple[float, str, dict[str, Pose], ObservationSet]]:
    """Every camera of ``scene`` capturing at its own rate (``fps``, one
    for all or per robot) from its own offset (``offsets``, default: the
    cameras spread evenly over one frame, so that no two capture together)
    while the team moves by :func:`team_motion`: per frame, in time order,
    ``(time, observer, T_world_r of every robot at that time, what that
    camera saw)`` with ``sigma`` px noise, stamped with the time."""
    names = scene.names
    rates = {n: float(fps[n] if isinstance(fps, dict) else fps) for n in names}
    if offsets is None:
        offsets = {n: i / (len(names) * rates[n]) for i, n in enumerate(names)}
    at = team_motion(scene, seed=seed, **motion)
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 517])
    frames = sorted((round(offsets.get(n, 0.0) + k / rates[n], 9), n) for n in names
                    for k in range(int(np.floor((duration - offsets.get(n, 0.0)) * rates[n] - 1e-9)) + 1))
    out = []
    for t, a in frames:
        world = at(t)
        snap = TeamScene(scene.rig, world, scene.links, scene.max_range, dict(scene.extra))
        vis = [v for v in snap.visible() if v[0] == a]
        obs = snap.observations(sigma, rng, vis)
        out.append((t, a, world, ObservationSet.trusted(obs.observer, obs.marker, obs.uv, time=t)))
    return out
