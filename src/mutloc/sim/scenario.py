"""Synthetic data sets on disk: what ``mutloc simulate`` writes.

A scene (one frame) or a sequence of two robots facing each other, rendered
with :mod:`mutloc.sim.render`, with the ground truth in the SPEC's formats.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from ..core.pose import Pose
from ..errors import InputError
from ..io import save_rig, write_json
from ..io.trajectory import write_tum
from .render import moving_world, pixel_bearings, project_markers, relative_pose, render, two_robot_world
from .odometry import DEFAULT_DRIFT, DEFAULT_RATE, check_clock_offsets, write_odometry
from .synthetic import facing_pose
from .world import MARKER_KINDS, standard_rig

__all__ = ["write_simulation", "write_team_simulation", "single_frame_pose", "MARKER_KINDS"]


def single_frame_pose(distance: float, seed: int) -> Any:
    """T_qp of a single simulated frame: p about ``distance`` in front of q, facing it,
    with small seeded yaws, sideways offset and tilt (as in real use, never exactly head-on)."""
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 31337])
    return facing_pose(distance, yaw_p=np.radians(rng.uniform(-12.0, 12.0)),
                       yaw_q=np.radians(rng.uniform(-8.0, 8.0)), lateral=rng.uniform(-0.1, 0.1) * distance,
                       tilt=np.radians(rng.uniform(-2.0, 2.0, 3)))


def write_simulation(out: str | Path, *, markers: str = "balls", distance: float = 2.0, frames: int = 1,
                     fps: float = 30.0, seed: int = 0, noise: float = 1.0, jpeg: int | None = None,
                     blur: float = 0.0, k1: float = 0.0, size: tuple[int, int] = (960, 540),
                     focal: float = 800.0, room: bool = True, progress: bool = False,
                     camera_fps: dict[str, float] | None = None, camera_offset: dict[str, float] | None = None,
                     odometry_rate: float = DEFAULT_RATE, odometry_drift: tuple[float, float] = DEFAULT_DRIFT,
                     clock_offset: dict[str, float] | None = None) -> str:
    """Render a scene (``frames == 1``) or a sequence into ``out``; returns a one-line summary.

    Cameras need not be synchronized: ``camera_fps`` and ``camera_offset``
    (per robot, default ``fps`` and 0 s) make each camera capture at its own
    rate from its own offset over the sequence's ``frames / fps`` seconds;
    each robot's folder then has its own ``frames.csv``, and ``truth.json``
    has one entry per capture instant (with the ``cameras`` capturing then,
    their images and observations), ``truth.tum`` the pose at each instant.

    Files: ``rig.yaml``; ``p.png``, ``q.png`` and ``observations.json`` for a
    single frame, or ``p/NNNNNN.png``, ``q/NNNNNN.png``, ``frames.csv`` and
    ``truth.tum`` for a sequence; always ``truth.json`` with, per frame,
    ``T_qp`` ({R, t, quaternion_xyzw}), ``observations`` (exact pixels of every
    marker centre in view, SPEC observations form) and ``hidden`` (those of
    them something else hides).  A sequence also has ``odometry_NAME.tum``
    for each robot that moves (:func:`mutloc.sim.odometry.write_odometry`:
    ``odometry_rate`` Hz, ``odometry_drift`` = (percent of the distance,
    degrees per metre)).  ``clock_offset`` (per robot but q, seconds) puts
    that robot's stamps on its own clock, ``offset`` behind the true time
    (the reference's, q's): its ``frames.csv`` (then one per robot folder)
    and its odometry; ``truth.json`` records them as ``clock_offsets`` (the
    offset added to the robot's stamps to put them on the reference's
    clock) and keeps the true times.  Raises InputError for bad parameters
    and OSError when a file cannot be written.
    """
    out_dir = Path(out).expanduser()
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"output folder {str(out)!r} exists and is not a folder")
    if frames < 1:
        raise InputError(f"frames must be >= 1, got {frames}")
    if not (fps > 0 and np.isfinite(fps)):
        raise InputError(f"fps must be a finite number > 0, got {fps}")
    rig = standard_rig(markers, size=size, f=focal, k1=k1)
    cam = rig.robot("q").camera
    # A lens model that cannot be inverted over most of the image renders black: refuse it.
    bad = float(np.mean(~np.isfinite(pixel_bearings(cam)[..., 0])))
    if bad > 0.05:
        raise InputError(f"--k1 {k1:g}: the distortion is not invertible over {100 * bad:.0f}% of the "
                         f"{size[0]}x{size[1]} image; use a smaller |k1|")
    sequence = frames > 1
    stamps = _camera_times(frames, fps, camera_fps, camera_offset, sequence)
    clocks = check_clock_offsets(clock_offset, ("p", "q"), "q")
    if clocks and not sequence:
        raise InputError("clock offsets need a sequence (--frames 2 or more)")
    if sequence:
        world = moving_world(rig, distance=distance, room=room, seed=seed, source="p", target="q")
    else:
        world = two_robot_world(rig, single_frame_pose(distance, seed), room=room, seed=seed, source="p",
                                target="q")

    out_dir.mkdir(parents=True, exist_ok=True)
    save_rig(rig, out_dir / "rig.yaml")
    if sequence:
        for robot in ("p", "q"):
            (out_dir / robot).mkdir(exist_ok=True)

    truth_frames = []
    count = {"p": 0, "q": 0}
    own: dict[str, list[tuple[int, float]]] = {"p": [], "q": []}  # per camera: (frame, timestamp)
    steps = tqdm(stamps, desc="rendering", unit="frame", disable=not (progress and sequence))
    for i, (t, cameras) in enumerate(steps):
        images = {}
        for robot in cameras:
            k = count[robot] if stamps.unsynchronized else i
            img = render(world, robot, t, seed=seed + k, noise_sigma=noise, jpeg_quality=jpeg, blur_px=blur)
            rel = f"{robot}/{k:06d}.png" if sequence else f"{robot}.png"
            if not cv2.imwrite(str(out_dir / rel), img):
                raise OSError(f"{out_dir / rel}: cannot write image")
            images[robot] = rel
            own[robot].append((k, t))
            count[robot] += 1
        obs = {robot: project_markers(world, robot, t) for robot in cameras}
        seen = {robot: project_markers(world, robot, t, check_occlusion=True) for robot in cameras}
        entry = {
            "frame": i,
            "timestamp": t,
            "images": images,
            "T_qp": relative_pose(world, "p", "q", t).to_dict(),
            "observations": {r: {m: list(uv) for m, uv in o.items()} for r, o in obs.items()},
            "hidden": {r: sorted(set(obs[r]) - set(seen[r])) for r in obs},
        }
        if stamps.unsynchronized:
            entry["cameras"] = list(cameras)
        truth_frames.append(entry)

    truth = {
        "source": "p", "target": "q", "markers": markers, "frames_count": frames,
        "fps": fps if sequence else None, "seed": seed, "noise_sigma": noise, "jpeg_quality": jpeg,
        "blur_px": blur, "frames": truth_frames,
    }
    if stamps.unsynchronized:
        truth["cameras"] = {r: {"fps": stamps.fps[r], "offset": stamps.offset[r]} for r in ("p", "q")}
    if clocks:
        truth["clock_offsets"] = clocks
    write_json(truth, out_dir / "truth.json")
    files = ["rig.yaml", "truth.json"]
    if sequence:
        per_robot = stamps.unsynchronized or bool(clocks)
        _write_frames_csv([(out_dir / r / "frames.csv", own[r], clocks.get(r, 0.0)) for r in ("p", "q")] if per_robot
                          else [(out_dir / "frames.csv", [(fr["frame"], fr["timestamp"]) for fr in truth_frames], 0.0)])
        write_tum(out_dir / "truth.tum", [fr["timestamp"] for fr in truth_frames],
                  Pose.concatenate([relative_pose(world, "p", "q", fr["timestamp"]) for fr in truth_frames]),
                  comment="timestamp tx ty tz qx qy qz qw  (pose of p in q's camera frame, T_qp)")
        files += (["p/ (frames.csv)", "q/ (frames.csv)"] if per_robot else ["p/", "q/", "frames.csv"]) \
            + ["truth.tum"]
        files += write_odometry(out_dir, {r: (lambda t, r=r: world.pose(r, t)) for r in ("p", "q")},
                                truth_frames[-1]["timestamp"], rate=odometry_rate, drift=odometry_drift, seed=seed,
                                clock_offset=clocks)
    else:
        write_json(truth_frames[0]["observations"], out_dir / "observations.json")
        files += ["p.png", "q.png", "observations.json"]
    n = "1 frame" if frames == 1 else f"{frames} frames"
    return f"wrote {n} ({markers}, {size[0]}x{size[1]}) to {out_dir}: {', '.join(files)}"


def _write_frames_csv(files: list[tuple[Path, list[tuple[int, float]], float]]) -> None:
    """Each ``frames.csv`` of ``(path, [(frame, true time)], clock offset)``: the stamps on that clock."""
    for where, rows, offset in files:
        with open(where, "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(["frame", "timestamp"])
            for k, t in rows:
                w.writerow([k, f"{t - offset:.9f}"])


@dataclass
class _Stamps:
    """Capture instants of a simulated pair: ``(time, cameras capturing)`` in time order."""

    instants: list[tuple[float, tuple[str, ...]]]
    fps: dict[str, float]
    offset: dict[str, float]
    unsynchronized: bool

    def __iter__(self):
        return iter(self.instants)

    def __len__(self) -> int:
        return len(self.instants)


def _camera_times(frames: int, fps: float, camera_fps: dict[str, float] | None,
                  camera_offset: dict[str, float] | None, sequence: bool,
                  names: tuple[str, ...] = ("p", "q")) -> _Stamps:
    """Each camera's capture times over ``frames / fps`` seconds (see :func:`write_simulation`)."""
    rates = {n: float(fps) for n in names}
    offset = {n: 0.0 for n in names}
    for given, into, what in ((camera_fps, rates, "camera_fps"), (camera_offset, offset, "camera_offset")):
        for robot, value in (given or {}).items():
            if robot not in into:
                raise InputError(f"{what}: unknown robot {robot!r} (the simulated robots are {', '.join(names)})")
            into[robot] = float(value)
    unsync = bool(camera_fps or camera_offset)
    if unsync and not sequence:
        raise InputError("camera rates and offsets need a sequence (--frames 2 or more)")
    for r in rates:
        if not (np.isfinite(rates[r]) and rates[r] > 0):
            raise InputError(f"camera frame rate of {r} must be a finite number > 0, got {rates[r]}")
        if not (np.isfinite(offset[r]) and 0.0 <= offset[r] < 1.0 / rates[r]):
            raise InputError(f"camera offset of {r} must be in [0, one frame = {1.0 / rates[r]:.4g} s), "
                             f"got {offset[r]}")
    if not sequence:
        return _Stamps([(0.0, tuple(names))], rates, offset, False)
    if not unsync:
        return _Stamps([(i / fps, tuple(names)) for i in range(frames)], rates, offset, False)
    duration = frames / fps
    times: dict[float, list[str]] = {}
    for r in names:
        k = 0
        while (t := round(offset[r] + k / rates[r], 9)) < duration - 1e-9:
            times.setdefault(t, []).append(r)
            k += 1
    return _Stamps([(t, tuple(times[t])) for t in sorted(times)], rates, offset, True)


#: The loops of fast simulated robots (``--speed``/``--turn-rate``): radius (m) and heading swing (deg).
FAST_TEAM = {"amplitude": 0.3, "yaw_deg": 15.0}

# y-down world of mutloc.sim.team -> z-up world of the renderer
_Y_DOWN_TO_Z_UP = Pose(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]), np.zeros(3))


def write_team_simulation(out: str | Path, *, robots: int, markers: str = "balls", frames: int = 1,
                          fps: float = 30.0, seed: int = 0, noise: float = 1.0, jpeg: int | None = None,
                          size: tuple[int, int] = (960, 540), focal: float = 800.0, k1: float = 0.0,
                          room: bool = True, images: bool = True, progress: bool = False,
                          camera_fps: dict[str, float] | None = None,
                          camera_offset: dict[str, float] | None = None, speed: float | None = None,
                          turn_rate: float | None = None, odometry_rate: float = DEFAULT_RATE,
                          odometry_drift: tuple[float, float] = DEFAULT_DRIFT,
                          clock_offset: dict[str, float] | None = None) -> str:
    """A team of ``robots`` robots in a room (:func:`mutloc.sim.team.random_team`)
    carrying ``markers``: "balls" (four coloured balls each, every ball its
    own colour) or "tags" (two printed AprilTags each, distinct ids; the
    rig gives their corners); returns a one-line summary.

    One frame (``frames == 1``): ``rig.yaml``; ``observations.json`` (exact
    pixels of every marker centre a camera sees unhidden, SPEC observations
    form); ``truth.json`` (``reference`` r0 and ``robots``: each robot's
    ``T_ref_r`` as ``{R, t, quaternion_xyzw}``, plus ``observations`` and
    ``hidden``); with ``images``, one rendered image per robot (``r0.png``, ...).

    A sequence (``frames > 1``, every robot swaying on its own loop,
    :func:`mutloc.sim.team.team_motion`): ``NAME/NNNNNN.png`` per robot,
    ``frames.csv``, ``truth.json`` with per frame ``robots`` (as above) and
    ``observations``, and ``truth_NAME.tum`` per robot but the reference
    (its pose in r0's frame): what ``mutloc track`` writes as
    ``trajectory_NAME.tum``.  ``camera_fps``/``camera_offset`` as
    :func:`write_simulation`: each camera at its own times (each folder its
    own ``frames.csv``; ``truth.json`` per capture instant, with the
    ``cameras`` capturing then).  ``speed`` (m/s) and ``turn_rate`` (deg/s):
    fast robots, each driving a circle of 0.3 m radius about its place and
    swinging its heading by 15 degrees either way
    (:func:`mutloc.sim.team.team_motion`).  ``odometry_*`` and
    ``clock_offset`` (per robot but r0) as :func:`write_simulation`: a
    sequence's ``odometry_NAME.tum`` per moving robot, and robots on their
    own clocks (each folder its own ``frames.csv``).
    """
    from .render import project_markers, render, room_around
    from .team import TEAM_KINDS, random_team, team_motion
    from .world import World, WorldRobot

    if robots < 2:
        raise InputError(f"a team needs at least two robots, got {robots}")
    if markers not in TEAM_KINDS:
        raise InputError(f"a simulated team carries {' or '.join(TEAM_KINDS)}, not {markers!r}")
    if frames < 1 or not (fps > 0 and np.isfinite(fps)):
        raise InputError(f"frames must be >= 1 and fps a finite number > 0, got {frames}, {fps}")
    out_dir = Path(out).expanduser()
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"output folder {str(out)!r} exists and is not a folder")
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 4242])
    # tags face forward only and must be read: the robots closer, looking nearly at the team's centre
    tags = markers == "tags"
    scene = random_team(robots, rng, focal=focal, size=size, k1=k1, one_way=0.0,
                        radius=(0.4 * robots ** 0.5 + 0.6) if tags else (0.6 * robots ** 0.5 + 1.0),
                        kind=markers, yaw_jitter_deg=10.0 if tags else 30.0)
    names = scene.names
    sequence = frames > 1
    capture = _camera_times(frames, fps, camera_fps, camera_offset, sequence, tuple(names))
    clocks = check_clock_offsets(clock_offset, tuple(names), names[0])
    if clocks and not sequence:
        raise InputError("clock offsets need a sequence (--frames 2 or more)")
    fast = FAST_TEAM if speed is not None or turn_rate is not None else {}
    motion = (team_motion(scene, seed=seed, speed=speed, turn_rate=turn_rate, **fast) if sequence
              else (lambda t: scene.world))

    def pose_fn(n: str):
        return lambda t: _Y_DOWN_TO_Z_UP @ motion(t)[n]

    starts = [_Y_DOWN_TO_Z_UP.apply(T.t) for T in scene.world.values()]
    rm = room_around(starts, seed) if room else None
    world = World(robots={n: WorldRobot(scene.rig.robot(n), pose_fn(n)) for n in names}, room=rm)
    out_dir.mkdir(parents=True, exist_ok=True)
    save_rig(scene.rig, out_dir / "rig.yaml")
    if sequence and images:
        for n in names:
            (out_dir / n).mkdir(exist_ok=True)
    truth_frames = []
    poses: list[dict[str, Pose]] = []
    count = {n: 0 for n in names}
    own: dict[str, list[tuple[int, float]]] = {n: [] for n in names}  # per camera: (frame, timestamp)
    bar = tqdm(capture, desc="rendering", unit="frame", disable=not (progress and images))
    for i, (t, cameras) in enumerate(bar):
        obs, hidden = {}, {}
        for n in cameras:
            allm = project_markers(world, n, t)
            seen = project_markers(world, n, t, check_occlusion=True)
            if seen:
                obs[n] = {m: list(uv) for m, uv in seen.items()}
            hidden[n] = sorted(set(allm) - set(seen))
        for n in cameras:
            k = count[n] if capture.unsynchronized else i
            if images:
                img = render(world, n, t, seed=seed + k, noise_sigma=noise, jpeg_quality=jpeg)
                rel = f"{n}/{k:06d}.png" if sequence else f"{n}.png"
                if not cv2.imwrite(str(out_dir / rel), img):
                    raise OSError(f"{out_dir / rel}: cannot write image")
            own[n].append((k, t))
            count[n] += 1
        ref = world.pose(names[0], t).inverse()
        poses.append({n: ref @ world.pose(n, t) for n in names[1:]})
        truth_frames.append({"frame": i, "timestamp": t, "robots": {n: T.to_dict() for n, T in poses[-1].items()},
                             "observations": obs, "hidden": hidden})
        if capture.unsynchronized:
            truth_frames[-1]["cameras"] = list(cameras)
    files = ["rig.yaml", "truth.json"]
    common = {"reference": names[0], "markers": markers, "seed": seed, "noise_sigma": noise, "jpeg_quality": jpeg}
    if sequence:
        if capture.unsynchronized:
            common["cameras"] = {n: {"fps": capture.fps[n], "offset": capture.offset[n]} for n in names}
        if clocks:
            common["clock_offsets"] = clocks
        write_json({**common, "frames_count": frames, "fps": fps, "frames": truth_frames}, out_dir / "truth.json")
        per_robot = capture.unsynchronized or bool(clocks)
        _write_frames_csv([(out_dir / n / "frames.csv", own[n], clocks.get(n, 0.0)) for n in names if images]
                          if per_robot else
                          [(out_dir / "frames.csv", [(fr["frame"], fr["timestamp"]) for fr in truth_frames], 0.0)])
        stamps = [fr["timestamp"] for fr in truth_frames]
        for n in names[1:]:
            write_tum(out_dir / f"truth_{n}.tum", stamps,
                      Pose.concatenate([p[n] for p in poses]),
                      comment=f"timestamp tx ty tz qx qy qz qw  (pose of {n} in {names[0]}'s camera frame)")
        files += (["frames.csv in each robot's folder" if images else "(no images)"] if per_robot
                  else ["frames.csv"]) + \
            [f"truth_{names[1]}.tum ..."] + ([f"{names[0]}/ ... {names[-1]}/"] if images else [])
        odo = write_odometry(out_dir, {n: (lambda t, n=n: world.pose(n, t)) for n in names}, stamps[-1],
                             rate=odometry_rate, drift=odometry_drift, seed=seed, clock_offset=clocks)
        if odo:
            files.append(f"{odo[0]} ... ({len(odo)} robots)" if len(odo) > 2 else ", ".join(odo))
        n_obs = sum(len(v) for fr in truth_frames for v in fr["observations"].values())
        return (f"wrote {frames} frames of a team of {robots} robots ({markers}, {n_obs} marker observations) "
                f"to {out_dir}: {', '.join(files)}")
    fr = truth_frames[0]
    write_json(fr["observations"], out_dir / "observations.json")
    write_json({**common, "robots": fr["robots"], "observations": fr["observations"], "hidden": fr["hidden"]},
               out_dir / "truth.json")
    files.append("observations.json")
    if images:
        files.append(f"{names[0]}.png ... {names[-1]}.png")
    n_obs = sum(len(v) for v in fr["observations"].values())
    return f"wrote a team of {robots} robots ({markers}, {n_obs} marker observations) to {out_dir}: {', '.join(files)}"
