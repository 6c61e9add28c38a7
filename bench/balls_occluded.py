#!/usr/bin/env python
"""Partly hidden balls (issue 12), per scene, on tuning and held-out seeds.

    python bench/balls_occluded.py --gen bench --start 0 --n 12      # bench/balls_real.py's scenes
    python bench/balls_occluded.py --gen test --start 0 --n 12       # tests/test_balls_real.py's scenes
    python bench/balls_occluded.py --gen alt --start 0 --n 40        # scenes of that kind, other draws
    python bench/balls_occluded.py --gen alt --start 300 --n 40      # held out: seeds nothing was tuned on

Scenes: p 1.2-3.5 m in front of q, one ball of each robot 30-70 % hidden by
a pole, a cable or a box edge ("bench": the scenes of bench/balls_real.py,
"test": those of tests/test_balls_real.py's ``occluded_runs``, "alt": the
same distributions drawn in another order; scene ``i`` for i in
[start, start+n)).  Pose from mutloc.track.localize_images against
the rendered pose.  Prints median / 90th percentile of the translation error
(a scene without a pose counted infinite), the same over the posed scenes,
median rotation error, and the count of solved / unverified / unposed
scenes, and the CPU time of localize_images per frame (one run, measured
under whatever load there is: compare runs made together); ``--json``
writes the per-scene rows.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from mutloc.core.geometry import rotation_error_deg
from mutloc.errors import MutlocError
from mutloc.sim.render import relative_pose, render, two_robot_world
from mutloc.sim.scenes import OCCLUDERS, occluder, with_props
from mutloc.sim.synthetic import facing_pose
from mutloc.sim.world import standard_rig
from mutloc.track import localize_images

sys.path.insert(0, str(Path(__file__).parent))
from balls_real import scene as bench_scene  # noqa: E402


def test_scene(i: int, rig, exact: bool = True):
    """Scene ``i`` of tests/test_balls_real.py's ``occluded_runs`` (same draws in the same order); with
    ``exact`` False the same distributions drawn in another order (each occluder's draws after its ball's
    choice): other scenes of the same kind."""
    rng = np.random.default_rng(1000 + i)
    d = rng.uniform(1.2, 3.5)
    T = facing_pose(d, np.radians(rng.uniform(-10, 10)), np.radians(rng.uniform(-10, 10)),
                    rng.uniform(-0.15, 0.15) * d)
    world = two_robot_world(rig, T, seed=i)
    sides = (("q", ["M3", "M4"]), ("p", ["M1", "M2"]))
    if exact:
        picks = [(obs, str(rng.choice(ms))) for obs, ms in sides]
    props = []
    for k, (obs, ms) in enumerate(sides):
        m = picks[k][1] if exact else str(rng.choice(ms))
        props.append(occluder(world, obs, m, rng.uniform(0.3, 0.7), OCCLUDERS[rng.integers(3)],
                              side=rng.choice([-1, 1])))
    return with_props(world, *props)


def images(gen: str, i: int, rig, cache: Path | None):
    w = bench_scene("occluded", i, rig) if gen == "bench" else test_scene(i, rig, exact=gen == "test")
    f = cache / f"{gen}_{i}.npz" if cache else None
    if f is not None and f.exists():
        z = np.load(f)
        return w, {"p": z["p"], "q": z["q"]}
    imgs = {r: render(w, r, seed=i, noise_sigma=1.0) for r in ("p", "q")}
    if f is not None:
        np.savez(f, **imgs)
    return w, imgs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gen", choices=["bench", "test", "alt"], default="test")
    ap.add_argument("--start", type=int, default=0)
    ap.add_argument("--n", type=int, default=40)
    ap.add_argument("--cache", type=Path, default=None, help="folder to keep the rendered images in")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    rig = standard_rig("balls")
    if args.cache:
        args.cache.mkdir(parents=True, exist_ok=True)
    rows = []
    for i in range(args.start, args.start + args.n):
        w, imgs = images(args.gen, i, rig, args.cache)
        truth = relative_pose(w, "p", "q")
        c0 = time.process_time()
        try:
            est = localize_images(rig, imgs).estimate
            ms = 1000 * (time.process_time() - c0)
            row = dict(i=i, ms=ms, status=est.status, cm=100 * float(np.linalg.norm(est.t - truth.t)),
                       deg=float(rotation_error_deg(est.R, truth.R)), used=len(est.markers_used))
        except MutlocError as exc:
            ms = 1000 * (time.process_time() - c0)
            row = dict(i=i, ms=ms, status="none", cm=float("inf"), deg=float("inf"), used=0, why=type(exc).__name__)
        rows.append(row)
        print(json.dumps(row), flush=True)
    e = np.array([r["cm"] for r in rows])
    fin = e[np.isfinite(e)]
    st = [r["status"] for r in rows]
    print(f"{args.gen} {args.start}..{args.start + args.n - 1}: median {np.median(e):.3f} cm, "
          f"p90 {np.quantile(e, 0.9, method='higher'):.3f} cm; posed median {np.median(fin):.3f}, "
          f"p90 {np.quantile(fin, 0.9, method='higher'):.3f} cm; median rot "
          f"{np.median([r['deg'] for r in rows]):.4f} deg; solved {st.count('solved')}, "
          f"unverified {st.count('unverified')}, no pose {st.count('none')}; CPU per frame (both images' "
          f"detection, solve, second look) median {np.median([r['ms'] for r in rows]):.0f} ms, "
          f"max {max(r['ms'] for r in rows):.0f} ms")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
