"""Marker calibration end to end on rendered images (issue 27), as a user
would run it: ``simulate`` renders a sequence, the rig handed to the tools
is the true one with every marker moved by 1-2 cm (tags also turned by
2 deg), ``track --observations-out`` detects the markers with that rig and
logs them, ``calibrate-markers`` calibrates from the even frames of the
log, and the odd frames are localized with the given, the calibrated and the
true rig.  Cases: a ball pair, a tag team and a ball team (three robots).

Held-out localization uses only the detections the simulator's truth lists
(a wrong detection is localize's problem, not the rig's; the calibration
itself gets the whole log, wrong detections included).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["run_rendered", "CASES", "PIXEL_SIGMA"]

#: (name, robots, markers) of the rendered cases.
CASES = (("balls pair", 2, "balls"), ("tags team", 3, "tags"), ("balls team", 3, "balls"))
#: Detection noise stated to calibrate-markers (its outlier test's; rendered detections are good to a few
#: hundredths of a pixel, and the sigmas are for the noise the residuals show).
PIXEL_SIGMA = 0.1


def _one(d: Path, robots: int, markers: str, frames: int, seed: int) -> dict[str, Any]:
    from ..api import load_rig
    from ..calibration import calibrate_markers
    from ..core.geometry import rotation_error_deg, so3_exp
    from ..io import save_rig
    from ..io.logs import read_observation_log
    from ..sim.calibration import perturb_rig, true_positions, true_rotations
    from ..sim.scenario import write_simulation, write_team_simulation
    from ..track.sources import folder_frames

    t0 = time.perf_counter()
    if robots == 2:
        write_simulation(d, markers=markers, frames=frames, seed=seed)
    else:
        write_team_simulation(d, robots=robots, markers=markers, frames=frames, seed=seed)
    rendered = time.perf_counter() - t0
    truth = load_rig(d / "rig.yaml").to_dict()
    rng = np.random.default_rng([seed, 27])
    measured = perturb_rig(truth, rng, 0.01, 0.02, rotation_deg=2.0)
    save_rig(measured, d / "rig_measured.yaml")
    names = list(truth["robots"])
    streams = {r: folder_frames(d / r) for r in names}
    t0 = time.perf_counter()
    if robots == 2:
        from ..track.tracker import track

        track(measured, streams, observations_out=d / "log.jsonl", progress=False)
    else:
        from ..track.team import track_team

        track_team(measured, streams, observations_out=d / "log.jsonl", progress=False)
    tracked = time.perf_counter() - t0
    log = list(read_observation_log(d / "log.jsonl"))
    tp, tr = true_positions(truth), true_rotations(truth)
    first = list(truth["robots"][names[0]]["markers"])
    a, b = first[0], first[1]  # one tape-measured distance between two markers of the first robot
    t0 = time.perf_counter()
    res = calibrate_markers(measured, log[0::2], scale=(a, b, float(np.linalg.norm(tp[a] - tp[b]))),
                            pixel_sigma=PIXEL_SIGMA, measure_noise=True)
    seconds = time.perf_counter() - t0
    new = np.array([res.markers[n].new - tp[n] for n in res.markers])
    old = np.array([res.markers[n].old - tp[n] for n in res.markers])
    out: dict[str, Any] = {
        "frames": len(log), "calibration_frames": res.frames_total, "frames_used": res.frames_used,
        "outliers": len(res.outliers), "held_combinations": sum(w.held for w in res.weak_directions),
        "unobserved": res.unobserved, "pixel_sigma": PIXEL_SIGMA, "measured_pixel_sigma": res.measured_pixel_sigma,
        "sigma_noise_px": res.sigma_noise_px,
        "centre_rms_mm": 1000 * float(np.sqrt(np.mean(np.sum(new**2, axis=1)))),
        "given_centre_rms_mm": 1000 * float(np.sqrt(np.mean(np.sum(old**2, axis=1)))),
        "nees_per_axis": np.mean([((res.markers[n].new - tp[n]) / res.markers[n].sigma) ** 2
                                  for n in res.markers], axis=0).tolist(),
        "seconds": {"render": rendered, "track": tracked, "calibrate": seconds}}
    tags = [n for n in res.markers if res.markers[n].new_rotation is not None and n in tr]
    if tags:
        rms = lambda v: float(np.sqrt(np.mean(np.square(v))))  # noqa: E731
        out["rotation_rms_deg"] = rms([rotation_error_deg(so3_exp(res.markers[n].new_rotation), tr[n]) for n in tags])
        out["given_rotation_rms_deg"] = rms([rotation_error_deg(so3_exp(res.markers[n].old_rotation), tr[n])
                                             for n in tags])
    truth_frames = json.loads((d / "truth.json").read_text(encoding="utf-8"))["frames"]
    held = list(range(1, len(log), 2))
    out["held_out_median_translation_mm"] = {
        rig_name: _held_out(rig, log, truth_frames, held, names)
        for rig_name, rig in (("given", measured), ("calibrated", res.rig), ("true", truth))}
    return out


def _held_out(rig: Any, log: list, truth_frames: list, held: list[int], names: list[str]) -> float:
    """Median translation error (mm) of localize over the held-out frames."""
    from ..api import load_rig, localize
    from ..errors import InconsistentObservationsError, MutlocError
    from ..team import localize_team
    from ..track.frames import expanded_rig

    rig = expanded_rig(load_rig(rig))
    err = []
    for k in held:
        fr = truth_frames[k]
        obs = log[k]
        listed = fr["observations"]
        # the truth lists centres; a tag's corners (NAME#k) and a cylinder's bands (NAME#bK) go with them
        keep = np.array([m.split("#")[0] in listed.get(o, {}) for o, m in zip(obs.observer, obs.marker)],
                        dtype=bool)
        obs = obs.take(keep)
        try:
            if len(names) == 2:
                est = localize(rig, obs, confidence=1.0)
                err.append(float(np.linalg.norm(est.t - np.asarray(fr["T_qp"]["t"], float))))
                continue
            try:
                team = localize_team(rig, obs, reference=names[0])
            except InconsistentObservationsError as exc:
                team = exc.estimate
            if team is None:
                continue
            for r, T in fr["robots"].items():
                if r in team.poses:
                    err.append(float(np.linalg.norm(team.poses[r].t - np.asarray(T["t"], float))))
        except MutlocError:
            continue
    return 1000 * float(np.median(err)) if err else float("nan")


def run_rendered(out: Path, *, frames: int = 40, seed: int = 0, progress: bool = True) -> dict[str, Any]:
    """Every case of :data:`CASES` rendered into ``out/rendered/``; results per case."""
    from tqdm import tqdm

    results = {}
    for name, robots, markers in tqdm(CASES, desc="calibration, rendered", disable=not progress):
        results[name] = _one(Path(out) / "rendered" / name.replace(" ", "_"), robots, markers, frames, seed)
    return results


def report_lines(rendered: dict[str, Any], frames: int) -> list[str]:
    """The report's section on the rendered cases."""
    from ._common import fmt

    lines = ["## End to end on rendered images", "",
             f"`simulate` ({frames} frames), the rig moved by 1-2 cm per marker (tags turned by 2 deg), `track "
             "--observations-out` with that rig, `calibrate-markers` on the even frames "
             f"(--pixel-sigma {PIXEL_SIGMA:g}, one true distance between two markers of the first robot held), "
             "localize on the odd frames (median translation error; only the detections the truth lists).", "",
             "| case | frames used | outliers | held combinations | measured noise (px) | centre RMS: given / "
             "calibrated (mm) | rotation RMS: given / calibrated (deg) | NEES x/y/z | held-out: given / calibrated / "
             "true rig (mm) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, r in rendered.items():
        h = r["held_out_median_translation_mm"]
        rot = (f"{r['given_rotation_rms_deg']:.2f} / {r['rotation_rms_deg']:.3f}" if "rotation_rms_deg" in r
               else "-")
        lines.append(f"| {name} | {r['frames_used']} of {r['calibration_frames']} | {r['outliers']} | "
                     f"{r['held_combinations']} | {fmt(r['sigma_noise_px'], 1, 3)} | "
                     f"{fmt(r['given_centre_rms_mm'], 1, 1)} / "
                     f"{fmt(r['centre_rms_mm'], 1, 2)} | {rot} | "
                     + "/".join(f"{x:.2f}" for x in r["nees_per_axis"])
                     + f" | {fmt(h['given'], 1, 1)} / {fmt(h['calibrated'], 1, 1)} / {fmt(h['true'], 1, 1)} |")
    return lines + [""]
