"""Are calibrate-markers' sigmas right on rendered logs?  NEES per axis (mean over the markers of
(error / position_sigma)^2; 1 when right) over several perturbations of the rig, on one rendered log.

The log is rendered and tracked once (as ``mutloc.experiments.calibration_rendered`` does: ``simulate``,
the rig moved 1-2 cm per marker and tags turned 2 deg, ``track --observations-out`` with it) and kept in
WORK/CASE_sSEED; each perturbation then calibrates the even frames from another moved rig
(``--pixel-sigma 0.1``, the true distance between the first robot's first two markers held).

    .venv/bin/python bench/calibration_nees.py balls_team [--seed 0] [--perturbations 8] [--work /tmp/nees]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mutloc.api import load_rig
from mutloc.calibration import calibrate_markers
from mutloc.io import save_rig
from mutloc.io.logs import read_observation_log
from mutloc.sim.calibration import perturb_rig, true_positions
from mutloc.track.sources import folder_frames

CASES = {"balls_pair": (2, "balls"), "tags_team": (3, "tags"), "balls_team": (3, "balls")}


def rendered_log(d: Path, robots: int, markers: str, frames: int, seed: int) -> None:
    from mutloc.sim.scenario import write_simulation, write_team_simulation

    if (d / "log.jsonl").is_file():
        return
    if robots == 2:
        write_simulation(d, markers=markers, frames=frames, seed=seed)
    else:
        write_team_simulation(d, robots=robots, markers=markers, frames=frames, seed=seed)
    truth = load_rig(d / "rig.yaml").to_dict()
    measured = perturb_rig(truth, np.random.default_rng([seed, 27]), 0.01, 0.02, rotation_deg=2.0)
    save_rig(measured, d / "rig_measured.yaml")
    streams = {r: folder_frames(d / r) for r in truth["robots"]}
    if robots == 2:
        from mutloc.track.tracker import track

        track(measured, streams, observations_out=d / "log.jsonl", progress=False)
    else:
        from mutloc.track.team import track_team

        track_team(measured, streams, observations_out=d / "log.jsonl", progress=False)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case", choices=sorted(CASES))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--perturbations", type=int, default=8)
    ap.add_argument("--work", type=Path, default=Path("/tmp/calibration_nees"))
    ap.add_argument("--stated-noise", action="store_true", help="sigmas for the stated 0.1 px (measure_noise=False)")
    a = ap.parse_args()
    d = a.work / f"{a.case}_s{a.seed}"
    rendered_log(d, *CASES[a.case], a.frames, a.seed)
    truth = load_rig(d / "rig.yaml").to_dict()
    log = list(read_observation_log(d / "log.jsonl"))[0::2]
    tp = true_positions(truth)
    first = list(truth["robots"][next(iter(truth["robots"]))]["markers"])
    scale = (first[0], first[1], float(np.linalg.norm(tp[first[0]] - tp[first[1]])))
    nees, old, new, held, noise = [], [], [], [], []
    for s in range(a.perturbations):
        measured = perturb_rig(truth, np.random.default_rng([s, 27]), 0.01, 0.02, rotation_deg=2.0)
        res = calibrate_markers(measured, log, scale=scale, pixel_sigma=0.1, measure_noise=not a.stated_noise)
        err = np.array([m.new - tp[n] for n, m in res.markers.items()])
        nees.append(np.mean((err / np.array([m.sigma for m in res.markers.values()])) ** 2, axis=0))
        old.append(np.sqrt(np.mean([np.sum((m.old - tp[n]) ** 2) for n, m in res.markers.items()])))
        new.append(np.sqrt(np.mean(np.sum(err**2, axis=1))))
        held.append(sum(w.held for w in res.weak_directions))
        noise.append(res.sigma_noise_px)
    print(f"{a.case} seed {a.seed}, {a.perturbations} perturbations: NEES x/y/z "
          + " / ".join(f"{x:.2f}" for x in np.mean(nees, axis=0))
          + f"; centre RMS {1000 * np.mean(old):.1f} -> {1000 * np.mean(new):.1f} mm; held {np.mean(held):.1f}; "
          f"noise behind the sigmas {np.mean(noise):.4f} px")


if __name__ == "__main__":
    main()
