#!/usr/bin/env python
"""Render the Blender fisheye sequences (issue 36): two robots with back-to-back fisheyes carrying tags.

    MUTLOC_BLENDER_PYTHON=.venv-render/bin/python PYTHONPATH=src python bench/make_blender_fisheye.py
        [--out bench/blender_fisheye] [--frames 8] [--samples 4] [--bounces 2] [--noise 1.5] [--only facing,side_by_side]

Robots ``p`` and ``q`` (``base_link``: x forward, y left, z up, on the floor): a grey cylinder body
(radius 0.215 m, 0.05-0.50 m up) with eight tag36h11 tags (0.14 m black square, 0.175 m card with its
white margin) on standoffs all around it at 0.30 m, 45 degrees apart (ids 0-7 on p, 8-15 on q, the
first one facing forward), and a mast with a camera housing carrying two fisheyes back to back, front
and back, 0.65 m up, 0.08 m either side of the mast.  Each fisheye is the ideal equidistant lens
(``FisheyeCamera(K, [0, 0, 0, 0])``, 195 degrees, ``r = f * theta`` with f = 400 px / 97.5 deg = 235.06
px/rad) on an 800x800 image: the image circle of a 1280x800 sensor with a 400 px circle, without the
black side bands (Cycles' ``FISHEYE_EQUIDISTANT``; checked by bench/check_blender_fisheye.py).

Situations, ``--frames`` frames each, the robots moving and turning between frames (distance 1.3-1.9 m):

- ``facing``: facing each other (front cameras see each other), q driving in, both yawing +-15 deg;
- ``one_away``: q turned away from p, turning through +-30 deg (p's front, q's back camera);
- ``both_away``: back to back (back cameras), drifting and turning;
- ``side_by_side``: both facing +x, q 1.5 m to p's left sliding from 0.25 m behind to 0.25 m ahead: the
  markers 80-100 deg off both cameras' axes, at the rim of both lenses.

Per situation ``NAME/``: ``rig.yaml`` (``cameras:``, the same for all), ``frame_KK/`` with one PNG per
camera (``p_front.png``, ``p_back.png``, ``q_front.png``, ``q_back.png``; a camera with no tag of the other
robot within 10 degrees of its field is not rendered (``truth.json``'s ``rendered``): Cycles, ``--samples`` samples, ``--bounces`` bounces,
OpenImageDenoise, then Gaussian sensor noise of ``--noise`` grey levels) and ``truth.json``: the robots'
poses in the world, ``T_qp`` (p's base_link in q's), and per camera every tag of the other robot with its
true corner pixels (OpenCV order, raw pixels), the angle of its centre off the optical axis, the angle
between the card's normal and the line of sight, and ``visible`` (all four corners inside the 195-degree
circle and the printed side turned less than 75 degrees from the camera).  Frames already rendered (their
``truth.json`` present) are kept: re-running completes a set.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import cv2
import numpy as np
import yaml

from mutloc.core.geometry import so3_exp, so3_log
from mutloc.core.lenses import FisheyeCamera
from mutloc.core.pose import Pose
from mutloc.core.rig import Marker, Mount, Rig, Robot
from mutloc.sim.blender import render_spec, scene_spec
from mutloc.sim.bodies import OPTICAL_IN_BASE
from mutloc.sim.render import room_around
from mutloc.sim.world import Prop, World, WorldRobot, tag_corners

ROOT = Path(__file__).resolve().parent
SITUATIONS = ("facing", "one_away", "both_away", "side_by_side")
CAMERAS = ("p/front", "p/back", "q/front", "q/back")
SIZE = 800
FOV_DEG = 195.0
F_PX = 0.5 * SIZE / math.radians(FOV_DEG / 2)
TAG_SIZE, TAG_Z, TAG_RADIUS = 0.14, 0.30, 0.225
BODY_RADIUS, BODY_Z = 0.215, (0.05, 0.50)
CAM_Z, CAM_X = 0.65, 0.08
#: A tag counts as visible to a camera when its printed side is turned less than this from the line of sight.
MAX_INCIDENCE_DEG = 75.0


def _yaw(a: float) -> np.ndarray:
    return so3_exp(np.array([0.0, 0.0, a]))


def lens() -> FisheyeCamera:
    c = (SIZE - 1) / 2
    return FisheyeCamera([[F_PX, 0, c], [0, F_PX, c], [0, 0, 1]], [0.0, 0.0, 0.0, 0.0], (SIZE, SIZE))


def robot(name: str, first_id: int) -> Robot:
    cams = {c: Mount(c, lens(), Pose(_yaw(a) @ OPTICAL_IN_BASE, _yaw(a) @ np.array([CAM_X, 0.0, 0.0]) + [0, 0, CAM_Z]))
            for c, a in (("front", 0.0), ("back", math.pi))}
    markers = {}
    for k in range(8):
        a = math.radians(45.0 * k)
        n = np.array([math.cos(a), math.sin(a), 0.0])  # the card's outward normal
        y = np.array([0.0, 0.0, -1.0])  # tag frame: x right, y down as printed, z into the card
        z = -n
        R = np.column_stack([np.cross(y, z), y, z])
        tid = first_id + k
        markers[f"{name}T{k}"] = Marker(f"{name}T{k}", name, np.array([TAG_RADIUS * n[0], TAG_RADIUS * n[1], TAG_Z]),
                                        tag={"family": "tag36h11", "id": tid, "size": TAG_SIZE,
                                             "rotation": so3_log(R).tolist()})
    return Robot(name, None, markers, cameras=cams)


def make_rig() -> Rig:
    return Rig({"p": robot("p", 0), "q": robot("q", 8)})


def body_props(T: Pose) -> list[Prop]:
    """Body cylinder, mast, camera housing and the two lens barrels of a robot at ``T`` (base -> world)."""
    zc = 0.5 * sum(BODY_Z)
    rv = tuple(float(x) for x in so3_log(T.R))
    x_axis = tuple(float(x) for x in T.R[:, 0])
    out = [Prop("pole", tuple(T.apply([0, 0, zc])), (BODY_RADIUS, BODY_Z[1] - BODY_Z[0]), (0.0, 0.0, 1.0),
                (95, 95, 100)),
           Prop("pole", tuple(T.apply([0, 0, 0.5 * (BODY_Z[1] + CAM_Z - 0.03)])), (0.02, CAM_Z - 0.03 - BODY_Z[1]),
                (0.0, 0.0, 1.0), (60, 60, 60)),
           Prop("box", tuple(T.apply([0, 0, CAM_Z])), (0.05, 0.03, 0.03), rv, (40, 40, 40))]
    for s in (1.0, -1.0):
        out.append(Prop("pole", tuple(T.apply([s * 0.0625, 0, CAM_Z])), (0.02, 0.025), x_axis, (25, 25, 25)))
    return out


def base_pose(x: float, y: float, yaw_deg: float) -> Pose:
    return Pose(_yaw(math.radians(yaw_deg)), np.array([x, y, 0.0]))


def poses(situation: str, n: int) -> list[tuple[Pose, Pose]]:
    """``(T_wp, T_wq)`` (base_link -> world) of each frame."""
    out = []
    for i in range(n):
        s = i / max(n - 1, 1)  # 0 .. 1 along the sequence
        w = math.sin(2 * math.pi * s)
        if situation == "facing":
            d = 1.9 - 0.6 * s
            out.append((base_pose(0, 0, 15 * w), base_pose(d, 0.25 * math.sin(math.pi * s) - 0.1, 180 - 15 * w)))
        elif situation == "one_away":
            d = 1.4 + 0.4 * s
            out.append((base_pose(0, 0, 8 * w), base_pose(d, 0.15 * w, -30 + 60 * s)))
        elif situation == "both_away":
            d = 1.3 + 0.5 * math.sin(math.pi * s)
            out.append((base_pose(0, 0, 180 + 20 * w), base_pose(d, -0.2 + 0.4 * s, -20 * w)))
        elif situation == "side_by_side":
            out.append((base_pose(0, 0, 5 * w), base_pose(-0.25 + 0.5 * s, 1.5, -5 * w)))
        else:
            raise SystemExit(f"unknown situation {situation!r} (one of {', '.join(SITUATIONS)})")
    return out


def tag_truth(rig: Rig, T_w: dict[str, Pose]) -> dict[str, dict[str, dict]]:
    """Per camera key, every tag of the other robot: corners' pixels, angles, visibility."""
    out: dict[str, dict[str, dict]] = {}
    for key in CAMERAS:
        obs, cname = key.split("/")
        other = "q" if obs == "p" else "p"
        mount = rig.robot(obs).mounts[cname]
        T_cw = (T_w[obs] @ mount.pose).inverse()
        cam = mount.camera
        half = math.radians(FOV_DEG / 2)
        seen = {}
        for mname, m in rig.robot(other).markers.items():
            C = np.array([T_cw.apply(T_w[other].apply(P)) for P in tag_corners(m)])
            X = T_cw.apply(T_w[other].apply(m.position))
            n_out = -(T_cw.R @ T_w[other].R @ so3_exp(np.asarray(m.tag["rotation"]))[:, 2])
            incidence = math.degrees(math.acos(float(np.clip(n_out @ (-X / np.linalg.norm(X)), -1, 1))))
            thetas = [math.atan2(math.hypot(P[0], P[1]), P[2]) for P in C]
            uv = np.array([cam.project(P) for P in C])
            visible = bool(max(thetas) < half and incidence < MAX_INCIDENCE_DEG)
            seen[mname] = {"corners": uv.tolist() if np.all(np.isfinite(uv)) else None,
                           "off_axis_deg": math.degrees(math.atan2(math.hypot(X[0], X[1]), X[2])),
                           "incidence_deg": incidence, "distance_m": float(np.linalg.norm(X)), "visible": visible}
        out[key] = seen
    return out


def make(out: Path, situation: str, i: int, T_w: dict[str, Pose], room, rig: Rig, args) -> dict:
    folder = out / situation / f"frame_{i:02d}"
    if (folder / "truth.json").exists():
        return json.loads((folder / "truth.json").read_text())
    folder.mkdir(parents=True, exist_ok=True)
    world = World(robots={r: WorldRobot(rig.robot(r), T_w[r], body=False) for r in ("p", "q")}, room=room,
                  props=tuple(body_props(T_w["p"]) + body_props(T_w["q"])))
    k = SITUATIONS.index(situation)
    tags = tag_truth(rig, T_w)
    # A camera with no tag of the other robot in or near its field (printed side or edge towards it) is not
    # rendered: nothing in its image counts, and CPU time is what limits the set.
    shown = [key for key in CAMERAS if any(t["off_axis_deg"] < FOV_DEG / 2 + 10 and t["incidence_deg"] < 90
                                           for t in tags[key].values())]
    files = {key: folder / f"{key.replace('/', '_')}.png" for key in shown}
    spec = scene_spec(world, files, texture_dir=out / "textures", samples=args.samples, seed=100 * k + i,
                      bounces=args.bounces)
    t0 = time.time()
    imgs = render_spec(spec, python=args.python, timeout=3600.0)
    seconds = time.time() - t0
    for j, key in enumerate(shown):
        noise = np.random.default_rng([36, k, i, j]).normal(0.0, args.noise, imgs[key].shape)
        cv2.imwrite(str(files[key]), np.clip(np.rint(imgs[key] + noise), 0, 255).astype(np.uint8))
    T_qp = T_w["q"].inverse() @ T_w["p"]
    truth = {"situation": situation, "frame": i, "T_qp": {"R": T_qp.R.tolist(), "t": T_qp.t.tolist()},
             "poses": {r: {"R": T.R.tolist(), "t": T.t.tolist()} for r, T in T_w.items()},
             "rendered": shown, "tags": tags, "blender_seconds": seconds, "bounces": args.bounces, "samples": args.samples, "noise": args.noise}
    (folder / "truth.json").write_text(json.dumps(truth, indent=1))
    return truth


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "blender_fisheye")
    ap.add_argument("--frames", type=int, default=8, help="frames per situation")
    ap.add_argument("--samples", type=int, default=4, help="Cycles samples per pixel (denoised)")
    ap.add_argument("--bounces", type=int, default=2, help="Cycles light bounces")
    ap.add_argument("--noise", type=float, default=1.5, help="Gaussian sensor noise added after the render (grey levels)")
    ap.add_argument("--only", default=None, help="comma-separated situations")
    ap.add_argument("--python", default=None, help="the interpreter with bpy (default $MUTLOC_BLENDER_PYTHON)")
    args = ap.parse_args()
    chosen = args.only.split(",") if args.only else list(SITUATIONS)
    for c in chosen:
        if c not in SITUATIONS:
            raise SystemExit(f"unknown situation {c!r} (one of {', '.join(SITUATIONS)})")
    rig = make_rig()
    seqs = {}
    for c in chosen:
        seq = poses(c, args.frames)
        room = room_around([T.t for pair in seq for T in pair], seed=360 + SITUATIONS.index(c))
        seqs[c] = (seq, room)
        (args.out / c).mkdir(parents=True, exist_ok=True)
        (args.out / c / "rig.yaml").write_text(yaml.safe_dump(rig.to_dict(), sort_keys=False))
    total = args.frames * len(chosen)
    t0 = time.time()
    done = 0
    for i in range(args.frames):  # round-robin: a stopped run still covers every situation
        for c in chosen:
            seq, room = seqs[c]
            Tp, Tq = seq[i]
            tr = make(args.out, c, i, {"p": Tp, "q": Tq}, room, rig, args)
            done += 1
            vis = {k: sum(v["visible"] for v in tags.values()) for k, tags in tr["tags"].items()}
            el = time.time() - t0
            print(f"[{done}/{total}] {c} frame {i:02d}: |t_qp| {np.linalg.norm(tr['T_qp']['t']):.2f} m, visible tags "
                  + " ".join(f"{k} {n}" for k, n in vis.items()) + f"; rendered {' '.join(tr['rendered'])}"
                  + f"; Blender {tr['blender_seconds']:.0f} s; elapsed {el / 60:.1f} min, "
                  f"left ~{el / done * (total - done) / 60:.0f} min", flush=True)
    index = {"situations": chosen, "frames": args.frames, "cameras": list(CAMERAS), "size": [SIZE, SIZE],
             "fov_deg": FOV_DEG, "f_px": F_PX, "samples": args.samples, "bounces": args.bounces, "noise": args.noise}
    (args.out / "index.json").write_text(json.dumps(index, indent=1))
    print(f"{total} frames in {(time.time() - t0) / 60:.1f} min -> {args.out}")


if __name__ == "__main__":
    main()
