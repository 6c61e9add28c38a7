#!/usr/bin/env python
"""How often do two robots see each other?  The fraction of time two robots moving independently in a room
see each other both ways (each robot sees the other) and at least one way, per camera set-up.

    PYTHONPATH=src python bench/visibility.py                # 20000 configurations, ~1 min
    PYTHONPATH=src python bench/visibility.py --n 2000       # quick
    PYTHONPATH=src python bench/visibility.py --plot docs/images/visibility.png

The model (both robots alike, only the cameras change):

* **Room and motion.** A 6 x 6 m room.  Each sample is one instant: each robot's centre uniform in the room
  0.3 m clear of the walls, the two centres at least 1 m apart (redrawn otherwise), headings uniform and
  independent.  This is the distribution of time of two robots that drive independently and cover the room
  evenly; ``--drive`` also runs a time simulation (constant speed, heading random walk, reflected at the
  walls; instants with the robots under 1 m apart left out) as a check.
* **Robots.** A vertical cylinder 0.2 m in radius and 0.40 m high, with a camera head on top: every camera
  at 0.47 m, 0.06 m out from the axis in its looking direction, looking horizontally (a real
  :class:`~mutloc.core.rig.Mount`, ``T_robot_camera``, in the robot's ``base_link``: x forward, y left, z
  up).  Twelve markers on the cylinder's side: 6 azimuths (every 60 degrees) x 2 heights (0.20 and 0.36 m).
* **Sees.** A camera sees a marker when the marker projects through its lens into its image (the lens
  class's ``project`` finite and ``in_image``; for the fisheye, within ``max_angle``), the marker faces
  the camera (at most 75 degrees between its outward normal and the direction to the camera: a flat tag
  seen more obliquely is lost) and the observer's own body does not hide it.  A robot *sees* the other
  when its cameras together see at least 3 of the other's markers.  Point markers, no range limit: the
  room is at most 8 m across.
* **Set-ups.** One forward pinhole of 60 degrees (horizontal; 960x540, the paper's set-up), one of 90
  degrees; two back-to-back fisheyes of 190 degrees (Kannala-Brandt, 1280x800, the image circle inside the
  image); three pinholes of 120 degrees (960x540) looking at 0, 120 and 240 degrees, and the same with
  125 degrees (fields overlapping by 5 degrees).

Every set-up is evaluated on the same samples.  Writes bench/results/visibility.json (fractions with
95 % Wilson intervals).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from mutloc.core.camera import Camera
from mutloc.core.geometry import so3_exp
from mutloc.core.lenses import FisheyeCamera
from mutloc.core.pose import Pose
from mutloc.core.rig import Marker, Mount, Rig, Robot
from mutloc.sim.bodies import OPTICAL_IN_BASE, body_observations

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _machine import machine, result_file  # noqa: E402

ROOM = 6.0
WALL = 0.3
MIN_SEP = 1.0
BODY_R = 0.20
BODY_H = 0.40
CAM_Z = 0.47
CAM_OUT = 0.06
MARKER_Z = (0.20, 0.36)
MARKER_AZ = np.radians(np.arange(0, 360, 60))
MAX_OBLIQUE = np.radians(75.0)
MIN_MARKERS = 3


def _yaw(a: float) -> np.ndarray:
    return so3_exp(np.array([0.0, 0.0, a]))


def pinhole(hfov_deg: float, w: int = 960, h: int = 540) -> Camera:
    f = 0.5 * w / math.tan(math.radians(hfov_deg) / 2)
    return Camera([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]], size=(w, h))


def fisheye(fov_deg: float = 190.0) -> FisheyeCamera:
    """Kannala-Brandt, 1280x800, the image circle of ``fov_deg`` 400 px in radius (inside the short side)."""
    k = np.array([0.012, -0.004, 0.0006, -0.0001])
    th = math.radians(fov_deg) / 2
    th_d = th * (1 + k[0] * th**2 + k[1] * th**4 + k[2] * th**6 + k[3] * th**8)
    f = 400.0 / th_d
    return FisheyeCamera([[f, 0, 639.5], [0, f, 399.5], [0, 0, 1]], k, (1280, 800))


def mounts(lenses: list[tuple[str, object, float]]) -> dict[str, Mount]:
    """Cameras on the head: ``(name, lens, yaw in degrees)``, looking out horizontally."""
    out = {}
    for name, lens, yaw_deg in lenses:
        a = math.radians(yaw_deg)
        R = _yaw(a) @ OPTICAL_IN_BASE
        t = _yaw(a) @ np.array([CAM_OUT, 0.0, 0.0]) + np.array([0.0, 0.0, CAM_Z])
        out[name] = Mount(name, lens, Pose(R, t))
    return out


def setups() -> dict[str, dict[str, Mount]]:
    return {
        "one 60 deg pinhole (paper)": mounts([("front", pinhole(60), 0)]),
        "one 90 deg pinhole": mounts([("front", pinhole(90), 0)]),
        "two back-to-back 190 deg fisheyes": mounts([("front", fisheye(190), 0), ("back", fisheye(190), 180)]),
        "three 120 deg pinholes": mounts([("c0", pinhole(120), 0), ("c120", pinhole(120), 120),
                                          ("c240", pinhole(120), 240)]),
        "three 125 deg pinholes (overlapping)": mounts([("c0", pinhole(125), 0), ("c120", pinhole(125), 120),
                                                        ("c240", pinhole(125), 240)]),
    }


def markers_body() -> tuple[np.ndarray, np.ndarray]:
    """Marker positions (12, 3) in base_link and their outward normals (12, 3)."""
    pos, nrm = [], []
    for z in MARKER_Z:
        for a in MARKER_AZ:
            n = np.array([math.cos(a), math.sin(a), 0.0])
            pos.append(BODY_R * n + [0.0, 0.0, z])
            nrm.append(n)
    return np.array(pos), np.array(nrm)


def robot(name: str, cams: dict[str, Mount]) -> Robot:
    pos, _ = markers_body()
    ms = {f"{name}{i}": Marker(f"{name}{i}", name, p) for i, p in enumerate(pos)}
    return Robot(name, None, ms, cameras=cams)


# ---------------------------------------------------------------------------
# sampling
# ---------------------------------------------------------------------------


def sample_instants(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 2, 3): per instant, each robot's (x, y, yaw)."""
    out = np.empty((0, 2, 3))
    while len(out) < n:
        m = 2 * (n - len(out)) + 16
        xy = rng.uniform(WALL, ROOM - WALL, (m, 2, 2))
        yaw = rng.uniform(0, 2 * np.pi, (m, 2, 1))
        ok = np.linalg.norm(xy[:, 0] - xy[:, 1], axis=1) >= MIN_SEP
        out = np.concatenate([out, np.concatenate([xy, yaw], axis=2)[ok]])
    return out[:n]


def drive(rng: np.random.Generator, n: int, dt: float = 0.1, speed: float = 0.4,
          turn_sigma: float = 0.6) -> np.ndarray:
    """(n, 2, 3) instants of two robots driving independently (constant speed, heading a random walk of
    ``turn_sigma`` rad/sqrt(s), reflected at the walls), instants closer than MIN_SEP left out."""
    state = sample_instants(rng, 1)[0].copy()
    rows = []
    steps = 0
    while len(rows) < n:
        steps += 1
        for r in range(2):
            x, y, a = state[r]
            a += turn_sigma * math.sqrt(dt) * rng.standard_normal()
            x += speed * dt * math.cos(a)
            y += speed * dt * math.sin(a)
            if x < WALL or x > ROOM - WALL:
                x = min(max(x, WALL), ROOM - WALL)
                a = math.pi - a
            if y < WALL or y > ROOM - WALL:
                y = min(max(y, WALL), ROOM - WALL)
                a = -a
            state[r] = (x, y, math.atan2(math.sin(a), math.cos(a)))
        if np.hypot(*(state[0, :2] - state[1, :2])) >= MIN_SEP:
            rows.append(state.copy())
    return np.array(rows)


# ---------------------------------------------------------------------------
# visibility
# ---------------------------------------------------------------------------


def _rot_z(yaw: np.ndarray) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.zeros((len(yaw), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


def _own_body_hides(C: np.ndarray, M: np.ndarray, axis_xy: np.ndarray) -> np.ndarray:
    """Whether the segment from camera C (n, k, 3) to marker M crosses the observer's cylinder (axis at
    ``axis_xy`` (n, 2), radius BODY_R, 0 <= z <= BODY_H): below the top it must stay outside the radius."""
    zc, zm = C[..., 2], M[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        s0 = np.where(zc > BODY_H, (zc - BODY_H) / (zc - zm), 0.0)
    s0 = np.clip(np.nan_to_num(s0, nan=2.0), 0.0, 2.0)
    a = C[..., :2] - axis_xy[:, None, :]
    d = M[..., :2] - C[..., :2]
    dd = np.einsum("nki,nki->nk", d, d)
    s = np.clip(-np.einsum("nki,nki->nk", a, d) / np.maximum(dd, 1e-18), s0, 1.0)
    closest = a + s[..., None] * d
    return (s0 <= 1.0) & (np.einsum("nki,nki->nk", closest, closest) < BODY_R**2)


def seen_counts(cams: dict[str, Mount], inst: np.ndarray, observer: int, tag_size: float = 0.0,
                min_px: float = 0.0) -> np.ndarray:
    """How many of the other robot's markers robot ``observer`` sees (any of its cameras), per instant.
    With ``min_px``: only markers whose tag of side ``tag_size`` (flat on the body, facing out) covers at
    least ``min_px`` x ``min_px`` pixels' area (through the lens's Jacobian: distance, obliquity and the
    lens's pixel density where the marker falls)."""
    other = 1 - observer
    pos, nrm = markers_body()
    Ro, Rt = _rot_z(inst[:, observer, 2]), _rot_z(inst[:, other, 2])
    to = np.c_[inst[:, observer, :2], np.zeros(len(inst))]
    tt = np.c_[inst[:, other, :2], np.zeros(len(inst))]
    Mw = np.einsum("nij,kj->nki", Rt, pos) + tt[:, None, :]       # markers in the world (n, 12, 3)
    Nw = np.einsum("nij,kj->nki", Rt, nrm)
    seen = np.zeros(Mw.shape[:2], dtype=bool)
    for mount in cams.values():
        Rc = np.einsum("nij,jk->nik", Ro, mount.pose.R)            # camera in the world
        tc = np.einsum("nij,j->ni", Ro, mount.pose.t) + to
        Xc = np.einsum("nji,nkj->nki", Rc, Mw - tc[:, None, :])    # markers in the camera frame
        uv, J = mount.camera.project_jacobian(Xc.reshape(-1, 3))
        uv = np.asarray(uv, float)
        ok = np.all(np.isfinite(uv), axis=1)
        ok[ok] = np.asarray(mount.camera.in_image(uv[ok]), bool)
        if min_px > 0:
            up = np.broadcast_to([0.0, 0.0, 1.0], Nw.shape)
            axes = [np.cross(up, Nw), up]                               # the tag's sides (world)
            cols = [np.einsum("nji,nkj->nki", Rc, a).reshape(-1, 3) for a in axes]  # in the camera frame
            J = np.asarray(J, float).reshape(-1, 2, 3)
            d1, d2 = (np.einsum("mij,mj->mi", J, c) for c in cols)
            area = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) * tag_size**2
            ok &= np.nan_to_num(area, nan=0.0) >= min_px**2
        ok = ok.reshape(Mw.shape[:2])
        to_cam = tc[:, None, :] - Mw
        cos_ob = np.einsum("nki,nki->nk", to_cam, Nw) / np.linalg.norm(to_cam, axis=2)
        ok &= cos_ob >= math.cos(MAX_OBLIQUE)
        ok &= ~_own_body_hides(np.broadcast_to(tc[:, None, :], Mw.shape), Mw, inst[:, observer, :2])
        seen |= ok
    return seen.sum(axis=1)


def in_field_keys(cams: dict[str, Mount], inst: np.ndarray) -> list[set]:
    """Per instant, which cameras have any marker in their field and image (no facing or occlusion test)
    -- what :func:`mutloc.sim.bodies.body_observations` reports -- as a check of the vectorized
    projections against the library's own."""
    pos, _ = markers_body()
    out = []
    for o in range(2):
        other = 1 - o
        Ro, Rt = _rot_z(inst[:, o, 2]), _rot_z(inst[:, other, 2])
        to = np.c_[inst[:, o, :2], np.zeros(len(inst))]
        tt = np.c_[inst[:, other, :2], np.zeros(len(inst))]
        Mw = np.einsum("nij,kj->nki", Rt, pos) + tt[:, None, :]
        for name, mount in cams.items():
            Rc = np.einsum("nij,jk->nik", Ro, mount.pose.R)
            tc = np.einsum("nij,j->ni", Ro, mount.pose.t) + to
            Xc = np.einsum("nji,nkj->nki", Rc, Mw - tc[:, None, :])
            uv = np.asarray(mount.camera.project(Xc.reshape(-1, 3)), float)
            ok = np.all(np.isfinite(uv), axis=1)
            ok[ok] = np.asarray(mount.camera.in_image(uv[ok]), bool)
            out.append((o, name, ok.reshape(Mw.shape[:2]).any(axis=1)))
    return [{f"{'pq'[o]}/{name}" for o, name, ok in out if ok[i]} for i in range(len(inst))]


def check_against_library(cams: dict[str, Mount], inst: np.ndarray) -> None:
    rig = Rig({"p": robot("p", cams), "q": robot("q", cams)})
    mine = in_field_keys(cams, inst)
    for i, (a, b) in enumerate(inst):
        poses = {"p": Pose(_yaw(a[2]), [a[0], a[1], 0.0]), "q": Pose(_yaw(b[2]), [b[0], b[1], 0.0])}
        lib = set(body_observations(rig, poses))
        assert lib == mine[i], (i, lib, mine[i])


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    p = k / n
    den = 1 + z * z / n
    c = (p + z * z / (2 * n)) / den
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return c - h, c + h


def measure(inst: np.ndarray, **resolution: float) -> dict:
    res = {}
    for name, cams in setups().items():
        a = seen_counts(cams, inst, 0, **resolution) >= MIN_MARKERS
        b = seen_counts(cams, inst, 1, **resolution) >= MIN_MARKERS
        n = len(inst)
        both, one = int(np.sum(a & b)), int(np.sum(a | b))
        res[name] = {"both_ways": both / n, "both_ways_ci95": wilson(both, n),
                     "at_least_one_way": one / n, "at_least_one_way_ci95": wilson(one, n),
                     "one_robot_sees_other": float(np.mean(np.r_[a, b]))}
    return res


def plot(results: dict, path: str, resolution_title: str = "") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("uniform", "field of view only")]
    if "uniform_resolution" in results:
        panels.append(("uniform_resolution", resolution_title))
    names = list(results["uniform"])
    labels = [k.replace(" (paper)", "\n(the paper)").replace("back-to-back ", "back-to-back\n")
              .replace("three ", "three\n").replace(" (overlapping)", "\n(overlapping)").replace("one ", "one\n") for k in names]
    x = np.arange(len(names))
    fig, axes = plt.subplots(1, len(panels), figsize=(6.2 * len(panels), 3.8), dpi=110, sharey=True,
                             squeeze=False)
    for ax, (key, title) in zip(axes[0], panels):
        both = [100 * results[key][k]["both_ways"] for k in names]
        one = [100 * results[key][k]["at_least_one_way"] for k in names]
        b1 = ax.bar(x - 0.2, both, 0.4, label="both ways (each sees the other)", color="#3b6ea5")
        b2 = ax.bar(x + 0.2, one, 0.4, label="at least one way", color="#9cc3e6")
        for bars in (b1, b2):
            for r in bars:
                v = r.get_height()
                ax.annotate(f"{v:.1f}", (r.get_x() + r.get_width() / 2, v), ha="center", va="bottom",
                            fontsize=7, xytext=(0, 2), textcoords="offset points")
        ax.set_xticks(x, labels, fontsize=7)
        ax.set_title(title, fontsize=9)
        ax.set_ylim(0, 115)
    axes[0][0].set_ylabel("% of the time")
    axes[0][0].legend(fontsize=7, loc="upper left")
    fig.suptitle(f"Two robots in a 6 x 6 m room: how often they see each other (>= {MIN_MARKERS} markers)",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    print(f"wrote {path}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=20000, help="instants (samples) per model")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--drive", action="store_true", help="also the driving time simulation")
    ap.add_argument("--tag-size", type=float, default=0.15, help="tag side (m) for the resolution model")
    ap.add_argument("--min-px", type=float, default=20.0,
                    help="resolution model: a tag must cover this many pixels squared (0: skip the model)")
    ap.add_argument("--out", default=result_file("visibility.json"))
    ap.add_argument("--plot", default=None, help="write a bar chart (PNG) there")
    args = ap.parse_args(argv)

    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    inst = sample_instants(rng, args.n)
    for cams in setups().values():
        check_against_library(cams, inst[:200])
    results = {"uniform": measure(inst)}
    if args.min_px > 0:
        results["uniform_resolution"] = measure(inst, tag_size=args.tag_size, min_px=args.min_px)
    if args.drive:
        results["drive"] = measure(drive(rng, args.n))
    took = time.perf_counter() - t0

    print(f"{'set-up':38s} {'both ways':>11s} {'>= one way':>11s}" + ("   drive: both / one" if args.drive else ""))
    for name, r in results["uniform"].items():
        line = f"{name:38s} {100 * r['both_ways']:10.1f}% {100 * r['at_least_one_way']:10.1f}%"
        if args.drive:
            d = results["drive"][name]
            line += f"   {100 * d['both_ways']:5.1f}% / {100 * d['at_least_one_way']:5.1f}%"
        print(line)
    if "uniform_resolution" in results:
        print(f"with {args.tag_size:g} m tags that must cover >= {args.min_px:g} x {args.min_px:g} px:")
        for name, r in results["uniform_resolution"].items():
            print(f"{name:38s} {100 * r['both_ways']:10.1f}% {100 * r['at_least_one_way']:10.1f}%")
    print(f"({args.n} instants, {took:.1f} s)")

    doc = {
        "benchmark": "visibility",
        "command": "PYTHONPATH=src python bench/visibility.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "model": {
            "room_m": [ROOM, ROOM], "wall_clearance_m": WALL, "min_separation_m": MIN_SEP,
            "body": {"radius_m": BODY_R, "height_m": BODY_H}, "camera_height_m": CAM_Z,
            "camera_out_from_axis_m": CAM_OUT,
            "markers": {"azimuths_deg": np.degrees(MARKER_AZ).tolist(), "heights_m": list(MARKER_Z),
                        "max_obliquity_deg": math.degrees(MAX_OBLIQUE)},
            "sees": f">= {MIN_MARKERS} of the other robot's markers in the robot's cameras together: projected "
                    "by the lens (finite, in_image), facing the camera within the obliquity, not hidden by "
                    "the observer's own body",
            "instants": args.n, "seed": args.seed,
            "resolution_model": None if args.min_px <= 0 else {
                "tag_size_m": args.tag_size, "min_px": args.min_px,
                "rule": "results.uniform_resolution: a marker counts only if a flat square tag of tag_size on "
                        "the body covers >= min_px^2 pixels' area (lens Jacobian at the marker)"},
        },
        "cameras": {name: {c: {"model": m.camera.model, "K": m.camera.K.tolist(), "size": list(m.camera.size),
                               "pose_t": m.pose.t.tolist()} for c, m in cams.items()}
                    for name, cams in setups().items()},
        "results": results,
        "seconds": took,
        "machine": machine(),
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.out}")
    if args.plot:
        plot(results, args.plot, f"and resolution: {args.tag_size:g} m tags cover >= {args.min_px:g} x "
                                 f"{args.min_px:g} px")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
