"""Banded ("barcode") cylinder markers: the detector (stages in runs.py and edges.py).

A cylinder marker (rig key ``cylinder: {radius, height, code}``, see
:mod:`mutloc.sim.world`) is a cylinder centred on the marker's ``position``
with its axis along the robot's y, wrapped in ``len(code)`` equal bands;
``code[0]`` is the top band (robot -y side), 1 = dark.  The points the
solver uses are the centres of the bands on the axis, markers ``NAME#b0``,
``NAME#b1``, ... (:func:`band_points`, :func:`expand_cylinder_bands`), plus
the cylinder centre ``NAME`` itself.

Detector (:func:`detect_cylinders`), per image:

1. Dark pixels (darker than an absolute level and than a fraction of the
   local *light* level, the brightest smoothed value within 30 px), opened
   with a 3x3 square to drop thin clutter such as text.
2. Per-row dark segments (short gaps such as a specular highlight bridged)
   are linked downwards into tracks of constant left/right extent, giving
   dark *runs*; a row where the band touches clutter beside it is bridged, so
   a band keeps its own rows.  Runs stacked on top of each other with similar
   widths are chained.  A band touching dark clutter beside it over its whole
   height never makes a run of its own width, so each run also reads the
   middle of its own columns up and down (nothing can be inside a cylinder's
   silhouette): the rows where that is all dark, with the silhouette's edge
   free on one side at least, are the chain's runs, each with the extent of
   its own rows.  A contiguous sub-chain is read as a code: run lengths and
   gaps in band heights must match a marker's code (trimmed to its
   first..last dark band), and the narrowest run's width / band height must
   match the cylinder's diameter / band height within 30 %.  One dark run may
   be missing (merged with clutter over its whole height); it is then placed
   from the code, and must show the silhouette's edge on some of its rows.
   After refinement every band's middle must read as its bit (all dark bands
   darker than all light ones), and every boundary between two of the
   cylinder's own bands must be found, which rejects wrong codes and false
   chains; found cylinders may not overlap.
3. Sub-pixel, in grey levels raised to 1.7 (part way to linear light, see
   ``_EDGE_LUT``), two rounds of:

   * *across*: both silhouette edges on every row of the dark bands, each
     by the integral method over a few pixels about the steepest step (an
     edge of the background close by stays out), fitted robustly as two
     parallel lines (the start: the centre most of the runs' sides vote for,
     given the half-width the cylinder's proportions and the band height
     imply), so clutter spoiling one side of some bands costs only those;
   * *along*: each dark/light boundary on vertical profiles at offsets ``w``
     across the cylinder, by the integral method (at the cylinder's ends, the
     background's level just beyond the step).  Every boundary is the front
     arc of an ellipse, ``v = v0 + b sqrt(1 - (w / R)^2) + t w``, with ``v0``
     (the boundary circle's centre on the axis), ``b`` and the tilt ``t`` all
     linear in the boundary index; all edges are fitted at once, robustly,
     a boundary with little support dropped (at the ends, a poster's edge
     taken for the cylinder's).  The band pitch must agree with the
     silhouette's width.

   The second round starts from the first's pitch (the runs' ends may be off
   where clutter touches a band's end).  The band centres and the cylinder
   centre are on the fitted line ``v0(j)``, at the centre line's ``u``.

Candidates are the placements of each code on the runs (each scored once,
:func:`~.runs.placements`), best first; one whose bands do not even read as
its code where it puts them (:func:`~.edges.reads_code`) is not refined; at
most :data:`MAX_REFINES` are tried per marker.  Through a wide-angle lens
(:func:`mutloc.detect.detect_image`), :func:`detect_cylinders_in_views`
ranks the candidates of all the lens's rectified views together: that many
per marker and frame, not per view.

With a ``camera`` the across position is moved from the silhouette's
middle to the axis's image (they differ by up to 0.3 px at 1.2 m near the
image's side, for the standard 3 cm radius).

Limits: the cylinder must look roughly upright in the image (axis within
about 20 degrees of the image's vertical; a camera rolled upside down reads
nothing), its code must have at least two dark runs or one dark run with a
known light band on each side is not enough to find it, and lens distortion
is ignored (the axis is treated as straight in the image).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np

from ...core.camera import Camera
from ...core.rig import Marker, Robot
from ..base import Detection, DetectionResult, as_bgr
from .edges import axis_u, reads_code, refine
from .geometry import band_marker_names, cylinder_spec
from .runs import Run, column_chains, dark_mask, dark_runs, links, placements

__all__ = ["detect_cylinders", "detect_cylinders_in_views", "MAX_REFINES"]

#: Candidates (placements of a marker's code on dark runs) that are refined, best first, before the marker
#: is given up -- per image, or per frame across all the rectified views of a wide-angle lens: a textured
#: floor makes hundreds of candidates, each refinement a few milliseconds (a cylinder found was among the
#: first four candidates refined in every image measured, pinhole or fisheye).
MAX_REFINES = 32

Spec = tuple[float, float, np.ndarray]


def _specs(markers: Mapping[str, Marker] | Robot) -> dict[str, Spec]:
    if isinstance(markers, Robot):
        markers = markers.markers
    return {n: cylinder_spec(m) for n, m in markers.items() if m.extra.get("cylinder") is not None}


def _aspect(spec: Spec) -> float:
    radius, height, code = spec
    return 2 * radius / (height / len(code))


def _candidates(gray: np.ndarray, specs: dict[str, Spec], view: int = 0) -> list[tuple]:
    """Stages 1-2 on one grey image: every placement of every marker's code on its dark runs,
    ``(cost, -length, view, name, part)``."""
    dark = dark_mask(gray)
    runs = dark_runs(dark)
    # How far a cylinder's code reaches from one of its dark runs, in run widths.
    reach = max(len(code) * (height / len(code)) / (2 * radius) for radius, height, code in specs.values())
    cols = column_chains(dark, runs, reach)
    linked = links(runs)
    out = []
    for name, spec in specs.items():
        for cost, part in placements(runs, cols, spec[2], _aspect(spec), linked):
            out.append((cost, -(part[-1].bot - part[0].top), view, name, part))
    return out


def _key(part: list[Run]) -> tuple[int, int, float, float]:
    return (part[0].top, part[-1].bot, float(np.median([r.xc for r in part])),
            float(np.median([r.width for r in part])))


def _part_centre(part: list[Run]) -> np.ndarray:
    """The middle of a placement's dark runs (image pixels)."""
    return np.array([statistics.median(r.xc for r in part), 0.5 * (part[0].top + part[-1].bot)])


def _overlaps(key: tuple, used: list[tuple]) -> bool:
    return any(key[0] <= u[1] and u[0] <= key[1] and abs(key[2] - u[2]) < 0.5 * max(key[3], u[3]) for u in used)


def _refine(gray: np.ndarray, part: list[Run], spec: Spec, camera: Camera | None) -> dict | None:
    ref = refine(gray, part, spec[2], _aspect(spec))
    if ref is not None and camera is not None:
        # The silhouette's middle is not the axis's image: seen off to one side, the near edge of a round
        # body turns away (up to 0.3 px at 1.2 m near the image's side).  From the edges' directions, the
        # axis's is their mean angle (an upright axis, as the detector assumes; distortion ignored).
        ref["bands"] = [(axis_u(u, ref["radius_px"], camera), v) for u, v in ref["bands"]]
        ref["centre"] = (axis_u(ref["centre"][0], ref["radius_px"], camera), ref["centre"][1])
    return ref


def _search(cands: list[tuple], grays: list[np.ndarray], cameras: list[Camera | None], specs: dict[str, Spec]
            ) -> dict[str, tuple[int, float, list[Run], dict]]:
    """Stage 3 over candidates from one or more images (``view`` indexes ``grays``): best first, each
    marker's candidates refined until one bears its code out or :data:`MAX_REFINES` have been tried (those
    whose bands do not read as the code where they put them, :func:`~.edges.reads_code`, are tried
    without refining); one cylinder per region of an image.  Returns name -> (view, cost, part, refined)."""
    cands = sorted(cands, key=lambda c: (c[0], c[1]))
    found: dict[str, tuple[int, float, list[Run], dict]] = {}
    used: dict[int, list[tuple]] = {}
    tries: dict[str, int] = {}
    failed: set[tuple] = set()
    for cost, _, view, name, part in cands:
        if name in found or tries.get(name, 0) >= MAX_REFINES:
            continue
        key = _key(part)
        if _overlaps(key, used.get(view, [])):
            continue
        tries[name] = tries.get(name, 0) + 1
        same = (view, name, tuple((r.top, r.bot, r.left, r.right, r.synthetic) for r in part))
        if same in failed:
            continue
        if not reads_code(grays[view], part, specs[name][2]):  # (a try: a quick one)
            failed.add(same)
            continue
        ref = _refine(grays[view], part, specs[name], cameras[view])
        if ref is None:
            failed.add(same)
            continue
        used.setdefault(view, []).append(key)
        found[name] = (view, cost, part, ref)
    return found


def _detections(name: str, spec: Spec, cost: float, ref: dict) -> dict[str, Detection]:
    info = {"code_cost": float(cost), "band_px": ref["unit_px"], "edge_rms_px": ref["edge_rms_px"]}
    out = {name: Detection(name, np.array(ref["centre"]), score=1.0 - cost, info=info)}
    for bname, uv in zip(band_marker_names(name, len(spec[2])), ref["bands"]):
        out[bname] = Detection(bname, np.array(uv), score=1.0 - cost, info={"cylinder": name})
    return out


def _missing(result: DetectionResult, specs: dict[str, Spec]) -> None:
    for name, (_, _, code) in specs.items():
        if name not in result.detections:
            result.missing.append(name)
            result.missing.extend(band_marker_names(name, len(code)))


def detect_cylinders(image: Any, markers: Mapping[str, Marker] | Robot, *, camera: Camera | None = None
                     ) -> DetectionResult:
    """Find each banded-cylinder marker of ``markers`` (those with a ``cylinder`` key).

    Reports ``NAME`` (the cylinder centre) and ``NAME#bK`` (band ``K``'s centre on the
    axis) for every cylinder found; all of them go to ``missing`` for one not found.
    """
    specs = _specs(markers)
    result = DetectionResult()
    if not specs:
        return result
    gray = cv2.cvtColor(as_bgr(image), cv2.COLOR_BGR2GRAY)
    found = _search(_candidates(gray, specs), [gray], [camera], specs)
    for name in specs:  # the markers' order
        if name in found:
            _, cost, _, ref = found[name]
            result.detections.update(_detections(name, specs[name], cost, ref))
    _missing(result, specs)
    return result


def detect_cylinders_in_views(image: Any, markers: Mapping[str, Marker] | Robot, camera: Any, views: Any
                              ) -> DetectionResult:
    """:func:`detect_cylinders` through a wide-angle lens's rectified ``views``
    (:func:`mutloc.detect.views.views_for`), one search over all of them: the candidates of every view
    ranked together, each marker's refined up to :data:`MAX_REFINES` times per frame (not per view: in
    the views where a marker is not, that many wrong candidates were refined for nothing); then, where
    the view it was found in is not the one it lies farthest inside, its candidate at the same place in
    such a view is refined too and the more central one kept (as :func:`~mutloc.detect.views.detect_in_views`
    keeps it).  Results are the raw image's pixels."""
    from ..views import detection_to_raw, linearized

    specs = _specs(markers)
    result = DetectionResult()
    if not specs:
        return result
    views = list(views)
    bgr = as_bgr(image)
    # Resampled in colour, as the other detectors' views are (grey first would mix light differently where
    # colours meet: measurably different band edges).
    lin = linearized(bgr)
    grays = [cv2.cvtColor(view.rectify(bgr, linear=lin), cv2.COLOR_BGR2GRAY) for view in views]
    cameras = [view.camera for view in views]
    cands = [c for i, g in enumerate(grays) for c in _candidates(g, specs, i)]
    found = _search(cands, grays, cameras, specs)
    for name, (vi, cost, part, ref) in list(found.items()):
        found[name] = _most_central(name, (vi, cost, part, ref), cands, grays, views, specs[name])
    for name in specs:
        if name not in found:
            continue
        vi, cost, _, ref = found[name]
        dets = {n: detection_to_raw(d, views[vi]) for n, d in _detections(name, specs[name], cost, ref).items()}
        if all(d is not None for d in dets.values()):
            result.detections.update(dets)
    _missing(result, specs)
    return result


def _most_central(name: str, hit: tuple, cands: list[tuple], grays: list[np.ndarray], views: Any, spec: Spec
                  ) -> tuple:
    """``hit`` (view, cost, part, refined), or the same cylinder refined in a view it lies farther inside:
    per other view, its best candidate of ``name`` at the same place in the raw image (the middle of its
    dark runs within a run's width of ``hit``'s)."""
    vi, _, part0, ref = hit
    best_off = views[vi].off_centre(ref["centre"])
    raw = views[vi].to_raw(_part_centre(part0))
    tol = max(2.0, _key(part0)[3] * views[vi].raw_per_view_px(_part_centre(part0)))
    tried: set[int] = {vi}
    for cost, _, v, n, part in sorted((c for c in cands if c[3] == name and c[2] != vi), key=lambda c: (c[0], c[1])):
        if v in tried:
            continue
        uv = _part_centre(part)
        if views[v].off_centre(uv) >= best_off or not np.linalg.norm(views[v].to_raw(uv) - raw) <= tol:
            continue
        tried.add(v)
        ref2 = _refine(grays[v], part, spec, views[v].camera)
        if ref2 is not None and views[v].off_centre(ref2["centre"]) < best_off:
            hit, best_off = (v, cost, part, ref2), views[v].off_centre(ref2["centre"])
    return hit


#: :func:`mutloc.detect.views.detect_in_views` hands a wide-angle lens's views to this.
detect_cylinders.in_views = detect_cylinders_in_views  # type: ignore[attr-defined]
