#!/usr/bin/env python
"""Light identity over fast motion, measured on mutloc's own rendered
sequences (a room with posters and clutter; robot q's camera pans while p
drives in front of it, faster than ``moving_world``'s defaults).

Identity fraction: among the frames after the first second in which one of
p's lights is lit and visible (centre in the image and not hidden), those in
which the tracker reports that light by its own name within ``--tol`` px of
its true projection, and closer to it than to the other light.  Wrong labels
(in any frame, a name reported nearer the other light than its own, or
measured lit more than 10 px from its own) are counted separately.

    python bench/blink_identity.py [--seeds 0,1,2] [--distances 1.5,2,3] [--period 4] [--pan 15]
                                   [--size 960x540 --f 800] [--frames 90] [--cache DIR] [--fixed-motion]
                                   [--centroid]

Each seed draws its own room, motion phases and blink phases
(:func:`mutloc.sim.tracking.varied_world`); ``--fixed-motion`` changes only
the room (how the figures before 2026-11-25 were measured).

Also the centre error of lit lights: in those frames, the distance from each lit light's measured
centre (reported under its name, not predicted) to its true projection, median and p90 per distance.
``--centroid``: clipped lights without a halo measured by their centroid (before the edge fit).

Writes bench/results/blink_identity_results.json (``--out``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from mutloc.detect.blink import BlinkTracker
from mutloc.sim.tracking import light_identity, light_view, varied_world
from mutloc.sim.world import light_is_on, standard_rig

sys.path.insert(0, str(Path(__file__).resolve().parent))


def sequence(size: tuple[int, int], f: float, distance: float, seed: int, n: int, fps: float, period: float,
             pan_deg: float, cache: Path | None = None, vary: bool = True):
    """Robot q's frames of p's two lights, the true projections (visible
    markers only) and which lights are lit, per frame (rendered or read from ``cache``)."""
    key = (f"{size[0]}x{size[1]}_f{f:g}_d{distance:g}_s{seed}_n{n}_fps{fps:g}_T{period:g}_pan{pan_deg:g}"
           f"{'_v' if vary else ''}.npz")
    rig, world = varied_world(standard_rig("lights", size=size, f=f), seed, distance=distance, period=period,
                              pan_deg=pan_deg, vary=vary)
    markers = rig.robot("p").markers
    if cache is not None and (cache / key).exists():
        data = np.load(cache / key, allow_pickle=True)
        frames, truth = list(data["frames"]), list(data["truth"])
        lit = [{m: light_is_on(mk, k / fps) for m, mk in markers.items()} for k in range(n)]
        return rig, markers, frames, truth, lit
    # The same frames as mutloc.sim.tracking.panning_lights.
    frames, truth, lit = light_view(world, "q", list(markers), n, fps, seed * 1000)
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        np.savez(cache / key, frames=np.array(frames), truth=np.array(truth, dtype=object))
    return rig, markers, frames, truth, lit


def identity(results, truth, lit, fps: float, tol: float) -> dict:
    """Identity fraction after the first second, and the failures."""
    r = light_identity(results, truth, lit, fps, tol)
    return {"good": r.good, "total": r.total, "fraction": r.fraction, "wrong_labels": r.wrong,
            "failures": r.failures}


def centre_errors(results, truth, lit, fps: float) -> list[float]:
    """After the first second, every lit light's measured centre (reported under its name, not
    predicted): its distance (px) to the light's true projection."""
    out = []
    for k, (res, tr, on) in enumerate(zip(results, truth, lit)):
        if k < fps:
            continue
        for name, det in res.detections.items():
            if name in tr and on.get(name) and not det.predicted:
                out.append(float(np.hypot(*(det.uv - np.asarray(tr[name])))))
    return out


def run_tracker(rig, markers, frames, fps: float, use_camera: bool = True):
    cam = rig.robot("q").camera if use_camera else None
    tracker = BlinkTracker(markers, fps, camera=cam)
    return [tracker.update(img, k / fps) for k, img in enumerate(frames)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--distances", default="1.5,2,3")
    ap.add_argument("--size", default="960x540")
    ap.add_argument("--f", type=float, default=800.0)
    ap.add_argument("--frames", type=int, default=90)
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--period", type=float, default=4.0, help="path period (s); moving_world's default is 8")
    ap.add_argument("--pan", type=float, default=15.0, help="camera pan amplitude (deg); default 6")
    ap.add_argument("--tol", type=float, default=3.0)
    ap.add_argument("--cache", default=None, help="folder caching the rendered frames")
    ap.add_argument("--no-camera", action="store_true", help="track without the camera model")
    ap.add_argument("--fixed-motion", action="store_true",
                    help="same motion and blink phases for every seed (only the room changes)")
    ap.add_argument("--centroid", action="store_true",
                    help="a clipped light without a halo measured by its centroid, as before the edge fit "
                         "(mutloc.detect.blink.measure.EDGE_FALLBACK False)")
    from _machine import machine, result_file

    ap.add_argument("--out", default=result_file("blink_identity_results.json"))
    args = ap.parse_args(argv)
    if args.centroid:
        from mutloc.detect.blink import measure

        measure.EDGE_FALLBACK = False

    size = tuple(int(s) for s in args.size.split("x"))
    cache = Path(args.cache) if args.cache else None
    res = {"machine": machine(), "command": " ".join(["python"] + sys.argv), "runs": []}
    per_distance: dict[str, list[int]] = {}
    centres: dict[str, list[float]] = {}
    for d in (float(s) for s in args.distances.split(",")):
        for seed in (int(s) for s in args.seeds.split(",")):
            t0 = time.perf_counter()
            rig, markers, frames, truth, lit = sequence(size, args.f, d, seed, args.frames, args.fps,
                                                        args.period, args.pan, cache, not args.fixed_motion)
            t1 = time.perf_counter()
            results = run_tracker(rig, markers, frames, args.fps, not args.no_camera)
            out = identity(results, truth, lit, args.fps, args.tol)
            errs = centre_errors(results, truth, lit, args.fps)
            centres.setdefault(f"{d:g}", []).extend(errs)
            t2 = time.perf_counter()
            g = per_distance.setdefault(f"{d:g}", [0, 0, 0])
            g[0] += out["good"]
            g[1] += out["total"]
            g[2] += out["wrong_labels"]
            print(f"d={d:g} m seed={seed}: identity {out['good']}/{out['total']} = {out['fraction']:.3f}, "
                  f"wrong labels {out['wrong_labels']} (render {t1 - t0:.1f} s, track {t2 - t1:.1f} s) "
                  f"{out['failures'][:8]}", flush=True)
            res["runs"].append({"distance": d, "seed": seed, **out})
    res["per_distance"] = {k: {"good": g, "total": n, "fraction": g / max(n, 1), "wrong_labels": w,
                               "centre_px_median": float(np.median(centres[k])) if centres[k] else None,
                               "centre_px_p90": float(np.quantile(centres[k], 0.9)) if centres[k] else None,
                               "centres": len(centres[k])}
                           for k, (g, n, w) in per_distance.items()}
    for k, v in res["per_distance"].items():
        print(f"distance {k} m: identity {v['good']}/{v['total']} = {v['fraction']:.3f}, "
              f"wrong labels {v['wrong_labels']}; lit centres median {v['centre_px_median']:.4f} px, "
              f"p90 {v['centre_px_p90']:.4f} px ({v['centres']})")
    Path(args.out).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
