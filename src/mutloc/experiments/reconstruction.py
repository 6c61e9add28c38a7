"""The paper's 3D reconstruction experiment (Sec. V-C).

A static camera q and a moving camera p, each with two coloured balls beside
it, see each other and a textured room (posters on the walls, printed mats
on the floor).  p stops at several poses; at each, both cameras take a
frame.  Camera poses (p's pose in q's frame at each stop) come from

- ``mutual``: mutloc on the balls found by the real detector;
- ``bundler``: structure from motion (COLMAP, :mod:`mutloc.baselines.sfm`)
  over every frame of both robots plus a few walk-around photos of the room,
  intrinsics fixed, scale from the true distance between the two registered
  walk-around photos farthest apart (an oracle that favours it), features
  matched between the pairs of images whose views can share a point of the
  scene on the true poses (as in the localization experiment);
- ``egomotion``: the two-frame baseline, five-point essential matrix from
  SIFT matches with RANSAC, scale from the true camera distance (an oracle).

One triangulator for every method: COLMAP's point triangulator, with the
camera poses held fixed, over the same SIFT features and verified matches of
the robots' frames (q at its true world pose, p placed by each method's
``T_qp``); points whose mean reprojection error exceeds
:data:`MAX_REPROJ_PX` are dropped.  The clouds are written as PLY in the world
frame.  The paper's metric: the mean distance from each point to the true
scene surface (exact here: :func:`mutloc.sim.render.surface_distance`; the
paper used an RGB-D scan), discarding points farther than 1 m.

Output in ``OUT/reconstruction/``: ``results.json`` (SPEC), ``report.md``,
``mutual.ply``, ``bundler.ply``, ``egomotion.ply``, ``reconstruction.png``
(top view of the clouds and the room) and the error histogram
``distance_histogram.png``.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from ._common import (StageTimer, fmt, median, pose_errors, pyplot, reproduce_lines, save_figure, versions,
                      write_results)

__all__ = ["run_reconstruction", "PAPER", "QUICK", "OUTLIER_M"]

NAME = "reconstruction"
METHODS = ("mutual", "bundler", "egomotion")
# Mean NN distance (m), Sec. V-C: the paper's baseline is Bundler's poses.
PAPER = {"mutual": 0.176, "bundler": 0.331}
OUTLIER_M = 1.0  # the paper discards points with nearest neighbours further than 1 m
MAX_REPROJ_PX = 2.0
POSES = 8
WALKAROUND_VIEWS = 8
QUICK = dict(poses=3, walkaround_views=8)
NOISE_SIGMA = 2.0
CAMERA_HEIGHT = 0.5
# q looks along world +x turned this far towards the +y wall; p looks back at
# q turned the same way, so both see that wall and the floor between them.
CONVERGE_DEG = 30.0
# Wide-angle cameras (100 x 68 degrees at 960x540): facing cameras share
# the floor between them and a side wall only with a wide field of view.
FOCAL_PX = 400.0
FLOOR_DECALS = 4.0


def _scene(rng: np.random.Generator, poses: int, seed: int):
    """q's pose, p's poses (camera -> world) and the room."""
    from ..sim.world import Room, camera_to_world_facing

    T_wq = camera_to_world_facing((0.0, 0.0, CAMERA_HEIGHT), yaw=math.radians(CONVERGE_DEG))
    T_wp = []
    for k in range(poses):
        s = k / max(1, poses - 1)
        pos = np.array([2.1 + 0.5 * s + rng.uniform(-0.05, 0.05), -0.5 + 0.9 * s + rng.uniform(-0.05, 0.05),
                        CAMERA_HEIGHT])
        to_q = math.atan2(-pos[1], -pos[0])
        yaw = to_q - math.radians(CONVERGE_DEG + rng.uniform(-3.0, 3.0))
        T_wp.append(camera_to_world_facing(pos, yaw=yaw))
    room = Room(center=(1.3, -0.9), size=(6.0, 5.0), seed=int(seed), floor_decals=FLOOR_DECALS)
    return T_wq, T_wp, room


def _sfm_relative(scene, walk, names: list[tuple[str, str]]) -> tuple[dict[int, Any], dict[str, Any]]:
    """Bundler: T_qp per pose from structure from motion over every image, scaled by the
    two registered walk-around photos farthest apart; {pose: Pose or failure}, summary."""
    from ..baselines.sfm import farthest_reference
    from ..errors import MutlocError

    out: dict[int, Any] = {}
    info: dict[str, Any] = {}
    try:
        res = scene.reconstruct()
        ref = farthest_reference({n: T.t for n, T in walk}, res.poses)
        res = res.scaled(ref)
        info = {"registered_images": len(res.poses), "images": res.images, "sfm_points": res.points,
                "scale_reference": {"a": ref.a, "b": ref.b, "distance_m": ref.distance}}
        for k, (pn, qn) in enumerate(names):
            try:
                out[k] = res.relative(pn, qn)
            except MutlocError as e:
                out[k] = str(e)
    except MutlocError as e:
        info = {"registered_images": 0, "failure": str(e)}
        out = {k: f"structure from motion failed: {e}" for k in range(len(names))}
    return out, info


def run_reconstruction(out_dir: str | Path, *, seed: int = 0, poses: int = POSES,
                       walkaround_views: int = WALKAROUND_VIEWS, progress: bool = True,
                       command: str | None = None) -> dict[str, Any]:
    """Run the reconstruction experiment; write ``out_dir/reconstruction/...``."""
    from tqdm import tqdm

    import mutloc
    from ..baselines.egomotion import egomotion_pose
    from ..baselines.sfm import SfmScene
    from ..errors import MutlocError
    from ..io.pointcloud import write_ply
    from ..sim.render import project_markers, relative_pose, render, surface_distance
    from ..sim.walkaround import render_view, robot_points, view_overlap, walkaround_poses
    from ..sim.world import Light, World, WorldRobot, standard_rig
    from ..track.frames import detect_markers

    if poses < 1:
        raise ValueError("poses must be >= 1")
    if walkaround_views < 2:
        raise ValueError("the Bundler baseline needs at least two walk-around views (its scale reference)")
    out = Path(out_dir) / NAME
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    timer = StageTimer()
    rng = np.random.default_rng(seed)
    rig = standard_rig("balls", f=FOCAL_PX)
    cam_p, cam_q = rig.robot("p").camera, rig.robot("q").camera
    T_wq, T_wp, room = _scene(rng, poses, seed)
    # One lamp for every frame (the world's default light would follow p).
    mid = 0.5 * (T_wq.t + np.mean([T.t for T in T_wp], axis=0))
    light = Light(position=(float(mid[0]) + 0.7, float(mid[1]) - 0.9, room.height - 0.2))

    worlds = [World(robots={"q": WorldRobot(rig.robot("q"), T_wq), "p": WorldRobot(rig.robot("p"), T)},
                    room=room, light=light) for T in T_wp]
    per_pose: list[dict[str, Any]] = []
    frames: dict[str, np.ndarray] = {}
    est: dict[str, dict[int, Any]] = {m: {} for m in METHODS}
    solved: list[int] = []
    for k in tqdm(range(poses), desc="reconstruction experiment (poses)", unit="pose", disable=not progress,
                  leave=False):
        world = worlds[k]
        truth = relative_pose(world, "p", "q")
        row: dict[str, Any] = {"pose": k, "t_true": truth.t.tolist()}
        per_pose.append(row)
        seen = {o: project_markers(world, o, check_occlusion=True) for o in ("p", "q")}
        if len(seen["p"]) < 2 or len(seen["q"]) < 2:
            row["status"] = "markers not in view"
            continue
        with timer("render robot frames"):
            img = {o: render(world, o, seed=seed * 1000 + k, noise_sigma=NOISE_SIGMA) for o in ("p", "q")}
        frames[f"p{k:02d}"], frames[f"q{k:02d}"] = img["p"], img["q"]
        solved.append(k)
        with timer("two-frame egomotion baseline"):
            try:
                est["egomotion"][k], _ = egomotion_pose(img["p"], img["q"], cam_p, cam_q,
                                                        float(np.linalg.norm(truth.t)), seed=seed)
            except MutlocError as e:
                row["egomotion_failure"] = str(e)
        with timer("detect balls"):
            obs = {o: {n: tuple(map(float, d.uv)) for n, d in detect_markers(rig, o, img[o]).detections.items()}
                   for o in ("p", "q")}
        with timer("mutual localization"):
            try:
                est["mutual"][k] = mutloc.localize(rig, obs, "p", "q").pose
            except MutlocError as e:
                row["mutual_failure"] = str(e)
        row["status"] = "ok"

    # The walk-around photos: q in its place, p away.
    world_q = World(robots={"q": WorldRobot(rig.robot("q"), T_wq)}, room=room, light=light)
    walk = [(f"w{j:02d}", T) for j, T in enumerate(walkaround_poses(mid, int(walkaround_views), radius=1.8,
                                                                    height=0.9, room=room))]
    images = dict(frames)
    with timer("render walk-around"):
        images.update({n: render_view(world_q, cam_q, T, seed=seed * 1000 + 900 + j, noise_sigma=NOISE_SIGMA)
                       for j, (n, T) in enumerate(walk)})
    cameras = {n: (cam_p if n.startswith("p") else cam_q) for n in images}
    # Match the pairs of images whose views can share a point of the scene (true poses; the same rule as
    # the localization experiment).
    with timer("SfM: choose image pairs"):
        q_pts = robot_points(rig.robot("q"), T_wq)
        views = {n: (cameras[n], T) for n, T in walk}
        objects: dict[str, dict[Any, np.ndarray]] = {n: {"q": q_pts} for n, _T in walk}
        for k in solved:
            p_pts = robot_points(rig.robot("p"), T_wp[k])
            views[f"p{k:02d}"], views[f"q{k:02d}"] = (cam_p, T_wp[k]), (cam_q, T_wq)
            objects[f"p{k:02d}"] = objects[f"q{k:02d}"] = {"q": q_pts, ("p", k): p_pts}
        overlap = view_overlap(room, views, objects=objects)
        pairs = [(a, b) for (a, b), f in overlap.items() if a < b and max(f, overlap[(b, a)]) > 0]
    clouds: dict[str, np.ndarray] = {}
    colours: dict[str, np.ndarray] = {}
    dists: dict[str, np.ndarray] = {}
    methods: dict[str, Any] = {}
    with SfmScene(images, cameras, seed=seed, num_threads=2, pairs=pairs, progress=progress, timer=timer) as scene:
        sfm, sfm_info = _sfm_relative(scene, walk, [(f"p{k:02d}", f"q{k:02d}") for k in solved])
        for i, k in enumerate(solved):
            if isinstance(sfm[i], str):
                per_pose[k]["bundler_failure"] = sfm[i]
            else:
                est["bundler"][k] = sfm[i]
        for m in METHODS:
            for k, T in est[m].items():
                per_pose[k][f"{m}_translation_m"], per_pose[k][f"{m}_rotation_deg"] = pose_errors(
                    T, relative_pose(worlds[k], "p", "q"))
            # q never moves; p where this method puts it.
            cams = {f"q{k:02d}": T_wq for k in solved}
            cams.update({f"p{k:02d}": T_wq @ T for k, T in est[m].items()})
            X = np.empty((0, 3))
            C = np.empty((0, 3), np.uint8)
            if est[m]:
                X, err, _len, C = scene.triangulate(cams)
                keep = err <= MAX_REPROJ_PX
                X, C = X[keep], C[keep]
            # p moved between poses: a point is on the scene's surface at one of them.
            with timer("distance to the true surface"):
                d = np.min([surface_distance(w, X) for w in worlds], axis=0) if len(X) else np.empty(0)
            keep = d <= OUTLIER_M
            clouds[m], colours[m], dists[m] = X[keep], C[keep], d[keep]
            with timer("plots and files"):
                write_ply(out / f"{m}.ply", X[keep], C[keep])
            methods[m] = {"mean_nn_distance_m": float(np.mean(d[keep])) if keep.any() else float("nan"),
                          "median_nn_distance_m": median(d[keep]), "points": int(keep.sum()),
                          "outliers": int((~keep).sum()), "poses_solved": len(est[m]),
                          "median_translation_m": median(r[f"{m}_translation_m"] for r in per_pose
                                                         if f"{m}_translation_m" in r),
                          "median_rotation_deg": median(r[f"{m}_rotation_deg"] for r in per_pose
                                                        if f"{m}_rotation_deg" in r)}
    methods["bundler"].update(sfm_info)
    methods["bundler"].update({"matched_pairs": len(pairs), "all_pairs": len(images) * (len(images) - 1) // 2})
    elapsed = time.perf_counter() - started
    results: dict[str, Any] = {
        "experiment": NAME,
        "seed": int(seed),
        "methods": methods,
        "paper": {m: {"mean_nn_distance_m": v} for m, v in PAPER.items()},
        "poses": per_pose,
        "setup": {"rig": f"standard_rig('balls', f={FOCAL_PX:g})", "image_size": [960, 540], "focal_px": FOCAL_PX,
                  "poses": poses, "walkaround_views": int(walkaround_views), "outlier_m": OUTLIER_M,
                  "max_reprojection_px": MAX_REPROJ_PX, "sensor_noise_dn": NOISE_SIGMA,
                  "converge_deg": CONVERGE_DEG, "light_position": list(light.position),
                  "triangulator": "COLMAP point triangulator (pycolmap), poses fixed"},
        "command": command or f"mutloc.experiments.reconstruction.run_reconstruction(seed={seed})",
        "versions": versions(),
        "elapsed_s": round(elapsed, 2),
    }
    with timer("plots and files"):
        _plots(clouds, dists, T_wq, T_wp, room, results, out)
    results["timing"] = timer.as_dict()
    write_results(results, out)
    (out / "report.md").write_text(_report(results), encoding="utf-8")
    return results


def _plots(clouds, dists, T_wq, T_wp, room, results, out: Path) -> None:
    plt = pyplot()
    fig, axes = plt.subplots(1, len(METHODS), figsize=(5.5 * len(METHODS), 5), sharex=True, sharey=True)
    cx, cy = room.center
    sx, sy = room.size
    for ax, m in zip(axes, METHODS):
        P = clouds[m]
        ax.plot([cx - sx / 2, cx + sx / 2, cx + sx / 2, cx - sx / 2, cx - sx / 2],
                [cy - sy / 2, cy - sy / 2, cy + sy / 2, cy + sy / 2, cy - sy / 2], "k-", lw=1, label="room walls")
        if len(P):
            ax.scatter(P[:, 0], P[:, 1], s=1, c=P[:, 2], cmap="viridis", vmin=0, vmax=room.height)
        ax.plot(*T_wq.t[:2], "r^", ms=9, label="q (static)")
        ax.plot([T.t[0] for T in T_wp], [T.t[1] for T in T_wp], "bv", ms=7, label="p poses")
        r = results["methods"][m]
        ax.set_title(f"{m}: {r['points']} points, mean distance {fmt(r['mean_nn_distance_m'], 100, 1)} cm")
        ax.set_aspect("equal")
        ax.set_xlabel("world x [m]")
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("world y [m]")
    axes[0].legend(fontsize=7, loc="lower left")
    fig.suptitle("Reconstructed points, top view (colour = height)")
    save_figure(fig, out / "reconstruction.png", 110)

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    bins = np.linspace(0, OUTLIER_M, 51)
    for i, m in enumerate(METHODS):
        if len(dists[m]):
            ax.hist(dists[m], bins=bins, histtype="step", color=f"C{i}", lw=1.5, label=m, density=True)
    ax.set_xlabel("distance to the true surface [m]")
    ax.set_ylabel("density")
    ax.set_yscale("log")
    ax.legend()
    ax.grid(True, alpha=0.3)
    save_figure(fig, out / "distance_histogram.png", 110)


def _report(results: dict[str, Any]) -> str:
    ms, setup = results["methods"], results["setup"]
    lines = [
        "# 3D reconstruction experiment (paper Sec. V-C)", "",
        f"A static camera q and a moving camera p ({setup['poses']} poses), each with two balls beside it, "
        "see each other and a textured room. One triangulator for every method: COLMAP's point triangulator "
        "with the camera poses held fixed, over the same SIFT features and verified matches of the robots' "
        "frames (q at its true pose, p placed by each method's T_qp); points with a mean reprojection error "
        f"above {setup['max_reprojection_px']:g} px dropped, the rest compared with the true scene surface "
        f"(points farther than {setup['outlier_m']:g} m discarded, as in the paper).", "",
        "| method | mean distance to the surface | median | points (outliers) | poses solved | pose error "
        "(median) | paper |", "|---|---|---|---|---|---|---|",
    ]
    for m in METHODS:
        r = ms[m]
        lines.append(f"| {m} | {fmt(r['mean_nn_distance_m'], 1, 4)} m | {fmt(r['median_nn_distance_m'], 1, 4)} m | "
                     f"{r['points']} ({r['outliers']}) | {r['poses_solved']}/{setup['poses']} | "
                     f"{fmt(r['median_translation_m'], 100, 2)} cm / {fmt(r['median_rotation_deg'], 1, 3)} deg | "
                     + (f"{PAPER[m]:g} m |" if m in PAPER else "(not in the paper) |"))
    lines += [
        "", "Notes: the Bundler baseline is COLMAP's structure from motion over every robot frame plus "
        f"{setup['walkaround_views']} walk-around photos of the room (intrinsics fixed), scaled by the true "
        "distance between the two registered walk-around photos farthest apart; the two-frame egomotion "
        "baseline gets the true camera distance as its scale. Both scales are oracles in the baselines' favour. "
        f"Features are matched over {ms['bundler'].get('matched_pairs', '?')} of the "
        f"{ms['bundler'].get('all_pairs', '?')} image pairs, those whose views can share a point of the scene "
        "(true poses). "
        "The paper ran PMVS on the poses and aligned an RGB-D scan by hand; here the surface is known exactly, "
        "so the distances measure pose error and matching noise only.", "",
    ]
    b = ms["bundler"]
    if "registered_images" in b:
        lines += [f"Structure from motion registered {b['registered_images']} of {b.get('images', '?')} images"
                  + (f" ({b['failure']})" if b.get("failure") else "") + ".", ""]
    lines += [
        "Files: `mutual.ply`, `bundler.ply`, `egomotion.ply` (world frame, coloured), `reconstruction.png`, "
        "`distance_histogram.png`.", "",
    ]
    lines += reproduce_lines(results)
    return "\n".join(lines)
