"""Measurement stage of the light tracker: spots that changed, their contrast,
and the centre of a light (centroid, or the halo of a clipped light against
background plates)."""

from __future__ import annotations

import math

import cv2
import numpy as np

from .halo import CLIP_LEVEL, HALO_LEVELS, HALO_MIN_LEVEL, MAX_PLATES, SRGB_LUT, halo_kernel
from .state import Plate, Track

__all__ = ["MeasureStage", "own_colour_image"]


def own_colour_image(channels: list[np.ndarray], own: np.ndarray) -> np.ndarray:
    """An image's brightness in one colour: the least of the colour's own
    channels (``own``, a mask over ``channels``) less the largest of the
    others (a red light: red less the larger of green and blue).  Pale or
    grey things, bright in every channel, are dark in it."""
    idx, oth = np.flatnonzero(own), np.flatnonzero(~own)
    lo = channels[int(idx[0])]
    for i in idx[1:]:
        lo = cv2.min(lo, channels[int(i)])
    hi = channels[int(oth[0])]
    for i in oth[1:]:
        hi = cv2.max(hi, channels[int(i)])
    return cv2.subtract(lo, hi)

# Triples of points sampled along a plateau's outline, as fractions of its
# length (see MeasureStage._plateau_circle).
_TRIPLES = np.random.default_rng(0).random((300, 3))

# A clipped light's centroid window may take in another bright object beside
# it (3 m seed 1 of bench/blink_identity.py: a pale poster 20 px above a green
# light dragged its centroid 20 px, and the light was taken for off in two
# "on" frames and lost for 18).  When the bright patches in the window apart
# from the largest one hold more than this share of the weight, they are not
# the light's own.  Measured on that bench: at a share of 0.4 too few windows
# are cleaned (3 m seed 1 keeps 55 of 60 frames); at 0.1, or always, the
# light's own ragged fringe is cut too and 2 m seed 1 loses a frame; 0.2 and
# 0.25 lose none anywhere.
NEIGHBOUR_SHARE = 0.25

# Levels (fractions of the way from the background to the clip level) at
# which a clipped light without a halo is measured by its core's edge (see
# MeasureStage._edge_centre); EDGE_FALLBACK False: by its centroid.
EDGE_LEVELS = (0.75, 0.85, 0.95)
EDGE_FALLBACK = True

# A clipped streak leaving a glowing light's core (its reflection in a
# polished mount) glows too, and pulls the halo's contours its way (0.3 px
# down the rod, bench/bench_lights_blender.py's ``glow`` scenes): such a light
# is measured by its core's edge instead, whose rays down the streak are
# outliers.  A streak: at least STREAK_MIN_PX clipped pixels more than
# STREAK_MARGIN_PX beyond the core's radius, in one direction (the mean of
# their unit vectors at least STREAK_RESULTANT long), over a background that
# was dark while the light was off (median below STREAK_DARK_BG in linear
# light, own channel): clipping over a bright background is the glow's, which
# the halo fit is for (mutloc's renderer: 0.37-0.46 there, Blender's rods
# 0.03-0.11).
STREAK_MIN_PX = 3
STREAK_MARGIN_PX = 1.5
STREAK_RESULTANT = 0.8
STREAK_DARK_BG = 0.25


def reflection_streak(clipped: np.ndarray, plate: np.ndarray, cx: float, cy: float, r_core: float) -> bool:
    """Whether a clipped light's core has a streak of its own light (see :data:`STREAK_MIN_PX`):
    ``clipped`` the window's clipped pixels, ``plate`` its background while the light was off (linear,
    NaN where unknown), ``(cx, cy)`` the light's centre in window pixels and ``r_core`` its core's radius."""
    ys, xs = np.nonzero(clipped)
    dx, dy = xs - cx, ys - cy
    rr = np.hypot(dx, dy)
    out = rr > r_core + STREAK_MARGIN_PX
    if np.count_nonzero(out) < STREAK_MIN_PX:
        return False
    ux, uy = float(np.mean(dx[out] / rr[out])), float(np.mean(dy[out] / rr[out]))
    if math.hypot(ux, uy) < STREAK_RESULTANT:
        return False
    under = plate[ys[out], xs[out]]
    under = under[np.isfinite(under)]
    return under.size >= STREAK_MIN_PX and float(np.median(under)) < STREAK_DARK_BG


def _circle_centre(g: np.ndarray, uv: np.ndarray, x0: int, y0: int, levels: np.ndarray, step: float, rmax: float,
                   min_used: int, min_quadrants: int, max_shift: float) -> np.ndarray | None:
    """The centre (image pixels) of the circles where ``g`` (a window whose corner is ``(x0, y0)``) falls
    through ``levels`` along 64 rays from ``uv`` (:func:`~mutloc.detect.blink.halo.halo_kernel`, rays
    sampled every ``step`` px up to ``rmax``); None unless at least ``min_used`` crossings in
    ``min_quadrants`` quadrants fit and the centre is within ``max_shift`` px of ``uv``."""
    out = np.empty(5)
    if not halo_kernel(g, float(uv[0]) - x0, float(uv[1]) - y0, levels, 64, step, float(rmax), 3, out):
        return None
    if out[2] < min_used or out[3] < min_quadrants:
        return None
    found = np.array([out[0] + x0, out[1] + y0])
    if math.hypot(*(found - uv)) > max_shift:
        return None
    return found


class MeasureStage:
    """Methods of :class:`~mutloc.detect.blink.tracker.LightTracker` for this stage (it holds the state)."""

    def _blobs(self, cur: np.ndarray, prev: np.ndarray,
               exposed: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Candidate light switches: ``(centroids (n, 2), turned_on (n,), spread (n,))``."""
        # Morphological differential: blind to any motion <= motion_radius.
        turned_on = cv2.subtract(cur, cv2.dilate(prev, self._kernel))
        turned_off = cv2.subtract(prev, cv2.dilate(cur, self._kernel))
        change = cv2.max(turned_on, turned_off)
        # The border the camera motion uncovered has no previous frame.
        sx, sy = exposed
        r = self.motion_radius
        if sx > 0:
            change[:, : sx + r] = 0
        elif sx < 0:
            change[:, sx - r:] = 0
        if sy > 0:
            change[: sy + r] = 0
        elif sy < 0:
            change[sy - r:] = 0
        _, mask = cv2.threshold(change, self.diff_threshold - 1, 255, cv2.THRESH_BINARY)  # >= threshold
        pts = cv2.findNonZero(mask)
        if pts is None:
            return np.empty((0, 2)), np.empty(0, bool), np.empty(0)
        pts = pts.reshape(-1, 2)
        # Labels only (cheap); the statistics come from the sparse pixels.
        n, labels = cv2.connectedComponents(mask, connectivity=8, ltype=cv2.CV_32S)
        x, y = pts[:, 0].astype(float), pts[:, 1].astype(float)
        lab = labels[pts[:, 1], pts[:, 0]]
        area = np.bincount(lab, minlength=n).astype(float)
        area[0] = 1.0  # background label: never kept, avoid 0/0
        mx = np.bincount(lab, x, minlength=n) / area
        my = np.bincount(lab, y, minlength=n) / area
        # Spread (RMS radius, px): a light's is a few pixels; the strip swept
        # by a moving edge is long.
        var = (np.bincount(lab, x * x, minlength=n) / area - mx * mx
               + np.bincount(lab, y * y, minlength=n) / area - my * my)
        on_w = np.bincount(lab, turned_on[pts[:, 1], pts[:, 0]].astype(float), minlength=n)
        off_w = np.bincount(lab, turned_off[pts[:, 1], pts[:, 0]].astype(float), minlength=n)
        keep = (area <= self.max_blob_area) & (var <= self.max_blob_std**2)
        keep[0] = False
        idx = np.flatnonzero(keep)
        cents = np.column_stack([mx[idx], my[idx]])
        lit_now = on_w[idx] >= off_w[idx]
        spread = np.sqrt(np.maximum(var[idx], 0.0))
        # A light switching is a compact spot of change, and in the frame in
        # which it is lit a spot brighter than its surroundings.  A moving
        # edge or corner of a robot body sweeps a strip of change that
        # continues through a ring around it, and the brightness it uncovers
        # continues too.  (The ring's 80th percentile forgives a small bright
        # neighbour.)
        need = 0.5 * self.diff_threshold

        def lit_spot(c: np.ndarray, on: bool, sp: float) -> bool:
            con = self._contrast(cur if on else prev, c, sp, 80.0, margin=self._glow_px)
            if con >= need:
                return True
            if on or self.colour_contrast <= 0 or con < 0:
                # Switching on, a spot must stand out in brightness (with
                # colour as well: 3 m seed 2 of bench/blink_identity.py lost
                # 7 frames, measured).
                return False
            # A light switching off over background as bright in its own
            # colour: its colour in the previous frame (as it was, not
            # aligned: where it was then) must stand out instead.
            at = c - np.asarray(exposed, float)
            return self._colour_contrast(at, sp, self._glow_px, self._prev_colour) >= self.colour_contrast

        is_light = np.array([
            self._contrast(turned_on if on else turned_off, c, sp) >= need and lit_spot(c, on, sp)
            for c, on, sp in zip(cents, lit_now, spread)
        ], bool)
        return cents[is_light], lit_now[is_light], spread[is_light]

    def _contrast(self, img: np.ndarray, c: np.ndarray, spread: float, ring_q: float = 100.0,
                  reach: float = 2.0, margin: int = 0) -> float:
        """How far the peak near ``c`` stands above a ring around it.

        The inner square holds a light of RMS radius ``spread``; the ring
        (square, cheap) lies just outside, ``reach`` RMS radii plus ``margin``
        pixels out.  Against the ring's maximum
        (``ring_q=100``), a compact spot scores high and a strip or edge that
        continues through the ring scores low; a lower percentile forgives a
        small bright neighbour touching the ring.
        """
        r_in = int(min(max(8, 3.0 * self.max_blob_std), max(2, math.ceil(reach * spread) + 1)) + margin)
        r_out = r_in + 3
        cx, cy = round(float(c[0])), round(float(c[1]))
        h, w = img.shape
        masks = self._ring_masks.get(r_in)
        if masks is None:
            ys, xs = np.mgrid[-r_out:r_out + 1, -r_out:r_out + 1]
            d = np.maximum(np.abs(ys), np.abs(xs)).ravel()
            masks = self._ring_masks[r_in] = (np.flatnonzero(d <= r_in), np.flatnonzero(d > r_in + 1))
        if r_out <= cx < w - r_out and r_out <= cy < h - r_out:
            patch = img[cy - r_out:cy + r_out + 1, cx - r_out:cx + r_out + 1].ravel()
            inner, ring = patch[masks[0]], patch[masks[1]]
        else:  # at the image border: the part of the window inside
            x0, x1, y0, y1 = max(0, cx - r_out), min(w, cx + r_out + 1), max(0, cy - r_out), min(h, cy + r_out + 1)
            ys, xs = np.ogrid[y0 - cy:y1 - cy, x0 - cx:x1 - cx]
            d = np.maximum(np.abs(ys), np.abs(xs))
            patch = img[y0:y1, x0:x1]
            inner, ring = patch[d <= r_in], patch[d > r_in + 1]
            if inner.size == 0 or ring.size == 0:
                return 0.0
        if ring_q >= 100:
            level = float(ring.max())
        else:
            k = round(ring_q / 100.0 * (ring.size - 1))
            level = float(np.partition(ring, k)[k])
        return float(inner.max()) - level

    def _colour_contrast(self, c: np.ndarray, spread: float, margin: int = 0,
                         img: np.ndarray | None = None) -> float:
        """How far the colour of the brightest spot near ``c`` lies from the
        median colour of a ring around it (largest channel difference, grey
        levels) in ``img`` (default the current frame); 0 unless the spot has the colour of one
        of the lights (within ``colour_match``, channels scaled to a brightest
        of 1).  A lit light over background nearly as bright as it in its own
        colour stands out in the other channels."""
        img = self._colour if img is None else img
        if img is None or img.ndim < 3 or img.shape[2] < 3:
            return 0.0
        r_in = int(min(max(8, 3.0 * self.max_blob_std), max(2, math.ceil(2.0 * spread) + 1)) + margin)
        r_out = r_in + 3
        cx, cy = round(float(c[0])), round(float(c[1]))
        h, w = img.shape[:2]
        x0, x1, y0, y1 = max(0, cx - r_out), min(w, cx + r_out + 1), max(0, cy - r_out), min(h, cy + r_out + 1)
        ys, xs = np.ogrid[y0 - cy:y1 - cy, x0 - cx:x1 - cx]
        d = np.maximum(np.abs(ys), np.abs(xs))
        patch = img[y0:y1, x0:x1].astype(np.int16)
        inner, ring = patch[d <= r_in], patch[d > r_in + 1]
        if inner.size == 0 or ring.size == 0:
            return 0.0
        v = inner.max(axis=1)
        core = inner[v >= v.max() - 2]
        # The purest of the brightest pixels: a lit light's own colour (its
        # glow is mixed with the background's).
        peak = core[int(np.argmin(core.sum(axis=1)))]
        # Only a spot of one of the lights' own colours (any of them: which
        # light it is, its blink says) -- bright texture of another colour
        # than its surroundings is not a light.
        norm = peak / max(float(peak.max()), 1.0)
        if float(np.abs(self._lit_colours - norm[None, :]).max(axis=1).min()) > self.colour_match:
            return 0.0
        return float(np.abs(peak - np.median(ring, axis=0)).max())

    def _own_frames(self, img: np.ndarray) -> list[np.ndarray]:
        """The frame's brightness in each of the lights' colours
        (``_own_groups``): the least of the colour's own channels less the
        largest of the others (a red light: red less the larger of green and
        blue).  Empty for a grey image."""
        if not self._own_groups or img.ndim < 3 or img.shape[2] < 3:
            return []
        chans = cv2.split(img)
        return [own_colour_image(chans, own) for own in self._own_groups]

    def _own_colour(self, name: str | None) -> np.ndarray | None:
        """The current frame in light ``name``'s own colour
        (:meth:`_own_frames`; the tracker's own channel if it tracks one
        colour's lights); None for a white light or a grey image."""
        if self._meas is not None:
            return self._cur
        if name is None:
            return None
        g = self._own_group[self.marker_names.index(name)]
        return self._own_now[g] if g >= 0 and self._own_now else None

    def _own_colour_centre(self, name: str | None, centre: np.ndarray, reach: int,
                           spot: int) -> tuple[np.ndarray, float, float] | None:
        """Centroid, RMS radius and peak, in light ``name``'s own colour
        (:meth:`_own_colour`), of the brightest spot within ``reach`` of
        ``centre``; None if there is no such colour, no spot or the spot is
        larger than a light."""
        img = self._own_colour(name)
        if img is None:
            return None
        h, w = img.shape
        cx, cy = round(float(centre[0])), round(float(centre[1]))
        x0, x1, y0, y1 = max(0, cx - reach), min(w, cx + reach + 1), max(0, cy - reach), min(h, cy + reach + 1)
        if x0 >= x1 or y0 >= y1:
            return None
        patch = img[y0:y1, x0:x1]
        k = int(np.argmax(patch))
        py, px = divmod(k, x1 - x0)
        peak = float(patch[py, px])
        if peak < self.diff_threshold:
            return None
        found = self._centroid(img, x0 + px, y0 + py, peak, spot)
        if found is None or found[1] > self.max_blob_std:
            return None
        return found[0], found[1], peak

    def _own_colour_at(self, name: str, uv: np.ndarray) -> float:
        """The current frame's brightness in light ``name``'s own colour at
        the pixel nearest ``uv`` (0 outside the image or without a colour)."""
        img = self._own_colour(name)
        if img is None:
            return 0.0
        u, v = round(float(uv[0])), round(float(uv[1]))
        h, w = img.shape
        return float(img[v, u]) if 0 <= u < w and 0 <= v < h else 0.0

    @staticmethod
    def _halo_radius(clip_radius: float) -> int:
        """Half-size of the window over which the halo of a light whose
        clipped core has radius ``clip_radius`` (px) is measured."""
        return math.ceil(1.5 * clip_radius) + 12

    def _take_plate(self, tr: Track, frame: int) -> None:
        """Keep the neighbourhood of a dark light that clips when on: the
        background its halo will be measured against.

        A few plates are kept, with the light in different places: where the
        dark light hides the background in the newest, an older one may show
        it (a light moving by less than its halo's size per frame).
        """
        if not math.isfinite(tr.clip_radius) or self._colour is None:
            return
        # Room for the light to move over the background (motion-compensated
        # speed: the plate is aligned by the camera offset) before it is on again.
        half = self._halo_radius(tr.clip_radius) + math.ceil(6.0 + 4.0 * float(np.hypot(*tr.vel)) / self.fps)
        centre = tr.pos + self._offset
        cx, cy = round(float(centre[0])), round(float(centre[1]))
        h, w = self._colour.shape[:2]
        x0, x1, y0, y1 = max(0, cx - half), min(w, cx + half + 1), max(0, cy - half), min(h, cy + half + 1)
        if x1 - x0 < 2 or y1 - y0 < 2:
            return
        lin = SRGB_LUT[self._colour[y0:y1, x0:x1]]
        plate = Plate(lin, x0, y0, self._offset.copy(), centre.copy(), frame)
        plates = tr.plates
        # The newest plate with the light (nearly) where it is now adds
        # nothing an up-to-date one does not: replace it.
        if plates and math.hypot(*((plates[-1].light - plates[-1].offset) - (centre - self._offset))) \
                < 0.25 * tr.clip_radius + 1.0:
            plates[-1] = plate
        else:
            plates.append(plate)
        max_age = round(self.fps)
        while plates and (len(plates) > MAX_PLATES or frame - plates[0].frame > max_age):
            plates.pop(0)

    def _halo_centre(self, tr: Track, uv: np.ndarray) -> np.ndarray | None:
        """Centre of a lit light whose core is clipped, from its halo.

        A light bright enough to clip is surrounded by its glow (lens bloom),
        and where the glow adds to a bright background the image clips too:
        the clipped region reaches further out over bright background than
        over dark, so its centroid (or outline) is pulled towards the bright
        side -- by over a pixel for a light beside a poster's edge.  The glow
        itself is radially symmetric, so it is isolated by subtracting the
        background seen around the light while it was off (the track's
        plates, moved by the camera motion since; the newest that shows each
        pixel), in linear light and in the light's own colour channel (the
        one it brightens most).  Where the clipped core, the dark light in
        the plates and their edges leave it unknown, rays from the centre
        measure where the glow crosses a few levels; the crossings are fitted
        robustly by circles (with second harmonics, for the slightly
        elliptical image of a sphere) of one common centre.  None if there
        is no plate or too little fits, or if a streak of the light's own
        light leaves its core (:func:`reflection_streak`: the streak's glow
        is no circle around the light).
        """
        col = self._colour
        max_age = round(self.fps)
        plates = [p for p in tr.plates if self._frame - p.frame <= max_age]
        if not plates or col is None:
            return None
        r_core = tr.clip_radius
        rmax = self._halo_radius(r_core)
        h, w = col.shape[:2]
        cx, cy = round(float(uv[0])), round(float(uv[1]))
        x0, x1, y0, y1 = max(0, cx - rmax), min(w, cx + rmax + 1), max(0, cy - rmax), min(h, cy + rmax + 1)
        pw, ph = x1 - x0, y1 - y0
        if pw < 8 or ph < 8:
            return None
        raw = col[y0:y1, x0:x1]
        cur = SRGB_LUT[raw]
        # The dark light in a plate: a disc about as large as the clipped
        # core now (the glow widens the core, JPEG and blur narrow it a
        # little), with a margin for the smoothing below.
        r_mask = r_core + 1.5
        ys, xs = np.ogrid[0:ph, 0:pw]
        bg = np.full(cur.shape, np.nan, np.float32)
        missing = np.ones((ph, pw), bool)
        for plate in reversed(plates):  # newest first
            # Where the static scene now is: the camera moved by the change
            # of the cumulative offset since the plate was taken.
            moved = self._offset - plate.offset
            m = np.float32([[1, 0, x0 - moved[0] - plate.x0], [0, 1, y0 - moved[1] - plate.y0]])
            b = cv2.warpAffine(plate.lin, m, (pw, ph), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=(math.nan,) * 4)
            if b.ndim == 2:
                b = b[:, :, None]
            old = plate.light + moved - np.array([x0, y0])
            use = missing & ~np.isnan(b[:, :, 0]) & ((xs - old[0]) ** 2 + (ys - old[1]) ** 2 > r_mask ** 2)
            bg[use] = b[use]
            missing &= ~use
            if not missing.any():
                break
        glow = cur - bg
        c = int(np.argmax(np.nansum(glow, axis=(0, 1))))
        clipped = raw[:, :, c] >= CLIP_LEVEL
        if reflection_streak(clipped, bg[:, :, c], float(uv[0]) - x0, float(uv[1]) - y0, r_core):
            return None
        g = glow[:, :, c]
        unknown = np.isnan(g)
        g = np.where(unknown, np.float32(0.0), g)
        g = cv2.GaussianBlur(g, (5, 5), 1.0)
        unknown |= clipped
        unknown = cv2.dilate(unknown.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
        g[unknown] = np.nan
        b = bg[:, :, c]
        fin = np.isfinite(b)
        ref = float(np.median(b[fin])) if fin.any() else 0.0
        levels = np.maximum(HALO_MIN_LEVEL, max(0.1, 1.0 - ref) * np.array(HALO_LEVELS))
        return _circle_centre(g, uv, x0, y0, levels, 0.5, rmax, 16, 3, max(2.0, 0.5 * r_core))

    def _edge_centre(self, img: np.ndarray, uv: np.ndarray, clip_radius: float) -> np.ndarray | None:
        """Centre of a clipped light without a halo, from its clipped core's edge.

        A light with no glow around it (a sharp lens, a path tracer without
        bloom: :mod:`mutloc.sim.blender`) has no halo to measure
        (:meth:`_halo_centre`), and its clipped core's centroid follows any
        clipped patch joined to it: a polished mount's reflection of the
        light, a streak along the rod, dragged it 0.4-0.55 px down the rod
        (bench/bench_lights_blender.py).  The core's disc is measured by its
        edge instead: rays from ``uv`` find where the image falls through
        :data:`EDGE_LEVELS` of the way from the window's background (border
        median) to the clip level, and the crossings are fitted robustly by
        circles of one centre (:func:`~mutloc.detect.blink.halo.halo_kernel`),
        so the few rays that run down a streak are outliers.  None if too
        little fits, if the fit lacks a quadrant, or if it moves the centre
        by more than half the core's radius (or 1.5 px)."""
        if not math.isfinite(clip_radius) or clip_radius < 2.0:
            return None
        rmax = clip_radius + 5.0
        half = math.ceil(rmax) + 2
        h, w = img.shape
        cx, cy = round(float(uv[0])), round(float(uv[1]))
        x0, x1, y0, y1 = max(0, cx - half), min(w, cx + half + 1), max(0, cy - half), min(h, cy + half + 1)
        if x1 - x0 < 8 or y1 - y0 < 8:
            return None
        patch = img[y0:y1, x0:x1].astype(np.float32)
        border = np.concatenate([patch[0], patch[-1], patch[1:-1, 0], patch[1:-1, -1]])
        bg = float(np.median(border))
        if CLIP_LEVEL - bg < self.diff_threshold:
            return None
        levels = (np.array(EDGE_LEVELS) * (CLIP_LEVEL - bg)).astype(np.float64)
        return _circle_centre(patch - np.float32(bg), uv, x0, y0, levels, 0.25, rmax, 24, 4,
                              max(1.5, 0.5 * clip_radius))

    @staticmethod
    def _plateau_circle(img: np.ndarray, uv: np.ndarray, r: int) -> tuple[np.ndarray, float] | None:
        """Centre and radius of the clipped plateau around ``uv``, by a robust
        circle fit to its outline.

        Where the light's glow adds to a bright background the plateau bleeds
        outwards on that side, which drags a centroid by pixels; the outline
        on the other sides is the core's own.  The outline (less the window's
        edge) is fitted by the circle most of its points lie on (within 1 px;
        a fixed sample of triples of points proposes circles), refined by a
        least-squares fit to those points.  None if they are under 40 % of
        the outline or do not go round at least 6 of 8 octants.
        """
        h, w = img.shape
        cx, cy = round(float(uv[0])), round(float(uv[1]))
        x0, x1, y0, y1 = max(0, cx - r), min(w, cx + r + 1), max(0, cy - r), min(h, cy + r + 1)
        if x1 - x0 < 5 or y1 - y0 < 5:
            return None
        mask = (img[y0:y1, x0:x1] >= CLIP_LEVEL).view(np.uint8)
        n, labels = cv2.connectedComponents(mask, connectivity=8)
        if n < 2:
            return None
        # The plateau: the clipped component nearest the window's centre.
        lx, ly = cx - x0, cy - y0
        if labels[ly, lx]:
            lab = labels[ly, lx]
        else:
            pts = cv2.findNonZero(mask).reshape(-1, 2)
            k = int(np.argmin((pts[:, 0] - lx) ** 2 + (pts[:, 1] - ly) ** 2))
            lab = labels[pts[k, 1], pts[k, 0]]
        comp = (labels == lab).astype(np.uint8)
        contours, _ = cv2.findContours(comp, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        if not contours:
            return None
        c = max(contours, key=len).reshape(-1, 2).astype(float)
        ph, pw = comp.shape
        inner = ((c[:, 0] > 0) & (c[:, 0] < pw - 1) & (c[:, 1] > 0) & (c[:, 1] < ph - 1))
        c = c[inner]
        if len(c) < 12:
            return None
        # Circles through triples of outline points (a fixed sample: the
        # same frame measures the same); the one most points lie on wins.
        idx = (_TRIPLES * len(c)).astype(int)
        p1, p2, p3 = c[idx[:, 0]], c[idx[:, 1]], c[idx[:, 2]]
        a, b = p2 - p1, p3 - p1
        det = 2.0 * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
        ok = np.abs(det) > 1e-6
        a, b, det, p1 = a[ok], b[ok], det[ok], p1[ok]
        if not len(det):
            return None
        aa, bb = (a * a).sum(axis=1), (b * b).sum(axis=1)
        centres = p1 + np.column_stack([(b[:, 1] * aa - a[:, 1] * bb) / det, (a[:, 0] * bb - b[:, 0] * aa) / det])
        radii = np.hypot(*(centres - p1).T)
        dist = np.hypot(c[None, :, 0] - centres[:, None, 0], c[None, :, 1] - centres[:, None, 1])
        score = (np.abs(dist - radii[:, None]) <= 1.0).sum(axis=1)
        score[radii > r] = 0
        best = int(np.argmax(score))
        inl = np.abs(dist[best] - radii[best]) <= 1.0
        for _ in range(2):
            if inl.sum() < max(12, 0.4 * len(c)):
                return None
            q = c[inl]
            # Algebraic (Kasa) fit on the inliers: x^2 + y^2 = 2ax + 2by + k.
            m = np.column_stack([2 * q[:, 0], 2 * q[:, 1], np.ones(len(q))])
            sol, *_ = np.linalg.lstsq(m, (q * q).sum(axis=1), rcond=None)
            centre = sol[:2]
            rad = math.sqrt(max(sol[2] + centre @ centre, 0.0))
            inl = np.abs(np.hypot(*(c - centre).T) - rad) <= 1.0
        # The fitted points must go round the circle, not be one short arc.
        ang = np.arctan2(*(c[inl] - centre).T[::-1])
        if len(np.unique(np.floor((ang + math.pi) / (math.pi / 4)).astype(int) % 8)) < 6:
            return None
        # Boundary pixels lie half a pixel inside the plateau's edge.
        return centre + np.array([x0, y0], float), rad + 0.5

    @staticmethod
    def _spot_area(img: np.ndarray, uv: np.ndarray, peak: float, r: int) -> float:
        """Apparent area (px^2) of an unclipped lit spot: the pixels above half
        way from the window's background to the peak (a uniformly bright disc
        blurred by a symmetric spread crosses that level at its edge)."""
        h, w = img.shape
        cx, cy = round(float(uv[0])), round(float(uv[1]))
        patch = img[max(0, cy - r):min(h, cy + r + 1), max(0, cx - r):min(w, cx + r + 1)]
        if patch.shape[0] < 3 or patch.shape[1] < 3:
            return math.nan
        border = np.concatenate([patch[0], patch[-1], patch[1:-1, 0], patch[1:-1, -1]])
        bg = float(np.median(border))
        return float(np.count_nonzero(patch >= bg + 0.5 * (peak - bg)))

    def _centroid(self, img: np.ndarray, px: int, py: int, peak: float,
                  r: int) -> tuple[np.ndarray, float] | None:
        """Intensity-weighted centroid of the bright spot around pixel (px, py),
        and the spot's RMS radius (px).

        The brightest pixel of a saturated spot may sit anywhere on its
        plateau, so a window centred on it can clip the spot: if the centroid
        lands more than half a pixel away, it is measured again around itself.
        A spot that still reaches the window's edge is larger than the track
        believed (a light coming closer): the window grows until it holds it.
        """
        r_max = max(r, math.ceil(3.0 * self.max_blob_std))
        cx, cy = px, py
        out = self._centroid_at(img, cx, cy, peak, r)
        for _ in range(2):  # per frame; the track's size estimate adapts over frames
            if out is None or not out[2] or r >= r_max:
                break
            r = min(r_max, math.ceil(1.5 * r))
            cx, cy = round(float(out[0][0])), round(float(out[0][1]))
            out = self._centroid_at(img, cx, cy, peak, r)
        if out is None:
            return None
        if max(abs(out[0][0] - cx), abs(out[0][1] - cy)) > 0.5:
            again = self._centroid_at(img, round(float(out[0][0])), round(float(out[0][1])), peak, r)
            out = again if again is not None else out
        return out[0], out[1]

    @staticmethod
    def _drop_neighbours(wts: np.ndarray) -> None:
        """Zero, in place, the weights of bright patches apart from the
        spot's own (the connected patch of largest weight), when together
        they hold more than ``NEIGHBOUR_SHARE`` of the weight."""
        n, lab = cv2.connectedComponents((wts > 0).astype(np.uint8), connectivity=8)
        if n <= 2:
            return
        sums = np.bincount(lab.ravel(), weights=wts.ravel(), minlength=n)
        sums[0] = 0.0
        k = int(np.argmax(sums))
        if sums[k] < (1.0 - NEIGHBOUR_SHARE) * float(sums.sum()):
            wts[lab != k] = 0.0

    def _centroid_at(self, img: np.ndarray, px: int, py: int, peak: float,
                     r: int) -> tuple[np.ndarray, float, bool] | None:
        h, w = img.shape
        x0, x1 = max(0, px - r), min(w, px + r + 1)
        y0, y1 = max(0, py - r), min(h, py + r + 1)
        patch = img[y0:y1, x0:x1].astype(np.float32)
        if patch.shape[0] < 3 or patch.shape[1] < 3:
            return None
        # Background from the window's border: local, and robust (median) to
        # a bright neighbour touching it.
        border = np.concatenate([patch[0], patch[-1], patch[1:-1, 0], patch[1:-1, -1]])
        bg = float(np.median(border))
        # A clipped (saturated) spot: its plateau's edge is what is sharp; the
        # skirt around it is glow added to whatever background lies there,
        # which pulls the centroid towards the brighter side.
        level = self.centroid_level if peak < 250 else max(self.centroid_level, self._saturated_level)
        thr = bg + level * (peak - bg)
        wts = patch - thr
        np.maximum(wts, 0.0, out=wts)
        if peak >= CLIP_LEVEL:
            self._drop_neighbours(wts)
        s = float(wts.sum())
        if s <= 0:
            return None
        cols, rows = wts.sum(axis=0), wts.sum(axis=1)
        xs, ys = np.arange(x1 - x0, dtype=np.float64), np.arange(y1 - y0, dtype=np.float64)
        mu, mv = float(cols @ xs) / s, float(rows @ ys) / s
        var = float(cols @ (xs - mu) ** 2) / s + float(rows @ (ys - mv) ** 2) / s
        # Clipped by the window (not by the image border) -- unless most of
        # the border is above the threshold: a bright area, not a spot.
        clipped = bool((cols[0] > 0 and x0 > 0) or (cols[-1] > 0 and x1 < w)
                       or (rows[0] > 0 and y0 > 0) or (rows[-1] > 0 and y1 < h))
        clipped = clipped and 2 * int(np.count_nonzero(border > thr)) < border.size
        return np.array([x0 + mu, y0 + mv]), math.sqrt(max(var, 0.0)), clipped

    # -------------------------------------------------------------- identity

