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

from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np

from ...core.camera import Camera
from ...core.rig import Marker, Robot
from ..base import Detection, DetectionResult, as_bgr
from .edges import axis_u, refine
from .geometry import band_marker_names, cylinder_spec
from .runs import column_chains, dark_mask, dark_runs, match, stack_chains

__all__ = ["detect_cylinders", "MAX_REFINES"]

#: Chains matching a marker's code that are refined, best match first, before it is given up: a textured
#: floor seen in a wide rectified view makes hundreds of chains, each refinement a few milliseconds (a
#: cylinder found was the first or second chain refined in every image measured).
MAX_REFINES = 32

def detect_cylinders(image: Any, markers: Mapping[str, Marker] | Robot, *, camera: Camera | None = None
                     ) -> DetectionResult:
    """Find each banded-cylinder marker of ``markers`` (those with a ``cylinder`` key).

    Reports ``NAME`` (the cylinder centre) and ``NAME#bK`` (band ``K``'s centre on the
    axis) for every cylinder found; all of them go to ``missing`` for one not found.
    """
    if isinstance(markers, Robot):
        markers = markers.markers
    cyl = {n: m for n, m in markers.items() if m.extra.get("cylinder") is not None}
    specs = {n: cylinder_spec(m) for n, m in cyl.items()}
    result = DetectionResult()
    if not cyl:
        return result
    bgr = as_bgr(image)
    gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    dark = dark_mask(gray)
    runs = dark_runs(dark)
    # How far a cylinder's code reaches from one of its dark runs, in run widths.
    reach = max(len(code) * (height / len(code)) / (2 * radius) for radius, height, code in specs.values())
    chains = stack_chains(runs) + column_chains(dark, runs, reach)
    cands = []  # (cost, -length, marker, part)
    for name, (radius, height, code) in specs.items():
        aspect = 2 * radius / (height / len(code))
        memo: dict = {}  # the chains share runs: each placement of the code scored once
        for chain in chains:
            got = match(chain, code, aspect, memo)
            if got is not None:
                cost, part = got
                cands.append((cost, -(part[-1].bot - part[0].top), name, part))
    cands.sort(key=lambda c: (c[0], c[1]))
    used: list[tuple[int, int, float, float]] = []
    tries: dict[str, int] = {}
    failed: set[tuple] = set()
    for cost, _, name, part in cands:
        if name in result.detections or tries.get(name, 0) >= MAX_REFINES:
            continue
        # One cylinder per image region: no overlap with one already found (better matches first).
        key = (part[0].top, part[-1].bot, float(np.median([r.xc for r in part])),
               float(np.median([r.width for r in part])))
        if any(key[0] <= u[1] and u[0] <= key[1] and abs(key[2] - u[2]) < 0.5 * max(key[3], u[3])
               for u in used):
            continue
        radius, height, code = specs[name]
        tries[name] = tries.get(name, 0) + 1
        # Chains sharing runs propose the same placement again and again: refined once (a failure counts
        # as a try each time, as if refined again, so what is found does not change).
        same = (name, tuple((r.top, r.bot, r.left, r.right, r.synthetic) for r in part))
        if same in failed:
            continue
        ref = refine(gray, part, code, 2 * radius / (height / len(code)))
        if ref is None:
            failed.add(same)
            continue
        if camera is not None:
            # The silhouette's middle is not the axis's image: seen off to one
            # side, the near edge of a round body turns away (up to 0.3 px at
            # 1.2 m near the image's side).  From the edges' directions, the
            # axis's is their mean angle (an upright axis, as the detector
            # assumes; distortion ignored, as elsewhere here).
            ref["bands"] = [(axis_u(u, ref["radius_px"], camera), v) for u, v in ref["bands"]]
            ref["centre"] = (axis_u(ref["centre"][0], ref["radius_px"], camera), ref["centre"][1])
        used.append(key)
        info = {"code_cost": float(cost), "band_px": ref["unit_px"], "edge_rms_px": ref["edge_rms_px"]}
        result.detections[name] = Detection(name, np.array(ref["centre"]), score=1.0 - cost, info=info)
        for bname, uv in zip(band_marker_names(name, len(specs[name][2])), ref["bands"]):
            result.detections[bname] = Detection(bname, np.array(uv), score=1.0 - cost, info={"cylinder": name})
    for name, (_, _, code) in specs.items():
        if name not in result.detections:
            result.missing.append(name)
            result.missing.extend(band_marker_names(name, len(code)))
    return result
