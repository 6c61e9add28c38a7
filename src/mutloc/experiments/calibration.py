"""Marker self-calibration (issue 14; SPEC "Marker calibration").

The true markers are the standard ball rig's; the *measured* rig moves every
marker by 1-2 cm in a random direction (what a tape measure against an
invisible optical centre gives).  Sequences of two robots facing each other
(1-3.5 m, yaw +-30 deg, roll +-15 deg on each) are simulated exactly
(:mod:`mutloc.sim.calibration`: true markers projected, Gaussian pixel
noise) and the measured rig is calibrated from them with
:func:`mutloc.calibrate_markers`, the scale held by the true distance
between p's two balls (one tape-measure distance between two visible balls).

Measured, over seeds: the error of the distances between markers of one
robot and of the absolute positions, against the number of frames and the
pixel noise; the predicted sigmas beside them (normalised squared errors);
``localize`` on held-out frames with the measured, the calibrated and the
true rig (and calibrated with the measured rig as a 1 cm prior); and the
team case (three robots, and two with roll +-45 deg); and robots with
several cameras (``bodies``: two and three robots with back-to-back
fisheyes and four balls each, driving about each other at random headings,
tilted up to 12 deg, :func:`mutloc.sim.calibration.body_sequence`; logs
keyed ``ROBOT/CAMERA``, the scale held by the true |M1-M2|).

Then, unless ``rendered_frames=0`` (``--quick``), the same end to end on
rendered images (:mod:`.calibration_rendered`: ``simulate``, ``track
--observations-out`` with the perturbed rig, ``calibrate-markers``,
held-out localize; a ball pair, a tag team and a ball team; a few minutes).

Output in ``OUT/calibration/``: ``results.json``, ``report.md``,
``error_vs_frames.png``, ``error_vs_sigma.png`` (and ``rendered/``).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ._common import fmt, pyplot, reproduce_lines, save_figure, versions, write_results

__all__ = ["run_calibration", "QUICK"]

NAME = "calibration"
SCALE = ("M3", "M4", 0.30)
# How well a tape measure gets the markers (1 sigma per axis) for the
# calibration that uses the measured rig as a prior.
PRIOR_SIGMA_M = 0.01
QUICK = dict(frames=(10, 40), sigmas=(0.5, 2.0), seeds=2, held_out=10, team_frames=40, rendered_frames=0,
             body_frames=40)
#: The robots of the body cases (``bodies``: back-to-back fisheyes, :func:`mutloc.sim.calibration.body_rig`).
BODY_CASES = {"two": ("p", "q"), "three": ("p", "q", "r")}


def _one(truth: dict, n: int, sigma: float, seed: int, *, held_out: int = 0, kind: str = "pair") -> dict[str, Any]:
    """Calibrate one seeded sequence; errors against the truth."""
    from ..calibration import calibrate_markers
    from ..errors import UnobservableMarkersError
    from ..sim.calibration import (body_sequence, held_out_errors, pair_sequence, perturb_rig, robots_of,
                                   team_sequence, true_positions)

    rng = np.random.default_rng([seed, n, int(sigma * 1000),
                                 {"pair": 0, "team": 1, "roll45": 2, "two": 3, "three": 4}[kind]])
    measured = perturb_rig(truth, rng)
    scale = SCALE
    if kind in BODY_CASES:
        tp = true_positions(truth)
        scale = ("M1", "M2", float(np.linalg.norm(tp["M1"] - tp["M2"])))
        make = lambda k: body_sequence(truth, k, rng, pixel_sigma=sigma)  # noqa: E731
    elif kind == "team":
        make = lambda k: team_sequence(truth, k, rng, pixel_sigma=sigma, radius=(0.8, 1.5))  # noqa: E731
    elif kind == "roll45":
        make = lambda k: pair_sequence(truth, k, rng, pixel_sigma=sigma, roll_deg=45.0)  # noqa: E731
    else:
        make = lambda k: pair_sequence(truth, k, rng, pixel_sigma=sigma)  # noqa: E731
    seq = make(n)
    t0 = time.perf_counter()
    try:
        res = calibrate_markers(measured, seq.frames, scale=scale, pixel_sigma=sigma)
    except UnobservableMarkersError as exc:
        return {"refused": str(exc)}
    elapsed = time.perf_counter() - t0
    with_prior = calibrate_markers(measured, seq.frames, scale=scale, pixel_sigma=sigma, prior_sigma=PRIOR_SIGMA_M)
    tp, own = true_positions(truth), robots_of(truth)
    names = res.covariance_markers
    err = np.array([res.markers[k].new - tp[k] for k in names])
    old = np.array([res.markers[k].old - tp[k] for k in names])
    nees = np.array([((res.markers[k].new - tp[k]) / res.markers[k].sigma) ** 2 for k in names])
    dist = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            if own[a] == own[b] and {a, b} != {scale[0], scale[1]}:
                dist.append(np.linalg.norm(res.markers[a].new - res.markers[b].new) - np.linalg.norm(tp[a] - tp[b]))
    err_prior = np.array([with_prior.markers[k].new - tp[k] for k in names])
    out = {"abs_sq": np.sum(err**2, axis=1).tolist(), "old_abs_sq": np.sum(old**2, axis=1).tolist(),
           "prior_abs_sq": np.sum(err_prior**2, axis=1).tolist(),
           "dist": dist, "nees": nees.tolist(), "seconds": elapsed,
           "weak_mm": [1000 * w.sigma_m for w in res.weak_directions],
           "largest_sigma_mm": 1000 * float(np.sqrt(max(np.linalg.eigvalsh(res.covariance).max(), 0.0))),
           "weak": [w.description for w in res.weak_directions]}
    if held_out:
        ho = make(held_out)
        out["held_out"] = {"measured": held_out_errors(measured, ho, "p", "q").tolist(),
                           "calibrated": held_out_errors(res.rig, ho, "p", "q").tolist(),
                           "calibrated_prior": held_out_errors(with_prior.rig, ho, "p", "q").tolist(),
                           "true": held_out_errors(truth, ho, "p", "q").tolist()}
    return out


def _summary(runs: list[dict[str, Any]]) -> dict[str, Any]:
    ok = [r for r in runs if "refused" not in r]
    s: dict[str, Any] = {"runs": len(runs), "refused": len(runs) - len(ok)}
    if not ok:
        return s
    cat = lambda k: np.concatenate([np.asarray(r[k], float).reshape(-1, *np.shape(r[k])[1:]) for r in ok])  # noqa: E731
    s["distance_rms_mm"] = 1000 * float(np.sqrt(np.mean(cat("dist") ** 2))) if any(r["dist"] for r in ok) else None
    s["position_rms_mm"] = 1000 * float(np.sqrt(np.mean(cat("abs_sq"))))
    s["measured_position_rms_mm"] = 1000 * float(np.sqrt(np.mean(cat("old_abs_sq"))))
    s["prior_position_rms_mm"] = 1000 * float(np.sqrt(np.mean(cat("prior_abs_sq"))))
    s["nees_per_axis"] = np.mean(cat("nees"), axis=0).tolist()
    s["weakest_sigma_mm"] = float(np.median([r["largest_sigma_mm"] for r in ok]))
    s["weak_reported"] = sum(bool(r["weak_mm"]) for r in ok)
    s["median_seconds"] = float(np.median([r["seconds"] for r in ok]))
    if all("held_out" in r for r in ok):
        ho = {}
        for rig in ("measured", "calibrated", "calibrated_prior", "true"):
            e = np.concatenate([np.asarray(r["held_out"][rig], float) for r in ok])
            ho[rig] = {"median_translation_m": float(np.nanmedian(e[:, 0])),
                       "rms_translation_m": float(np.sqrt(np.nanmean(e[:, 0] ** 2))),
                       "median_rotation_deg": float(np.nanmedian(e[:, 1]))}
        s["held_out"] = ho
    return s


def run_calibration(out_dir: str | Path, *, seed: int = 0, progress: bool = True, command: str | None = None,
                    frames: Sequence[int] = (10, 20, 40, 80, 160), sigmas: Sequence[float] = (0.25, 0.5, 1.0, 2.0),
                    seeds: int = 10, held_out: int = 20, team_frames: int = 80,
                    rendered_frames: int = 40, body_frames: int = 80) -> dict[str, Any]:
    """Run the experiment; write ``out_dir/calibration/`` and return the results.
    ``rendered_frames`` > 0 also runs the cases end to end on rendered images
    (:mod:`.calibration_rendered`; slow: a few minutes per case); ``body_frames``
    > 0 the robots with several cameras (:data:`BODY_CASES`) on logs of that many frames."""
    from tqdm import tqdm

    from ..sim.calibration import ball_rig, body_rig

    out = Path(out_dir) / NAME
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    pair = ball_rig(2)
    team = ball_rig(3, f=800.0, size=(1920, 1080))
    jobs = [("frames", n, 0.5, "pair", pair) for n in frames] + [("sigma", 40, s, "pair", pair) for s in sigmas]
    jobs += [("team", team_frames, 0.5, "team", team), ("team", team_frames, 0.5, "roll45", pair)]
    if body_frames > 0:
        jobs += [("bodies", body_frames, 0.5, k, body_rig(robots)) for k, robots in BODY_CASES.items()]
    by: dict[str, dict[str, Any]] = {"frames": {}, "sigma": {}, "team": {}, "bodies": {}}
    bar = tqdm(total=len(jobs) * seeds, desc="calibration", disable=not progress)
    for what, n, sigma, kind, truth in jobs:
        runs = []
        for k in range(seeds):
            runs.append(_one(truth, n, sigma, seed * 1000 + k, held_out=held_out if kind != "team" else 0,
                             kind=kind))
            bar.update()
        key = {"frames": str(n), "sigma": f"{sigma:g}", "team": kind, "bodies": kind}[what]
        by[what][key] = _summary(runs)
    bar.close()
    rendered = {}
    if rendered_frames > 0:
        from .calibration_rendered import run_rendered

        rendered = run_rendered(out, frames=rendered_frames, seed=seed, progress=progress)
    base = by["sigma"].get("0.5") or by["frames"].get("40") or next(iter(by["frames"].values()))
    methods = ({rig: base["held_out"][rig] for rig in ("measured", "calibrated", "calibrated_prior", "true")}
               if "held_out" in base else {})
    results = {"experiment": NAME, "seed": seed, "methods": methods, "frames": list(frames),
               "sigma_px": list(sigmas), "seeds": seeds, "held_out_frames": held_out, "team_frames": team_frames,
               "by_frames": by["frames"], "by_sigma": by["sigma"], "team": by["team"], "bodies": by["bodies"],
               "body_frames": body_frames,
               "rendered": rendered, "rendered_frames": rendered_frames,
               "command": command or f"mutloc experiment calibration --out {out_dir} --seed {seed}",
               "versions": versions(), "elapsed_s": time.perf_counter() - started}
    write_results(results, out)
    _plots(results, out)
    (out / "report.md").write_text(_report(results), encoding="utf-8")
    return results


def _plots(res: dict[str, Any], out: Path) -> None:
    plt = pyplot()
    for key, xs, xlabel, fname in (("by_frames", res["frames"], "frames", "error_vs_frames.png"),
                                   ("by_sigma", res["sigma_px"], "pixel noise sigma (px)", "error_vs_sigma.png")):
        rows = [res[key][str(x) if key == "by_frames" else f"{x:g}"] for x in xs]
        fig, ax = plt.subplots(1, 2, figsize=(10, 4))
        get = lambda r, k: np.nan if r.get(k) is None else r[k]  # noqa: E731
        ax[0].plot(xs, [get(r, "distance_rms_mm") for r in rows], "o-", label="distance between q's markers")
        ax[0].plot(xs, [get(r, "position_rms_mm") for r in rows], "s-", label="absolute position")
        ax[0].plot(xs, [get(r, "prior_position_rms_mm") for r in rows], "^-", label="absolute, with 1 cm prior")
        ax[0].plot(xs, [get(r, "measured_position_rms_mm") for r in rows], "k--", label="measured rig (input)")
        ax[0].set_xlabel(xlabel)
        ax[0].set_ylabel("RMS error (mm)")
        ax[0].set_yscale("log")
        ax[0].legend(fontsize=8)
        for rig, style in (("measured", "k--"), ("calibrated", "o-"), ("calibrated_prior", "^-"), ("true", "g:")):
            ax[1].plot(xs, [1000 * r["held_out"][rig]["median_translation_m"] if "held_out" in r else np.nan
                            for r in rows], style, label=rig.replace("_prior", ", 1 cm prior") + " rig")
        ax[1].set_xlabel(xlabel)
        ax[1].set_ylabel("held-out localize, median translation error (mm)")
        ax[1].legend(fontsize=8)
        if key == "by_frames":
            for a in ax:
                a.set_xscale("log")
        save_figure(fig, out / fname)


def _report(res: dict[str, Any]) -> str:
    def row(label: str, r: dict[str, Any]) -> str:
        if "position_rms_mm" not in r:
            return f"| {label} | refused ({r['refused']} of {r['runs']}) | | | | | | | | |"
        ho = r.get("held_out", {})
        h = lambda k: fmt(ho[k]["median_translation_m"], 1000, 1) if k in ho else "-"  # noqa: E731
        nees = "/".join(f"{x:.2f}" for x in r["nees_per_axis"])
        return (f"| {label} | {fmt(r['distance_rms_mm'], 1, 2)} | {fmt(r['position_rms_mm'], 1, 1)} | "
                f"{fmt(r['prior_position_rms_mm'], 1, 1)} | {fmt(r['weakest_sigma_mm'], 1, 1)} | {nees} | "
                f"{h('measured')} | {h('calibrated')} | {h('calibrated_prior')} | {h('true')} |")

    head = ["| setting | distance RMS (mm) | position RMS (mm) | position RMS, 1 cm prior (mm) | largest sigma (mm) | "
            "NEES x/y/z | held-out: measured rig (mm) | calibrated (mm) | calibrated, 1 cm prior (mm) | "
            "true rig (mm) |", "|---|---|---|---|---|---|---|---|---|---|"]
    lines = ["# Marker self-calibration", "",
             "Markers of the standard ball rig moved by 1-2 cm (the *measured* rig), calibrated from simulated "
             "sequences of mutual observations (two robots facing each other, 1-3.5 m, yaw +-30 deg, roll +-15 deg "
             "on each; exact projections plus Gaussian pixel noise), the scale held by the true distance between "
             f"p's two balls. {res['seeds']} seeds per setting; held-out localize on {res['held_out_frames']} "
             "frames per seed (median translation error). Distance RMS: between q's two markers (p's is held). "
             "NEES: mean normalised squared error of the new positions per axis (1 = sigmas calibrated).", "",
             "## Against the number of frames (0.5 px)", "", *head]
    lines += [row(f"{n} frames", res["by_frames"][str(n)]) for n in res["frames"]]
    lines += ["", "## Against pixel noise (40 frames)", "", *head]
    lines += [row(f"{s:g} px", res["by_sigma"][f"{s:g}"]) for s in res["sigma_px"]]
    lines += ["", "## Teams", "", *head]
    lines += [row("three robots (1920x1080, f = 800 px), 0.8-1.5 m", res["team"]["team"]),
              row("two robots, roll +-45 deg", res["team"]["roll45"])]
    if res.get("bodies"):
        lines += ["", f"## Robots with several cameras ({res['body_frames']} frames, 0.5 px)", "",
                  "Two back-to-back fisheyes (195 deg, 1280x800) and four balls per robot, driving about each other "
                  "at random headings, tilted up to 12 deg; logs keyed ROBOT/CAMERA; the scale held by the true "
                  "|M1-M2|. Held-out: p-q pair. Position RMS of the measured rig (input): "
                  + ", ".join(f"{k} robots {fmt(r.get('measured_position_rms_mm'), 1, 1)} mm"
                              for k, r in res["bodies"].items()) + ".", "", *head]
        lines += [row(f"{k} robots", r) for k, r in res["bodies"].items()]
    m = res["methods"]
    fr0, fr1 = res["by_frames"][str(res["frames"][0])], res["by_frames"][str(res["frames"][-1])]
    if m:
        lines += ["", "## Summary", "",
                  f"Held-out localize (40 frames, 0.5 px), median translation error: measured rig "
                  f"{fmt(m['measured']['median_translation_m'], 1000, 1)} mm, calibrated "
                  f"{fmt(m['calibrated']['median_translation_m'], 1000, 1)} mm, calibrated with the measured rig "
                  f"as a 1 cm prior {fmt(m['calibrated_prior']['median_translation_m'], 1000, 1)} mm, true rig "
                  f"{fmt(m['true']['median_translation_m'], 1000, 1)} mm (RMS "
                  f"{fmt(m['measured']['rms_translation_m'], 1000, 1)} / "
                  f"{fmt(m['calibrated']['rms_translation_m'], 1000, 1)} / "
                  f"{fmt(m['calibrated_prior']['rms_translation_m'], 1000, 1)} / "
                  f"{fmt(m['true']['rms_translation_m'], 1000, 1)} mm).",
                  "",
                  "Two robots that roll little relative to each other determine the distances between each "
                  "robot's markers to about a millimetre, but some combinations of absolute positions only to "
                  "centimetres (the largest sigma column: the largest 1-sigma of the markers' covariance, median "
                  "over seeds; `calibrate-markers` names such combinations and the motion that fixes them). "
                  f"From {res['frames'][0]} to {res['frames'][-1]} frames the absolute position RMS goes from "
                  f"{fmt(fr0['position_rms_mm'], 1, 1)} to {fmt(fr1['position_rms_mm'], 1, 1)} mm; a third robot "
                  f"gives {fmt(res['team']['team'].get('position_rms_mm'), 1, 1)} mm with {res['team_frames']} "
                  "frames. Counting the measured rig as a measurement (`--prior-sigma 0.01`) keeps the weak "
                  "combinations near it.", ""]
    if res.get("rendered"):
        from .calibration_rendered import report_lines

        lines += report_lines(res["rendered"], res["rendered_frames"])
    lines += ["Plots: `error_vs_frames.png`, `error_vs_sigma.png`.", ""]
    lines += reproduce_lines(res)
    return "\n".join(lines)
