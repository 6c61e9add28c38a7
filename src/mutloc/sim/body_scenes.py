"""Robots with several cameras in simulation: what ``mutloc simulate --cameras`` writes.

The robots are bodies (SPEC "Robots with several cameras, any lens"): each
robot's frame is a ``base_link`` on the floor (x forward, y left, z up), its
cameras have poses in it, and poses are between robot frames.

- :data:`CAMERA_SETS`: ``"single"`` (one pinhole camera per robot, what
  :func:`mutloc.sim.scenario.write_simulation` renders) and
  ``"back-to-back-fisheye"`` (:func:`fisheye_pair_rig`: two fisheyes of
  about 200 degrees, ``front`` and ``back``, on the front and back faces of
  the body, 1280x800).
- :data:`FACINGS`: ``"toward"`` (the robots face each other: the front
  cameras see the other robot) and ``"away"`` (back to back: only the back
  cameras see the other robot).
- :func:`body_pair_world` / :func:`moving_body_world` put such a rig in a
  room; :func:`passing_body_world` drives p past q's side, across the rims
  of q's fisheyes (80-95 degrees off their axes); :func:`mutloc.sim.render.render` renders any camera of it
  (``render(world, "p/back", t)``) and
  :func:`mutloc.sim.render.true_observations` gives the exact pixels.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np
from tqdm import tqdm

from ..core.geometry import so3_exp, so3_log
from ..core.lenses import FisheyeCamera
from ..core.pose import Pose
from ..core.rig import Marker, Mount, Rig, Robot
from ..errors import InputError
from ..io import save_rig, write_json
from ..io.trajectory import write_tum
from .render import project_markers, relative_pose, render, room_around
from .world import DEFAULT_BALL_RADIUS, DEFAULT_LIGHT_RADIUS, World, WorldRobot, tag_corners

__all__ = ["CAMERA_SETS", "FACINGS", "BODY_MARKER_KINDS", "TAG_FACES", "TAG_SIZE", "face_tag_rotation",
           "tag_corner_pixels", "FISHEYE_DIST", "FISHEYE_SIZE", "FISHEYE_FOCAL",
           "fisheye_pair_rig", "body_pair_pose", "body_pair_world", "moving_body_world", "passing_body_world",
           "write_cameras_simulation", "image_name"]

CAMERA_SETS = ("single", "back-to-back-fisheye")
FACINGS = ("toward", "away")
#: Marker kinds a simulated body carries, seen from all round: balls, lights, upright banded cylinders, and
#: printed tags on the body's four sides (one tag per side, :data:`TAG_FACES`).
BODY_MARKER_KINDS = ("balls", "lights", "cylinders", "tags")

#: Kannala-Brandt k1..k4 of the simulated fisheyes: the model images up to 99.7 degrees off the axis
#: (a 199-degree image circle, black outside), compressing towards the rim as real fisheyes do.
FISHEYE_DIST = (-0.01, 0.0, 0.0, -0.0012)
FISHEYE_SIZE = (1280, 800)
#: Focal length (px) at 1280x800: the image circle (395 px radius) just fits the 800 px height.
FISHEYE_FOCAL = 261.0

# Camera mounts in the base_link frame: on the body's front and back faces (x = +-0.20, see
# mutloc.sim.render.BODY_BOX), 30 cm above the floor.  Optical frame: z forward, x right, y down.
_R_FRONT = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
_R_BACK = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
_MOUNTS = {"front": Pose(_R_FRONT, np.array([0.21, 0.0, 0.30])),
           "back": Pose(_R_BACK, np.array([-0.21, 0.0, 0.30]))}
# Two markers per robot, left and right above the body (its top is at 0.36 m).
_LAYOUT = {"q": {"M1": (-0.02, 0.13, 0.42), "M2": (-0.02, -0.13, 0.42)},
           "p": {"M3": (-0.02, 0.13, 0.42), "M4": (-0.02, -0.13, 0.42)}}
_COLORS = {"M1": (0, 0, 255), "M2": (255, 255, 0), "M3": (255, 0, 0), "M4": (0, 255, 0)}
_BLINK = {"M1": 2.0, "M2": 3.0, "M3": 5.0, "M4": 7.5}
#: Banded cylinders standing on the body (axis along base_link z, :func:`mutloc.sim.world.cylinder_up`):
#: 5 cm radius, 24 cm tall, six 4 cm bands (the standard rig's codes: dark bands at both ends), their
#: centres 0.505 m above the floor (the body's top is at 0.36 m): 5 px bands at 2 m through the 1280x800
#: fisheyes.
CYLINDER_RADIUS, CYLINDER_HEIGHT, CYLINDER_Z = 0.05, 0.24, 0.505
_CODES = {"M1": [1, 0, 1, 0, 0, 1], "M2": [1, 1, 0, 1, 0, 1], "M3": [1, 0, 0, 1, 1, 1], "M4": [1, 1, 1, 0, 0, 1]}
#: Printed tags (tag36h11, 20 cm; the card with its white margin 25 cm) on the body's four sides, 1 cm proud of
#: the faces of :data:`mutloc.sim.render.BODY_BOX`, centred 15.5 cm above the floor (below the cameras, which
#: are 30 cm up): face -> (outward normal in base_link, centre).  q carries M1..M4 (ids 0..3: front, left,
#: back, right), p M5..M8 (ids 4..7).  A tag of 20 cm is 33 px across 1.6 m away through the 1280x800 fisheyes.
TAG_SIZE = 0.20
TAG_FACES = {"front": ((1.0, 0.0, 0.0), (0.21, 0.0, 0.155)), "left": ((0.0, 1.0, 0.0), (0.0, 0.16, 0.155)),
             "back": ((-1.0, 0.0, 0.0), (-0.21, 0.0, 0.155)), "right": ((0.0, -1.0, 0.0), (0.0, -0.16, 0.155))}
_TAG_NAMES = {"q": ("M1", "M2", "M3", "M4"), "p": ("M5", "M6", "M7", "M8")}


def face_tag_rotation(normal: Any) -> np.ndarray:
    """``R_robot_tag`` of a tag printed on a vertical face whose outward normal is ``normal`` (base_link):
    the tag frame (:mod:`mutloc.detect.tags`: x right and y down as printed, z into the tag) upright, read
    from outside: z = -normal, y = -z_up, x = y x z."""
    n = np.asarray(normal, float)
    z = -n / np.linalg.norm(n)
    y = np.array([0.0, 0.0, -1.0])
    return np.column_stack([np.cross(y, z), y, z])


def image_name(key: str) -> str:
    """File stem of a camera's images: ``p/front`` -> ``p_front``."""
    return key.replace("/", "_")


def fisheye_pair_rig(markers: str = "balls", *, size: tuple[int, int] = FISHEYE_SIZE) -> Rig:
    """Robots ``p`` (M3, M4) and ``q`` (M1, M2), each with fisheyes ``front`` and ``back`` back to back.

    Cameras: :class:`~mutloc.core.lenses.FisheyeCamera` with :data:`FISHEYE_DIST`, centred principal
    point, focal :data:`FISHEYE_FOCAL` scaled with ``size`` (default 1280x800).  Markers: coloured balls,
    blinking lights or upright banded cylinders (``markers``, :data:`BODY_MARKER_KINDS`) above the body,
    or printed tags on its four sides (``"tags"``: q M1..M4, p M5..M8, :data:`TAG_FACES`), each with its
    ``rotation`` so that its corners are known points.
    """
    if markers not in BODY_MARKER_KINDS:
        raise InputError(f"robots with several cameras carry {', '.join(BODY_MARKER_KINDS)}, not {markers!r}")
    w, h = int(size[0]), int(size[1])
    f = FISHEYE_FOCAL * min(w / FISHEYE_SIZE[0], h / FISHEYE_SIZE[1])
    K = np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    robots = {}
    for rname in ("p", "q"):
        cams = {c: Mount(c, FisheyeCamera(K, FISHEYE_DIST, (w, h)), T) for c, T in _MOUNTS.items()}
        ms = {}
        if markers == "tags":
            for i, (mname, (normal, pos)) in enumerate(zip(_TAG_NAMES[rname], TAG_FACES.values())):
                tid = i + (0 if rname == "q" else 4)
                ms[mname] = Marker(mname, rname, np.array(pos), tag={
                    "family": "tag36h11", "id": tid, "size": TAG_SIZE,
                    "rotation": [float(x) for x in so3_log(face_tag_rotation(normal))]})
        for mname, pos in ({} if markers == "tags" else _LAYOUT[rname]).items():
            if markers == "balls":
                ms[mname] = Marker(mname, rname, np.array(pos), color=_COLORS[mname],
                                   extra={"radius": DEFAULT_BALL_RADIUS})
            elif markers == "lights":
                ms[mname] = Marker(mname, rname, np.array(pos), color=_COLORS[mname], blink_hz=_BLINK[mname],
                                   extra={"radius": DEFAULT_LIGHT_RADIUS})
            else:
                ms[mname] = Marker(mname, rname, np.array([pos[0], pos[1], CYLINDER_Z]), extra={"cylinder": {
                    "radius": CYLINDER_RADIUS, "height": CYLINDER_HEIGHT, "code": list(_CODES[mname])}})
        robots[rname] = Robot(rname, None, ms, cameras=cams)
    return Rig(robots)


def _yaw(a: float) -> np.ndarray:
    return so3_exp([0.0, 0.0, float(a)])


def _place(facing: str, distance: float, yaw_q: float, yaw_p: float, lateral: float,
           ) -> tuple[Pose, Pose]:
    """World poses of q and p (base_link on the floor): q at the origin heading +x turned by ``yaw_q``; p
    ``distance`` ahead of q (``toward``) or behind it (``away``), shifted ``lateral`` sideways, heading back
    towards -x turned by ``yaw_p``."""
    if facing not in FACINGS:
        raise InputError(f"facing must be one of {', '.join(FACINGS)}, got {facing!r}")
    sign = 1.0 if facing == "toward" else -1.0
    T_wq = Pose(_yaw(yaw_q), np.zeros(3))
    T_wp = Pose(_yaw(math.pi + yaw_p), np.array([sign * distance, lateral, 0.0]))
    return T_wq, T_wp


def body_pair_pose(distance: float, seed: int, facing: str = "toward") -> tuple[Pose, Pose]:
    """World poses ``(T_wq, T_wp)`` of a single simulated frame: robots ``distance`` apart (robot origins),
    facing each other or back to back, with small seeded headings and sideways offset."""
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 31338])
    return _place(facing, distance, math.radians(rng.uniform(-8.0, 8.0)), math.radians(rng.uniform(-12.0, 12.0)),
                  rng.uniform(-0.1, 0.1) * distance)


def body_pair_world(rig: Rig, T_wq: Pose, T_wp: Pose, *, room: bool = True, seed: int = 0,
                    body: bool = True) -> World:
    """A room with robots q and p of ``rig`` at world poses ``T_wq``, ``T_wp`` (robot -> world)."""
    robots = {"q": WorldRobot(rig.robot("q"), T_wq, body=body), "p": WorldRobot(rig.robot("p"), T_wp, body=body)}
    rm = room_around([T_wq.t, T_wp.t], seed) if room else None
    return World(robots=robots, room=rm)


def moving_body_world(rig: Rig, *, distance: float = 2.0, facing: str = "toward", period: float = 8.0,
                      lateral: float = 0.3, room: bool = True, seed: int = 0) -> World:
    """Robot p drives a smooth figure ahead of (or behind) q: sways sideways by ``lateral * distance``, in
    and out by 15 %, heading wobbling 5 degrees; q's heading pans 6 degrees.  Periodic in ``period``."""
    if not (math.isfinite(distance) and distance > 0):
        raise InputError(f"distance must be > 0, got {distance!r}")
    w = 2 * math.pi / period

    def poses(t: float) -> tuple[Pose, Pose]:
        return _place(facing, distance * (1.0 + 0.15 * math.sin(2 * w * t + 0.3)),
                      math.radians(6.0) * math.sin(w * t + 1.0), math.radians(5.0) * math.sin(1.5 * w * t),
                      lateral * distance * math.sin(w * t))

    T_wq: Callable[[float], Pose] = lambda t: poses(t)[0]  # noqa: E731
    T_wp: Callable[[float], Pose] = lambda t: poses(t)[1]  # noqa: E731
    robots = {"q": WorldRobot(rig.robot("q"), T_wq), "p": WorldRobot(rig.robot("p"), T_wp)}
    rm = room_around([T_wq(0.0).t] + [T_wp(s).t for s in np.linspace(0.0, period, 33)], seed) if room else None
    return World(robots=robots, room=rm)


def passing_body_world(rig: Rig, *, lateral: float = 1.1, start: float = 0.55, speed: float = 0.3,
                       turn: float = 0.1, room: bool = False, seed: int = 0) -> World:
    """Robot p drives past q's left side, sideways to q (its markers one behind the other along q's x), so
    they sweep across the rims of q's fisheyes: p's origin at ``(start - speed * t, lateral)`` in q's frame
    (q at the origin heading +x), heading -90 degrees plus ``turn * t`` rad.  With the defaults the nearer
    marker is 67 degrees off q's front camera's axis at t = 0 and 89 at 1.5 s, the farther 79 to past 93
    (where q's own body hides it from that camera: its back camera sees it)."""
    if not (math.isfinite(lateral) and lateral > 0.5):
        raise InputError(f"lateral must be more than 0.5 m (the robots' bodies), got {lateral!r}")
    T_wq = Pose(np.eye(3), np.zeros(3))

    def T_wp(t: float) -> Pose:
        return Pose(_yaw(-0.5 * math.pi + turn * t), np.array([start - speed * t, lateral, 0.0]))

    robots = {"q": WorldRobot(rig.robot("q"), T_wq), "p": WorldRobot(rig.robot("p"), T_wp)}
    rm = room_around([T_wq.t, T_wp(0.0).t, T_wp(3.0).t], seed) if room else None
    return World(robots=robots, room=rm)


def tag_corner_pixels(world: World, key: str, t: float, names: Any) -> dict[str, list[list[float]]]:
    """Exact raw pixels, through camera ``key``'s lens and mount, of the four corners (OpenCV order: the
    tag's top-left, top-right, bottom-right, bottom-left as printed) of each tag marker in ``names`` at
    ``t``: the truth for a detector's tag corners (``NAME#0..3``).  Corners may lie outside the image."""
    camera = world.camera(key)
    T_cw = world.camera_pose(key, t).inverse()
    out: dict[str, list[list[float]]] = {}
    for wr in world.robots.values():
        for m in wr.robot.markers.values():
            if m.name in names and m.tag is not None:
                X = (T_cw @ wr.pose_at(t)).apply(tag_corners(m))
                out[m.name] = np.asarray(camera.project(X), float).reshape(4, 2).tolist()
    return out


def write_cameras_simulation(out: str | Path, *, cameras: str = "back-to-back-fisheye", facing: str = "toward",
                             markers: str = "balls", distance: float = 2.0, frames: int = 1, fps: float = 30.0,
                             seed: int = 0, noise: float = 1.0, jpeg: int | None = None, blur: float = 0.0,
                             size: tuple[int, int] | None = None, room: bool = True,
                             progress: bool = False) -> str:
    """Render robots p and q with several cameras each (``cameras``, :data:`CAMERA_SETS` but ``single``)
    into ``out``; returns a one-line summary.

    Files: ``rig.yaml`` (``cameras:``); one image per camera, ``p_front.png``,
    ``p_back.png``, ``q_front.png``, ``q_back.png`` (a sequence: folders
    ``p_front/NNNNNN.png`` ... and ``frames.csv``, ``truth.tum``);
    ``observations.json`` for a single frame (keyed ``ROBOT/CAMERA``, cameras
    seeing nothing left out); ``truth.json`` as
    :func:`mutloc.sim.scenario.write_simulation`'s, poses between robot
    (body) frames: per frame ``T_qp``, ``images`` per camera,
    ``observations`` (exact raw pixels of every marker centre in a camera's
    view) and ``hidden`` (those something hides), for tags also ``corners``
    (per camera, per tag whose centre it views: its four corners' exact raw
    pixels, :func:`tag_corner_pixels`, the truth of the corner markers
    ``NAME#0..3``), plus ``cameras`` and ``facing``.  ``distance``: between the robots' origins.
    """
    if cameras not in CAMERA_SETS or cameras == "single":
        raise InputError(f"cameras must be one of {', '.join(CAMERA_SETS[1:])} here, got {cameras!r}")
    if facing not in FACINGS:
        raise InputError(f"facing must be one of {', '.join(FACINGS)}, got {facing!r}")
    if markers not in BODY_MARKER_KINDS:
        raise InputError(f"--markers {markers}: robots with several cameras carry "
                         f"{', '.join(BODY_MARKER_KINDS)} (seen from all round)")
    out_dir = Path(out).expanduser()
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"output folder {str(out)!r} exists and is not a folder")
    if frames < 1 or not (fps > 0 and np.isfinite(fps)):
        raise InputError(f"frames must be >= 1 and fps a finite number > 0, got {frames}, {fps}")
    if not (math.isfinite(distance) and distance > 0.5):
        raise InputError(f"distance must be more than 0.5 m (the robots' bodies), got {distance!r}")
    rig = fisheye_pair_rig(markers, size=size or FISHEYE_SIZE)
    sequence = frames > 1
    if sequence:
        world = moving_body_world(rig, distance=distance, facing=facing, room=room, seed=seed)
    else:
        world = body_pair_world(rig, *body_pair_pose(distance, seed, facing), room=room, seed=seed)
    keys = rig.observer_keys()
    out_dir.mkdir(parents=True, exist_ok=True)
    save_rig(rig, out_dir / "rig.yaml")
    if sequence:
        for k in keys:
            (out_dir / image_name(k)).mkdir(exist_ok=True)
    truth_frames: list[dict[str, Any]] = []
    steps = tqdm(range(frames), desc="rendering", unit="frame", disable=not (progress and sequence))
    for i in steps:
        t = i / fps
        images = {}
        obs, hidden, corners = {}, {}, {}
        for k in keys:
            img = render(world, k, t, seed=seed + i, noise_sigma=noise, jpeg_quality=jpeg, blur_px=blur)
            rel = f"{image_name(k)}/{i:06d}.png" if sequence else f"{image_name(k)}.png"
            if not cv2.imwrite(str(out_dir / rel), img):
                raise OSError(f"{out_dir / rel}: cannot write image")
            images[k] = rel
            allm = project_markers(world, k, t)
            seen = project_markers(world, k, t, check_occlusion=True)
            if allm:
                obs[k] = {m: list(uv) for m, uv in allm.items()}
                hidden[k] = sorted(set(allm) - set(seen))
                if markers == "tags":
                    corners[k] = tag_corner_pixels(world, k, t, allm)
        truth_frames.append({"frame": i, "timestamp": t, "images": images,
                             "T_qp": relative_pose(world, "p", "q", t).to_dict(),
                             "observations": obs, "hidden": hidden, **({"corners": corners} if corners else {})})
    truth = {"source": "p", "target": "q", "cameras": cameras, "facing": facing, "markers": markers,
             "frames_count": frames, "fps": fps if sequence else None, "seed": seed, "noise_sigma": noise,
             "jpeg_quality": jpeg, "blur_px": blur, "frames": truth_frames}
    write_json(truth, out_dir / "truth.json")
    files = ["rig.yaml", "truth.json"]
    if sequence:
        with open(out_dir / "frames.csv", "w", newline="", encoding="utf-8") as fh:
            wr = csv.writer(fh)
            wr.writerow(["frame", "timestamp"])
            for fr in truth_frames:
                wr.writerow([fr["frame"], f"{fr['timestamp']:.9f}"])
        write_tum(out_dir / "truth.tum", [fr["timestamp"] for fr in truth_frames],
                  Pose.concatenate([relative_pose(world, "p", "q", fr["timestamp"]) for fr in truth_frames]),
                  comment="timestamp tx ty tz qx qy qz qw  (pose of p's body frame in q's, T_qp)")
        files += [f"{image_name(k)}/" for k in keys] + ["frames.csv", "truth.tum"]
    else:
        write_json(truth_frames[0]["observations"], out_dir / "observations.json")
        files += [f"{image_name(k)}.png" for k in keys] + ["observations.json"]
    w, h = rig.robot("p").cameras["front"].camera.size
    n = "1 frame" if frames == 1 else f"{frames} frames"
    return (f"wrote {n} ({cameras}, facing {facing}, {markers}, {w}x{h}) to {out_dir}: {', '.join(files)}")
