#!/usr/bin/env python
"""Issue "never a silent wrong pose", measured on mutloc's own rendered
sequences (rooms with posters and clutter): per marker kind and seed, how
many frames are solved, how many of those are off by more than 5 cm or 2
degrees (must be none), and how many of the frames a correct detection
would solve are solved.

Each seed draws its own room, robot motion (path and pan phases, sway,
period) and blink phases (:func:`mutloc.sim.tracking.varied_world`);
``--fixed-motion`` keeps the motion and blinks of seed 0's scenario and
changes only the room (how the figures before 2026-11-25 were measured).

"A correct detection would solve" is measured, not guessed: the same
tracker (same filter, same statuses) is run on the exact projections of the
markers a perfect detector reports -- every marker centre in the image and
not hidden, and for blinking lights only the lights that are on (a light
that is off shows nothing) -- and its ``solved`` frames are the solvable
ones.  Lights are named by their blink, which takes a history: for them the
ratio counts the frames after the first ``--warmup`` seconds (1 s, as the
blink-identity figure), for balls and tags every frame.

``--tracker team`` runs the team tracker on the pair (the two robots as a
team of two, q the reference) on the detections the pair's run made (its
observation log: the same detections, second looks included), and the
oracle through the same tracker: the two trackers side by side.

    python bench/trust_sequences.py [--seeds 10] [--frames 60] [--fps 30] [--kinds balls,lights,tags]
                                   [--seed-list 2,5,6] [--cache DIR] [--fixed-motion] [--tracker pair|team]

Writes bench/results/trust_results.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
from tqdm import tqdm

from mutloc.io.logs import iter_observation_log
from mutloc.sim.render import relative_pose, render
from mutloc.sim.tracking import correct_detections, varied_world
from mutloc.sim.world import standard_rig
from mutloc.track.sources import Frame, Stream
from mutloc.track.tracker import track, track_log

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import machine, result_file  # noqa: E402


def rendered(world, kind: str, seed: int, n: int, fps: float, cache: Path | None,
             vary: bool = True) -> dict[str, list[np.ndarray]]:
    """Both robots' frames, rendered or read from ``cache`` (one npz per kind and seed)."""
    path = None if cache is None else cache / f"{kind}_s{seed}_n{n}_fps{fps:g}{'_v' if vary else ''}.npz"
    if path is not None and path.exists():
        data = np.load(path)
        return {r: list(data[r]) for r in ("p", "q")}
    images = {r: [render(world, r, i / fps, seed=seed + i, noise_sigma=1.0) for i in range(n)] for r in ("p", "q")}
    if path is not None:
        cache.mkdir(parents=True, exist_ok=True)
        np.savez(path, **{r: np.array(v) for r, v in images.items()})
    return images


def _team_log(rig, frames, **kw):
    from mutloc.track.team import track_team_log

    return track_team_log(rig, frames, reference="q", **kw).tracks["p"]


def run(kind: str, seed: int, n: int, fps: float, warmup: float, cache: Path | None = None,
        vary: bool = True, tracker: str = "pair") -> dict:
    rig, world = varied_world(standard_rig(kind), seed, distance=2.0, vary=vary)
    images = rendered(world, kind, seed, n, fps, cache, vary)
    frames = {r: [Frame(i, i / fps, img) for i, img in enumerate(images[r])] for r in ("p", "q")}
    truth, oracle = [], []
    rng = np.random.default_rng(seed)
    for i in range(n):
        t = i / fps
        truth.append(relative_pose(world, "p", "q", t))
        oracle.append((t, correct_detections(world, t, rng)))
    log_fn = track_log if tracker == "pair" else _team_log
    ideal = log_fn(rig, oracle, progress=False)
    solvable = [str(r.status) == "solved" and r.t >= warmup - 1e-9 for r in ideal.rows]
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "log.jsonl"
        traj = track(rig, {r: Stream(iter(f), fps, r) for r, f in frames.items()}, progress=False,
                     observations_out=log)
        if tracker == "team":
            traj = _team_log(rig, list(iter_observation_log(log)), progress=False)
    out = {"frames": n, "statuses": {}, "solved": 0, "solved_wrong": 0, "solvable": int(sum(solvable)),
           "solvable_solved": 0, "correct_detection_statuses": {}}
    for row, ok in zip(ideal.rows, solvable):
        st = out["correct_detection_statuses"]
        st[str(row.status)] = st.get(str(row.status), 0) + 1
    for row, T, ok in zip(traj.rows, truth, solvable):
        out["statuses"][str(row.status)] = out["statuses"].get(str(row.status), 0) + 1
        if str(row.status) == "solved":
            out["solved"] += 1
            if row.estimate.pose.translation_error(T) > 0.05 or row.estimate.pose.rotation_error_deg(T) > 2.0:
                out["solved_wrong"] += 1
            out["solvable_solved"] += ok
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--kinds", default="balls,lights,tags")
    ap.add_argument("--warmup", type=float, default=1.0,
                    help="seconds at the start not counted for lights (blink identification needs a history)")
    ap.add_argument("--seed-list", default=None, help="comma-separated seeds instead of 0..seeds-1")
    ap.add_argument("--cache", default=None, help="folder caching the rendered frames")
    ap.add_argument("--fixed-motion", action="store_true",
                    help="same motion and blink phases for every seed (only the room changes)")
    ap.add_argument("--tracker", choices=("pair", "team"), default="pair",
                    help="team: the team tracker on the two robots, on the pair run's detections")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    if args.out is None:
        args.out = result_file("trust_results.json" if args.tracker == "pair" else "trust_results_team.json")
    cache = Path(args.cache) if args.cache else None
    seeds = [int(s) for s in args.seed_list.split(",")] if args.seed_list else list(range(args.seeds))
    res = {"machine": machine(), "command": " ".join(["python"] + sys.argv), "tracker": args.tracker, "kinds": {}}
    for kind in args.kinds.split(","):
        warmup = args.warmup if kind == "lights" else 0.0
        per = [{"seed": s, **run(kind, s, args.frames, args.fps, warmup, cache, not args.fixed_motion, args.tracker)} for s in tqdm(seeds, desc=kind)]
        tot: dict = {k: sum(p[k] for p in per) for k in ("frames", "solved", "solved_wrong", "solvable",
                                                          "solvable_solved")}
        for key in ("statuses", "correct_detection_statuses"):
            st: dict[str, int] = {}
            for p in per:
                for k, v in p[key].items():
                    st[k] = st.get(k, 0) + v
            tot[key] = st
        tot["warmup_s"] = warmup
        tot["solvable_solved_fraction"] = tot["solvable_solved"] / max(tot["solvable"], 1)
        res["kinds"][kind] = {"total": tot, "per_seed": per}
        print(f"{kind}: {tot['frames']} frames {tot['statuses']}; solved but off by > 5 cm / 2 deg: "
              f"{tot['solved_wrong']} of {tot['solved']}; frames a correct detection solves (after {warmup:g} s): "
              f"{tot['solvable_solved']} / {tot['solvable']} solved ({100 * tot['solvable_solved_fraction']:.1f}%)")
    Path(args.out).write_text(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
