#!/usr/bin/env python
"""Render the fixed Blender light set (issue 28): blinking lights on mounting rods, by Cycles and by
mutloc's own renderer, with exact truth.

    MUTLOC_BLENDER_PYTHON=.venv-render/bin/python python bench/make_blender_lights.py
        [--out bench/blender_lights] [--worlds 3] [--samples 4]
    python bench/make_blender_lights.py --export-test tests/data/blender_lights --scenes metal_00,...

The rig is ``standard_rig("lights")`` (p carries M3 red 5 Hz and M4 green 7.5 Hz, q carries M1 blue
2 Hz and M2 yellow 3 Hz; spheres of 2 cm radius, emissive when lit).  Each light sits on a vertical
mounting rod (8 mm thick, 12 cm long, touching the light from below).  World ``i`` (robots 2-3 m
apart, facing each other within 10 degrees, lateral offset up to 15 % of the distance, room seed per
world, even light) is rendered three times, the rods' finish and the glow the only differences:

- ``metal_ii``: polished metal rods (Cycles reflects the lit light in them and the light's own
  emission lights the rod: a bright tail below the light);
- ``matte_ii``: the same rods matte grey (the control);
- ``glow_ii``: the polished rods again, with a camera's glow (bloom) around whatever is bright -- the lit
  light and its reflection in the rod alike (Blender's compositor, :func:`mutloc.sim.blender.scene_spec`'s
  ``glare``): the light's halo, which the detector measures a glowing light by, meets the rod's.

mutloc's own renderer has no polished metal and its lights light nothing (their glow is the sensor's
bloom), so its two images of a world differ only in noise: its rows are a control of the detector.

A light blinks: a frame holds each light lit or dark.  Since the robots stand still, every frame of a
blink sequence is one of four states of the two lights an observer sees (both dark, either lit, both
lit), so those four are rendered per world and observer (both robots' lights in the same state:
M1 = M3, M2 = M4; an observer's own lights lie behind its camera) and a sequence is composed from them
by the lights' blink (bench/bench_lights_blender.py), with fresh sensor noise per frame.

Per scene ``NAME/``: ``blender_{p,q}_{s}.png`` and ``mutloc_{p,q}_{s}.png`` for the states ``s`` in
``00, 01, 10, 11`` (first digit: the observed robot's first light, M1 / M3, lit; second: M2 / M4),
noise-free 8-bit sRGB (Cycles: ``--samples`` samples per pixel, OpenImageDenoise); ``truth.json``:
per observer every light's true projected centre (the projection of its sphere's centre), apparent
radius, distance and colour.  Scenes already rendered (``truth.json`` present) are kept.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import cv2
import numpy as np

from _blender_sets import set_parser, subset_or_export, write_crop
from mutloc.sim.blender import render_spec, scene_spec
from mutloc.sim.render import project_markers, render, two_robot_world
from mutloc.sim.scenes import with_props
from mutloc.sim.synthetic import facing_pose
from mutloc.sim.world import Prop, World, ball_radius, standard_rig

ROOT = Path(__file__).resolve().parent
FINISHES = ("metal", "matte", "glow")
STATES = ("00", "01", "10", "11")
#: The lights each observer sees, in the order of a state's digits.
OBSERVED = {"q": ("M3", "M4"), "p": ("M1", "M2")}
MOUNT_LENGTH, MOUNT_RADIUS = 0.12, 0.004
ROD_COLOUR = (200, 200, 205)


def mounts(world: World) -> tuple[Prop, ...]:
    """A vertical rod under every light (world frame), touching it."""
    out = []
    for wr in world.robots.values():
        T = wr.pose_at(0.0)
        for m in wr.robot.markers.values():
            c = T.apply(m.position)
            out.append(Prop("pole", tuple(c - np.array([0.0, 0.0, ball_radius(m) + MOUNT_LENGTH / 2])),
                            (MOUNT_RADIUS, MOUNT_LENGTH), (0.0, 0.0, 1.0), ROD_COLOUR))
    return tuple(out)


def in_state(world: World, state: str) -> World:
    """``world`` with every robot's first light lit iff ``state[0] == "1"``, its second iff
    ``state[1] == "1"`` at t = 0 (a blink phase of 0 cycles is lit at t = 0, of 0.5 dark)."""
    robots = {}
    for rname, wr in world.robots.items():
        markers = {}
        for k, (mname, m) in enumerate(sorted(wr.robot.markers.items())):
            phase = 0.0 if state[k] == "1" else 0.5
            markers[mname] = dataclasses.replace(m, extra={**m.extra, "phase": phase})
        robots[rname] = dataclasses.replace(wr, robot=dataclasses.replace(wr.robot, markers=markers))
    return dataclasses.replace(world, robots=robots)


def world_of(i: int, rig=None) -> tuple[World, float]:
    """World ``i`` of the set (fixed draws) with its mounts, and the robots' distance (m)."""
    rig = rig if rig is not None else standard_rig("lights")
    rng = np.random.default_rng([2812, i])
    d = float(rng.uniform(2.0, 3.0))
    T = facing_pose(d, np.radians(rng.uniform(-10, 10)), np.radians(rng.uniform(-10, 10)),
                    rng.uniform(-0.15, 0.15) * d)
    w = two_robot_world(rig, T, seed=900 + i)
    return with_props(w, *mounts(w)), d


def light_truth(world: World, observer: str) -> dict[str, dict]:
    """Every observed light's true projected centre, apparent radius (px), distance and colour."""
    uvs = project_markers(world, observer)
    cam = world.camera(observer)
    T_cw = world.pose(observer).inverse()
    out = {}
    for rname, wr in world.robots.items():
        if rname == observer:
            continue
        for m in wr.robot.markers.values():
            if m.name not in uvs:
                continue
            X = T_cw.apply(world.pose(rname).apply(m.position))
            D = float(np.linalg.norm(X))
            r = ball_radius(m)
            out[m.name] = {"u": float(uvs[m.name][0]), "v": float(uvs[m.name][1]), "distance_m": D,
                           "radius_px": float(cam.K[0, 0] * math.tan(math.asin(min(1.0, r / D)))),
                           "color": list(m.color), "blink_hz": float(m.blink_hz)}
    return out


def make(out: Path, finish: str, i: int, samples: int, python: str | None) -> dict:
    folder = out / f"{finish}_{i:02d}"
    if (folder / "truth.json").exists():
        return json.loads((folder / "truth.json").read_text())
    folder.mkdir(parents=True, exist_ok=True)
    w, d = world_of(i)
    metal = list(range(len(w.props))) if finish in ("metal", "glow") else []
    glare = {} if finish == "glow" else None
    seconds = 0.0
    for s in STATES:
        ws = in_state(w, s)
        spec = scene_spec(ws, {o: folder / f"blender_{o}_{s}.png" for o in ("p", "q")},
                          texture_dir=out / "textures", metal=metal, samples=samples, seed=i, glare=glare)
        t0 = time.time()
        render_spec(spec, python=python)
        seconds += time.time() - t0
        for o in ("p", "q"):
            cv2.imwrite(str(folder / f"mutloc_{o}_{s}.png"), render(ws, o))
    truth = {"name": folder.name, "finish": finish, "world": i, "distance_m": d, "states": list(STATES),
             "observed": OBSERVED, "lights": {o: light_truth(w, o) for o in ("p", "q")},
             "blender_seconds": seconds, "samples": samples}
    (folder / "truth.json").write_text(json.dumps(truth, indent=1))
    return truth


def export_crops(out: Path, dest: Path, scenes: list[str], half: int = 26, glow_half: int = 40) -> None:
    """The test subset: per scene, observer and light, the Blender images with that light lit
    (the other dark) and with both dark, cropped around the light (PNG; ``half`` pixels each side,
    ``glow_half`` for the ``glow`` scenes, whose halo the tracker measures out to there), and
    ``truth.json`` with the light's true centre in crop pixels and the crop's intrinsics (principal
    point moved by its corner)."""
    dest.mkdir(parents=True, exist_ok=True)
    rig = standard_rig("lights")
    index = {}
    for name in scenes:
        truth = json.loads((out / name / "truth.json").read_text())
        hw = glow_half if truth["finish"] == "glow" else half
        for obs, lights in truth["lights"].items():
            for k, m in enumerate(OBSERVED[obs]):
                if m not in lights:
                    continue
                b = lights[m]
                on = "10" if k == 0 else "01"
                img_on = cv2.imread(str(out / name / f"blender_{obs}_{on}.png"))
                img_off = cv2.imread(str(out / name / f"blender_{obs}_00.png"))
                H, W = img_on.shape[:2]
                x0, y0 = max(0, round(b["u"]) - hw), max(0, round(b["v"]) - hw)
                x1, y1 = min(W, round(b["u"]) + hw + 1), min(H, round(b["v"]) + hw + 1)
                key = f"{name}_{obs}_{m}"
                for tag, img in (("on", img_on), ("off", img_off)):
                    K = write_crop(dest / f"{key}_{tag}.png", img, x0, y0, x1, y1, rig.robot(obs).camera.K)
                index[key] = {"scene": name, "finish": truth["finish"], "observer": obs, "marker": m,
                              "corner": [x0, y0], "size": [x1 - x0, y1 - y0], "K": K.tolist(),
                              "light": {**b, "u": b["u"] - x0, "v": b["v"] - y0}}
    (dest / "truth.json").write_text(json.dumps(index, indent=1))
    print(f"{len(index)} crops -> {dest}")


def main() -> None:
    ap = set_parser(__doc__.splitlines()[0], ROOT / "blender_lights", "comma-separated finishes (metal, matte, glow)")
    ap.add_argument("--worlds", type=int, default=3, help="worlds (each rendered with metal, matte and glowing metal rods)")
    args = ap.parse_args()
    finishes = subset_or_export(args, export_crops, FINISHES, "finish")
    if finishes is None:
        return
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    for i in range(args.worlds):
        for f in finishes:
            tr = make(args.out, f, i, args.samples, args.python)
            print(f"{tr['name']}: {tr['distance_m']:.2f} m, Blender {tr['blender_seconds']:.0f} s", flush=True)
    print(f"done in {time.time() - t0:.0f} s -> {args.out}")


if __name__ == "__main__":
    main()
