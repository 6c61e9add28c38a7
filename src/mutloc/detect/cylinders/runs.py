"""Stage 1-2 of the cylinder detector: dark pixels, dark runs, chains of runs
and reading a chain as a marker's code."""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass

import cv2
import numba
import numpy as np

__all__ = ["Run", "links", "stack_chains", "code_runs", "column_chains", "dark_mask", "dark_runs", "match", "placements",
           "MAX_PLACEMENTS"]

@dataclass
class Run:
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


def dark_mask(gray: np.ndarray) -> np.ndarray:
    g = gray.astype(np.float32)
    # The reference is the local *light* level (the brightest smoothed value nearby), so the
    # inside of a large dark band still reads as dark at close range.
    local = cv2.dilate(cv2.blur(g, (5, 5)), np.ones((61, 61), np.uint8))
    dark = ((g < 90) & (g < 0.6 * local)).astype(np.uint8)
    return cv2.morphologyEx(dark, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))


def dark_runs(dark: np.ndarray) -> list[Run]:
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
    runs: list[Run] = []
    for rows, lefts, rights, _, _ in done:
        if len(rows) < 2 or rows[-1] - rows[0] < 1:
            continue
        runs.append(Run(int(rows[0]), int(rows[-1]), float(np.median(lefts)), float(np.median(rights))))
    return runs


def column_chains(dark: np.ndarray, runs: list[Run], reach: float) -> list[list[Run]]:
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
    n = len(runs)
    top = np.array([r.top for r in runs], np.int64)
    bot = np.array([r.bot for r in runs], np.int64)
    par = np.zeros((n, 8), np.int64)  # valid, c0, c1, r0, r1, xl, xr, span
    for i, run in enumerate(runs):
        w = run.width
        c0 = int(math.ceil(run.left + 0.25 * w))
        c1 = int(math.floor(run.right - 0.25 * w))
        valid = w >= 5 and run.bot - run.top >= 1 and not (c1 < c0 or c0 < 0 or c1 >= W)
        par[i] = (valid, c0, c1, max(0, int(run.top - reach * w)), min(H, int(run.bot + reach * w) + 1),
                  int(round(run.left)) - 1, int(round(run.right)) + 1, int(math.ceil(2 * w)))
    idx, ext, sides = _column_kernel(np.ascontiguousarray(dark, np.uint8), top, bot, par)
    out: list[list[Run]] = []
    seen: set[tuple] = set()
    k = 0
    while k < len(idx):
        i = idx[k]
        chain = []
        while k < len(idx) and idx[k] == i:
            chain.append(Run(int(ext[k, 0]), int(ext[k, 1]), float(sides[k, 0]), float(sides[k, 1])))
            k += 1
        if len(chain) < 2:
            continue
        key = (round(runs[i].left), round(runs[i].right), tuple((r.top, r.bot) for r in chain))
        if key in seen:
            continue
        seen.add(key)
        out.append(chain)
    return out


@numba.njit(cache=True)
def _column_kernel(dark: np.ndarray, top: np.ndarray, bot: np.ndarray, par: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`column_chains`' reading, run by run (``par``: valid, c0, c1, r0, r1, xl, xr, span): the bands
    read down each run's middle columns, as (run index, (top, bot), (left, right))."""
    H, W = dark.shape
    n = len(top)
    cov = np.zeros((max(16, 4 * n), 4), np.int64)  # (top, bot, c0, c1) of bands already read
    nc = 0
    o_idx = np.zeros(cov.shape[0], np.int64)
    o_ext = np.zeros((cov.shape[0], 2), np.int64)
    o_sid = np.zeros((cov.shape[0], 2), np.float64)
    for i in range(n):
        valid, c0, c1, r0, r1, xl, xr, span = par[i]
        if not valid:
            continue
        # A run inside a band already read down a column like its own would read the same chain again.
        inside = False
        for k in range(nc):
            if cov[k, 0] <= top[i] and bot[i] <= cov[k, 1] and cov[k, 2] - 2 <= c0 and c1 <= cov[k, 3] + 2:
                inside = True
                break
        if inside:
            continue
        L = r1 - r0
        full = np.zeros(L, np.bool_)
        for rr in range(L):
            allk = True
            for cc in range(c0, c1 + 1):
                if dark[r0 + rr, cc] == 0:
                    allk = False
                    break
            full[rr] = allk
        a = 0
        while a < L:
            if not full[a]:
                a += 1
                continue
            b = a
            while b < L and full[b]:
                b += 1
            lo_a, hi_b = a, b
            a = b
            if hi_b - lo_a < 2 or lo_a == 0 or hi_b == L:
                continue  # too thin, or running out of the range: extent unknown
            nr = hi_b - lo_a
            # Beside a band, on one side at least, the silhouette's edge: not dark just outside its extent.
            free = 0.0
            if xl - 2 >= 0:
                cnt = 0
                for rr in range(r0 + lo_a, r0 + hi_b):
                    if dark[rr, xl - 2] == 0 or dark[rr, xl - 1] == 0 or dark[rr, xl] == 0:
                        cnt += 1
                free = max(free, cnt / nr)
            if xr + 2 < W:
                cnt = 0
                for rr in range(r0 + lo_a, r0 + hi_b):
                    if dark[rr, xr] == 0 or dark[rr, xr + 1] == 0 or dark[rr, xr + 2] == 0:
                        cnt += 1
                free = max(free, cnt / nr)
            if free < 0.5:
                continue
            # Its own extent: the dark segment through the middle, row by row.
            lo = max(0, c0 - span)
            hi = min(W, c1 + 1 + span)
            lefts = np.empty(nr, np.float64)
            rights = np.empty(nr, np.float64)
            for j in range(nr):
                rr = r0 + lo_a + j
                lv = lo
                for cc in range(c0 - 1, lo - 1, -1):
                    if dark[rr, cc] == 0:
                        lv = cc + 1
                        break
                rv = hi - 1
                for cc in range(c1 + 1, hi):
                    if dark[rr, cc] == 0:
                        rv = cc - 1
                        break
                lefts[j] = lv
                rights[j] = rv
            if nc == cov.shape[0]:
                cov = np.concatenate((cov, np.zeros_like(cov)))
                o_idx = np.concatenate((o_idx, np.zeros_like(o_idx)))
                o_ext = np.concatenate((o_ext, np.zeros_like(o_ext)))
                o_sid = np.concatenate((o_sid, np.zeros_like(o_sid)))
            o_idx[nc] = i
            o_ext[nc, 0] = r0 + lo_a
            o_ext[nc, 1] = r0 + hi_b - 1
            o_sid[nc, 0] = np.median(lefts)
            o_sid[nc, 1] = np.median(rights)
            cov[nc, 0] = r0 + lo_a
            cov[nc, 1] = r0 + hi_b - 1
            cov[nc, 2] = c0
            cov[nc, 3] = c1
            nc += 1
    return o_idx[:nc], o_ext[:nc], o_sid[:nc]


def links(runs: list[Run]) -> tuple[list[Run], list[list[int]]]:
    """``runs`` sorted top to bottom, and for each the runs that may come next below it in a stack: similar
    width and centre, below it, at most six widths down."""
    runs = sorted(runs, key=lambda r: r.top)
    if not runs:
        return runs, []
    top = np.array([r.top for r in runs], float)
    bot = np.array([r.bot for r in runs], float)
    wid = np.array([r.width for r in runs])
    xc = np.array([r.xc for r in runs])
    wmax = np.maximum(wid[:, None], wid[None, :])
    ok = ((top[None, :] > bot[:, None]) & (np.abs(xc[:, None] - xc[None, :]) < 0.25 * wmax + 1.0)
          & (np.minimum(wid[:, None], wid[None, :]) > 0.7 * wmax - 1.0) & (top[None, :] - bot[:, None] < 6 * wmax))
    ok &= np.triu(np.ones(ok.shape, bool), 1)  # j after i in the sorted order (as the pairwise loop took them)
    nxt: list[list[int]] = [np.flatnonzero(row).tolist() for row in ok]
    return runs, nxt


def stack_chains(runs: list[Run]) -> list[list[Run]]:
    """Maximal top-to-bottom chains of runs of similar width and centre."""
    runs, nxt = links(runs)
    out: list[list[Run]] = []

    def walk(path: list[int]) -> None:
        ends = nxt[path[-1]]
        if not ends or len(out) > 2000:
            out.append([runs[k] for k in path])
            return
        for j in ends:
            walk(path + [j])

    has_prev = {j for v in nxt for j in v}
    for i in range(len(runs)):
        if i not in has_prev:
            walk([i])
    return out


#: Placements of one code scored per image at most (:func:`placements`): a guard against pathological clutter
#: (the rectified views of a cluttered room make a few thousand).
MAX_PLACEMENTS = 200_000


def placements(runs: list[Run], chains: list[list[Run]], code: np.ndarray, aspect: float,
               linked: tuple[list[Run], list[list[int]]] | None = None) -> list[tuple[float, list[Run]]]:
    """Every placement of ``code``'s dark runs that fits (see :func:`match`), each scored once: on runs
    stacked one below the other (paths through the links :func:`stack_chains` follows -- every part of
    a chain, without walking the chains, which in clutter share their runs thousands of times over) and
    on consecutive runs of each of ``chains`` (:func:`column_chains`).  Returns ``(cost, runs)``, the
    code's missing dark run (if any) placed from the code as in :func:`match`.  ``linked``: ``links(runs)``
    if the caller has it (one per image, whatever the code).
    """
    cr = code_runs(code)
    if cr is None:
        return []
    first, last, druns = cr
    m = len(druns)
    srt, nxt = links(runs) if linked is None else linked
    subsets = [list(range(m))] + ([[k for k in range(m) if k != skip] for skip in range(m)] if m >= 2 else [])
    out: list[tuple[float, list[Run]]] = []
    scored = 0
    for sub in subsets:
        ms = len(sub)
        full = ms == m
        parts: list[list[Run]] = []
        # Paths of ms linked runs (iterative, depth-first).
        stack = [[i] for i in range(len(srt))]
        while stack and scored + len(parts) < MAX_PLACEMENTS:
            path = stack.pop()
            if len(path) == ms:
                parts.append([srt[k] for k in path])
                continue
            stack.extend(path + [j] for j in nxt[path[-1]])
        for chain in chains:
            parts.extend(chain[off:off + ms] for off in range(len(chain) - ms + 1))
        scored += len(parts)
        for part in parts:
            got = _score(part, druns, sub, full, first, last, aspect)
            if got:
                cost, o, unit = got
                out.append((cost if full else cost + 0.5, _placed(part, druns, sub, o, unit)))
    return out


def _placed(part: list[Run], druns: list[tuple[int, int]], sub: list[int], o: float, unit: float) -> list[Run]:
    """One run per dark run of the code: ``part``'s for those in ``sub``, the others placed from the code
    (offset ``o``, band height ``unit``) with ``part``'s median extent, marked ``synthetic``."""
    if len(sub) == len(druns):
        return list(part)
    runs, it = [], iter(part)
    left = statistics.median(r.left for r in part)
    right = statistics.median(r.right for r in part)
    for k, (s0, e0) in enumerate(druns):
        if k in sub:
            runs.append(next(it))
        else:
            runs.append(Run(int(round(o + s0 * unit)), int(round(o + e0 * unit)) - 1, left, right, synthetic=True))
    return runs


def code_runs(code: np.ndarray) -> tuple[int, int, list[tuple[int, int]]] | None:
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


def match(chain: list[Run], code: np.ndarray, aspect: float, memo: dict | None = None
          ) -> tuple[float, list[Run]] | None:
    """Best (cost, runs) placing the code's dark runs on a contiguous part of ``chain``.

    ``aspect`` is the cylinder's diameter over one band's height: a dark run's
    width over the band height in the image must agree with it (perspective
    changes both alike), within 30 %.  When all the code's dark runs are
    present the band height comes from the span, else from the width and
    ``aspect``: then one dark run may be missing (it touches dark clutter
    over its whole height) and is put where the code says, marked
    ``synthetic``; such a match costs 0.5 more and is only kept if
    :func:`refine` verifies every band.

    ``memo``: a dict kept by the caller across the chains of one image for
    one ``code`` and ``aspect``: a placement's score depends on the runs it
    covers only, and the chains of a cluttered image (maximal paths through
    the same runs, :func:`stack_chains`) share most of their runs, so each
    placement is scored once (a wide rectified view of a textured room makes
    thousands of chains).
    """
    cr = code_runs(code)
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
            if memo is not None:
                key = (tuple(map(id, part)), full, tuple(sub))
                hit = memo.get(key)
                if hit is None:
                    hit = memo[key] = _score(part, druns, sub, full, first, last, aspect)
                if not hit:
                    continue
                cost, o, unit = hit
            else:
                got = _score(part, druns, sub, full, first, last, aspect)
                if not got:
                    continue
                cost, o, unit = got
            if not full:
                cost += 0.5
            if best is not None and not cost < best[0]:
                continue
            best = (cost, _placed(part, druns, sub, o, unit))
    return best


def _score(part: list[Run], druns: list[tuple[int, int]], sub: list[int], full: bool, first: int, last: int,
           aspect: float) -> tuple[float, float, float] | tuple[()]:
    """(cost, offset, band height) of the code's dark runs ``sub`` placed on ``part``, or () if it does not fit
    (see :func:`match`)."""
    if any(r.synthetic for r in part):
        return ()
    # The narrowest run: dark clutter touching a band only widens it.
    unit_w = min(r.width for r in part) / aspect
    if full:
        unit = (part[-1].bot + 1 - part[0].top) / (last - first)
    else:
        unit = unit_w
    if unit < 2.0 or not 0.7 < unit / unit_w < 1.3:
        return ()
    obs = [druns[k] for k in sub]
    # offset: v of code index 0 (least squares over the observed boundaries)
    ends = ([r.top - s0 * unit for (s0, _), r in zip(obs, part)]
            + [r.bot + 1 - e0 * unit for (_, e0), r in zip(obs, part)])
    o = sum(ends) / len(ends)
    cost = 0.0
    for (s0, e0), run in zip(obs, part):
        cost = max(cost, abs((run.top - o) / unit - s0), abs((run.bot + 1 - o) / unit - e0))
    if cost >= 0.35:
        return ()
    return cost, o, unit
