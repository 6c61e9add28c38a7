#!/usr/bin/env python
"""Live: two ``mutloc node`` processes and a ``mutloc localizer`` on a pair whose one tag is seen far off
its normal -- does q's node find p's tag where the localizer's poses on ``/tf`` put it?

    python bench/live_steep_tags.py [--seconds 3] [--tilt 55] [--distance 3] [--work DIR]

The sequence: p moving 3 m in front of q (``mutloc.sim.render.moving_world``), one 12 cm tag36h11 tag per
robot 12 cm below its camera (``tests/test_tags_real.tag_rig``), p's turned ``--tilt`` degrees about its
vertical axis, so q sees it that far off its normal while p sees q's nearly face-on; 960x540 at 30 fps,
optical blur 0.8 px, noise 2 DN; replayed as BMP by each robot's node in real time, in step, with the
localizer (:func:`mutloc.live.demo.run_live_pair`, DDS on loopback).

Reported: of q's observation messages (the frames its node processed, its log), how many held p's tag (the
localizer's received log, ``log.jsonl``) and how many of those the node found where the localizer's poses
put it (its log), beside how many of q's frames the node's detector finds it in alone (offline, the same
frames: what a node without the localizer's poses would send); the poses received and their translation error against the
rendered pose (median / p90 cm).  Then the same frames tracked offline (``mutloc track``, the frames in
step) with its looks and with both switched off (as ``bench/tags_second_look.py --track``), for scale.
Writes bench/results/live_steep_tags_results.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT.parent / "tests"))

from _machine import machine  # noqa: E402
from tags_second_look import looks_switched_off  # noqa: E402
from test_tags_real import tag_rig  # noqa: E402

from mutloc.io import save_rig  # noqa: E402
from mutloc.live.demo import run_live_pair  # noqa: E402
from mutloc.sim.render import moving_world, relative_pose, render  # noqa: E402
from mutloc.track.frames import detect_markers, expanded_rig  # noqa: E402
from mutloc.track.sources import open_streams  # noqa: E402

FPS = 30.0


def render_sequence(folder: Path, tilt: float, distance: float, frames: int):
    """Render (once) the sequence into ``folder``: rig.yaml, p/ and q/ (BMP), frames.csv; returns the world."""
    rig = tag_rig(tilt_p_deg=tilt)
    world = moving_world(rig, distance=distance, period=8.0, seed=0)
    world = dataclasses.replace(world, sensor=dataclasses.replace(world.sensor, psf_sigma_px=0.8))
    if not (folder / "frames.csv").exists():
        for r in ("p", "q"):
            (folder / r).mkdir(parents=True, exist_ok=True)
            for k in range(frames):
                cv2.imwrite(str(folder / r / f"{k:06d}.bmp"), render(world, r, k / FPS, seed=1 + k, noise_sigma=2.0))
            print(f"rendered {frames} frames of {r}", flush=True)
        save_rig(rig, folder / "rig.yaml")
        (folder / "frames.csv").write_text("index,timestamp\n" + "".join(f"{k},{k / FPS:.9f}\n" for k in range(frames)))
    return rig, world


def offline_tracks(rig, folder: Path, world) -> dict:
    import mutloc.track.tracker as tracker

    out = {}
    for looks in (True, False):
        with looks_switched_off(not looks):
            traj = tracker.track(rig, open_streams({"p": folder / "p", "q": folder / "q"}), progress=False)
        e = [100 * r.estimate.pose.translation_error(relative_pose(world, "p", "q", r.t)) for r in traj.rows
             if r.estimate is not None and r.t >= 0.5]
        out["looks" if looks else "no looks"] = {"rows": len(e), "cm_median": float(np.median(e)),
                                                 "cm_p90": float(np.quantile(e, 0.9, method="higher"))}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--tilt", type=float, default=55.0)
    ap.add_argument("--distance", type=float, default=3.0)
    ap.add_argument("--work", type=Path, default=None, help="keep the rendered sequence here (reused)")
    ap.add_argument("--json", type=Path, default=ROOT / "results" / "live_steep_tags_results.json")
    args = ap.parse_args()
    frames = int(round(args.seconds * FPS))
    work = args.work or Path(tempfile.mkdtemp(prefix="live_steep_"))
    folder = work / f"tilt{args.tilt:g}_d{args.distance:g}_n{frames}"
    print(machine())
    rig, world = render_sequence(folder, args.tilt, args.distance, frames)
    ex = expanded_rig(rig)
    alone = sum("TP#0" in detect_markers(ex, "q", cv2.imread(str(f)), targets=["p"]).detections
                for f in sorted((folder / "q").glob("*.bmp")))
    live = run_live_pair(folder / "rig.yaml", {"p": folder / "p", "q": folder / "q"}, work / "live",
                         seconds=args.seconds, truth=lambda st: relative_pose(world, "p", "q", st))
    with_tag = 0  # records of the localizer's log with q's pixels of p's tag (a message without any is not logged)
    for line in (work / "live" / "localizer" / "log.jsonl").read_text().splitlines():
        with_tag += "TP#0" in json.loads(line)["observations"].get("q", {})
    node_q = (work / "live" / "q.log").read_text()
    q_msgs = int(re.search(r"(\d+) processed", node_q).group(1))
    again = re.search(r"(\d+) tags found again", node_q)
    found_again = int(again.group(1)) if again else 0
    err = live["translation_error_cm"]
    print(f"live: q's node processed {q_msgs} frames and sent p's tag in {with_tag} of them ({found_again} found "
          f"where the localizer's poses put it); its detector alone finds it in {alone} of the {frames} frames; "
          f"{live['poses_received']} poses, error median {err['median']:.3f} cm, p90 {err['p90']:.3f} cm",
          flush=True)
    offline = offline_tracks(rig, folder, world)
    print("offline track of the same frames: " + "; ".join(
        f"{k}: {v['rows']} rows, {v['cm_median']:.3f} / {v['cm_p90']:.3f} cm" for k, v in offline.items()))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"machine": machine(), "tilt_deg": args.tilt, "distance_m": args.distance,
                                     "frames": frames, "q_messages": q_msgs, "q_messages_with_tag": with_tag,
                                     "q_tags_found_again": found_again,
                                     "detector_alone_frames_with_tag": alone, "live": live, "offline": offline},
                                    indent=1, default=str))


if __name__ == "__main__":
    main()
