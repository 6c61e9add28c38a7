"""``mutloc experiment team``: teams of 3-10 robots, the joint estimate
(:func:`mutloc.localize_team`) against chained pair estimates and the joint
Cramer-Rao bound; error against team size and against hops from the
reference.

Random teams (:func:`mutloc.sim.team.random_team`: robots in a room looking
roughly at the team's centre, four markers each, some ties one-way),
Gaussian pixel noise.  *Chained pairwise*: every robot reached from the
reference over pairs with at least four observations (either direction;
fewer leave the pair ambiguous), the fewest hops first, each pair solved on
its own by :func:`mutloc.localize` and the pair poses composed.  *CRB*: the
joint covariance at the true poses, per robot.
"""

from __future__ import annotations

import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from ._common import fmt, pyplot, reproduce_lines, save_figure, versions, write_results

__all__ = ["run_team", "QUICK"]

QUICK = {"sizes": (3, 5, 8, 10), "teams": 12}
PAIR_MIN = 4


def _pair_tree(counts: np.ndarray, ref: int) -> dict[int, list[int]]:
    """Path (robot indices, reference first) to every robot reachable over
    pairs with at least PAIR_MIN observations, fewest hops (breadth first)."""
    tie = counts + counts.T
    paths = {ref: [ref]}
    queue = deque([ref])
    while queue:
        a = queue.popleft()
        for b in np.flatnonzero(tie[a] >= PAIR_MIN).tolist():
            if b not in paths:
                paths[b] = paths[a] + [b]
                queue.append(b)
    return paths


def _errors(est_R: np.ndarray, est_t: np.ndarray, T: Any) -> tuple[float, float]:
    from ..core.geometry import rotation_error_deg

    return float(np.linalg.norm(est_t - T.t)), float(rotation_error_deg(est_R, T.R))


def run_team(out_dir: str | Path, *, seed: int = 0, progress: bool = True, command: str | None = None,
             sizes: tuple[int, ...] = (3, 4, 5, 6, 7, 8, 9, 10), teams: int = 60, sigma_px: float = 1.0) -> dict:
    """Run the experiment; writes ``out_dir/team/{results.json, report.md, team.png}``."""
    from ..api import localize
    from ..core.pose import Pose
    from ..core.team import solve_team
    from ..errors import MutlocError
    from ..sim.team import random_team
    from ..team import localize_team, team_problem

    started = time.perf_counter()
    out = Path(out_dir) / "team"
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 1010])
    rows: list[dict[str, Any]] = []
    failures = 0
    total = len(sizes) * teams
    with tqdm(total=total, desc="teams", unit="team", disable=not progress) as bar:
        for n in sizes:
            for _ in range(teams):
                bar.update(1)
                scene = random_team(n, rng, radius=0.9 * np.sqrt(n) + 1.2)
                obs = scene.observations(sigma_px, rng)
                truth = scene.truth()
                try:
                    team = localize_team(scene.rig, obs, pixel_sigma=sigma_px, confidence=1.0)
                except MutlocError:
                    failures += 1
                    continue
                problem, names, _ = team_problem(scene.rig, obs)
                loc = np.array([r in team.poses for r in names])
                at_truth = solve_team(problem, 0, initial=(np.array([truth[r].R for r in names]),
                                                           np.array([truth[r].t for r in names]), loc), max_iter=0)
                crb = at_truth.covariance(sigma_px)
                paths = _pair_tree(problem.counts(), 0)
                pair_cache: dict[tuple[int, int], Any] = {}
                for i, r in enumerate(team.robots):
                    ri = names.index(r)
                    jt, jr = _errors(team.poses[r].R, team.poses[r].t, truth[r])
                    row = {"size": n, "robot": r, "joint_t": jt, "joint_r": jr,
                           "crb_t": float(np.sqrt(np.trace(crb[6 * i + 3:6 * i + 6, 6 * i + 3:6 * i + 6]))),
                           "crb_r": float(np.degrees(np.sqrt(np.trace(crb[6 * i:6 * i + 3, 6 * i:6 * i + 3])))),
                           "hops": None, "chained_t": None, "chained_r": None}
                    path = paths.get(ri)
                    if path is not None:
                        row["hops"] = len(path) - 1
                        T = Pose.identity()
                        try:
                            for a, b in zip(path[:-1], path[1:]):
                                if (a, b) not in pair_cache:
                                    pair_cache[(a, b)] = localize(scene.rig, obs, source=names[b], target=names[a],
                                                                  pixel_sigma=sigma_px, confidence=1.0).pose
                                T = T @ pair_cache[(a, b)]
                            row["chained_t"], row["chained_r"] = _errors(T.R, T.t, truth[r])
                        except MutlocError:
                            pass
                    rows.append(row)

    def stats(sel: list[dict[str, Any]]) -> dict[str, Any]:
        both = [x for x in sel if x["chained_t"] is not None]
        rms = lambda v: float(np.sqrt(np.mean(np.square(v)))) if len(v) else float("nan")  # noqa: E731
        return {
            "robots": len(sel), "robots_chained": len(both),
            "joint": {"rmse_translation_m": rms([x["joint_t"] for x in sel]),
                      "rmse_rotation_deg": rms([x["joint_r"] for x in sel]),
                      "median_translation_m": float(np.median([x["joint_t"] for x in sel])) if sel else None,
                      "median_rotation_deg": float(np.median([x["joint_r"] for x in sel])) if sel else None},
            "joint_same_robots": {"rmse_translation_m": rms([x["joint_t"] for x in both]),
                                  "rmse_rotation_deg": rms([x["joint_r"] for x in both])},
            "chained": {"rmse_translation_m": rms([x["chained_t"] for x in both]),
                        "rmse_rotation_deg": rms([x["chained_r"] for x in both]),
                        "median_translation_m": float(np.median([x["chained_t"] for x in both])) if both else None,
                        "median_rotation_deg": float(np.median([x["chained_r"] for x in both])) if both else None},
            "crlb": {"rmse_translation_m": rms([x["crb_t"] for x in sel]),
                     "rmse_rotation_deg": rms([x["crb_r"] for x in sel]),
                     "median_translation_m": float(np.median([x["crb_t"] for x in sel])) if sel else None,
                     "median_rotation_deg": float(np.median([x["crb_r"] for x in sel])) if sel else None},
        }

    overall = stats(rows)
    by_size = {str(n): stats([x for x in rows if x["size"] == n]) for n in sizes}
    hops = sorted({x["hops"] for x in rows if x["hops"] is not None})
    by_hops = {str(h): stats([x for x in rows if x["hops"] == h]) for h in hops}
    results = {
        "experiment": "team", "seed": seed, "sigma_px": sigma_px, "sizes": list(sizes), "teams_per_size": teams,
        "failed_teams": failures,
        "methods": {m: {"median_translation_m": overall[m]["median_translation_m"],
                        "median_rotation_deg": overall[m]["median_rotation_deg"],
                        "rmse_translation_m": overall[m]["rmse_translation_m"],
                        "rmse_rotation_deg": overall[m]["rmse_rotation_deg"]} for m in ("joint", "chained", "crlb")},
        "overall": overall, "by_team_size": by_size, "by_hops": by_hops,
        "command": command or f"mutloc experiment team --out {out_dir} --seed {seed}",
        "versions": versions(),
    }
    _plot(by_size, by_hops, out / "team.png")
    results["elapsed_s"] = time.perf_counter() - started
    write_results(results, out)
    (out / "report.md").write_text(_report(results), encoding="utf-8")
    return results


def _plot(by_size: dict, by_hops: dict, path: Path) -> None:
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, data, xlabel in ((axes[0], by_size, "robots in the team"), (axes[1], by_hops, "hops from the reference")):
        xs = [int(k) for k in data]
        for key, label, style in (("joint_same_robots", "joint", "o-"), ("chained", "chained pairwise", "s--"),
                                  ("crlb", "joint CRB (all robots)", "k:")):
            ys = [100 * data[k][key]["rmse_translation_m"] for k in data]
            ax.plot(xs, ys, style, label=label)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("translation RMSE (cm)")
        ax.grid(alpha=0.3)
    axes[0].set_title("error against team size")
    axes[1].set_title("error against hops (pair chain length)")
    axes[0].legend()
    save_figure(fig, path)


def _report(res: dict) -> str:
    o = res["overall"]
    lines = [
        "# Teams: joint versus chained pairwise estimates", "",
        f"{len(res['sizes'])} team sizes ({', '.join(map(str, res['sizes']))} robots), {res['teams_per_size']} random "
        f"teams each, {res['sigma_px']:g} px Gaussian pixel noise; every robot's pose in robot r0's frame. "
        "*Joint*: `mutloc.localize_team` (one maximum-likelihood problem over every observation). *Chained*: pair "
        f"estimates (`mutloc.localize`, pairs with >= {PAIR_MIN} observations) composed along the fewest hops from "
        "r0. *CRB*: the joint Cramer-Rao bound (covariance at the true poses). RMSE over robots; "
        "joint and chained compared on the robots both reach.", "",
        "| | robots | joint RMSE | chained RMSE | CRB RMSE |", "|---|---|---|---|---|",
        f"| all | {o['robots_chained']} | {fmt(o['joint_same_robots']['rmse_translation_m'], 100, 2)} cm / "
        f"{fmt(o['joint_same_robots']['rmse_rotation_deg'], 1, 3)} deg | "
        f"{fmt(o['chained']['rmse_translation_m'], 100, 2)} cm / {fmt(o['chained']['rmse_rotation_deg'], 1, 3)} deg | "
        f"{fmt(o['crlb']['rmse_translation_m'], 100, 2)} cm / {fmt(o['crlb']['rmse_rotation_deg'], 1, 3)} deg |",
    ]
    for title, data, label in (("team size", res["by_team_size"], "robots"), ("hops", res["by_hops"], "hops")):
        lines += ["", f"## Against {title}", "",
                  f"| {label} | robots | joint (same robots) | chained | joint (all) | CRB (all) | chained / joint |",
                  "|---|---|---|---|---|---|---|"]
        for k, s in data.items():
            j, c = s["joint_same_robots"]["rmse_translation_m"], s["chained"]["rmse_translation_m"]
            ratio = c / j if j and np.isfinite(j) and np.isfinite(c) else float("nan")
            lines.append(f"| {k} | {s['robots']} | {fmt(j, 100, 2)} cm | {fmt(c, 100, 2)} cm | "
                         f"{fmt(s['joint']['rmse_translation_m'], 100, 2)} cm | "
                         f"{fmt(s['crlb']['rmse_translation_m'], 100, 2)} cm | {fmt(ratio, 1, 2)} |")
    lines += ["", f"Teams that failed: {res['failed_teams']}.", "", "Plots: `team.png`.", ""]
    lines += reproduce_lines(res)
    return "\n".join(lines)
