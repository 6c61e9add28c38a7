#!/usr/bin/env python
"""detect_balls of another revision against this tree's: how far apart are their detections?

    PYTHONPATH=src python bench/balls_equivalence.py [--rev main] [--n 12] [--cache DIR]

Images: bench_detectors' mutloc.sim stills (960x540 and 1920x1080), ball_tools'
demo frames, and the scenes of bench/balls_real.py (every condition, ``--n``
per condition, both robots' images; each image searched for the other
robot's balls and for the observer's own, which must not be found on
posters).  Each image runs through both detectors with the camera, without
it, through a lens with radial distortion, for linear images, at full- and
at quarter-resolution search, without white balance and with a fixed light
colour.  Prints, per image set, the detections compared, the largest centre
difference (px), the largest score difference, markers found by one only,
and differing missing reasons or alternatives.  ``--cache`` keeps the rendered images (an .npz per set) for
repeated runs.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import balls_real  # noqa: E402
import bench_detectors as bd  # noqa: E402
from ball_tools import demo_image  # noqa: E402
from compare_balls import load_old  # noqa: E402

from mutloc.core.camera import Camera  # noqa: E402
from mutloc.detect.balls import BallParams, detect_balls  # noqa: E402
from mutloc.sim.render import render  # noqa: E402
from mutloc.sim.world import standard_rig  # noqa: E402


def _cached(cache: Path | None, name: str, make):
    """``make()``'s list of images, kept in ``cache/name.npz`` when a cache is given."""
    if cache is None:
        return make()
    f = cache / f"{name}.npz"
    if f.exists():
        with np.load(f) as z:
            return [z[k] for k in sorted(z.files, key=int)]
    imgs = make()
    cache.mkdir(parents=True, exist_ok=True)
    np.savez(f, **{str(i): im for i, im in enumerate(imgs)})
    return imgs


def image_sets(n: int, cache: Path | None) -> list[tuple[str, list[tuple[np.ndarray, dict, object]]]]:
    """(name, [(image, markers, camera)]) for every set the comparison runs on."""
    sets = []
    for size in ((960, 540), (1920, 1080)):
        times = list(np.linspace(0, 6, 12))
        rig = bd.four_ball_rig(size, bd.F_960 * size[0] / 960.0)
        frames = _cached(cache, f"stills{size[0]}", lambda: bd.render_stills("balls", size, times, 0)[1])
        markers, cam = rig.robot(bd.SOURCE).markers, rig.robot(bd.TARGET).camera
        sets.append((f"stills {size[0]}x{size[1]}", [(f, markers, cam) for f in frames]))
    demo = [demo_image(seed) for seed in range(6)]
    sets.append(("demo 960x540", [(d[0], d[1], d[2]) for d in demo]))
    rig = standard_rig("balls")
    for cond in ("even", "occluded", "hard", "dim", "warm", "backlit"):
        def make():
            out = []
            for i in range(n):
                w = balls_real.scene(cond, i, rig)
                out += [render(w, r, seed=i, noise_sigma=1.0) for r in ("p", "q")]
            return out
        imgs = _cached(cache, f"real_{cond}_{n}", make)
        items = []
        for k, img in enumerate(imgs):
            obs = ("p", "q")[k % 2]
            other = "q" if obs == "p" else "p"
            cam = rig.robot(obs).camera
            items += [(img, rig.robot(other).markers, cam), (img, rig.robot(obs).markers, cam)]
        sets.append((f"balls_real {cond}", items))
    return sets


def compare(a, b, acc: dict) -> None:
    """Accumulate the differences between two DetectionResults into ``acc``."""
    acc["one_only"] += len(set(a.detections) ^ set(b.detections))
    for k in set(a.detections) & set(b.detections):
        da, db = a.detections[k], b.detections[k]
        acc["n"] += 1
        acc["max_uv"] = max(acc["max_uv"], float(np.hypot(*(np.asarray(da.uv) - np.asarray(db.uv)))))
        acc["max_score"] = max(acc["max_score"], abs(da.score - db.score))
    acc["reasons"] += sum(a.missing_reasons.get(m) != b.missing_reasons.get(m)
                          for m in set(a.missing_reasons) | set(b.missing_reasons))
    acc["alts"] += sum(len(a.alternatives.get(m, [])) != len(b.alternatives.get(m, []))
                       for m in set(a.alternatives) | set(b.alternatives))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rev", default="main")
    ap.add_argument("--n", type=int, default=12, help="balls_real scenes per condition")
    ap.add_argument("--cache", type=Path, default=None, help="directory keeping the rendered images")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    old, OldParams = load_old(args.rev)
    variants = [({}, {}), ({"camera": None}, {"camera": None})]
    for p in ({"srgb": False}, {"downscale": 1, "hue_tol_deg": 20.0}, {"min_radius_px": 6.0},
              {"white_balance": "off"}, {"white_balance": (255, 190, 120)}):
        try:  # parameters the revision does not know are left out
            variants.append(({"params": OldParams(**p)}, {"params": BallParams(**p)}))
        except TypeError:
            print(f"(revision {args.rev} has no {', '.join(p)}: not compared)")
    total = {"max_uv": 0.0}
    print(f"{'set':22s} {'compared':>8s} {'max d(uv) px':>12s} {'max d(score)':>12s} {'one only':>8s} "
          f"{'reasons':>7s} {'alts':>4s}")
    for name, items in image_sets(args.n, args.cache):
        acc = {"n": 0, "max_uv": 0.0, "max_score": 0.0, "one_only": 0, "reasons": 0, "alts": 0}
        for img, markers, cam in items:
            # Also through a lens with distortion (the fit's other path).
            h, w = img.shape[:2]
            lens = Camera(cam.K, dist=[-0.12, 0.03, 0.0, 0.0], size=(w, h)) if cam is not None else None
            for ko, kn in variants + [({"camera": lens}, {"camera": lens})]:
                compare(old(img, markers, **{"camera": cam, **ko}), detect_balls(img, markers, **{"camera": cam, **kn}),
                        acc)
        total["max_uv"] = max(total["max_uv"], acc["max_uv"])
        print(f"{name:22s} {acc['n']:8d} {acc['max_uv']:12.2e} {acc['max_score']:12.2e} {acc['one_only']:8d} "
              f"{acc['reasons']:7d} {acc['alts']:4d}", flush=True)
    print(f"largest centre difference over all sets: {total['max_uv']:.2e} px")


if __name__ == "__main__":
    main()
