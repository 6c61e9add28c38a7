#!/usr/bin/env python
"""Check Blender's fisheye against mutloc's lens model: where Cycles images known points.

    MUTLOC_BLENDER_PYTHON=.venv-render/bin/python PYTHONPATH=src python bench/check_blender_fisheye.py
        [--samples 64] [--out bench/results/blender_fisheye_check.json]

Small emissive spheres on a black background at known directions from a camera (0 to 97 degrees off its
axis, all around it), the camera turned and placed at random in the world, drawn by
:mod:`mutloc.sim.blender` (Cycles) through the two fisheyes it renders: ``FISHEYE_EQUIDISTANT`` on a
square image (800x800) and ``FISHEYE_LENS_POLYNOMIAL`` on a 1280x800 one, both meant as
``FisheyeCamera(K, [0, 0, 0, 0])`` with ``f = 400 px / (195 deg / 2)``, ``(cx, cy) = ((W - 1) / 2, (H - 1) / 2)``
(mutloc's pixels: (0, 0) is the centre of the top-left pixel).  Each sphere's intensity-weighted centroid
is compared with ``FisheyeCamera.project`` of its centre, and an equidistant lens with free ``fx, fy, cx,
cy`` is fitted to the centroids (what Blender really draws, found without mutloc's model).  A flipped axis,
a half-pixel shift or another radius law shows as residuals of pixels, not hundredths.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import least_squares

from mutloc.core.geometry import so3_exp
from mutloc.core.lenses import FisheyeCamera
from mutloc.core.pose import Pose
from mutloc.sim.blender import render_spec

ROOT = Path(__file__).resolve().parent
FOV_DEG = 195.0
DISTANCE, RADIUS = 2.0, 0.012


def directions() -> list[tuple[float, float]]:
    """(theta, phi) in degrees: the axis, then rings out to 97 degrees."""
    out = [(0.0, 0.0)]
    for i, th in enumerate((20.0, 45.0, 70.0, 85.0, 90.0, 95.0, 97.0)):
        for k in range(8):
            out.append((th, 45.0 * k + 11.0 * i))
    return out


def centroids(img: np.ndarray) -> np.ndarray:
    g = img.astype(float).sum(axis=2)
    n, lab, _st, _c = cv2.connectedComponentsWithStats((g > 0.03 * g.max()).astype(np.uint8))
    out = []
    for i in range(1, n):
        ys, xs = np.nonzero(lab == i)
        w = g[ys, xs]
        out.append((float(np.sum(xs * w) / w.sum()), float(np.sum(ys * w) / w.sum())))
    return np.array(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--python", default=None)
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "blender_fisheye_check.json")
    args = ap.parse_args()
    f = 400.0 / math.radians(FOV_DEG / 2)
    rng = np.random.default_rng(36)
    T_wc = Pose(so3_exp(rng.normal(size=3)), rng.uniform(-1, 1, 3))  # any pose: the check is in the camera frame
    dirs = directions()
    P_cam = []
    for th, ph in dirs:
        t, p = math.radians(th), math.radians(ph)
        P_cam.append(DISTANCE * np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)]))
    P_cam = np.array(P_cam)
    objects = [{"kind": "sphere", "centre": [float(x) for x in T_wc.apply(P)], "radius": RADIUS,
                "finish": "emissive", "emission": [0.8, 0.8, 0.8], "color": [0.0, 0.0, 0.0], "name": f"s{i}"}
               for i, P in enumerate(P_cam)]
    report: dict = {"fov_deg": FOV_DEG, "f_px": f, "sphere_radius_m": RADIUS, "distance_m": DISTANCE,
                    "samples": args.samples, "lenses": {}}
    with tempfile.TemporaryDirectory() as tmp:
        views, cams = [], {}
        for name, (W, H) in (("equidistant_800x800", (800, 800)), ("polynomial_1280x800", (1280, 800))):
            K = [[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]]
            cams[name] = FisheyeCamera(K, [0, 0, 0, 0], (W, H))
            views.append({"robot": name, "size": [W, H], "K": K, "lens": {"model": "fisheye", "f": f},
                          "R": T_wc.R.tolist(), "t": T_wc.t.tolist(), "out": str(Path(tmp) / f"{name}.png")})
        spec = {"render": {"samples": args.samples, "denoise": False, "seed": 0, "bounces": 0, "threads": 2},
                "background": [0.0, 0.0, 0.0], "objects": objects,
                "light": {"position": [0.0, 0.0, 50.0], "color": [1.0, 1.0, 1.0], "power_w": 0.0, "radius": 0.1},
                "views": views}
        t0 = time.time()
        imgs = render_spec(spec, python=args.python)
        report["blender_seconds"] = time.time() - t0
        for name, cam in cams.items():
            W, H = cam.size
            truth = np.array([cam.project(P) for P in P_cam])
            got = centroids(imgs[name])
            d = np.linalg.norm(got[:, None] - truth[None], axis=2)
            j = d.argmin(axis=1)
            if len(set(j.tolist())) != len(got) or len(got) != len(truth):
                raise SystemExit(f"{name}: {len(got)} blobs for {len(truth)} spheres, or two blobs on one sphere")
            order = np.argsort(j)
            got = got[order]
            res = got - truth
            th = np.array([t for t, _ in dirs])

            def model(x: np.ndarray) -> np.ndarray:
                fx, fy, cx, cy = x
                theta = np.arctan2(np.hypot(P_cam[:, 0], P_cam[:, 1]), P_cam[:, 2])
                rr = np.hypot(P_cam[:, 0], P_cam[:, 1])
                s = np.where(rr > 0, theta / np.maximum(rr, 1e-12), 0.0)
                return np.column_stack([fx * s * P_cam[:, 0] + cx, fy * s * P_cam[:, 1] + cy])

            fit = least_squares(lambda x, got=got: (model(x) - got).ravel(), [f * 1.05, f * 0.95, W / 2, H / 2])
            fres = (model(fit.x) - got)
            per_ring = {f"{t:g}": float(np.sqrt(np.mean(np.sum(res[th == t] ** 2, axis=1)))) for t in sorted(set(th))}
            report["lenses"][name] = {
                "size": [W, H], "spheres": len(got),
                "residual_rms_px": float(np.sqrt(np.mean(np.sum(res ** 2, axis=1)))),
                "residual_max_px": float(np.max(np.linalg.norm(res, axis=1))),
                "residual_mean_px": res.mean(axis=0).tolist(),
                "residual_rms_px_by_theta_deg": per_ring,
                "fit": {"fx": fit.x[0], "fy": fit.x[1], "cx": fit.x[2], "cy": fit.x[3],
                        "rms_px": float(np.sqrt(np.mean(np.sum(fres ** 2, axis=1))))},
                "expected": {"f": f, "cx": (W - 1) / 2, "cy": (H - 1) / 2},
            }
            r = report["lenses"][name]
            print(f"{name}: {len(got)} spheres, residual to FisheyeCamera.project rms {r['residual_rms_px']:.3f} px, "
                  f"max {r['residual_max_px']:.3f} px, mean ({res.mean(0)[0]:+.3f}, {res.mean(0)[1]:+.3f}); "
                  f"free fit fx {fit.x[0]:.3f} fy {fit.x[1]:.3f} cx {fit.x[2]:.3f} cy {fit.x[3]:.3f} "
                  f"(expected f {f:.3f}, c ({(W - 1) / 2}, {(H - 1) / 2})), rms {r['fit']['rms_px']:.3f} px")
            print("   rms by theta (deg): " + ", ".join(f"{k}: {v:.3f}" for k, v in per_ring.items()))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1))
    print(f"-> {args.out} (Blender {report['blender_seconds']:.0f} s)")


if __name__ == "__main__":
    main()
