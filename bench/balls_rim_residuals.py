#!/usr/bin/env python
"""Where a ball's rim measurement goes wrong: per-ray edge residuals against the true outline (issue 28).

    python bench/balls_rim_residuals.py [--set bench/blender_set] [--only hard,dim,warm,backlit]
        [--renderer blender|mutloc] [--params '{"local_half_window_px": 2.0}'] [--quiet] [--json OUT.json]

For every whole ball (hidden share 0) of the set's scenes the rim is sampled as the first look's second
round does (:func:`mutloc.detect.balls.rim.sample_rim` with the detector's window and the light's gains), but along rays cast from the *true* projected centre and expected on the *true* outline
(the sphere's cone), so what is left is the rim measurement alone, with no fit or blob choice in it.  Per ball:

- ``mean``: mean radial residual over the valid rays (px; negative: the rim is found inside the
  outline -- a shrinking circle);
- ``shift``: the centre shift the rays' first harmonic implies (``2/n sum e_i (cos, sin)``, px),
  what a free-size circle fit inherits from the rim (a terminator or a highlight on one side shows here);
- ``valid``: share of rays with an edge;
- ``fit``: the first look's centre error (px) on the same ball (:func:`detect_balls`, with the camera).

Per condition it prints the medians of |shift| and of the fit's error (and its p90), and the ball pairs'
*separation* error along the image x axis (the two balls of a robot: what the pose's depth follows;
median, and p90 of the fit's), over the images where both balls are whole.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import cv2
import numpy as np

from mutloc.detect.balls import detect_balls
from mutloc.detect.balls.fit import CameraModel, cone_rim
from mutloc.detect.balls.light import light_gains, lut_gains
from mutloc.detect.balls.params import BallParams, value_lut
from mutloc.detect.balls.rim import rim_radii, sample_rim
from mutloc.sim.world import standard_rig

ROOT = Path(__file__).resolve().parent


def residuals(img, cam: CameraModel, tb: dict, radius_m: float, params: BallParams) -> dict:
    """Per-ray residuals of ``img``'s rim against the true outline of ball ``tb`` (truth.json row)."""
    d = cam.camera.pixels_to_bearings(np.array([tb["u"], tb["v"]]))
    d = np.asarray(d, float) / np.linalg.norm(d)
    cos_a = math.sqrt(1.0 - (radius_m / tb["distance_m"]) ** 2)
    outline = cone_rim(cam.camera, d, cos_a)
    cx, cy = float(outline[:, 0].mean()), float(outline[:, 1].mean())
    r = float(np.hypot(outline[:, 0] - cx, outline[:, 1] - cy).mean())
    n = min(max(round(2 * math.pi * r), 24), 96)
    ang = np.arange(n) * (2 * math.pi / n)
    rexp = rim_radii(outline, cx, cy, ang)
    lut = value_lut(bool(params.srgb), float(params.mix_gamma))
    g = light_gains(img, params)
    rim = sample_rim(img, lut, cx, cy, ang, rexp, params.local_half_window_px, params.step_px,
                     lut_gains(g, params) if g is not None else None)
    e = np.where(rim.valid, rim.radius - rexp, np.nan)
    ok = np.isfinite(e)
    shift = (2.0 / max(ok.sum(), 1)) * np.array([np.sum(e[ok] * np.cos(ang[ok])), np.sum(e[ok] * np.sin(ang[ok]))])
    return {"mean": float(np.nanmean(e)) if ok.any() else float("nan"), "shift": shift.tolist(),
            "valid": float(ok.mean()), "ang": ang.tolist(), "res": [None if not f else float(x) for x, f in zip(e, ok)]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", type=Path, default=ROOT / "blender_set")
    ap.add_argument("--only", default="hard,dim,warm,backlit")
    ap.add_argument("--renderer", default="blender")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--params", default="{}", help="BallParams fields as JSON, e.g. '{\"local_half_window_px\": 2}'")
    ap.add_argument("--quiet", action="store_true", help="the summary only")
    args = ap.parse_args()
    rig = standard_rig("balls")
    params = BallParams(**json.loads(args.params))
    conds = args.only.split(",")
    out = []
    for folder in sorted(p.parent for p in args.set.glob("*/truth.json")):
        truth = json.loads((folder / "truth.json").read_text())
        if truth["condition"] not in conds:
            continue
        for obs, other in (("p", "q"), ("q", "p")):
            img = cv2.imread(str(folder / f"{args.renderer}_{obs}.png"), cv2.IMREAD_COLOR)
            cam = CameraModel(rig.robot(obs).camera)
            markers = rig.robot(other).markers
            det = detect_balls(img, markers, camera=rig.robot(obs).camera, params=params)
            row = {"scene": folder.name, "condition": truth["condition"], "observer": obs, "balls": {}}
            for m, tb in truth["balls"][obs].items():
                if tb["hidden"] > 0:
                    continue
                res = residuals(img, cam, tb, float(markers[m].extra.get("radius", 0.03)), params)
                dd = det.detections.get(m)
                res["fit"] = None if dd is None else [float(dd.uv[0] - tb["u"]), float(dd.uv[1] - tb["v"])]
                res["u"] = tb["u"]
                row["balls"][m] = res
            out.append(row)
            parts = []
            for m, b in row["balls"].items():
                f = "miss" if b["fit"] is None else f"({b['fit'][0]:+.3f},{b['fit'][1]:+.3f})"
                parts.append(f"{m} mean {b['mean']:+.3f} shift ({b['shift'][0]:+.3f},{b['shift'][1]:+.3f}) "
                             f"valid {b['valid']:.2f} fit {f}")
            if not args.quiet:
                print(f"{folder.name:11s} {obs}: " + "; ".join(parts), flush=True)
    print()
    print(f"{'condition':10s} {'|shift| med':>11s} {'|fit| med':>9s} {'|fit| p90':>9s} {'sep(shift)':>10s} "
          f"{'sep(fit)':>8s} {'sep p90':>7s}  (px)")
    for c in conds + ["all"]:
        rows = [r for r in out if c == "all" or r["condition"] == c]
        sh = [math.hypot(*b["shift"]) for r in rows for b in r["balls"].values()]
        ft = [math.hypot(*b["fit"]) for r in rows for b in r["balls"].values() if b["fit"] is not None]
        sep_s, sep_f = [], []
        for r in rows:
            bs = sorted(r["balls"].values(), key=lambda b: b["u"])
            if len(bs) == 2:
                sep_s.append(abs(bs[1]["shift"][0] - bs[0]["shift"][0]))
                if bs[0]["fit"] is not None and bs[1]["fit"] is not None:
                    sep_f.append(abs(bs[1]["fit"][0] - bs[0]["fit"][0]))
        med = lambda x: float(np.median(x)) if x else float("nan")  # noqa: E731
        p90 = lambda x: float(np.quantile(x, 0.9)) if x else float("nan")  # noqa: E731
        print(f"{c:10s} {med(sh):11.3f} {med(ft):9.3f} {p90(ft):9.3f} {med(sep_s):10.3f} {med(sep_f):8.3f} "
              f"{p90(sep_f):7.3f}")
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
