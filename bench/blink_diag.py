#!/usr/bin/env python
"""Frame-by-frame diagnosis of the blink tracker against the rendered truth.

Per frame and light: ``L`` lit, ``o`` off, ``h`` hidden, ``-`` outside the
image, the true pixel, and the tracker's report (``D`` measured, ``P``
predicted) with its distance to the truth in px and its track id.  With
``--why``, for each light lit but not reported within 3 px (after the first
second), the nearest tracks and the identity figures that decide their name
(score at the light's frequency and half a bin below / above, blink
amplitude, switch events against those needed, recent brightness history).

    python bench/blink_diag.py trust SEED --cache /tmp/tl_hold [--observer p] [--why]
    python bench/blink_diag.py identity SEED --distance 2 --cache /tmp/lt_hold [--why] [--param colour_contrast=0]

Reads the frames the two benches cached (bench/trust_sequences.py,
bench/blink_identity.py); renders them if the cache lacks them.
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

import numpy as np

from mutloc.core.rig import MarkerKind
from mutloc.detect.blink import BlinkTracker
from mutloc.detect.blink.params import BlinkParams
from mutloc.sim.render import project_markers
from mutloc.sim.tracking import varied_world
from mutloc.sim.world import light_is_on, standard_rig

sys.path.insert(0, str(Path(__file__).resolve().parent))
from blink_identity import sequence  # noqa: E402
from trust_sequences import rendered  # noqa: E402


def why(bt: BlinkTracker, name: str, uv: np.ndarray, t: float) -> list[str]:
    """The identity figures of the tracks nearest ``uv`` for light ``name``."""
    times = np.array(bt._times)
    k = bt.marker_names.index(name)
    out = []
    near = sorted(bt._tracks, key=lambda tr: np.hypot(*(tr.predict(t, bt._horizon, bt._offset) + bt._offset - uv)))[:2]
    for tr in near:
        d = float(np.hypot(*(tr.predict(t, bt._horizon, bt._offset) + bt._offset - uv)))
        if d > 15.0:
            continue
        h = np.asarray(tr.hist, float)
        head = f"    {name} track {tr.id} {d:.1f} px off, named {tr.marker}, born frame {tr.born_frame}"
        if len(h) < bt.min_history:
            out.append(f"{head}: history {len(h)} < {bt.min_history} frames")
            continue
        h = h - h.mean()
        c = h @ bt._basis(times[-len(h):])
        e = (c[0::2] ** 2 + c[1::2] ** 2).reshape(3, len(bt.freqs))
        r = e / max(float(h @ h), 1e-9)
        amp = np.sqrt(2.0 * e[0] / len(h))
        need = bt.freqs[k] * len(tr.events) / bt.fps
        out.append(f"{head}: score {r[0, k]:.2f} (below {r[1, k]:.2f}, above {r[2, k]:.2f}; min {bt.min_score}), "
                   f"amplitude {amp[k]:.1f} (loud >= {0.3 * bt.diff_threshold:.0f}), events {sum(tr.events)} "
                   f"(need {need:.1f}), history {[int(x) for x in list(tr.hist)[-16:]]}")
    return out


def run(frames, truth, lit, markers, camera, fps: float, explain: bool, params: BlinkParams | None = None) -> None:
    bt = BlinkTracker(markers, fps, params=params, camera=camera)
    for i, img in enumerate(frames):
        t = i / fps
        res = bt.update(img, t)
        parts, notes = [], []
        for n in markers:
            uv = truth[i].get(n)
            s = f"{n}:{'-' if uv is None else lit[i][n]}"
            if uv is not None:
                s += f"({uv[0]:.0f},{uv[1]:.0f})"
            det = res.detections.get(n)
            if det is not None:
                d = np.hypot(*(det.uv - uv)) if uv is not None else float("nan")
                s += f" {'P' if det.predicted else 'D'}{d:.0f} tr{det.info['track']}"
                if not d <= 5.0:
                    s += f"@({det.uv[0]:.0f},{det.uv[1]:.0f})"
            if (explain and uv is not None and lit[i][n] == "L" and i >= fps
                    and (det is None or np.hypot(*(det.uv - uv)) > 3.0)):
                notes += why(bt, n, np.asarray(uv, float), t)
            parts.append(s.ljust(40))
        print(f"{i:3d} " + " ".join(parts) + f" tracks {len(bt._tracks)}")
        for line in notes:
            print(line)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bench", choices=["trust", "identity"])
    ap.add_argument("seed", type=int)
    ap.add_argument("--cache", default=None)
    ap.add_argument("--observer", default="p,q", help="trust: whose views (p, q or both)")
    ap.add_argument("--distance", type=float, default=2.0, help="identity: distance (m)")
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--why", action="store_true", help="explain lights lit but not reported")
    ap.add_argument("--fixed-motion", action="store_true", help="the benches' --fixed-motion scenarios")
    ap.add_argument("--param", action="append", default=[], help="a BlinkParams field, NAME=VALUE (Python literal)")
    args = ap.parse_args(argv)
    params = BlinkParams(**{k: ast.literal_eval(v) for k, v in (p.split("=", 1) for p in args.param)})
    cache = Path(args.cache) if args.cache else None
    fps = args.fps
    if args.bench == "identity":
        n = args.frames or 90
        rig, markers, frames, truth, on = sequence((960, 540), 800.0, args.distance, args.seed, n, fps, 4.0, 15.0,
                                                   cache, not args.fixed_motion)
        lit = [{m: ("L" if on[i][m] else "o") for m in markers} for i in range(n)]
        run(frames, truth, lit, markers, rig.robot("q").camera, fps, args.why, params)
        return 0
    n = args.frames or 60
    rig, world = varied_world(standard_rig("lights"), args.seed, distance=2.0, vary=not args.fixed_motion)
    images = rendered(world, "lights", args.seed, n, fps, cache, not args.fixed_motion)
    everyone = {m.name: m for wr in world.robots.values() for m in wr.robot.markers.values()}
    for obs in args.observer.split(","):
        other = "q" if obs == "p" else "p"
        markers = {k: m for k, m in rig.robot(other).markers.items() if m.kind == MarkerKind.LIGHT}
        truth, lit = [], []
        for i in range(n):
            seen = project_markers(world, obs, i / fps, check_occlusion=True)
            every = project_markers(world, obs, i / fps, check_occlusion=False)
            truth.append({m: every[m] for m in markers if m in every})
            lit.append({m: ("h" if m not in seen else "L" if light_is_on(everyone[m], i / fps) else "o")
                        for m in markers})
        print(f"=== observer {obs}: " + ", ".join(f"{k} {m.blink_hz:g} Hz" for k, m in markers.items()))
        run(images[obs], truth, lit, markers, rig.robot(obs).camera, fps, args.why, params)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
