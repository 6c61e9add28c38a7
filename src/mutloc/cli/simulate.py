"""``mutloc simulate``: render a synthetic scene or sequence with ground truth."""

from __future__ import annotations

import argparse
import math
import re
from pathlib import Path
from typing import Any

from ._common import int_in_range, nonnegative_float, positive_float

ORDER = 70

# As mutloc.sim.world.MARKER_KINDS (not imported: keep `mutloc --help` light).
MARKER_KINDS = ("balls", "lights", "tags", "cylinders")


def _image_size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX,]\s*(\d+)\s*", text)
    if not m or int(m.group(1)) < 16 or int(m.group(2)) < 16:
        raise argparse.ArgumentTypeError(f"size must be WIDTHxHEIGHT (each >= 16), e.g. 960x540, got {text!r}")
    return int(m.group(1)), int(m.group(2))


def _finite_float(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(x):
        raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
    return x


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``simulate``."""
    p = subparsers.add_parser(
        "simulate",
        help="render a synthetic scene or sequence, with ground truth",
        description=(
            "Render two robots p and q facing each other in a textured room with the built-in "
            "ray caster. Writes rig.yaml, the images (p.png and q.png, or p/ and q/ folders for a "
            "sequence with frames.csv), truth.json (T_qp and exact marker pixels per frame) and, "
            "for sequences, truth_tum.txt (pose of p in q's frame, TUM format)."
        ),
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created if missing)")
    p.add_argument("--markers", choices=MARKER_KINDS, default="balls",
                   help="marker kind on each robot (default balls)")
    p.add_argument("--distance", type=positive_float, default=2.0, metavar="M",
                   help="distance between the cameras in metres (default 2.0)")
    p.add_argument("--frames", type=int_in_range(1), default=1, metavar="N",
                   help="number of frames; more than 1 renders a sequence of p moving (default 1)")
    p.add_argument("--fps", type=positive_float, default=30.0, help="frame rate of a sequence (default 30)")
    p.add_argument("--seed", type=int, default=0, help="seed of the room, the pose and the noise (default 0)")
    p.add_argument("--noise", type=nonnegative_float, default=1.0, metavar="SIGMA",
                   help="sensor noise, standard deviation in grey levels (default 1.0)")
    p.add_argument("--jpeg", type=int_in_range(1, 100, 'JPEG quality'), metavar="Q",
                   help="pass each image through JPEG at quality Q (files stay PNG)")
    p.add_argument("--blur", type=nonnegative_float, default=0.0, metavar="PX",
                   help="horizontal motion blur length in pixels (default 0)")
    p.add_argument("--k1", type=_finite_float, default=0.0, help="radial distortion k1 of both cameras (default 0)")
    p.add_argument("--size", type=_image_size, default=(960, 540), metavar="WxH",
                   help="image size (default 960x540)")
    p.add_argument("--focal", type=positive_float, default=800.0, metavar="PX",
                   help="focal length in pixels (default 800)")
    p.add_argument("--no-room", action="store_true", help="robots on a black background, no room")
    return p


def run(args: argparse.Namespace) -> int:
    """Render and write the files; prints a one-line summary."""
    summary = write_simulation(
        args.out, markers=args.markers, distance=args.distance, frames=args.frames, fps=args.fps,
        seed=args.seed, noise=args.noise, jpeg=args.jpeg, blur=args.blur, k1=args.k1, size=args.size,
        focal=args.focal, room=not args.no_room, progress=True,
    )
    print(summary)
    return 0


def _pose_json(T: Any) -> dict[str, Any]:
    return {"R": T.R.tolist(), "t": T.t.tolist(), "quaternion_xyzw": T.quaternion_xyzw.tolist()}


def single_frame_pose(distance: float, seed: int) -> Any:
    """T_qp of a single simulated frame: p about ``distance`` in front of q, facing it,
    with small seeded yaws, sideways offset and tilt (as in real use, never exactly head-on)."""
    import numpy as np

    from ..sim.synthetic import facing_pose

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
    ``truth_tum.txt`` for a sequence; always ``truth.json`` with, per frame,
    ``T_qp`` ({R, t, quaternion_xyzw}), ``observations`` (exact pixels of every
    marker centre in view, SPEC observations form) and ``hidden`` (those of
    them something else hides).  Raises InputError for bad parameters and
    OSError when a file cannot be written.
    """
    import csv

    import cv2
    import numpy as np
    from tqdm import tqdm

    from ..errors import InputError
    from ..io import save_rig, write_json
    from ..sim.render import (
        moving_world,
        pixel_bearings,
        project_markers,
        relative_pose,
        render,
        two_robot_world,
    )
    from ..sim.world import standard_rig

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
            "T_qp": _pose_json(relative_pose(world, "p", "q", t)),
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
        lines = ["# timestamp tx ty tz qx qy qz qw  (pose of p in q's camera frame, T_qp)"]
        for fr in truth_frames:
            vals = [fr["timestamp"], *fr["T_qp"]["t"], *fr["T_qp"]["quaternion_xyzw"]]
            lines.append(" ".join(f"{v + 0.0:.9f}" for v in vals))  # + 0.0: no "-0.000000000"
        (out_dir / "truth_tum.txt").write_text("\n".join(lines) + "\n", encoding="utf-8")
        files += ["p/", "q/", "frames.csv", "truth_tum.txt"]
    else:
        write_json(truth_frames[0]["observations"], out_dir / "observations.json")
        files += ["p.png", "q.png", "observations.json"]
    n = "1 frame" if frames == 1 else f"{frames} frames"
    return f"wrote {n} ({markers}, {size[0]}x{size[1]}) to {out_dir}: {', '.join(files)}"
