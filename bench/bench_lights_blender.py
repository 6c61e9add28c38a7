#!/usr/bin/env python
"""The blinking-light detector on lights mounted on rods, rendered by Blender and by mutloc (issue 28).

    python bench/make_blender_lights.py            # once: renders bench/blender_lights/ (see there)
    python bench/bench_lights_blender.py [--set bench/blender_lights] [--frames 60] [--phases 2]
                                         [--json OUT.json] [--renderer blender] [--centroid]

Per scene, observer, renderer and blink-phase draw: a still sequence of ``--frames`` frames at 30 fps
composed from the scene's four rendered light states (the state of each observed light at frame ``k``
by its ``blink_hz`` and phase: ``mutloc.sim.world.light_is_on``), each frame with fresh sensor noise
(1 grey level, Gaussian), run through :class:`mutloc.detect.blink.BlinkTracker` (defaults, the
observer's camera, the observed robot's markers).  Phase draw 0 is the rig's (every light's phase
0); draw ``j > 0`` draws each light's phase in [0, 1).

Light-centre error: in every frame from the first second on in which a light is lit, the distance
(px) from the centre the tracker measured there (reported under the light's name, not predicted) to
the true projection of the light's centre; ``dv`` its signed vertical part (+: down, along the rod).
A lit light not reported as measured counts as missed.  Prints per renderer, mount (metal / matte
rod, or metal with a camera's glow) and light colour: median / p90 error, median dv, lit frames and missed; writes them and a row
per sequence and light to ``--json`` (default bench/results/lights_blender_results.json).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np

from mutloc.detect.blink import BlinkTracker, measure
from mutloc.sim.world import light_is_on, standard_rig

ROOT = Path(__file__).resolve().parent
RENDERERS = ("blender", "mutloc")
COLOURS = {"M1": "blue", "M2": "yellow", "M3": "red", "M4": "green"}
OBSERVED = {"q": ("M3", "M4"), "p": ("M1", "M2")}


def phased(markers, j: int, seed: int):
    """The observed markers with phase draw ``j`` (0: as in the rig)."""
    if j == 0:
        return dict(markers)
    rng = np.random.default_rng([2813, seed, j])
    return {n: dataclasses.replace(m, extra={**m.extra, "phase": float(rng.uniform())}) for n, m in markers.items()}


def sequence(states: dict[str, np.ndarray], markers, order, n: int, fps: float, seed):
    """``n`` frames composed from the state images by the lights' blink, and which lights are lit."""
    rng = np.random.default_rng(seed)
    frames, lit = [], []
    for k in range(n):
        on = {m: light_is_on(markers[m], k / fps) for m in order}
        s = "".join("1" if on[m] else "0" for m in order)
        img = states[s].astype(np.float32) + rng.normal(0.0, 1.0, states[s].shape).astype(np.float32)
        frames.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
        lit.append(on)
    return frames, lit


def light_errors(frames, lit, markers, camera, truth: dict, fps: float, warmup_s: float = 1.0) -> list[dict]:
    """Per lit light and frame after the warm-up: the measured centre's error against ``truth``."""
    tracker = BlinkTracker(markers, fps, camera=camera)
    rows = []
    for k, (img, on) in enumerate(zip(frames, lit)):
        res = tracker.update(img, k / fps)
        if k < warmup_s * fps:
            continue
        for m, is_on in on.items():
            if not is_on or m not in truth:
                continue
            d = res.detections.get(m)
            row = {"frame": k, "marker": m}
            if d is None or d.predicted:
                row.update(err_px=None)
            else:
                du, dv = float(d.uv[0] - truth[m]["u"]), float(d.uv[1] - truth[m]["v"])
                row.update(err_px=float(np.hypot(du, dv)), du=du, dv=dv)
            rows.append(row)
    return rows


def q(x, p):
    x = [v for v in x if v is not None]
    return float(np.quantile(x, p, method="higher")) if x else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", type=Path, default=ROOT / "blender_lights")
    ap.add_argument("--renderer", choices=RENDERERS, action="append", default=None)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--phases", type=int, default=2, help="blink-phase draws per scene and observer")
    ap.add_argument("--json", type=Path, default=ROOT / "results" / "lights_blender_results.json")
    ap.add_argument("--centroid", action="store_true",
                    help="a clipped light without a halo measured by its centroid, as before the edge fit "
                         "(mutloc.detect.blink.measure.EDGE_FALLBACK False)")
    args = ap.parse_args()
    if args.centroid:
        measure.EDGE_FALLBACK = False
    renderers = args.renderer or list(RENDERERS)
    rig = standard_rig("lights")
    scenes = sorted(p.parent for p in args.set.glob("*/truth.json"))
    if not scenes:
        raise SystemExit(f"no scenes in {args.set}: run bench/make_blender_lights.py first")
    rows, seqs = [], []
    for si, folder in enumerate(scenes):
        truth = json.loads((folder / "truth.json").read_text())
        for obs, order in OBSERVED.items():
            other = "p" if obs == "q" else "q"
            cam = rig.robot(obs).camera
            for ren in renderers:
                states = {s: cv2.imread(str(folder / f"{ren}_{obs}_{s}.png"), cv2.IMREAD_COLOR) for s in truth["states"]}
                for j in range(args.phases):
                    markers = phased(rig.robot(other).markers, j, truth["world"])
                    frames, lit = sequence(states, markers, order, args.frames, args.fps,
                                           seed=[2814, si, j, int(obs == "q"), RENDERERS.index(ren)])
                    errs = light_errors(frames, lit, markers, cam, truth["lights"][obs], args.fps)
                    for r in errs:
                        r.update(scene=folder.name, finish=truth["finish"], renderer=ren, observer=obs, phase=j,
                                 colour=COLOURS[r["marker"]])
                    rows += errs
                    txt = []
                    for m in order:
                        e = [r["err_px"] for r in errs if r["marker"] == m]
                        got = [x for x in e if x is not None]
                        seqs.append({"scene": folder.name, "finish": truth["finish"], "renderer": ren, "observer": obs,
                                     "phase": j, "marker": m, "colour": COLOURS[m], "lit": len(e),
                                     "missed": len(e) - len(got), "median_px": q(got, 0.5),
                                     "max_px": max(got, default=float("nan")),
                                     "median_dv_px": q([r.get("dv") for r in errs if r["marker"] == m], 0.5)})
                        txt.append(f"{m} {COLOURS[m]} med {q(got, 0.5):.2f} max {max(got, default=float('nan')):.2f}"
                                   f" ({len(got)}/{len(e)})")
                    print(f"{folder.name:9s} {obs} {ren:7s} phase {j}: " + ", ".join(txt), flush=True)
    print()
    print(f"{'renderer':8s} {'mount':6s} {'colour':7s} {'med px':>7s} {'p90 px':>7s} {'med dv':>7s} {'lit':>5s} "
          f"{'missed':>6s}")
    summary = {}
    for ren in renderers:
        for fin in ("metal", "matte", "glow"):
            for col in [*COLOURS.values(), "all"]:
                sel = [r for r in rows if r["renderer"] == ren and r["finish"] == fin
                       and (col == "all" or r["colour"] == col)]
                if not sel:
                    continue
                e = [r["err_px"] for r in sel]
                dv = [r.get("dv") for r in sel]
                missed = sum(x is None for x in e)
                s = {"median_px": q(e, 0.5), "p90_px": q(e, 0.9), "median_dv_px": q(dv, 0.5), "lit": len(e),
                     "missed": missed}
                summary[f"{ren}/{fin}/{col}"] = s
                print(f"{ren:8s} {fin:6s} {col:7s} {s['median_px']:7.3f} {s['p90_px']:7.3f} {s['median_dv_px']:+7.3f} "
                      f"{len(e):5d} {missed:6d}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"set": str(args.set), "frames": args.frames, "phases": args.phases,
                                     "summary": summary, "sequences": seqs}, indent=1))


if __name__ == "__main__":
    main()
