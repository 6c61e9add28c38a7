"""Synthetic data sets on disk: what ``mutloc simulate`` writes.

A scene (one frame) or a sequence of two robots facing each other, rendered
with :mod:`mutloc.sim.render`, with the ground truth in the SPEC's formats.
"""

from __future__ import annotations

import csv
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
                     focal: float = 800.0, room: bool = True, progress: bool = False) -> str:
    """Render a scene (``frames == 1``) or a sequence into ``out``; returns a one-line summary.

    Files: ``rig.yaml``; ``p.png``, ``q.png`` and ``observations.json`` for a
    single frame, or ``p/NNNNNN.png``, ``q/NNNNNN.png``, ``frames.csv`` and
    ``truth.tum`` for a sequence; always ``truth.json`` with, per frame,
    ``T_qp`` ({R, t, quaternion_xyzw}), ``observations`` (exact pixels of every
    marker centre in view, SPEC observations form) and ``hidden`` (those of
    them something else hides).  Raises InputError for bad parameters and
    OSError when a file cannot be written.
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
    steps = tqdm(range(frames), desc="rendering", unit="frame", disable=not (progress and sequence))
    for i in steps:
        t = i / fps if sequence else 0.0
        images = {}
        for robot in ("p", "q"):
            img = render(world, robot, t, seed=seed + i, noise_sigma=noise, jpeg_quality=jpeg, blur_px=blur)
            rel = f"{robot}/{i:06d}.png" if sequence else f"{robot}.png"
            if not cv2.imwrite(str(out_dir / rel), img):
                raise OSError(f"{out_dir / rel}: cannot write image")
            images[robot] = rel
        obs = {robot: project_markers(world, robot, t) for robot in ("p", "q")}
        seen = {robot: project_markers(world, robot, t, check_occlusion=True) for robot in ("p", "q")}
        truth_frames.append({
            "frame": i,
            "timestamp": t,
            "images": images,
            "T_qp": relative_pose(world, "p", "q", t).to_dict(),
            "observations": {r: {m: list(uv) for m, uv in o.items()} for r, o in obs.items()},
            "hidden": {r: sorted(set(obs[r]) - set(seen[r])) for r in obs},
        })

    truth = {
        "source": "p", "target": "q", "markers": markers, "frames_count": frames,
        "fps": fps if sequence else None, "seed": seed, "noise_sigma": noise, "jpeg_quality": jpeg,
        "blur_px": blur, "frames": truth_frames,
    }
    write_json(truth, out_dir / "truth.json")
    files = ["rig.yaml", "truth.json"]
    if sequence:
        with open(out_dir / "frames.csv", "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(["frame", "timestamp"])
            for fr in truth_frames:
                w.writerow([fr["frame"], f"{fr['timestamp']:.9f}"])
        write_tum(out_dir / "truth.tum", [fr["timestamp"] for fr in truth_frames],
                  Pose.concatenate([relative_pose(world, "p", "q", fr["timestamp"]) for fr in truth_frames]),
                  comment="timestamp tx ty tz qx qy qz qw  (pose of p in q's camera frame, T_qp)")
        files += ["p/", "q/", "frames.csv", "truth.tum"]
    else:
        write_json(truth_frames[0]["observations"], out_dir / "observations.json")
        files += ["p.png", "q.png", "observations.json"]
    n = "1 frame" if frames == 1 else f"{frames} frames"
    return f"wrote {n} ({markers}, {size[0]}x{size[1]}) to {out_dir}: {', '.join(files)}"


# y-down world of mutloc.sim.team -> z-up world of the renderer
_Y_DOWN_TO_Z_UP = Pose(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]), np.zeros(3))


def write_team_simulation(out: str | Path, *, robots: int, seed: int = 0, noise: float = 1.0,
                          jpeg: int | None = None, size: tuple[int, int] = (960, 540), focal: float = 800.0,
                          k1: float = 0.0, room: bool = True, images: bool = True, progress: bool = False) -> str:
    """A team of ``robots`` robots in a room (:func:`mutloc.sim.team.random_team`),
    each with four coloured balls around its camera, every ball its own
    colour; returns a one-line summary.

    Files: ``rig.yaml``; ``observations.json`` (exact pixels of every ball
    centre a camera sees unhidden, SPEC observations form); ``truth.json``
    (``reference`` r0 and ``robots``: each robot's ``T_ref_r`` as
    ``{R, t, quaternion_xyzw}``, plus ``observations`` and ``hidden``); with
    ``images``, one rendered image per robot (``r0.png``, ...).
    """
    from .render import project_markers, render, room_around
    from .team import random_team
    from .world import World, WorldRobot

    if robots < 2:
        raise InputError(f"a team needs at least two robots, got {robots}")
    out_dir = Path(out).expanduser()
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"output folder {str(out)!r} exists and is not a folder")
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 4242])
    scene = random_team(robots, rng, focal=focal, size=size, k1=k1, one_way=0.0, radius=0.6 * robots ** 0.5 + 1.0)
    names = scene.names
    world_poses = {n: _Y_DOWN_TO_Z_UP @ T for n, T in scene.world.items()}
    rm = room_around([T.t for T in world_poses.values()], seed) if room else None
    world = World(robots={n: WorldRobot(scene.rig.robot(n), world_poses[n]) for n in names}, room=rm)
    out_dir.mkdir(parents=True, exist_ok=True)
    save_rig(scene.rig, out_dir / "rig.yaml")
    obs, hidden = {}, {}
    for n in names:
        allm = project_markers(world, n)
        seen = project_markers(world, n, check_occlusion=True)
        if seen:
            obs[n] = {m: list(uv) for m, uv in seen.items()}
        hidden[n] = sorted(set(allm) - set(seen))
    files = ["rig.yaml", "observations.json", "truth.json"]
    if images:
        for n in tqdm(names, desc="rendering", unit="robot", disable=not progress):
            img = render(world, n, 0.0, seed=seed, noise_sigma=noise, jpeg_quality=jpeg)
            if not cv2.imwrite(str(out_dir / f"{n}.png"), img):
                raise OSError(f"{out_dir / n}.png: cannot write image")
        files.append(f"{names[0]}.png ... {names[-1]}.png")
    truth = scene.truth(names[0])
    write_json(obs, out_dir / "observations.json")
    write_json({"reference": names[0], "robots": {n: truth[n].to_dict() for n in names[1:]}, "seed": seed,
                "noise_sigma": noise, "jpeg_quality": jpeg, "observations": obs, "hidden": hidden},
               out_dir / "truth.json")
    n_obs = sum(len(v) for v in obs.values())
    return f"wrote a team of {robots} robots ({n_obs} marker observations) to {out_dir}: {', '.join(files)}"
