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

import math
import statistics
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

# The values in which edges are located: encoded grey levels raised to 1.7,
# part way to linear light (as the ball detector's, see _MIX_GAMMA there).
# Pixel area and blur mix *light*: in encoded values a dark band's edges
# sit ~0.2 px inside it (the bands read thinner, the code's pitch shorter);
# JPEG's chroma subsampling, on the other hand, mixes encoded values.
_EDGE_LUT = ((np.arange(256) / 255.0) ** 1.7 * 255.0).astype(np.float32)


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


def _dark_runs(dark: np.ndarray) -> list[_Run]:
    """Dark rectangles: vertical stacks of per-row dark segments of consistent extent.

    Each row's dark segments are linked to the open tracks of the rows above
    whose left and right ends they repeat (within a pixel or so).  A segment
    that *contains* a track's extent (the band touching dark clutter beside it
    on those rows) bridges the track for up to a band-width of rows, provided
    clean rows of the same extent follow; a track that neither repeats nor is
    bridged ends.  So a dark band keeps its own rows whatever touches it.
    """
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


def _column_chains(dark: np.ndarray, runs: list[_Run], reach: float) -> list[list[_Run]]:
    """Chains read down the middle of each run's column.

    A dark band touching dark clutter beside it over its whole height (a
    poster's dark shape, text) never forms a run of its own width: its rows'
    dark segments are wider.  But nothing can be *inside* a cylinder's
    silhouette, so the middle of the columns of any clean run of the cylinder
    shows its bands alone: rows whose middle half is all dark are the dark
    bands, whatever touches them at the sides.  ``reach`` is how far above
    and below a run to look, in run widths (the longest code over the
    widest aspect).  Each run proposes one chain, of runs with its extent.
    """
    H, W = dark.shape
    out: list[list[_Run]] = []
    seen: set[tuple] = set()
    covered: list[tuple[int, int, int, int]] = []  # (top, bot, c0, c1) of bands already read
    for run in runs:
        w = run.width
        if w < 5 or run.bot - run.top < 1:
            continue
        c0 = int(math.ceil(run.left + 0.25 * w))
        c1 = int(math.floor(run.right - 0.25 * w))
        if c1 < c0 or c0 < 0 or c1 >= W:
            continue
        # A run inside a band already read down a column like its own would
        # read the same chain again.
        if any(t <= run.top and run.bot <= b and a0 - 2 <= c0 and c1 <= a1 + 2 for t, b, a0, a1 in covered):
            continue
        r0 = max(0, int(run.top - reach * w))
        r1 = min(H, int(run.bot + reach * w) + 1)
        full = dark[r0:r1, c0:c1 + 1].min(axis=1) > 0
        edges = np.diff(np.concatenate([[0], full.view(np.int8), [0]]))
        starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
        # Beside a band, on one side at least, the silhouette's edge: not dark
        # just outside its extent (a wide dark area is not a band).
        xl = int(round(run.left)) - 1
        xr = int(round(run.right)) + 1
        span = int(math.ceil(2 * w))  # how far out a band's own extent is looked for
        chain = []
        for a, b in zip(starts.tolist(), ends.tolist()):
            if b - a < 2 or a == 0 or b == r1 - r0:
                continue  # too thin, or running out of the range: extent unknown
            rows = slice(r0 + a, r0 + b)
            free = 0.0
            if xl - 2 >= 0:
                free = max(free, float(np.mean(dark[rows, xl - 2:xl + 1].min(axis=1) == 0)))
            if xr + 2 < W:
                free = max(free, float(np.mean(dark[rows, xr:xr + 3].min(axis=1) == 0)))
            if free < 0.5:
                continue
            # Its own extent: the dark segment through the middle, row by row
            # (clutter beside the band widens only some rows, or one side).
            lo = max(0, c0 - span)
            left_part = dark[rows, lo:c0][:, ::-1] == 0  # outward from the middle
            hit = left_part.any(axis=1)
            lefts = np.where(hit, c0 - np.argmax(left_part, axis=1), lo)
            hi = min(W, c1 + 1 + span)
            right_part = dark[rows, c1 + 1:hi] == 0
            hit = right_part.any(axis=1)
            rights = np.where(hit, c1 + np.argmax(right_part, axis=1), hi - 1)
            chain.append(_Run(r0 + a, r0 + b - 1, float(np.median(lefts)), float(np.median(rights))))
            covered.append((r0 + a, r0 + b - 1, c0, c1))
        if len(chain) < 2:
            continue
        key = (round(run.left), round(run.right), tuple((r.top, r.bot) for r in chain))
        if key in seen:
            continue
        seen.add(key)
        out.append(chain)
    return out


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
            # The narrowest run: dark clutter touching a band only widens it.
            unit_w = min(r.width for r in part) / aspect
            if full:
                unit = (part[-1].bot + 1 - part[0].top) / (last - first)
            else:
                unit = unit_w
            if unit < 2.0 or not 0.7 < unit / unit_w < 1.3:
                continue
            obs = [druns[k] for k in sub]
            # offset: v of code index 0 (least squares over the observed boundaries)
            ends = ([r.top - s0 * unit for (s0, _), r in zip(obs, part)]
                    + [r.bot + 1 - e0 * unit for (_, e0), r in zip(obs, part)])
            o = sum(ends) / len(ends)
            cost = 0.0
            for (s0, e0), run in zip(obs, part):
                cost = max(cost, abs((run.top - o) / unit - s0), abs((run.bot + 1 - o) / unit - e0))
            if cost >= 0.35:
                continue
            runs, it = [], iter(part)
            left = statistics.median(r.left for r in part)
            right = statistics.median(r.right for r in part)
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


def _across(g: np.ndarray, rows: list[int], cx0: float, cx1: float, R: float, prior: float = 0.0
            ) -> tuple[float, float, float, set[int]] | None:
    """The silhouette's centre line ``x = cx0 + cx1 v`` and half-width from
    both edges on ``rows`` (of dark bands: their shading is too dark to bend
    the edge profile).

    Each edge is located by the integral method between the levels just
    outside and just inside it; the left and right edges are fitted robustly
    as two parallel lines ``R`` either side of the centre line, so dark
    clutter touching a band on one side (or an edge of the background close
    by) costs only that side's rows.  ``(cx0, cx1, R)`` is the starting
    guess, ``R`` from the band height and the cylinder's proportions; the
    line starts where most edges put it.  ``prior``: how many edges' worth
    the guessed ``R`` counts.  Returns the line, the half-width and the rows
    with an edge on the fitted lines; None if too few edges agree.
    """
    H, W = g.shape
    m = 2 + int(round(0.1 * R))
    for it in range(2):
        vs, xs, right = [], [], []
        for v in rows:
            xc = cx0 + cx1 * v
            for sgn in (-1, 1):
                xe = xc + sgn * R
                i0, i1 = int(math.floor(xe - m)), int(math.ceil(xe + m))
                lo, hi = i0 - 4, i1 + 4
                if lo < 0 or hi >= W or v < 0 or v >= H:
                    continue
                row = g[v, lo:hi + 1]
                # The steepest step the right way round (light outside, dark
                # inside) in the window, then the integral method over a few
                # pixels about it, between the levels just beyond: another
                # edge of the background a few pixels out stays out of it.
                d = np.diff(row[i0 - lo:i1 - lo + 2]) * sgn
                k = int(np.argmax(d))
                if d[k] <= 0:
                    continue
                c = i0 - lo + k  # the step is between samples c and c + 1
                a0, a1 = c - 2, c + 3
                before, after = float(row[a0 - 1]), float(row[a1 + 1])
                if (sgn < 0) != (before > after):
                    continue
                e = _edge(row, a0, a1, before, after)
                if e is None:
                    continue
                vs.append(v)
                xs.append(lo + e)
                right.append(sgn > 0)
        if len(vs) < 6 or all(right) or not any(right):
            return None
        rt = np.array(right)
        va = np.array(vs, float)
        y = np.array(xs)
        # Unknowns: centre line (cx0, cx1) and half-width R.
        side = np.where(rt, 1.0, -1.0)
        A = np.column_stack([np.ones_like(va), va, side])
        if it == 0:
            # Start where most edges put the centre line (each edge, moved by
            # the half-width, is a vote).
            cx0 = float(np.median(y - side * R - cx1 * va))
        res = y - A @ np.array([cx0, cx1, R])
        wts = np.ones(len(y))
        R0 = R
        for _ in range(6):
            scale = max(0.1, 1.4826 * float(np.median(np.abs(res[wts > 0]))))
            u = res / (4.685 * scale)
            wts = np.where(np.abs(u) < 1, (1 - u * u) ** 2, 0.0)
            if np.count_nonzero((wts > 0) & rt) < 2 or np.count_nonzero((wts > 0) & ~rt) < 2:
                return None
            sw = np.sqrt(wts)
            Aw, yw = A * sw[:, None], y * sw
            if prior > 0:
                # The half-width the band pitch gives, worth ``prior`` edges.
                k = math.sqrt(prior)
                Aw = np.vstack([Aw, [0.0, 0.0, k]])
                yw = np.append(yw, k * R0)
            sol, *_ = np.linalg.lstsq(Aw, yw, rcond=None)
            res = y - A @ sol
        cx0, cx1, R = float(sol[0]), float(sol[1]), float(sol[2])
        if R <= 1.0:
            return None
    return cx0, cx1, R, set(va[wts > 0].astype(int).tolist())


def _along(jj: np.ndarray, sq: np.ndarray, ww: np.ndarray, y: np.ndarray, n: int
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Robust fit of the band boundaries' edges ``y`` (boundary index ``jj``,
    ``sq = sqrt(1 - (w / R)^2)`` and ``ww = w / R`` at the profile's offset
    ``w``): ``v = al j + be + b_j sq + t_j ww``, see :func:`_refine`.

    Starts from the line through the boundaries' median edges that most of
    them agree with; a boundary with little support (its edges are mostly
    someone else's: a poster's edge beside the cylinder's end) is dropped
    and the rest fitted again.  Returns (solution, inliers, residuals).
    """
    use = np.ones(len(y), bool)
    jn = (jj - 0.5 * n) / n
    for _ in range(3):
        js = sorted(set(jj[use].tolist()))
        if len(js) < 2:
            return None
        if len(js) >= 3:
            A = np.column_stack([jj, np.ones_like(jj), sq, sq * jn, ww, ww * jn])
        else:
            A = np.column_stack([jj, np.ones_like(jj), sq, ww])
        # Start: of the lines through two boundaries' median edges, the one
        # the most boundaries are close to.
        med = {j: float(np.median(y[use & (jj == j)])) for j in js}
        best = None
        for a in range(len(js)):
            for b in range(a + 1, len(js)):
                al = (med[js[b]] - med[js[a]]) / (js[b] - js[a])
                be = med[js[a]] - al * js[a]
                cost = float(np.median([abs(med[j] - al * j - be) for j in js]))
                if best is None or cost < best[0]:
                    best = (cost, al, be)
        res = y - (best[1] * jj + best[2])
        wts = use.astype(float)
        for _ in range(8):
            act = wts > 0
            scale = max(0.05, 1.4826 * float(np.median(np.abs(res[act] - np.median(res[act])))))
            u = (res - np.median(res[act])) / (4.685 * scale)
            wts = np.where(use & (np.abs(u) < 1), (1 - u * u) ** 2, 0.0)
            if np.count_nonzero(wts) < 6:
                return None
            sw = np.sqrt(wts)
            sol, *_ = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)
            res = y - A @ sol
        keep = wts > 0
        weak = [j for j in js
                if np.count_nonzero(keep & (jj == j)) < max(3, 0.4 * np.count_nonzero(use & (jj == j)))]
        if not weak:
            return sol, keep, res
        use &= ~np.isin(jj, weak)
    return None


def _start_line(runs: list[_Run], R: float, unit: float) -> tuple[float, float]:
    """Starting centre line ``x = cx0 + cx1 v``: each side of each dark run
    seen, moved in by the half-width ``R``, votes for a centre; a side
    touching clutter votes wide of the others."""
    votes = np.array([r.left - 0.5 + R for r in runs] + [r.right + 0.5 - R for r in runs])
    vv = np.array([0.5 * (r.top + r.bot) for r in runs] * 2)
    support = [np.count_nonzero(np.abs(votes - x) <= 1.5) for x in votes]
    near = np.abs(votes - votes[int(np.argmax(support))]) <= 1.5
    if np.ptp(vv[near]) > 2 * unit and np.count_nonzero(near) >= 3:
        cx1, cx0 = np.polyfit(vv[near], votes[near], 1)
        return float(cx0), float(cx1)
    return float(np.median(votes[near])), 0.0


def _boundary_edges(g: np.ndarray, bounds: list[tuple[int, float, bool]], cx0: float, cx1: float, R: float,
                    unit: float, n: int) -> tuple[list[float], ...]:
    """Sub-pixel edges of the band boundaries ``(index j, coarse v, dark
    above?)`` on vertical profiles across the cylinder, at offsets ``w`` from
    its centre line: lists of v, sqrt(1 - (w / R)^2), w / R, j and the
    step's contrast."""
    H, W = g.shape
    hw = int(np.clip(math.floor(0.45 * unit), 1, 4))
    offs = np.linspace(-1.0, 1.0, 9) * max(0.5 * R, min(0.85 * R, R - 2.0))
    rows_v, rows_sq, rows_w, rows_j, rows_c = [], [], [], [], []
    for j, v0, dark_above in bounds:
        for w in offs:
            # Vertical profile along the centre line shifted by w.
            vv = np.arange(int(math.floor(v0 - hw - 3 * unit)), int(math.ceil(v0 + hw + 3 * unit)) + 1)
            if vv[0] < 0 or vv[-1] >= H:
                continue
            xx = cx0 + cx1 * vv + w
            if xx.min() < 0 or xx.max() > W - 1:
                continue
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
            a, b = statistics.median(above.tolist()), statistics.median(below.tolist())
            if j in (0, n):
                # An end of the cylinder, against the background: the
                # steepest step the right way round, integrated over a few
                # pixels about it, with the background level just beyond (an
                # edge of the background a few pixels off stays out of it).
                d = np.diff(prof[i0:i1 + 2]) * (1.0 if dark_above else -1.0)
                k = int(np.argmax(d))
                cs = i0 + k  # the step is between samples cs and cs + 1
                lo_, hi_ = cs - 2, cs + 3
                if d[k] <= 0 or lo_ < 1 or hi_ + 1 >= len(prof):
                    continue
                if j == 0:
                    a = float(prof[lo_ - 1])
                else:
                    b = float(prof[hi_ + 1])
                i0, i1 = lo_, hi_
            if dark_above != (a < b):
                continue
            e = _edge(prof, i0, i1, a, b)
            if e is None:
                continue
            rows_v.append(vv[0] + e)
            rows_sq.append(math.sqrt(max(0.0, 1 - (w / R) ** 2)))
            rows_w.append(w / R)
            rows_j.append(j)
            rows_c.append(abs(a - b))
    return rows_v, rows_sq, rows_w, rows_j, rows_c


def _refine(gray: np.ndarray, part: list[_Run], code: np.ndarray, aspect: float) -> dict[str, Any] | None:
    """Sub-pixel band centres of a cylinder whose dark runs (top to bottom,
    one per dark run of ``code``) are ``part``; ``aspect`` is its diameter
    over a band's height.  None if the image does not bear the code out.

    Two rounds of: the centre line from the silhouette's edges
    (:func:`_across`), then the band boundaries along it (:func:`_along`);
    the second round starts from the first's band pitch and boundaries
    (the runs' ends may be off where clutter touches a band's end).
    """
    first, last, druns = _code_runs(code)  # type: ignore[misc]
    n = len(code)
    H, W = gray.shape
    unit = (part[-1].bot + 1 - part[0].top) / (last - first)
    o = part[0].top - first * unit  # v of the code's top
    g = _EDGE_LUT[gray]
    seen = [r for r in part if not r.synthetic]
    # Boundaries (index j, coarse v, dark above?) of each dark run.
    bounds = []
    for (s, e), run in zip(druns, part):
        bounds.append((s, run.top - 0.5, False))  # light/background above, dark below
        bounds.append((e, run.bot + 0.5, True))
    for rnd in range(2):
        R = 0.5 * aspect * unit
        cx0, cx1 = _start_line(seen, R, unit)
        # Across: the silhouette's edges on the dark bands' rows (away from their ends).
        rows = []
        for k in np.nonzero(code)[0]:
            a, b = o + k * unit, o + (k + 1) * unit
            rows.extend(range(int(math.ceil(a + 0.25 * unit)), int(math.floor(b - 0.25 * unit)) + 1))
        # The second round knows the half-width from the band pitch.
        got = _across(g, rows, cx0, cx1, R, prior=10.0 if rnd else 0.0)
        edge_rows: set[int] = set()
        if got is not None:
            cx0, cx1, R, edge_rows = got
        rows_v, rows_sq, rows_w, rows_j, rows_c = _boundary_edges(g, bounds, cx0, cx1, R, unit, n)
        if len(rows_v) < 2 * len(bounds):
            return None
        # A boundary with the background (the code's ends) is only as good as
        # the background: where that is dark too, the step found is some other
        # edge (a dark poster's), so it must show about the contrast of the
        # cylinder's own dark/light boundaries.
        jj = np.array(rows_j, float)
        con = np.array(rows_c)
        use = np.ones(len(jj), bool)
        inner = (jj > 0) & (jj < n)
        if inner.any():
            use = inner | (con >= 0.5 * float(np.median(con[inner])))
        # Every boundary is a circle about the axis, seen as the front arc of an
        # ellipse: v = v0_j + b_j sqrt(1 - (w / R)^2) + t_j w, with v0_j (the
        # circle's centre), b_j (how much of the circle's top or underside shows)
        # and t_j (the ellipse's tilt, off the image centre) all linear in the
        # boundary index j -- the axis is straight and, across the cylinder's
        # length, so is the view of it.  All edges are fitted at once, robustly:
        # over the offsets used, sqrt(1 - (w / R)^2) varies too little for one
        # boundary alone to tell its v0 from its b.
        fit = _along(jj[use], np.array(rows_sq)[use], np.array(rows_w)[use], np.array(rows_v)[use], n)
        if fit is None:
            return None
        sol, keep, res = fit
        al, be = float(sol[0]), float(sol[1])
        # The cylinder's own dark/light boundaries (not its ends, which may
        # be against dark background) can only be hidden by something in
        # front of it: each must be there.
        found_j = set(jj[use][keep].tolist())
        if any(0 < j < n and j not in found_j for j, _, _ in bounds):
            return None
        # The band pitch must agree with the silhouette's width and the
        # cylinder's proportions (perspective scales both alike).
        if not 0.85 < al * aspect / (2.0 * R) < 1.2:
            return None
        # Second round: boundaries where the fit puts them.
        unit, o = al, be
        bounds = [(j, be + al * j, above) for j, _, above in bounds]
    # A dark run placed from the code (never seen as a run: it touches dark
    # clutter) must show the silhouette's edge, on one side at least, on a
    # good part of its rows: a false chain (a dark poster over a dark
    # skirting board) has no such edges where the code wants a dark band.
    for (s0, e0), run in zip(druns, part):
        band_rows = [v for v in rows if o + s0 * unit <= v <= o + e0 * unit]
        if run.synthetic and sum(v in edge_rows for v in band_rows) < max(1.0, 0.3 * len(band_rows)):
            return None
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
        levels.append(float(np.median(gray[r0:r1 + 1, c0:c1 + 1])))
    levels = np.array(levels)
    dk, lt = levels[code == 1], levels[code == 0]
    if lt.size and dk.size and not lt.min() - dk.max() > max(20.0, 0.3 * (np.median(lt) - np.median(dk))):
        return None
    vc = v_at(0.5 * n)
    return {"bands": band_uv, "centre": (cx0 + cx1 * vc, vc), "unit_px": al, "radius_px": R,
            "edge_rms_px": float(np.sqrt(np.mean(res[keep] ** 2)))}


def _axis_u(u: float, R: float, camera: Camera) -> float:
    """Column of an upright axis whose silhouette is centred at column ``u``
    with half-width ``R`` (px): the mean of the edges' angles, not of their
    columns."""
    fx, cx = float(camera.K[0, 0]), float(camera.K[0, 2])
    m = u - cx
    return cx + fx * math.tan(0.5 * (math.atan((m + R) / fx) + math.atan((m - R) / fx)))


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
    dark = _dark_mask(gray)
    runs = _dark_runs(dark)
    # How far a cylinder's code reaches from one of its dark runs, in run widths.
    reach = max(len(code) * (height / len(code)) / (2 * radius) for radius, height, code in specs.values())
    chains = _chains(runs) + _column_chains(dark, runs, reach)
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
        radius, height, code = specs[name]
        ref = _refine(gray, part, code, 2 * radius / (height / len(code)))
        if ref is None:
            continue
        if camera is not None:
            # The silhouette's middle is not the axis's image: seen off to one
            # side, the near edge of a round body turns away (up to 0.3 px at
            # 1.2 m near the image's side).  From the edges' directions, the
            # axis's is their mean angle (an upright axis, as the detector
            # assumes; distortion ignored, as elsewhere here).
            ref["bands"] = [(_axis_u(u, ref["radius_px"], camera), v) for u, v in ref["bands"]]
            ref["centre"] = (_axis_u(ref["centre"][0], ref["radius_px"], camera), ref["centre"][1])
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
