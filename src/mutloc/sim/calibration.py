"""Synthetic observation sequences for marker calibration, with ground truth.

Robots carry balls beside their cameras; over a sequence they face each
other at varied distances, yaws and rolls, and every marker each camera sees
is projected exactly (core.camera, with its distortion) and jittered with
Gaussian pixel noise.  A measured rig is the true one with every marker moved
by 1-2 cm (what a tape measure against an invisible optical centre gives).
Used by the calibration tests, the benchmark and ``mutloc experiment
calibration``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..core.camera import Camera
from ..core.geometry import so3_exp
from ..core.observations import ObservationSet
from ..core.pose import Pose
from .synthetic import USUAL_MARKERS, facing_pose, looking_pose

__all__ = ["ball_rig", "tag_rig", "point_rig", "perturb_rig", "true_rotations", "CalibrationSequence", "pair_sequence", "team_sequence", "true_positions",
           "robots_of", "held_out_errors", "observe", "pair_frames", "ROBOT_NAMES", "body_rig",
           "body_sequence"]

#: Robot names of the synthetic rigs, in order (SPEC's example: p, q).
ROBOT_NAMES = ("p", "q", "r", "s", "u", "v")
# A marker this close to the image border is not used (a detector would cut it).
BORDER_PX = 5.0
MAX_TRIES = 2000


def ball_rig(n_robots: int = 2, *, markers_per_robot: int = 2, f: float = 800.0,
             size: tuple[int, int] = (960, 540), dist: list[float] | None = None) -> dict[str, Any]:
    """A rig in rig-file form: ``n_robots`` robots, each with balls beside and
    below its camera (the usual mounting; a third marker sits above it).
    Markers are named M1, M2 on q, M3, M4 on p (the SPEC's example), then on;
    ``dist``: OpenCV distortion of every camera."""
    w, h = size
    cam = {"K": [[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]], "dist": list(dist or []),
           "size": [w, h]}
    layout = np.vstack([USUAL_MARKERS, [[0.0, -0.22, -0.05]], [[0.0, 0.12, -0.04]]])[:markers_per_robot]
    robots: dict[str, Any] = {}
    order = list(ROBOT_NAMES[:n_robots])
    # q's markers first in naming (M1, M2), as in the SPEC.
    naming = sorted(order, key=lambda r: (r != "q", order.index(r)))
    k = 1
    names: dict[str, list[str]] = {}
    for r in naming:
        names[r] = [f"M{k + i}" for i in range(markers_per_robot)]
        k += markers_per_robot
    for r in order:
        robots[r] = {"camera": cam, "markers": {n: {"position": layout[i].tolist()} for i, n in enumerate(names[r])}}
    return {"robots": robots}


def tag_rig(n_robots: int = 3, *, f: float = 800.0, size: tuple[int, int] = (1920, 1080)) -> dict[str, Any]:
    """A team rig in rig-file form (robots r0, r1, ...) whose robots carry two
    printed tags each, left and right of the camera, facing forward (what
    ``mutloc simulate --robots N --markers tags`` renders)."""
    from .team import robot_names, team_rig

    return team_rig(robot_names(n_robots), focal=f, size=size, kind="tags").to_dict()


def point_rig(rig: dict[str, Any]) -> dict[str, Any]:
    """``rig`` (rig-file form) with the points a detector reports as its
    markers: an oriented tag's four corners ``NAME#k`` instead of its centre,
    a cylinder's bands ``NAME#bK`` instead of its centre (what ``track
    --observations-out`` logs)."""
    from ..api import load_rig
    from ..track.frames import expanded_rig

    out = expanded_rig(load_rig(rig)).to_dict()
    for spec in out["robots"].values():
        parents = {m.get("tag_of") or m.get("cylinder_of") for m in spec["markers"].values()} - {None}
        spec["markers"] = {n: {"position": m["position"]} for n, m in spec["markers"].items() if n not in parents}
    return out


def perturb_rig(rig: dict[str, Any], rng: np.random.Generator, low: float = 0.01,
                high: float = 0.02, rotation_deg: float = 0.0) -> dict[str, Any]:
    """A copy of ``rig`` (rig-file form) with every marker moved ``low``..``high``
    metres in a random direction, and every tag's rotation turned by
    ``rotation_deg`` about a random axis."""
    from ..core.geometry import so3_log

    out = {"robots": {}}
    for r, spec in rig["robots"].items():
        markers = {}
        for n, m in spec["markers"].items():
            d = rng.normal(size=3)
            d *= rng.uniform(low, high) / np.linalg.norm(d)
            markers[n] = dict(m, position=(np.asarray(m["position"], float) + d).tolist())
            if rotation_deg and isinstance(m.get("tag"), dict) and "rotation" in m["tag"]:
                axis = rng.normal(size=3)
                axis *= np.radians(rotation_deg) / np.linalg.norm(axis)
                R = so3_exp(axis) @ so3_exp(np.asarray(m["tag"]["rotation"], float))
                markers[n]["tag"] = dict(m["tag"], rotation=so3_log(R).tolist())
        out["robots"][r] = dict(spec, markers=markers)
    return out


def true_rotations(rig: dict[str, Any]) -> dict[str, np.ndarray]:
    """``{tag: rotation matrix}`` of the tags of a rig in rig-file form that give one."""
    return {n: so3_exp(np.asarray(m["tag"]["rotation"], float)) for spec in rig["robots"].values()
            for n, m in spec["markers"].items() if isinstance(m.get("tag"), dict) and "rotation" in m["tag"]}


@dataclass
class CalibrationSequence:
    """Frames (one ObservationSet each, stamped with its time) and, per frame,
    every robot's true pose in the first robot's frame (``truth[k][robot]``)."""

    frames: list[ObservationSet]
    truth: list[dict[str, Pose]]


def observe(rig: dict[str, Any], poses: dict[str, Pose], rng: np.random.Generator, sigma: float,
             time: float) -> ObservationSet | None:
    """Every marker each robot sees (pixels + noise); None if one is out of view."""
    obs, mk, uv = [], [], []
    for o, ospec in rig["robots"].items():
        cam = Camera(**ospec["camera"])
        w, h = cam.size
        to_o = poses[o].inverse()
        for r, rspec in rig["robots"].items():
            if r == o:
                continue
            names = list(rspec["markers"])
            P = np.array([rspec["markers"][n]["position"] for n in names], float)
            X = (to_o @ poses[r]).apply(P)
            if np.any(X[:, 2] < 0.2):
                return None
            px = cam.project(X)
            if not np.all((px[:, 0] > BORDER_PX) & (px[:, 0] < w - 1 - BORDER_PX) & (px[:, 1] > BORDER_PX)
                          & (px[:, 1] < h - 1 - BORDER_PX)):
                return None
            px = px + rng.normal(scale=sigma, size=px.shape)
            obs += [o] * len(names)
            mk += names
            uv.append(px)
    return ObservationSet(obs, mk, np.vstack(uv), time)


def pair_sequence(rig: dict[str, Any], n_frames: int, rng: np.random.Generator, *, pixel_sigma: float = 0.5,
                  distance: tuple[float, float] = (1.0, 3.5), yaw_deg: float = 30.0, roll_deg: float = 15.0,
                  pitch_deg: float = 0.0, lateral: float = 0.25, fps: float = 10.0) -> CalibrationSequence:
    """Two robots (the rig's first two, p and q) facing each other: p at a
    random distance, each turned by up to ``yaw_deg``, rolled about its
    optical axis by up to ``roll_deg`` and pitched by up to ``pitch_deg``,
    sideways by up to ``lateral`` of the distance; all markers in view."""
    a, b = list(rig["robots"])[:2]
    frames, truth = [], []
    yaw, roll, pitch = np.radians([yaw_deg, roll_deg, pitch_deg])
    tries = 0
    while len(frames) < n_frames:
        tries += 1
        if tries > MAX_TRIES * max(n_frames, 1):
            raise RuntimeError("could not sample frames with every marker in view")
        d = rng.uniform(*distance)
        T = facing_pose(d, rng.uniform(-yaw, yaw), rng.uniform(-yaw, yaw), rng.uniform(-lateral, lateral) * d,
                        tilt=np.array([rng.uniform(-pitch, pitch), 0.0, rng.uniform(-roll, roll)]))
        # q rolls about its own optical axis too: x_q' = Rz(-roll_q) x_q.
        T = Pose(so3_exp([rng.uniform(-pitch, pitch), 0.0, rng.uniform(-roll, roll)]), np.zeros(3)) @ T
        poses = {b: Pose.identity(), a: T}
        ob = observe(rig, poses, rng, pixel_sigma, len(frames) / fps)
        if ob is None:
            continue
        frames.append(ob)
        truth.append({a: T, b: Pose.identity()})
    return CalibrationSequence(frames, truth)


def team_sequence(rig: dict[str, Any], n_frames: int, rng: np.random.Generator, *, pixel_sigma: float = 0.5,
                  radius: tuple[float, float] = (1.0, 2.0), yaw_deg: float = 10.0, roll_deg: float = 10.0,
                  fps: float = 10.0) -> CalibrationSequence:
    """Every robot of the rig on a circle of random radius, facing its centre
    (turned by up to ``yaw_deg``, rolled by up to ``roll_deg``), at random
    angles; every robot sees every other robot's markers.  Poses are in the
    first robot's frame."""
    names = list(rig["robots"])
    k = len(names)
    yaw, roll = np.radians([yaw_deg, roll_deg])
    frames, truth = [], []
    tries = 0
    while len(frames) < n_frames:
        tries += 1
        if tries > MAX_TRIES * max(n_frames, 1):
            raise RuntimeError("could not sample team frames with every marker in view")
        rho = rng.uniform(*radius)
        angles = 2 * np.pi * np.arange(k) / k + rng.uniform(-0.3, 0.3, k) + rng.uniform(0, 2 * np.pi)
        world: dict[str, Pose] = {}
        for n, phi in zip(names, angles):
            pos = rho * np.array([np.cos(phi), rng.uniform(-0.05, 0.05), np.sin(phi)])
            look = (so3_exp([0.0, rng.uniform(-yaw, yaw), 0.0]) @ -pos)
            world[n] = looking_pose(pos, look) @ Pose(so3_exp([0.0, 0.0, rng.uniform(-roll, roll)]), np.zeros(3))
        ref = world[names[0]].inverse()
        poses = {n: ref @ world[n] for n in names}
        ob = observe(rig, poses, rng, pixel_sigma, len(frames) / fps)
        if ob is None:
            continue
        frames.append(ob)
        truth.append(poses)
    return CalibrationSequence(frames, truth)


def pair_frames(rig: dict[str, Any], poses: list[Pose], rng: np.random.Generator, *, pixel_sigma: float = 0.5,
                fps: float = 10.0) -> list[ObservationSet]:
    """Frames of two robots (the rig's first two, p and q) at the given
    poses T_qp (e.g. a degenerate motion); a frame with a marker out of view
    raises RuntimeError."""
    a, b = list(rig["robots"])[:2]
    out = []
    for k, T in enumerate(poses):
        ob = observe(rig, {b: Pose.identity(), a: T}, rng, pixel_sigma, k / fps)
        if ob is None:
            raise RuntimeError(f"pose {k}: a marker is out of view")
        out.append(ob)
    return out


def true_positions(rig: dict[str, Any]) -> dict[str, np.ndarray]:
    """``{marker: position}`` of a rig in rig-file form."""
    return {n: np.asarray(m["position"], float) for spec in rig["robots"].values() for n, m in spec["markers"].items()}


def robots_of(rig: dict[str, Any]) -> dict[str, str]:
    """``{marker: robot}`` of a rig in rig-file form."""
    return {n: r for r, spec in rig["robots"].items() for n in spec["markers"]}


def held_out_errors(rig: Any, sequence: CalibrationSequence, source: str, target: str, **options: Any) -> np.ndarray:
    """Errors of ``localize`` with ``rig`` on every frame of a held-out
    ``sequence`` (T_target_source against the truth): (n, 2) translation (m)
    and rotation (deg); NaN where it fails."""
    from ..api import localize
    from ..errors import MutlocError

    out = []
    for frame, truth in zip(sequence.frames, sequence.truth):
        T = truth[target].inverse() @ truth[source]
        try:
            est = localize(rig, frame, source, target, confidence=1.0, **options)
            out.append((est.pose.translation_error(T), est.pose.rotation_error_deg(T)))
        except MutlocError:
            out.append((np.nan, np.nan))
    return np.array(out, dtype=float).reshape(-1, 2)



# ---------------------------------------------------------------------------
# robots with several cameras
# ---------------------------------------------------------------------------

#: Markers of a simulated body robot (base_link: x forward, y left, z up): four balls around and above the
#: body at different heights, seen from all round.
BODY_MARKERS = ((0.12, 0.14, 0.50), (-0.14, -0.12, 0.46), (0.10, -0.16, 0.62), (-0.12, 0.12, 0.66))
#: Height of a :func:`body_rig` robot's one pinhole camera above its base (metres).
PINHOLE_HEIGHT = 0.4


def body_rig(robots: tuple[str, ...] = ("p", "q"), *, pinhole: tuple[str, ...] = ()) -> dict[str, Any]:
    """A rig in rig-file form whose robots are bodies with two back-to-back fisheyes
    (:func:`mutloc.sim.bodies.back_to_back_fisheye`) and four balls each (:data:`BODY_MARKERS`, named
    M1.. robot by robot); the robots named in ``pinhole`` have one forward 90-degree pinhole camera
    instead (a robot given with ``camera:``, its frame the camera's)."""
    from ..core.rig import Rig
    from .bodies import back_to_back_fisheye

    out, k = {}, 1
    for r in robots:
        names = {f"M{k + i}": p for i, p in enumerate(BODY_MARKERS)}
        k += len(names)
        if r in pinhole:
            # the body's layout in the camera's optical frame (z forward, x right, y down; the camera
            # PINHOLE_HEIGHT above the body's origin, looking along its x axis)
            cam = {"K": [[480.0, 0.0, 479.5], [0.0, 480.0, 269.5], [0.0, 0.0, 1.0]], "dist": [], "size": [960, 540]}
            out[r] = {"camera": cam, "markers": {n: {"position": [-p[1], PINHOLE_HEIGHT - p[2], p[0]]}
                                                 for n, p in names.items()}}
        else:
            out[r] = Rig({r: back_to_back_fisheye(r, names)}).to_dict()["robots"][r]
    return {"robots": out}


def body_sequence(rig: dict[str, Any], n_frames: int, rng: np.random.Generator, *, pixel_sigma: float = 0.5,
                  distance: tuple[float, float] = (1.2, 3.0), tilt_deg: float = 12.0, fps: float = 10.0,
                  min_per_pair: int = 4) -> CalibrationSequence:
    """Robots of ``rig`` (rig-file form; bodies or robots with one camera) driving around each other: each at
    a random heading, tilted (roll and pitch) by up to ``tilt_deg``, the others ``distance`` from the first;
    every marker every camera images (:func:`mutloc.sim.bodies.body_observations`, keys ``ROBOT/CAMERA``)
    plus Gaussian noise.  Only frames where every robot sees at least ``min_per_pair`` markers of another
    are kept.  Poses are in the first robot's frame."""
    from ..api import load_rig
    from .bodies import OPTICAL_IN_BASE, body_observations

    loaded = load_rig(rig)
    names = list(loaded.robots)
    tilt = np.radians(tilt_deg)
    frames, truth = [], []
    tries = 0
    while len(frames) < n_frames:
        tries += 1
        if tries > MAX_TRIES * max(n_frames, 1):
            raise RuntimeError("could not sample frames where the robots see each other")
        world: dict[str, Pose] = {}
        for i, n in enumerate(names):
            d, a = (0.0, 0.0) if i == 0 else (rng.uniform(*distance), rng.uniform(0, 2 * np.pi))
            R = so3_exp([0.0, 0.0, rng.uniform(0, 2 * np.pi)]) @ so3_exp([rng.uniform(-tilt, tilt),
                                                                          rng.uniform(-tilt, tilt), 0.0])
            world[n] = Pose(R, np.array([d * np.cos(a), d * np.sin(a), rng.uniform(-0.1, 0.1)]))
            if not loaded.robots[n].is_body:  # its frame is its camera's optical frame
                world[n] = world[n] @ Pose(OPTICAL_IN_BASE, np.array([0.0, 0.0, PINHOLE_HEIGHT]))
        seen = body_observations(loaded, world, sigma=pixel_sigma, rng=rng)
        count: dict[tuple[str, str], int] = {}
        for key, ms in seen.items():
            for m in ms:
                pair = (loaded.observer(key)[0], loaded.owner(m))
                count[pair] = count.get(pair, 0) + 1
        if any(max(count.get((a, b), 0) + count.get((b, a), 0) for b in names if b != a) < min_per_pair
               for a in names):
            continue
        obs = ObservationSet.from_dict(seen, time=len(frames) / fps)
        ref = world[names[0]].inverse()
        frames.append(obs)
        truth.append({n: ref @ world[n] for n in names})
    return CalibrationSequence(frames, truth)
