#!/usr/bin/env python
"""Render the fixed Blender ball set (issue 28): each scene by Cycles and by mutloc's own renderer.

    MUTLOC_BLENDER_PYTHON=.venv-render/bin/python python bench/make_blender_set.py [--out bench/blender_set]
        [--frames 3] [--samples 4] [--only hard,dim]
    python bench/make_blender_set.py --export-test tests/data/blender --scenes pole_00,box_01,...
    ... make_blender_set.py --out DIR --seed 1 --only hard,dim    # the same scenes, another draw of render noise

(``.venv-render``: ``python3.11 -m venv .venv-render && .venv-render/bin/pip install bpy`` -- bpy 5.0 pins
numpy < 2, so it lives in a virtual environment of its own; see mutloc.sim.blender.)

Conditions (one ball per robot hidden in the occluded ones; robots 2-3 m apart, facing each other
within 10 degrees, lateral offset up to 15 % of the distance; room seed per scene):

- ``pole``: a pole or a cable in front of one ball of each robot, hiding 30-70 % of it; matte balls, even light;
- ``box``: the vertical edge of a box likewise;
- ``hard``: glossy plastic balls under one hard point light with little ambient (sharp terminator, highlight);
- ``dim``: plastic balls in dim light (exposure-starved: noise and the denoiser's smoothing matter);
- ``warm``: plastic balls under tungsten-coloured light;
- ``backlit``: the light behind the observed robot (balls seen in their own shade);
- ``mounts``: plastic balls on polished metal rods under the hard light (the rod reflects the ball's colour).

Per scene ``NAME/``: ``blender_p.png``, ``blender_q.png`` (Cycles, ``--samples`` samples per pixel,
OpenImageDenoise, plus 1 grey level of Gaussian sensor noise), ``mutloc_p.png``, ``mutloc_q.png``
(mutloc.sim.render, noise_sigma 1.0), ``truth.json``: the true pose T_qp, and per observer every
ball's true projected centre, apparent radius, distance and hidden share (rays against the same
geometry).  ``index.json`` lists the scenes and the render times.  Scenes already rendered (their
``truth.json`` present) are kept: re-running completes a set.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np

from _blender_sets import set_parser, subset_or_export, write_crop
from mutloc.sim.blender import ball_truth, render_spec, scene_spec
from mutloc.sim.render import relative_pose, render, two_robot_world
from mutloc.sim.scenes import lit, occluder, with_props
from mutloc.sim.synthetic import facing_pose
from mutloc.sim.world import Prop, standard_rig

CONDITIONS = ("pole", "box", "hard", "dim", "warm", "backlit", "mounts")
ROOT = Path(__file__).resolve().parent
_MOUNT_LENGTH, _MOUNT_RADIUS = 0.12, 0.004


def mounts(world) -> tuple[Prop, ...]:
    """A polished rod under every ball (world frame, vertical), touching it."""
    out = []
    for wr in world.robots.values():
        T = wr.pose_at(0.0)
        for m in wr.robot.markers.values():
            c = T.apply(m.position)
            r = float(m.extra.get("radius", 0.03))
            out.append(Prop("pole", tuple(c - np.array([0.0, 0.0, r + _MOUNT_LENGTH / 2])),
                            (_MOUNT_RADIUS, _MOUNT_LENGTH), (0.0, 0.0, 1.0), (200, 200, 205)))
    return tuple(out)


def scene(cond: str, i: int, rig):
    """``(world, metal prop indices, description)`` of scene ``i`` of condition ``cond`` (fixed draws)."""
    k = CONDITIONS.index(cond)
    rng = np.random.default_rng([2811, k, i])
    d = rng.uniform(2.0, 3.0)
    T = facing_pose(d, np.radians(rng.uniform(-10, 10)), np.radians(rng.uniform(-10, 10)),
                    rng.uniform(-0.15, 0.15) * d)
    w = two_robot_world(rig, T, seed=700 + 10 * k + i)
    desc: dict = {"condition": cond, "distance_m": d}
    metal: list[int] = []
    if cond in ("pole", "box"):
        props = []
        for obs, ms in (("q", ["M3", "M4"]), ("p", ["M1", "M2"])):
            m = str(rng.choice(ms))
            kind = ("pole", "cable")[int(rng.integers(2))] if cond == "pole" else "box"
            share = float(rng.uniform(0.3, 0.7))
            props.append(occluder(w, obs, m, share, kind, side=float(rng.choice([-1, 1]))))
            desc.setdefault("occluders", []).append({"observer": obs, "marker": m, "kind": kind, "share": share})
        w = with_props(w, *props)
    elif cond == "mounts":
        w = lit(w, "hard", observer="q", target="p", seed=i)
        w = with_props(w, *mounts(w))
        metal = list(range(len(w.props)))
    else:
        w = lit(w, cond, observer="q", target="p", seed=i)
    desc["lighting"] = {"pole": "even", "box": "even", "mounts": "hard"}.get(cond, cond)
    desc["finish"] = "matte" if w.ball_finish is None else "plastic"
    return w, metal, desc


def make(out: Path, cond: str, i: int, rig, samples: int, python: str | None, seed: int = 0) -> dict:
    folder = out / f"{cond}_{i:02d}"
    if (folder / "truth.json").exists():
        return json.loads((folder / "truth.json").read_text())
    folder.mkdir(parents=True, exist_ok=True)
    w, metal, desc = scene(cond, i, rig)
    spec = scene_spec(w, {o: folder / f"blender_{o}.png" for o in ("p", "q")}, texture_dir=out / "textures",
                      metal=metal, samples=samples, seed=i + 1000 * seed)
    t0 = time.time()
    imgs = render_spec(spec, python=python)
    seconds = time.time() - t0
    for j, o in enumerate(("p", "q")):
        draw = [2811, CONDITIONS.index(cond), i, j] + ([seed] if seed else [])
        noise = np.random.default_rng(draw).normal(0.0, 1.0, imgs[o].shape)
        cv2.imwrite(str(folder / f"blender_{o}.png"), np.clip(np.rint(imgs[o] + noise), 0, 255).astype(np.uint8))
        cv2.imwrite(str(folder / f"mutloc_{o}.png"), render(w, o, seed=1000 * CONDITIONS.index(cond) + i + 100_000 * seed,
                                                              noise_sigma=1.0))
    T = relative_pose(w, "p", "q")
    truth = {**desc, "name": folder.name, "T_qp": {"R": T.R.tolist(), "t": T.t.tolist()},
             "balls": {o: ball_truth(w, o) for o in ("p", "q")}, "blender_seconds": seconds,
             "samples": samples, "seed": seed}
    (folder / "truth.json").write_text(json.dumps(truth, indent=1))
    return truth


def export_crops(out: Path, dest: Path, scenes: list[str], margin: float = 24.0) -> None:
    """The test subset: per scene and observer, the Blender image cropped around the observed robot's
    balls (PNG) and ``truth.json`` with each ball's true centre in crop pixels, its hidden share and the
    crop's intrinsics (the principal point moved by the crop's corner)."""
    dest.mkdir(parents=True, exist_ok=True)
    rig = standard_rig("balls")
    index = {}
    for name in scenes:
        truth = json.loads((out / name / "truth.json").read_text())
        for obs, balls in truth["balls"].items():
            img = cv2.imread(str(out / name / f"blender_{obs}.png"))
            H, W = img.shape[:2]
            us = [b["u"] for b in balls.values()]
            vs = [b["v"] for b in balls.values()]
            r = max(b["radius_px"] for b in balls.values())
            x0, x1 = int(max(0, min(us) - 3 * r - margin)), int(min(W, max(us) + 3 * r + margin + 1))
            y0, y1 = int(max(0, min(vs) - 3 * r - margin)), int(min(H, max(vs) + 3 * r + margin + 1))
            key = f"{name}_{obs}"
            K = write_crop(dest / f"{key}.png", img, x0, y0, x1, y1, rig.robot(obs).camera.K)
            index[key] = {"scene": name, "condition": truth["condition"], "observer": obs, "corner": [x0, y0],
                          "size": [x1 - x0, y1 - y0], "K": K.tolist(),
                          "balls": {m: {**b, "u": b["u"] - x0, "v": b["v"] - y0} for m, b in balls.items()}}
    (dest / "truth.json").write_text(json.dumps(index, indent=1))
    print(f"{len(index)} crops -> {dest}")


def main() -> None:
    ap = set_parser(__doc__.splitlines()[0], ROOT / "blender_set", "comma-separated conditions")
    ap.add_argument("--frames", type=int, default=3, help="scenes per condition")
    ap.add_argument("--seed", type=int, default=0,
                    help="the renders' noise draw (Cycles' sampling seed and the added sensor noise): the same "
                         "scenes and truth drawn again, to tell the set's render noise from the detector's bias "
                         "(0: the fixed set)")
    args = ap.parse_args()
    if args.seed < 0:
        raise SystemExit(f"--seed must be 0 or more, got {args.seed}")
    conds = subset_or_export(args, export_crops, CONDITIONS, "condition")
    if conds is None:
        return
    rig = standard_rig("balls")
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    names = []
    for i in range(args.frames):  # round-robin: a stopped run still covers every condition
        for c in conds:
            tr = make(args.out, c, i, rig, args.samples, args.python, args.seed)
            names.append(tr["name"])
            hid = [f"{m} {100 * b['hidden']:.0f}%" for o in tr["balls"].values() for m, b in o.items() if b["hidden"] > 0]
            print(f"{tr['name']}: {tr['distance_m']:.2f} m, Blender {tr['blender_seconds']:.0f} s"
                  + (f", hidden {', '.join(hid)}" if hid else ""), flush=True)
    index = args.out / "index.json"
    old = json.loads(index.read_text())["scenes"] if index.exists() else []
    index.write_text(json.dumps({"scenes": sorted(set(old) | set(names)), "samples": args.samples,
                                 "conditions": list(CONDITIONS)}, indent=1))
    print(f"{len(names)} scenes in {time.time() - t0:.0f} s -> {args.out}")


if __name__ == "__main__":
    main()
