"""Banded ("barcode") cylinder markers: band geometry and a detector.

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
   widths are chained; a contiguous sub-chain is read as a code: run lengths
   and gaps in band heights must match a marker's code (trimmed to its
   first..last dark band), and width / band height must match the cylinder's
   diameter / band height within 30 %.  One dark run may be missing (merged
   with clutter over its whole height); it is then placed from the code.
   After refinement every band's middle must read as its bit (all dark bands
   darker than all light ones), which rejects wrong codes and false chains;
   found cylinders may not overlap.
3. Sub-pixel: each dark/light boundary is located on several columns across
   the cylinder by the integral of the unmixed intensity over a window around
   it (the edge position for any symmetric blur).  Every boundary is the
   front arc of an ellipse, ``v(w) = v0 + b * sqrt(1 - (w / R)^2)``, fitted
   jointly over all boundaries (``b`` linear in the boundary index), and
   ``v0`` is the boundary circle's centre on the axis.  A 1-D projective map
   from boundary index to ``v0`` (perspective along the axis) gives the band
   centres and the cylinder centre; the across position is the fitted centre
   line of the dark bands' silhouettes.

Limits: the cylinder must look roughly upright in the image (axis within
about 20 degrees of the image's vertical; a camera rolled upside down reads
nothing), its code must have at least two dark runs or one dark run with a
known light band on each side is not enough to find it, lens distortion is
ignored (the axis is treated as straight in the image), and the camera
argument is accepted for API symmetry but not used.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..core.camera import Camera
from ..core.rig import Marker, Rig, Robot
from ..errors import RigError
from .base import Detection, DetectionResult, as_bgr

__all__ = ["BAND_SEPARATOR", "band_marker_names", "band_points", "detect_cylinders", "expand_cylinder_bands"]

BAND_SEPARATOR = "#b"


def _spec(marker: Marker) -> tuple[float, float, np.ndarray]:
    from ..sim.world import cylinder_spec

    return cylinder_spec(marker)


def band_marker_names(name: str, n: int) -> list[str]:
    """``[NAME#b0, ..., NAME#b{n-1}]``."""
    return [f"{name}{BAND_SEPARATOR}{k}" for k in range(n)]


def band_points(marker: Marker) -> tuple[list[str], np.ndarray]:
    """Names and 3-D positions (n, 3), robot frame, of the band centres on the axis.

    Same geometry as the renderer: band ``k`` of ``n`` spans the axis
    coordinate (up = robot -y) ``s`` in ``[h - 2h(k+1)/n, h - 2hk/n]`` with
    ``h`` half the height, so its centre is at robot ``y = position_y - h +
    2h(k + 0.5)/n``.
    """
    _, height, code = _spec(marker)
    n = len(code)
    ys = -0.5 * height + height * (np.arange(n) + 0.5) / n
    pts = np.repeat(marker.position[None, :], n, axis=0)
    pts[:, 1] += ys
    return band_marker_names(marker.name, n), pts


def expand_cylinder_bands(rig: Rig | Mapping[str, Any] | str) -> Rig:
    """A copy of ``rig`` where each cylinder ``NAME`` also has band markers ``NAME#bK``.

    The bands are plain point markers (extra keys ``cylinder_of: NAME`` and
    ``band: K``); the cylinder marker itself is kept.  Idempotent.
    """
    from ..api import load_rig

    rig = load_rig(rig)
    robots: dict[str, Robot] = {}
    for rname, robot in rig.robots.items():
        new: dict[str, Marker] = dict(robot.markers)
        for name, marker in robot.markers.items():
            if marker.extra.get("cylinder_of") is not None or marker.extra.get("cylinder") is None:
                continue
            names, pts = band_points(marker)
            for k, (bname, X) in enumerate(zip(names, pts)):
                if bname in new:
                    old = new[bname]
                    if old.extra.get("cylinder_of") == name and np.allclose(old.position, X, atol=1e-12):
                        continue
                    raise RigError(f"robot {rname!r}: marker {bname!r} exists, so cylinder {name!r}'s band "
                                   "markers cannot be added")
                new[bname] = Marker(name=bname, robot=rname, position=X, extra={"cylinder_of": name, "band": k})
        robots[rname] = Robot(name=rname, camera=robot.camera, markers=new)
    return Rig(robots)


# ---------------------------------------------------------------------------
# detection
# ---------------------------------------------------------------------------


@dataclass
class _Run:
    top: int  # first dark row
    bot: int  # last dark row
    left: float  # median leftmost dark column
    right: float  # median rightmost dark column
    synthetic: bool = False  # placed from the code, not seen

    @property
    def width(self) -> float:
        return self.right - self.left + 1

    @property
    def xc(self) -> float:
        return 0.5 * (self.left + self.right)


def _dark_mask(gray: np.ndarray) -> np.ndarray:
    g = gray.astype(np.float32)
    # The reference is the local *light* level (the brightest smoothed value nearby), so the
    # inside of a large dark band still reads as dark at close range.
    local = cv2.dilate(cv2.blur(g, (5, 5)), np.ones((61, 61), np.uint8))
    dark = ((g < 90) & (g < 0.6 * local)).astype(np.uint8)
    return cv2.morphologyEx(dark, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))


def _dark_runs(gray: np.ndarray) -> list[_Run]:
    """Dark rectangles: vertical stacks of per-row dark segments of consistent extent.

    Each row's dark segments are linked to the open tracks of the rows above
    whose left and right ends they repeat (within a pixel or so).  A segment
    that *contains* a track's extent (the band touching dark clutter beside it
    on those rows) bridges the track for up to a band-width of rows, provided
    clean rows of the same extent follow; a track that neither repeats nor is
    bridged ends.  So a dark band keeps its own rows whatever touches it.
    """
    dark = _dark_mask(gray)
    H, W = dark.shape
    pad = np.zeros((H, W + 2), np.int8)
    pad[:, 1:-1] = dark
    d = np.diff(pad, axis=1)
    sr, sc = np.nonzero(d == 1)
    er, ec = np.nonzero(d == -1)  # same order: row-major, paired
    seg_rows: dict[int, list[tuple[int, int]]] = {}
    for r, a, b in zip(sr.tolist(), sc.tolist(), (ec - 1).tolist()):
        segs = seg_rows.setdefault(r, [])
        # A short gap (a specular highlight down the middle of a dark band) does not split a segment.
        if segs and a - segs[-1][1] - 1 <= max(2.0, 0.35 * min(b - a + 1, segs[-1][1] - segs[-1][0] + 1)):
            segs[-1] = (segs[-1][0], b)
        else:
            segs.append((a, b))
    for r in seg_rows:
        seg_rows[r] = [(a, b) for a, b in seg_rows[r] if b - a + 1 >= 3]
    # track: [rows(list), lefts, rights, last_clean_row, last_seen_row]
    open_tracks: list[list] = []
    done: list[list] = []
    for r in range(H):
        segs = seg_rows.get(r, [])
        still: list[list] = []
        taken = [False] * len(segs)
        for tr in open_tracks:
            tl, trr = tr[1][-1], tr[2][-1]
            w = trr - tl + 1
            tol = max(1.5, 0.08 * w)
            hit = None
            for k, (a, b) in enumerate(segs):
                if not taken[k] and abs(a - tl) <= tol and abs(b - trr) <= tol:
                    hit = k
                    break
            if hit is not None:
                taken[hit] = True
                a, b = segs[hit]
                tr[0].append(r)
                tr[1].append(a)
                tr[2].append(b)
                tr[3] = tr[4] = r
                still.append(tr)
                continue
            if (r - tr[3] <= max(2, w) and
                    any(a <= tl + tol and b >= trr - tol for a, b in segs)):
                tr[4] = r
                still.append(tr)
                continue
            done.append(tr)
        for k, (a, b) in enumerate(segs):
            if not taken[k]:
                still.append([[r], [a], [b], r, r])
        open_tracks = still
    done.extend(open_tracks)
    runs: list[_Run] = []
    for rows, lefts, rights, _, _ in done:
        if len(rows) < 2 or rows[-1] - rows[0] < 1:
            continue
        runs.append(_Run(int(rows[0]), int(rows[-1]), float(np.median(lefts)), float(np.median(rights))))
    return runs


def _chains(runs: list[_Run]) -> list[list[_Run]]:
    """Maximal top-to-bottom chains of runs of similar width and centre."""
    runs = sorted(runs, key=lambda r: r.top)
    nxt: dict[int, list[int]] = {i: [] for i in range(len(runs))}
    for i, a in enumerate(runs):
        for j in range(i + 1, len(runs)):
            b = runs[j]
            wmax = max(a.width, b.width)
            if (b.top > a.bot and abs(a.xc - b.xc) < 0.25 * wmax + 1.0
                    and min(a.width, b.width) > 0.7 * wmax - 1.0 and b.top - a.bot < 6 * wmax):
                nxt[i].append(j)
    out: list[list[_Run]] = []

    def walk(path: list[int]) -> None:
        ends = nxt[path[-1]]
        if not ends or len(out) > 2000:
            out.append([runs[k] for k in path])
            return
        for j in ends:
            walk(path + [j])

    has_prev = {j for v in nxt.values() for j in v}
    for i in range(len(runs)):
        if i not in has_prev:
            walk([i])
    return out


def _code_runs(code: np.ndarray) -> tuple[int, int, list[tuple[int, int]]] | None:
    """First and last dark band and the dark runs ``(start, end_exclusive)`` of a code."""
    ones = np.nonzero(code)[0]
    if len(ones) == 0:
        return None
    runs = []
    k = ones[0]
    while k <= ones[-1]:
        if code[k]:
            s = k
            while k <= ones[-1] and code[k]:
                k += 1
            runs.append((int(s), int(k)))
        else:
            k += 1
    return int(ones[0]), int(ones[-1]) + 1, runs


def _match(chain: list[_Run], code: np.ndarray, aspect: float) -> tuple[float, list[_Run]] | None:
    """Best (cost, runs) placing the code's dark runs on a contiguous part of ``chain``.

    ``aspect`` is the cylinder's diameter over one band's height: a dark run's
    width over the band height in the image must agree with it (perspective
    changes both alike), within 30 %.  When all the code's dark runs are
    present the band height comes from the span, else from the width and
    ``aspect``: then one dark run may be missing (it touches dark clutter
    over its whole height) and is put where the code says, marked
    ``synthetic``; such a match costs 0.5 more and is only kept if
    :func:`_refine` verifies every band.
    """
    cr = _code_runs(code)
    if cr is None:
        return None
    first, last, druns = cr
    m = len(druns)
    best = None
    subsets = [list(range(m))] + ([[k for k in range(m) if k != skip] for skip in range(m)] if m >= 2 else [])
    for sub in subsets:
        full = len(sub) == m
        ms = len(sub)
        for off in range(len(chain) - ms + 1):
            part = chain[off:off + ms]
            if any(r.synthetic for r in part):
                continue
            wmed = float(np.median([r.width for r in part]))
            unit_w = wmed / aspect
            if full:
                unit = (part[-1].bot + 1 - part[0].top) / (last - first)
            else:
                unit = unit_w
            if unit < 2.0 or not 0.7 < unit / unit_w < 1.3:
                continue
            obs = [druns[k] for k in sub]
            # offset: v of code index 0 (least squares over the observed boundaries)
            o = float(np.mean([r.top - s0 * unit for (s0, _), r in zip(obs, part)]
                              + [r.bot + 1 - e0 * unit for (_, e0), r in zip(obs, part)]))
            cost = 0.0
            for (s0, e0), run in zip(obs, part):
                cost = max(cost, abs((run.top - o) / unit - s0), abs((run.bot + 1 - o) / unit - e0))
            if cost >= 0.35:
                continue
            runs, it = [], iter(part)
            left = float(np.median([r.left for r in part]))
            right = float(np.median([r.right for r in part]))
            for k, (s0, e0) in enumerate(druns):
                if k in sub:
                    runs.append(next(it))
                else:
                    runs.append(_Run(int(round(o + s0 * unit)), int(round(o + e0 * unit)) - 1, left, right,
                                     synthetic=True))
            if not full:
                cost += 0.5
            if best is None or cost < best[0]:
                best = (cost, runs)
    return best


def _edge(profile: np.ndarray, i0: int, i1: int, a: float, b: float) -> float | None:
    """Position of a step from level ``a`` to ``b`` within samples ``i0..i1`` (integral method)."""
    if abs(a - b) < 8:
        return None
    seg = profile[i0:i1 + 1]
    frac = np.clip((seg - b) / (a - b), 0.0, 1.0)
    return i0 - 0.5 + float(frac.sum())


def _refine(gray: np.ndarray, part: list[_Run], code: np.ndarray) -> dict[str, Any] | None:
    first, last, druns = _code_runs(code)  # type: ignore[misc]
    n = len(code)
    H, W = gray.shape
    span = part[-1].bot + 1 - part[0].top
    unit = span / (last - first)
    # Centre line x = cx0 + cx1 * v from the runs' row-extent midpoints (refined below).
    vs = np.array([0.5 * (r.top + r.bot) for r in part if not r.synthetic])
    xs = np.array([r.xc for r in part if not r.synthetic])
    if len(vs) >= 2 and np.ptp(vs) > 0:
        cx1, cx0 = np.polyfit(vs, xs, 1)
    else:
        cx1, cx0 = 0.0, float(xs.mean())
    R = 0.5 * float(np.median([r.width for r in part if not r.synthetic]))
    hw = int(np.clip(math.floor(0.45 * unit), 1, 4))
    g = gray.astype(np.float32)

    # Across: sub-pixel silhouette edges of the dark runs, on their middle rows.
    mids_v, mids_x = [], []
    m = max(2, int(round(0.2 * R)) + 2)
    for run in part:
        if run.synthetic:
            continue
        hh = run.bot - run.top
        for v in range(run.top + max(1, hh // 4), run.bot - max(1, hh // 4) + 1):
            xc = cx0 + cx1 * v
            x0 = int(math.floor(xc - R - m - 3))
            x1 = int(math.ceil(xc + R + m + 3))
            if x0 < 0 or x1 >= W:
                continue
            row = g[v, x0:x1 + 1]
            inner = g[v, int(round(xc - 0.4 * R)):int(round(xc + 0.4 * R)) + 1]
            if inner.size == 0:
                continue
            d = float(np.median(inner))
            li = int(round(xc - R)) - x0
            ri = int(round(xc + R)) - x0
            el = _edge(row, li - m, li + m, float(row[max(0, li - m - 2)]), d)
            er = _edge(row, ri - m, ri + m, d, float(row[min(len(row) - 1, ri + m + 2)]))
            if el is None or er is None:
                continue
            mids_v.append(v)
            mids_x.append(x0 + 0.5 * (el + er))
            # NB: el is where background turns dark; the dark region spans (el, er) -> centre.
    if len(mids_v) >= 3:
        mv, mx = np.array(mids_v, float), np.array(mids_x, float)
        if np.ptp(mv) > 0.5 * unit:
            A = np.c_[np.ones_like(mv), mv]
            sol, *_ = np.linalg.lstsq(A, mx, rcond=None)
            res = mx - A @ sol
            keep = np.abs(res) < max(0.5, 3 * np.median(np.abs(res)))
            sol, *_ = np.linalg.lstsq(A[keep], mx[keep], rcond=None)
            cx0, cx1 = float(sol[0]), float(sol[1])
        else:
            cx0, cx1 = float(np.median(mx - cx1 * mv)), cx1

    # Along: boundaries (index j, coarse v, dark above?) of each dark run.
    bounds = []
    for (s, e), run in zip(druns, part):
        bounds.append((s, run.top - 0.5, False))  # light/background above, dark below
        bounds.append((e, run.bot + 0.5, True))
    offs = np.linspace(-0.6, 0.6, 7) * R
    rows_i, rows_v, rows_sq, rows_j = [], [], [], []
    for bi, (j, v0, dark_above) in enumerate(bounds):
        for w in offs:
            # Vertical profile along the centre line shifted by w.
            vv = np.arange(int(math.floor(v0 - hw - 3 * unit)), int(math.ceil(v0 + hw + 3 * unit)) + 1)
            if vv[0] < 0 or vv[-1] >= H:
                continue
            xx = cx0 + cx1 * vv + w
            prof = cv2.remap(g, xx.astype(np.float32)[None, :], vv.astype(np.float32)[None, :],
                             cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0]
            c = int(round(v0 + 0.5)) - vv[0]  # first sample below the boundary
            i0, i1 = c - hw - 1, c + hw
            # Levels from the middle of the band (or background) on each side: a band can be
            # as short as ~4 px, so the windows must not reach the next boundary.
            lq = max(0, int(round(0.15 * unit)))
            ca = int(round(v0 - 0.5 * unit - vv[0] + 0.5))
            cb = int(round(v0 + 0.5 * unit - vv[0] + 0.5))
            above = prof[max(0, ca - lq - 1):max(0, ca + lq)]
            below = prof[cb - lq:cb + lq + 1]
            if above.size == 0 or below.size == 0:
                continue
            a, b = float(np.median(above)), float(np.median(below))
            if dark_above != (a < b):
                continue
            e = _edge(prof, i0, i1, a, b)
            if e is None:
                continue
            rows_i.append(bi)
            rows_v.append(vv[0] + e)
            rows_sq.append(math.sqrt(max(0.0, 1 - (w / R) ** 2)))
            rows_j.append(j)
    nbnd = len(bounds)
    if len(rows_i) < 2 * nbnd:
        return None
    ri = np.array(rows_i)
    present = sorted(set(rows_i))
    col = {b: k for k, b in enumerate(present)}
    A = np.zeros((len(ri), len(present) + 2))
    A[np.arange(len(ri)), [col[b] for b in ri]] = 1.0
    sq = np.array(rows_sq)
    jj = np.array(rows_j, float)
    A[:, -2] = sq
    A[:, -1] = sq * (jj - 0.5 * n) / n
    y = np.array(rows_v)
    keep = np.ones(len(y), bool)
    for _ in range(3):
        sol, *_ = np.linalg.lstsq(A[keep], y[keep], rcond=None)
        res = y - A @ sol
        s = max(0.05, 1.4826 * np.median(np.abs(res[keep])))
        keep = np.abs(res) < 3 * s
    # Each boundary's centre on the axis (sq = 1 at the silhouette centre, 0 at its rims: v0 is the
    # ellipse centre).
    jb = np.array([bounds[b][0] for b in present], float)
    vb = sol[:len(present)]
    # Boundary index j -> v along the axis.
    # (A full 1-D homography is ill-conditioned over a few bands; the perspective
    # curvature over the cylinder's length is far below the edge noise, so a line.)
    al, be = np.polyfit(jb, vb, 1)
    for _ in range(len(jb) - 3):  # drop the worst boundary while it is clearly off the line
        r = np.abs(vb - (al * jb + be))
        if r.max() < 0.4 or len(jb) <= 3:
            break
        k = int(np.argmax(r))
        jb, vb = np.delete(jb, k), np.delete(vb, k)
        al, be = np.polyfit(jb, vb, 1)
    ga = 0.0

    def v_at(j: float) -> float:
        return float((al * j + be) / (ga * j + 1.0))

    band_uv = []
    for k in range(n):
        v = v_at(k + 0.5)
        band_uv.append((cx0 + cx1 * v, v))
    # Verify the code: every band's middle must read as its bit (dark bands all darker than light ones).
    unit_v = abs(al)
    hu, hr = max(0.5, 0.25 * unit_v), max(1.0, 0.4 * R)
    levels = []
    for u, v in band_uv:
        r0, r1 = int(round(v - hu)), int(round(v + hu))
        c0, c1 = int(round(u - hr)), int(round(u + hr))
        if r0 < 0 or c0 < 0 or r1 >= H or c1 >= W:
            return None
        levels.append(float(np.median(g[r0:r1 + 1, c0:c1 + 1])))
    levels = np.array(levels)
    dk, lt = levels[code == 1], levels[code == 0]
    if lt.size and dk.size and not lt.min() - dk.max() > max(20.0, 0.3 * (np.median(lt) - np.median(dk))):
        return None
    vc = v_at(0.5 * n)
    return {"bands": band_uv, "centre": (cx0 + cx1 * vc, vc), "unit_px": unit, "radius_px": R,
            "edge_rms_px": float(np.sqrt(np.mean(res[keep] ** 2)))}


def detect_cylinders(image: Any, markers: Mapping[str, Marker] | Robot, *, camera: Camera | None = None
                     ) -> DetectionResult:
    """Find each banded-cylinder marker of ``markers`` (those with a ``cylinder`` key).

    Reports ``NAME`` (the cylinder centre) and ``NAME#bK`` (band ``K``'s centre on the
    axis) for every cylinder found; all of them go to ``missing`` for one not found.
    """
    if isinstance(markers, Robot):
        markers = markers.markers
    cyl = {n: m for n, m in markers.items() if m.extra.get("cylinder") is not None}
    specs = {n: _spec(m) for n, m in cyl.items()}
    result = DetectionResult()
    if not cyl:
        return result
    bgr = as_bgr(image)
    gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    chains = _chains(_dark_runs(gray))
    cands = []  # (cost, -length, marker, part)
    for name, (radius, height, code) in specs.items():
        aspect = 2 * radius / (height / len(code))
        for chain in chains:
            got = _match(chain, code, aspect)
            if got is not None:
                cost, part = got
                cands.append((cost, -(part[-1].bot - part[0].top), name, part))
    cands.sort(key=lambda c: (c[0], c[1]))
    used: list[tuple[int, int, float, float]] = []
    for cost, _, name, part in cands:
        if name in result.detections:
            continue
        # One cylinder per image region: no overlap with one already found (better matches first).
        key = (part[0].top, part[-1].bot, float(np.median([r.xc for r in part])),
               float(np.median([r.width for r in part])))
        if any(key[0] <= u[1] and u[0] <= key[1] and abs(key[2] - u[2]) < 0.5 * max(key[3], u[3])
               for u in used):
            continue
        ref = _refine(gray, part, specs[name][2])
        if ref is None:
            continue
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
