#!/usr/bin/env python
"""Localize on the Blender fisheye sequences (issue 36): detection through the lens, then the pair solver.

    PYTHONPATH=src python bench/bench_blender_fisheye.py [--set bench/blender_fisheye]
        [--out bench/results/blender_fisheye_results.json] [--quad-decimate 1]

For every frame of the set bench/make_blender_fisheye.py rendered: each of the four cameras' images is
searched for the other robot's tags with ``mutloc.track.frames.detect_markers`` (through the lens's
locally rectified views; a tag's four corners are its measurements), the four cameras' detections go
together into ``mutloc.localize(rig, observations, "p", "q")`` (default options, ``pixel_sigma`` 1), and
the pose is compared with the truth ``T_qp``.

Reported per situation and overall: frames, frames with >= 3 tags visible (truth: a tag counts when
some camera of the robot looking at it has all four of its corners inside the 195-degree circle and sees
its printed side at less than 75 degrees from face-on; both robots' views added up), frames with a pose
(any status), the status counts, the median and largest rotation (deg) and translation (cm) errors, and
the poses beyond 5 sigma: ``NEES = e^T C^-1 e`` with ``e`` = (rotation vector of ``R_true R^T``,
``t_true - t``), the SPEC's convention, ``C`` the estimate's 6x6 covariance, against the chi-square
quantile with 6 degrees of freedom at the two-sided tail probability of 5 sigma of a Gaussian
(5.7e-7: NEES > 39.5), at the covariance ``localize`` reports (``pixel_sigma`` 1) and, the strict
test, at the corners' measured noise (the covariance scaled by ``sigma_measured**2``, sigma_measured the
rms of one coordinate's corner error over the whole set).  Per tag and camera: detected or missed against the truth's ``visible``, corner
pixel errors (detected against true corners), by angle off the optical axis and incidence, so a miss can
be traced to its image, tag and angle.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections import Counter
from pathlib import Path

import cv2
import numpy as np
from scipy.stats import chi2, norm

from mutloc.api import load_rig
from mutloc.core.geometry import so3_log
from mutloc.core.rig import MarkerKind
from mutloc.detect import detect_image
from mutloc.detect.base import DetectionResult, observations_of
from mutloc.errors import MutlocError
from mutloc.track.frames import detect_markers, expanded_rig

ROOT = Path(__file__).resolve().parent
CAMERAS = ("p/front", "p/back", "q/front", "q/back")
#: NEES threshold: chi-square (6 dof) at the two-sided 5-sigma Gaussian tail probability.
P_5SIGMA = 2 * norm.sf(5.0)
NEES_5SIGMA = float(chi2.isf(P_5SIGMA, 6))


def detect(rig, key: str, image, other: str, quad_decimate: float | None):
    """``detect_markers`` (the library's defaults), or with the AprilTag library's ``quad_decimate`` set:
    the same search through the lens's views, a tag's corners as its measurements."""
    if quad_decimate is None:
        return detect_markers(rig, key, image, targets=[other])
    from mutloc.track.frames import _add_tag_corners

    tags = {n: m for n, m in rig.robot(other).markers.items() if m.kind == MarkerKind.TAG}
    found = detect_image(MarkerKind.TAG, image, tags, rig.mount(key).camera, params={"quad_decimate": quad_decimate})
    _add_tag_corners(found, tags)
    return found


def run_frame(rig, folder: Path, quad_decimate: float | None = None) -> dict:
    import mutloc

    truth = json.loads((folder / "truth.json").read_text())
    dets, tags = {}, []
    t0 = time.time()
    for key in CAMERAS:
        robot = key.split("/")[0]
        other = "q" if robot == "p" else "p"
        path = folder / f"{key.replace('/', '_')}.png"
        # A camera not rendered (no tag of the other robot near its field) detects nothing.
        res = detect(rig, key, cv2.imread(str(path), cv2.IMREAD_COLOR), other, quad_decimate) if path.exists() \
            else DetectionResult()
        dets[key] = res
        for mname, tt in truth["tags"][key].items():
            got = [res.detections.get(f"{mname}#{c}") for c in range(4)]
            found = all(g is not None for g in got)
            row = {"camera": key, "tag": mname, "visible": tt["visible"], "found": found,
                   "off_axis_deg": tt["off_axis_deg"], "incidence_deg": tt["incidence_deg"],
                   "distance_m": tt["distance_m"]}
            if found and tt["corners"] is not None:
                e = np.array([list(map(float, g.uv)) for g in got]) - np.array(tt["corners"])
                row["corner_err_px"] = np.linalg.norm(e, axis=1).tolist()
                row["corners_px"] = [list(map(float, g.uv)) for g in got]
                row["true_corners_px"] = tt["corners"]
            tags.append(row)
    detect_s = time.time() - t0
    obs = observations_of(dets)
    R_true, t_true = np.array(truth["T_qp"]["R"]), np.array(truth["T_qp"]["t"])
    out = {"situation": truth["situation"], "frame": truth["frame"], "detect_seconds": detect_s,
           "tags_visible": sum(r["visible"] for r in tags), "tags_found": sum(r["found"] for r in tags),
           "tags": tags}
    try:
        est = mutloc.localize(rig, obs, "p", "q")
    except MutlocError as exc:
        out.update(status=f"error: {type(exc).__name__}", message=str(exc)[:300])
        return out
    e = np.concatenate([so3_log(R_true @ est.R.T), t_true - est.t])
    C = np.asarray(est.covariance, float)
    nees = float(e @ np.linalg.solve(C, e))
    out.update(status=est.status, rot_err_deg=math.degrees(float(np.linalg.norm(e[:3]))),
               trans_err_cm=100 * float(np.linalg.norm(e[3:])), nees=nees,
               sigma_t_cm=(100 * np.sqrt(np.diag(C)[3:])).tolist(),
               reprojection_rms_px=float(est.reprojection_rms_px), markers_used=len(est.markers_used),
               rejected=[r.get("marker", r) if isinstance(r, dict) else r for r in (est.rejected or [])])
    return out


#: Bins of the tag tables: angle of the tag's centre off the optical axis, and of its normal off the line of sight.
OFF_AXIS_BINS = (0.0, 45.0, 80.0, 90.0, 97.5)
INCIDENCE_BINS = (0.0, 30.0, 45.0, 60.0, 75.0)


def _by_bins(tags: list[dict], key: str, edges: tuple[float, ...]) -> dict[str, dict]:
    """Per bin of ``key``: visible tags, found, and the found ones' corner errors (median, max px)."""
    out = {}
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = [t for t in tags if t["visible"] and lo <= t[key] < hi]
        errs = [e for t in sel if "corner_err_px" in t for e in t["corner_err_px"]]
        out[f"{lo:g}-{hi:g}"] = {"visible": len(sel), "found": sum(t["found"] for t in sel),
                                 "corner_err_px_median": float(np.median(errs)) if errs else None,
                                 "corner_err_px_max": float(np.max(errs)) if errs else None}
    return out


def summarize(frames: list[dict], corner_rms: float) -> dict:
    posed = [f for f in frames if "nees" in f]
    eligible = [f for f in frames if f["tags_visible"] >= 3]
    posed_eligible = [f for f in eligible if "nees" in f]
    tags = [t for f in frames for t in f["tags"]]
    vis = [t for t in tags if t["visible"]]
    errs = [e for t in tags if "corner_err_px" in t for e in t["corner_err_px"]]
    s = {"frames": len(frames), "frames_3_tags_visible": len(eligible), "frames_with_pose": len(posed),
         "frames_3_visible_with_pose": len(posed_eligible),
         "pose_rate_where_3_visible": len(posed_eligible) / len(eligible) if eligible else None,
         "status": dict(Counter(f["status"] for f in frames)),
         "tags_visible": len(vis), "tags_visible_found": sum(t["found"] for t in vis),
         "tags_found_not_visible": sum(t["found"] and not t["visible"] for t in tags),
         "corner_err_px_median": float(np.median(errs)) if errs else None,
         "corner_err_px_p95": float(np.percentile(errs, 95)) if errs else None,
         "corner_err_px_max": float(np.max(errs)) if errs else None,
         "by_off_axis_deg": _by_bins(tags, "off_axis_deg", OFF_AXIS_BINS),
         "by_incidence_deg": _by_bins(tags, "incidence_deg", INCIDENCE_BINS)}
    if posed:
        rot = [f["rot_err_deg"] for f in posed]
        tr = [f["trans_err_cm"] for f in posed]
        s.update(rot_err_deg_median=float(np.median(rot)), rot_err_deg_max=float(np.max(rot)),
                 trans_err_cm_median=float(np.median(tr)), trans_err_cm_max=float(np.max(tr)),
                 beyond_5sigma=sum(f["nees"] > NEES_5SIGMA for f in posed),
                 nees_median=float(np.median([f["nees"] for f in posed])),
                 # The covariance at the corners' measured noise (C scales with pixel_sigma^2): the strict test.
                 beyond_5sigma_at_measured_noise=sum(f["nees"] / corner_rms**2 > NEES_5SIGMA for f in posed),
                 nees_median_at_measured_noise=float(np.median([f["nees"] for f in posed])) / corner_rms**2,
                 nees_max_at_measured_noise=float(np.max([f["nees"] for f in posed])) / corner_rms**2)
    return s


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", type=Path, default=ROOT / "blender_fisheye")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "blender_fisheye_results.json")
    ap.add_argument("--quad-decimate", type=float, default=None,
                    help="the AprilTag library's quad_decimate for the whole-view search (default: the library's "
                         "default in mutloc, 2)")
    args = ap.parse_args()
    index = json.loads((args.set / "index.json").read_text()) if (args.set / "index.json").exists() else {}
    sits = sorted(p.name for p in args.set.iterdir() if (p / "rig.yaml").exists())
    frames = []
    t0 = time.time()
    for sit in sits:
        rig = expanded_rig(load_rig(str(args.set / sit / "rig.yaml")))
        for folder in sorted((args.set / sit).glob("frame_*")):
            if not (folder / "truth.json").exists():
                continue
            f = run_frame(rig, folder, args.quad_decimate)
            frames.append(f)
            pose = (f"{f['status']}, {f['rot_err_deg']:.3f} deg, {f['trans_err_cm']:.2f} cm, NEES {f['nees']:.1f}"
                    if "nees" in f else f["status"])
            print(f"{sit} {folder.name}: tags found {f['tags_found']} / visible {f['tags_visible']}; {pose} "
                  f"({f['detect_seconds']:.1f} s)", flush=True)
    # The corners' measured noise: the rms of one coordinate's error over every corner found.
    errs = [e for f in frames for t in f["tags"] if "corner_err_px" in t for e in t["corner_err_px"]]
    corner_rms = float(np.sqrt(np.mean(np.square(errs)) / 2))
    report = {"set": index, "quad_decimate": args.quad_decimate, "nees_5sigma": NEES_5SIGMA, "p_5sigma": P_5SIGMA, "pixel_sigma": 1.0,
              "corner_rms_px_per_coordinate": corner_rms, "seconds": time.time() - t0,
              "situations": {s: summarize([f for f in frames if f["situation"] == s], corner_rms) for s in sits},
              "overall": summarize(frames, corner_rms), "frames": frames}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=1))
    hdr = (f"{'situation':14s} {'frames':>6s} {'>=3 vis':>7s} {'posed':>5s} {'rate':>6s} {'rot med':>8s} {'t med cm':>8s} "
           f"{'t max cm':>8s} {'>5sig':>5s} {'>5sig@meas':>10s}  status")
    print(hdr)
    for name, s in [*report["situations"].items(), ("overall", report["overall"])]:
        rate = f"{100 * s['pose_rate_where_3_visible']:.0f}%" if s["pose_rate_where_3_visible"] is not None else "-"
        print(f"{name:14s} {s['frames']:6d} {s['frames_3_tags_visible']:7d} {s['frames_with_pose']:5d} {rate:>6s} "
              f"{s.get('rot_err_deg_median', float('nan')):8.3f} {s.get('trans_err_cm_median', float('nan')):8.2f} "
              f"{s.get('trans_err_cm_max', float('nan')):8.2f} {s.get('beyond_5sigma', 0):5d} "
              f"{s.get('beyond_5sigma_at_measured_noise', 0):10d}  {s['status']}")
    o = report["overall"]
    print(f"corners: rms {corner_rms:.3f} px per coordinate, median {o['corner_err_px_median']:.3f} px, "
          f"max {o['corner_err_px_max']:.3f} px; tags visible {o['tags_visible']}, found {o['tags_visible_found']}, "
          f"found though not visible {o['tags_found_not_visible']}")
    for what in ("by_off_axis_deg", "by_incidence_deg"):
        print(f"{what}: " + "; ".join(f"{k}: {v['found']}/{v['visible']}" + (
            f" ({v['corner_err_px_median']:.2f}/{v['corner_err_px_max']:.2f} px)" if v["corner_err_px_median"] else "")
            for k, v in o[what].items()))
    print(f"-> {args.out}")


if __name__ == "__main__":
    main()
