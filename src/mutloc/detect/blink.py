"""Blinking-light markers, found and told apart over a video stream.

The paper (Section IV) detects its blinking lights with "a simple thresholding
strategy on the time differential of images ... coupled with decaying
confidence tracking".  :class:`BlinkTracker` does that and adds identity:

1. **Time differential.**  Each frame is reduced to one brightness channel
   (the HSV value ``max(B, G, R)`` by default, so a saturated red LED is as
   bright as a white one).  The camera's own motion (shake, or the observing
   robot turning) is estimated as a global image translation
   (:class:`GlobalMotion`: coarse-to-fine Lucas-Kanade on a small pyramid) and
   the previous frame is shifted to match.  The comparison is then
   *morphological*: a pixel counts as "turned on" only if it is brighter than
   every pixel of the previous frame within ``motion_radius`` pixels
   (symmetrically for "turned off"), so residual motion of static things up
   to that much produces no differential at all -- neither a static bright
   lamp nor a high-contrast edge of the background fires.  Pixels whose change
   exceeds ``diff_threshold`` form regions; a region is a candidate light
   switch only if it is compact and stands out of a ring around it, both in
   the differential and in the frame in which it is lit (the strip swept by
   the edge of a moving robot body continues through the ring).
2. **Decaying-confidence tracking.**  Candidates are associated with tracks by
   distance to each track's predicted position (global nearest neighbour,
   gated; the gate widens the longer a light has been off).  A track's
   confidence is boosted in every frame with a supporting candidate and
   multiplied by ``decay`` in frames without, so it survives the frames in
   which its light does not change (a light only produces a differential when
   it switches); tracks falling below ``min_confidence`` are dropped.  In
   every frame each track samples the peak brightness near its prediction,
   decides from two learned levels (on / off) whether its light is on, and,
   when it is, re-measures the light's sub-pixel centre as the
   intensity-weighted centroid of the bright spot (a spot claimed by two
   tracks goes to the one that predicted it best).  A light bright enough to
   clip is measured by its glow instead: the clipped core spreads further
   over bright background than over dark, which biases its centroid (by over
   a pixel beside a poster's edge), while the glow is radially symmetric.
   The background is taken from frames in which the light was off (a few
   "plates" per track), subtracted, and circles are fitted to where the glow
   crosses a few levels (:meth:`BlinkTracker._halo_centre`).  Positions are kept in
   camera-motion-compensated coordinates, where robots move smoothly: the
   prediction is a quadratic fitted to the last ``fit_window_s`` of "on"
   centres.
3. **Identity from frequency.**  Each track keeps the last ``window_s``
   seconds of its peak brightness.  For every marker's ``blink_hz`` the history
   is fitted (least squares, DC + cosine + sine at that frequency: the
   Goertzel/DFT bin when the window holds whole periods) and scored by the
   fraction of the signal's variance the fit explains.  A light blinking at
   that frequency scores about 0.8 (a 50 % square wave has 81 % of its power in
   the fundamental); clutter flickering at another frequency, noise, or a
   light at another marker's frequency score near zero.  The score must also
   be a local maximum in frequency (above the score half a resolution bin
   either side), which rejects flicker between the markers' frequencies; the
   track must have seen about as many switches as the frequency implies, and
   must not have been dark for longer than the light ever is.  Tracks are
   assigned to markers by the Hungarian method on the scores (one track per
   marker), with a small bonus that keeps an established identity.

Positions follow the SPEC: ``(u, v)`` with ``(0, 0)`` the centre of the
top-left pixel, raw (distorted) pixels.  A marker's reported position is the
centroid from its light's most recent "on" frame, predicted to the current
frame (the current centroid when the light is on now); ``info["on"]`` says
which.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import cv2
import numba
import numpy as np
from scipy.optimize import linear_sum_assignment

from ..core.refine import solve_spd
from ..core.rig import Marker
from ..errors import InputError
from .base import Detection, DetectionResult, as_bgr

__all__ = ["BlinkTracker", "GlobalMotion"]

# Cost of forbidden pairs in the Hungarian problem (far above any real cost).
_FORBIDDEN = 1e6

# sRGB-encoded uint8 -> linear light.
_SRGB_LUT = np.array(
    [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in np.arange(256) / 255.0],
    dtype=np.float32,
)
# A pixel at or above this (uint8) is taken as clipped.
_CLIP_LEVEL = 250
# Levels of the halo contours, as fractions of the headroom above the
# background (see BlinkTracker._halo_centre), and the lowest level in linear
# light (well above the noise of a difference of two frames).
_HALO_LEVELS = (0.1, 0.2, 0.35, 0.5, 0.7)
_HALO_MIN_LEVEL = 0.04
# Background plates kept per light.
_MAX_PLATES = 4


@numba.njit(cache=True)
def _halo_kernel(h, cx, cy, levels, nray, step, rmax, iters, out):
    """Centre of the circular contours of a radially symmetric halo.

    ``h`` (float32, NaN where unknown: clipped, masked or outside) is the
    light's own contribution in linear light, decreasing away from its centre.
    Rays from ``(cx, cy)`` (array coordinates) are sampled bilinearly every
    ``step`` px out to ``rmax``; past the first unknown stretch (the clipped
    core) each ray's crossing of each level is interpolated.  Crossings are
    fitted robustly (Tukey IRLS) with ``r = rho_level + dx cos a + dy sin a
    + second harmonics`` (an ellipse's contours have those), and the centre
    is moved by ``(dx, dy)``; ``iters`` rounds of rays.

    ``out``: centre x, y, inlier crossings, quadrants (of 4) holding inliers,
    robust residual scale (px).  Returns False when there is too little to fit.
    """
    hh, ww = h.shape
    nl = levels.shape[0]
    ns = int(rmax / step) + 1
    buf = np.empty(ns)
    npar = nl + 4
    maxc = nray * nl
    rows_l = np.empty(maxc, np.int64)
    rows_a = np.empty(maxc)
    rr = np.empty(maxc)
    wts = np.empty(maxc)
    res = np.empty(maxc)
    ata = np.empty((npar, npar))
    atb = np.empty(npar)
    sol = np.zeros(npar)
    row = np.empty(npar)
    x = cx
    y = cy
    n = 0
    scale = 0.0
    for it in range(iters):
        # --- crossings ---
        n = 0
        for i in range(nray):
            a = 2.0 * math.pi * i / nray
            ca = math.cos(a)
            sa = math.sin(a)
            for j in range(ns):
                px = x + ca * j * step
                py = y + sa * j * step
                if px < 0.0 or py < 0.0 or px > ww - 1.0 or py > hh - 1.0:
                    buf[j] = np.nan
                    continue
                x0 = min(int(px), ww - 2)
                y0 = min(int(py), hh - 2)
                fx = px - x0
                fy = py - y0
                buf[j] = ((1.0 - fx) * (1.0 - fy) * h[y0, x0] + fx * (1.0 - fy) * h[y0, x0 + 1]
                          + (1.0 - fx) * fy * h[y0 + 1, x0] + fx * fy * h[y0 + 1, x0 + 1])
            j0 = 0
            while j0 < ns and not math.isfinite(buf[j0]):
                j0 += 1
            if j0 >= ns:
                continue
            for lv in range(nl):
                t = levels[lv]
                if not buf[j0] > t:
                    continue  # the crossing is hidden in the clipped core
                for j in range(j0 + 1, ns):
                    v = buf[j]
                    if not math.isfinite(v):
                        break  # unknown before crossing: no measurement
                    if v <= t:
                        u = buf[j - 1]
                        rr[n] = step * (j - 1 + (u - t) / (u - v))
                        rows_l[n] = lv
                        rows_a[n] = a
                        n += 1
                        break
        if n < 12:
            return False
        # --- robust fit ---
        for k in range(n):
            wts[k] = 1.0
        for rnd in range(8):
            for p in range(npar):
                atb[p] = 0.0
                for q in range(npar):
                    ata[p, q] = 0.0
            for k in range(n):
                wk = wts[k]
                if wk <= 0.0:
                    continue
                for p in range(npar):
                    row[p] = 0.0
                row[rows_l[k]] = 1.0
                a = rows_a[k]
                row[nl] = math.cos(a)
                row[nl + 1] = math.sin(a)
                row[nl + 2] = math.cos(2.0 * a)
                row[nl + 3] = math.sin(2.0 * a)
                for p in range(npar):
                    if row[p] == 0.0:
                        continue
                    atb[p] += wk * row[p] * rr[k]
                    for q in range(npar):
                        ata[p, q] += wk * row[p] * row[q]
            for p in range(npar):
                ata[p, p] += 1e-9
            if not solve_spd(ata, atb, sol):  # normal equations: SPD
                return False
            for k in range(n):
                a = rows_a[k]
                res[k] = abs(rr[k] - sol[rows_l[k]] - sol[nl] * math.cos(a) - sol[nl + 1] * math.sin(a)
                             - sol[nl + 2] * math.cos(2.0 * a) - sol[nl + 3] * math.sin(2.0 * a))
            scale = max(0.1, 1.4826 * np.median(res[:n]))
            c = 4.685 * scale
            for k in range(n):
                u = res[k] / c
                wts[k] = (1.0 - u * u) ** 2 if u < 1.0 else 0.0
        x += sol[nl]
        y += sol[nl + 1]
        if abs(sol[nl]) < 0.01 and abs(sol[nl + 1]) < 0.01:
            break
    inl = 0
    quad = np.zeros(4, np.int64)
    for k in range(n):
        if wts[k] > 0.0:
            inl += 1
            quad[int(rows_a[k] / (0.5 * math.pi)) % 4] = 1
    out[0] = x
    out[1] = y
    out[2] = inl
    out[3] = quad.sum()
    out[4] = scale
    return True


class GlobalMotion:
    """Frame-to-frame image translation, by coarse-to-fine Lucas-Kanade.

    Works on a small Gaussian pyramid (levels ``levels``; level 2 is a quarter
    of the size), so it costs about a millisecond at 960x540 and follows
    shifts of a few tens of pixels per frame.  Residuals are clipped, and
    once nearly aligned large ones are ignored, so moving robots and blinking
    lights (a few percent of the image) barely pull on it; a scene without
    texture gives no reliable estimate and zero is returned.  ``update(frame)`` returns ``d`` such that what was at
    pixel ``x`` in the previous frame is at ``x + d`` now.
    """

    def __init__(self, levels: tuple[int, ...] = (4, 3, 2), iterations: int = 3, max_shift: float = 60.0,
                 clip: float = 25.0) -> None:
        self.levels = tuple(sorted(levels, reverse=True))  # coarse to fine
        self.iterations = int(iterations)
        self.max_shift = float(max_shift)
        self.clip = float(clip)
        self.reset()

    def reset(self) -> None:
        self._templates: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]] = {}
        self._last = np.zeros(2)

    def _pyramid(self, img: np.ndarray) -> dict[int, np.ndarray]:
        out: dict[int, np.ndarray] = {}
        level_img = img
        for lev in range(1, max(self.levels) + 1):
            level_img = cv2.pyrDown(level_img)
            if lev in self.levels:
                out[lev] = level_img.astype(np.float32)
        return out

    def _template(self, img: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None,
                                                 np.ndarray]:
        """Image, its gradients (interior), the inverse of J^T J (None if
        textureless) and J^T J per pixel."""
        m = 3  # the warped image's border is unreliable
        gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3, scale=1 / 8)[m:-m, m:-m]
        gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3, scale=1 / 8)[m:-m, m:-m]
        a = np.array([[float(np.vdot(gx, gx)), float(np.vdot(gx, gy))],
                      [float(np.vdot(gx, gy)), float(np.vdot(gy, gy))]])
        n = gx.size
        # Require some texture in both directions (mean squared gradient of
        # at least ~0.5 grey level per pixel along the weaker one).
        hinv = np.linalg.inv(a) if n and np.linalg.eigvalsh(a)[0] > 0.25 * n else None
        return img, gx, gy, hinv, a / max(n, 1)

    def _residual(self, cur: np.ndarray, tmpl: np.ndarray, d: np.ndarray) -> np.ndarray:
        """``cur(x + d) - tmpl(x)`` on the interior."""
        h, w = cur.shape
        m = np.float32([[1, 0, d[0]], [0, 1, d[1]]])
        warped = cv2.warpAffine(cur, m, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                borderMode=cv2.BORDER_REPLICATE)
        return cv2.subtract(warped, tmpl)[3:-3, 3:-3]

    def _cost(self, r: np.ndarray) -> float:
        """Robust (truncated quadratic) alignment cost."""
        return float(np.mean(np.minimum(r * r, self.clip * self.clip)))

    def update(self, frame: np.ndarray) -> np.ndarray:
        """Shift (px, full resolution) from the previous frame to ``frame``."""
        # Levels too small to hold texture are skipped (small images).
        pyr = {lev: im for lev, im in self._pyramid(frame).items() if min(im.shape) >= 24}
        if not pyr:
            return np.zeros(2)
        levels = sorted(pyr, reverse=True)
        templates = self._templates
        self._templates = {lev: self._template(im) for lev, im in pyr.items()}
        if set(templates) != set(pyr) or any(templates[lev][0].shape != pyr[lev].shape for lev in pyr):
            self._last = np.zeros(2)
            return self._last.copy()
        d = self._last / (2 ** levels[0])  # warm start: camera motion is smooth
        prev_level = levels[0]
        ok = True
        for lev in levels:
            d = d * (2 ** (prev_level - lev))
            prev_level = lev
            tmpl, gx, gy, hinv, _ = templates[lev]
            if hinv is None:
                ok = False
                break
            finest = lev == levels[-1]
            for it in range(self.iterations):
                r = self._residual(pyr[lev], tmpl, d)
                if finest and it > 0:
                    # Redescending weights once nearly aligned: what changed
                    # for real (a light switching, a robot moving) keeps large
                    # residuals and gets no say.
                    r[np.abs(r) > self.clip] = 0.0
                else:
                    # Far from aligned most residuals are large; clipping
                    # bounds the outliers' pull without silencing the rest.
                    np.clip(r, -self.clip, self.clip, out=r)
                step = -hinv @ np.array([float(np.vdot(gx, r)), float(np.vdot(gy, r))])
                d = d + step
                if not np.all(np.isfinite(d)) or np.hypot(*d) * 2**lev > self.max_shift:
                    ok = False
                    break
                if np.hypot(*step) < 0.01:
                    break
            if not ok:
                break
        if ok and np.hypot(*d) * 2**prev_level > 0.1:
            # Accept a shift only if aligning explains the change: it halves
            # the mismatch, or (small shifts, where the mismatch is mostly
            # noise) reduces it by at least half what the texture predicts
            # (d^T H d per pixel).  In a scene without texture the only
            # structure is the blinking lights, and their switching must not
            # be taken for camera motion.
            tmpl, cur, h_px = templates[prev_level][0], pyr[prev_level], templates[prev_level][4]
            c0 = self._cost(self._residual(cur, tmpl, np.zeros(2)))
            c1 = self._cost(self._residual(cur, tmpl, d))
            ok = c1 <= 0.5 * c0 or c0 - c1 >= 0.5 * float(d @ h_px @ d)
        self._last = d * (2 ** prev_level) if ok else np.zeros(2)
        return self._last.copy()


@dataclass
class _Plate:
    """The neighbourhood of a light while it was off: the background its halo
    is measured against when it is on (see BlinkTracker._halo_centre)."""

    lin: np.ndarray  # float32 (h, w, channels), linear light
    x0: int  # image column of lin[:, 0] then
    y0: int  # image row of lin[0] then
    offset: np.ndarray  # the tracker's cumulative camera offset then
    light: np.ndarray  # where the dark light was (image coordinates then)
    frame: int


@dataclass
class _Track:
    """One candidate light.  Positions are motion-compensated ("stabilised")
    pixel coordinates: image ``uv = pos + offset`` with the tracker's current
    cumulative camera offset."""

    id: int
    pos: np.ndarray  # best estimate in the current frame
    conf: float
    born_frame: int
    born_t: float
    hist: deque  # peak brightness near the light, one sample per frame
    events: deque  # per frame: did the differential see this light switch?
    samples: deque  # (t, pos) of recent "on" centres, for the motion model
    vel: np.ndarray = field(default_factory=lambda: np.zeros(2))  # px / s
    acc: np.ndarray = field(default_factory=lambda: np.zeros(2))  # px / s^2
    hi: float = math.nan  # learned peak brightness when on
    lo: float = math.nan  # learned peak brightness when off
    is_on: bool = False
    last_on_pos: np.ndarray | None = None
    last_on_t: float = math.nan
    last_on_frame: int = -1
    last_polarity_on: bool = True
    spread: float = 1.5  # RMS radius of the light's region of change (px): its size
    jump: float = math.inf  # distance from prediction to this frame's measurement (px)
    marker: str | None = None
    score: float = 0.0
    scores: dict[str, float] = field(default_factory=dict)
    measured_spread: float = 1.5  # RMS radius of the spot found this frame (px)
    dark: bool = False  # this frame: clearly off (a background plate may be taken)
    clip_radius: float = math.nan  # radius (px) of the clipped core when last on
    plates: list[_Plate] = field(default_factory=list)  # oldest first

    def predict(self, t: float, horizon: float) -> np.ndarray:
        """Position at time ``t`` from the motion model (stabilised coordinates)."""
        if self.last_on_pos is None:
            return self.pos
        dt = min(t - self.last_on_t, horizon)  # never extrapolate a curve far
        return self.last_on_pos + self.vel * dt + 0.5 * self.acc * dt * dt

    def last_seen_frame(self) -> int:
        return self.last_on_frame if self.last_on_frame >= 0 else self.born_frame


class BlinkTracker:
    """Streaming detector of blinking-light markers, told apart by ``blink_hz``.

    Call :meth:`update` once per frame; it returns a
    :class:`~mutloc.detect.base.DetectionResult` with a detection for every
    marker confidently tracked and identified, and the others in ``missing``.

    Parameters
    ----------
    markers:
        The markers to look for, ``{name: Marker}`` (e.g. ``rig.robot("q").markers``:
        what one camera can see).  Markers without ``blink_hz`` are ignored; at
        least one must have it, and no two may blink at frequencies the window
        cannot resolve.
    fps:
        Nominal frame rate; frame ``k`` is at ``k / fps`` seconds unless
        :meth:`update` is given the time.  Every ``blink_hz`` must be below
        ``fps / 2`` (Nyquist).
    diff_threshold:
        Minimum brightness change (0-255) between consecutive frames that
        counts as a light switching.
    decay:
        Factor applied to a track's confidence in each frame without support.
    boost:
        Added to a track's confidence (capped at 1) in each frame with support;
        also a new track's confidence.
    min_confidence:
        Tracks below it are dropped.  Default: low enough that a track survives
        1.5 half-periods of the slowest marker without support (a light only
        produces a differential when it switches).
    window_s:
        Length of the brightness history used to estimate frequency.  Default:
        long enough to resolve the two closest marker frequencies
        (``1 / spacing``) and to hold two periods of the slowest, at least 1 s,
        at most 10 s.
    min_history_s:
        History a track needs before it may be given an identity (default:
        0.7 ``window_s``).
    min_score:
        Minimum fraction of a track's brightness variance explained at a
        marker's frequency for the track to be that marker.
    stabilize:
        Estimate and compensate the camera's global image translation.
    motion_radius:
        Residual image motion (px per frame) of static things that must not
        register as a light switching.
    search_radius:
        Half-size of the window, around a track's prediction, searched for its
        light's peak.
    spot_radius:
        Half-size of the window, around the peak, over which the centroid is
        computed (must hold the light's bright spot).
    centroid_level:
        Pixels weigh in the centroid by how much they exceed
        ``background + centroid_level * (peak - background)``; the threshold
        keeps textured background out of it.
    gate_px, gate_growth, max_speed, max_gate_px:
        A candidate may join a track, and a bright spot found near it counts
        as its light, only within ``gate_px + growth * seconds_since_last_on``
        pixels of its prediction (capped at ``max_gate_px``), where the growth
        (px/s) is ``gate_growth`` plus a tenth of the light's image speed, or
        ``max_speed`` (the fastest image motion of a light assumed, px/s)
        while a track has no motion model yet.
    fit_window_s:
        "On" centres of the last this many seconds feed the motion model.
    max_blob_area, max_blob_std:
        Larger changed regions (a light switched in the room, a passing
        object), or more spread out ones (RMS radius in px), are not lights.
    max_tracks:
        Cap on simultaneous tracks (identified, then confident ones kept).
    brightness:
        ``"max"`` (HSV value; coloured LEDs) or ``"gray"`` (luma).
    """

    def __init__(
        self,
        markers: Mapping[str, Marker],
        fps: float,
        *,
        diff_threshold: int = 40,
        decay: float = 0.8,
        boost: float = 0.5,
        min_confidence: float | None = None,
        window_s: float | None = None,
        min_history_s: float | None = None,
        min_score: float = 0.45,
        stabilize: bool = True,
        motion_radius: int = 2,
        search_radius: int = 6,
        spot_radius: int = 5,
        centroid_level: float = 0.3,
        gate_px: float = 6.0,
        gate_growth: float = 30.0,
        max_speed: float | None = None,
        max_gate_px: float = 40.0,
        fit_window_s: float = 0.4,
        max_blob_area: int | None = None,
        max_blob_std: float | None = None,
        max_tracks: int = 64,
        brightness: str = "max",
    ) -> None:
        try:
            fps = float(fps)
        except (TypeError, ValueError):
            raise InputError(f"BlinkTracker: fps must be a number, got {fps!r}") from None
        if not math.isfinite(fps) or fps <= 0:
            raise InputError(f"BlinkTracker: fps must be positive and finite, got {fps}")
        if not isinstance(markers, Mapping):
            raise InputError("BlinkTracker: markers must be a mapping {name: Marker}")
        self.fps = fps
        names: list[str] = []
        freqs: list[float] = []
        for name, m in markers.items():
            hz = getattr(m, "blink_hz", None)
            if hz is None:
                continue  # a tag or a ball on the same robot: not ours to find
            try:
                hz = float(hz)
            except (TypeError, ValueError):
                raise InputError(f"marker {name!r}: blink_hz must be a number, got {hz!r}") from None
            if not math.isfinite(hz) or hz <= 0:
                raise InputError(f"marker {name!r}: blink_hz must be positive, got {hz}")
            if hz >= fps / 2:
                raise InputError(
                    f"marker {name!r}: blink_hz {hz:g} is not below half the frame rate ({fps / 2:g} Hz)"
                )
            names.append(str(name))
            freqs.append(hz)
        if not names:
            raise InputError("BlinkTracker: no marker has a blink_hz")
        self.marker_names = names
        self.freqs = np.array(freqs)

        order = np.argsort(self.freqs)
        sorted_f = self.freqs[order]
        gaps = np.diff(sorted_f)
        spacing = float(gaps.min()) if len(gaps) else math.inf
        if window_s is None:
            window_s = min(10.0, max(1.0, 2.0 / sorted_f[0], 1.0 / spacing if spacing > 0 else math.inf))
        window_s = float(window_s)
        if not (math.isfinite(window_s) and window_s > 0):
            raise InputError(f"BlinkTracker: window_s must be positive, got {window_s}")
        # Frequencies closer than one resolution bin (1 / window) look alike.
        if spacing * window_s < 0.999:
            i = int(np.argmin(gaps))
            a, b = names[int(order[i])], names[int(order[i + 1])]
            raise InputError(
                f"markers {a!r} and {b!r} blink at {sorted_f[i]:g} and {sorted_f[i + 1]:g} Hz: "
                f"a {window_s:g} s window cannot tell them apart (pass only the markers this "
                "camera can see, or a longer window_s)"
            )
        self.window_s = window_s
        self.window = max(4, round(window_s * fps))
        mh = 0.7 * window_s if min_history_s is None else float(min_history_s)
        self.min_history = int(min(self.window, max(4, round(mh * fps))))

        def number(name: str, value: Any, lo: float, hi: float, lo_open: bool = True) -> float:
            try:
                v = float(value)
            except (TypeError, ValueError):
                raise InputError(f"BlinkTracker: {name} must be a number, got {value!r}") from None
            if not (lo < v if lo_open else lo <= v) or not v <= hi:
                raise InputError(f"BlinkTracker: {name} must be in {'(' if lo_open else '['}{lo:g}, {hi:g}], got {v:g}")
            return v

        decay = number("decay", decay, 0.0, 0.999)
        boost = number("boost", boost, 0.0, 1.0)
        self.diff_threshold = int(number("diff_threshold", diff_threshold, 1, 254, lo_open=False))
        min_score = number("min_score", min_score, 0.0, 1.0, lo_open=False)
        for name, value in (("search_radius", search_radius), ("spot_radius", spot_radius),
                            ("gate_px", gate_px), ("max_gate_px", max_gate_px),
                            ("fit_window_s", fit_window_s)):
            number(name, value, 0.0, math.inf)
        for name, value in (("max_blob_std", max_blob_std), ("max_blob_area", max_blob_area)):
            if value is not None:
                number(name, value, 0.0, math.inf)
        for name, value in (("motion_radius", motion_radius), ("gate_growth", gate_growth),
                            ("centroid_level", centroid_level)):
            number(name, value, 0.0, math.inf, lo_open=False)
        if max_speed is not None:
            number("max_speed", max_speed, 0.0, math.inf, lo_open=False)
        if brightness not in ("max", "gray"):
            raise InputError(f"BlinkTracker: brightness must be 'max' or 'gray', got {brightness!r}")
        self.decay = float(decay)
        self.boost = float(boost)
        # Frames a track must outlive without support: 1.5 half-periods of
        # the slowest light (it switches only twice a period), plus margin.
        self.keep_frames = math.ceil(1.5 * fps / (2.0 * sorted_f[0])) + 2
        # Per marker: a light blinking at f is never dark for longer than
        # half a period; a track dark for much longer is not that light.
        self._marker_dark_frames = np.ceil(1.5 * fps / (2.0 * self.freqs)).astype(int) + 2
        if min_confidence is None:
            min_confidence = self.boost * self.decay**self.keep_frames
        self.min_confidence = float(min_confidence)
        self.min_score = float(min_score)
        self.stabilize = bool(stabilize)
        self.motion_radius = int(motion_radius)
        self.search_radius = int(search_radius)
        self.spot_radius = int(spot_radius)
        self.centroid_level = float(centroid_level)
        self.gate_px = float(gate_px)
        self.gate_growth = float(gate_growth)
        # Limits in pixels that depend on the image size (None: derived from
        # it at the first frame, see _set_scale).
        self._max_speed_arg = None if max_speed is None else float(max_speed)
        self._max_gate_arg = float(max_gate_px)
        self._max_blob_area_arg = None if max_blob_area is None else int(max_blob_area)
        self._max_blob_std_arg = None if max_blob_std is None else float(max_blob_std)
        self.fit_window_s = float(fit_window_s)
        self._set_scale(540)
        self.max_tracks = int(max_tracks)
        self.brightness = brightness
        k = 2 * self.motion_radius + 1
        self._kernel = np.ones((k, k), np.uint8)
        # Half a resolution bin either side of each marker frequency: the
        # local-maximum test that rejects flicker at in-between frequencies.
        self._delta_hz = 0.5 / window_s
        # Identity bonus for keeping the current assignment (hysteresis).
        self._sticky = 0.15
        # The motion model extrapolates at most this far (longest off period
        # a track survives).
        self._horizon = self.keep_frames / fps
        self._basis_cache: dict[bytes, np.ndarray] = {}
        self._ring_masks: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        # A lit light's glow (bloom, a few px) raises its surroundings; on a
        # bright background a saturated light stands out of them only beyond
        # it, so brightness contrast is measured this much further out.
        self._glow_px = 5
        # Centroid level for a clipped (saturated) spot, see _centroid_at.
        self._saturated_level = 0.75
        self._motion = GlobalMotion()
        self.reset()

    # ------------------------------------------------------------------ state

    def reset(self) -> None:
        """Forget every track and the previous frame (e.g. after a cut)."""
        self._prev: np.ndarray | None = None
        self._colour: np.ndarray | None = None  # the current frame, (H, W, channels) uint8
        self._prev_t = math.nan
        self._frame = 0
        self._times: deque[float] = deque(maxlen=self.window)
        self._tracks: list[_Track] = []
        self._next_id = 0
        self._offset = np.zeros(2)  # cumulative camera shift: image = stabilised + offset
        self.last_shift = np.zeros(2)  # camera shift estimated at the last frame (px)
        self._motion.reset()

    def track_states(self) -> list[dict[str, Any]]:
        """A snapshot of the current tracks in image coordinates (debugging, display)."""
        return [{
            "id": tr.id, "uv": (tr.pos + self._offset).tolist(), "velocity_px_s": tr.vel.tolist(),
            "confidence": tr.conf, "on": tr.is_on, "marker": tr.marker,
            "scores": dict(tr.scores), "history": len(tr.hist),
        } for tr in self._tracks]

    def _set_scale(self, short_side: int) -> None:
        """Pixel limits for images whose shorter side is ``short_side`` px.

        How large a light looks and how fast it moves in the image grow with
        the resolution (and as the light comes closer), so the limits not
        given explicitly are relative: an RMS radius of up to 3 % of the
        image's shorter side for a light's region of change, image speeds
        up to 60 % of it per second.
        """
        scale = max(1.0, short_side / 540.0)
        self.max_speed = (0.6 * short_side if self._max_speed_arg is None else self._max_speed_arg)
        self.max_gate_px = self._max_gate_arg * scale
        self.max_blob_std = (max(6.0, 0.03 * short_side) if self._max_blob_std_arg is None
                             else self._max_blob_std_arg)
        self.max_blob_area = (max(900, round(4 * math.pi * self.max_blob_std**2))
                              if self._max_blob_area_arg is None else self._max_blob_area_arg)

    def _reach(self, spread: float) -> int:
        """Half-size of the window searched for the peak of a light of RMS
        radius ``spread``: a large saturated spot's peak may be anywhere on it."""
        return max(self.search_radius, math.ceil(1.5 * spread))

    def _spot(self, spread: float) -> int:
        """Half-size of the centroid window: must hold the whole spot."""
        return max(self.spot_radius, math.ceil(2.0 * spread) + 2)

    # ----------------------------------------------------------------- frames

    def _to_brightness(self, image: Any) -> tuple[np.ndarray, np.ndarray]:
        """The brightness channel, and the image as (H, W, channels) uint8
        (BGR, or the grey image itself) for measuring lit lights."""
        if isinstance(image, np.ndarray) and image.ndim == 2 and image.dtype == np.uint8:
            if image.shape[0] < 2 or image.shape[1] < 2:
                raise InputError(f"BlinkTracker.update: image too small, shape {image.shape}")
            cur = np.ascontiguousarray(image)
            return cur, cur[:, :, None]
        bgr = as_bgr(image, "BlinkTracker.update image")
        if self.brightness == "gray":
            return cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY), bgr
        return cv2.max(cv2.max(bgr[:, :, 0], bgr[:, :, 1]), bgr[:, :, 2]), bgr

    def update(self, image: Any, t: float | None = None) -> DetectionResult:
        """Process the next frame; return the markers seen in it.

        ``image``: uint8 BGR ``(H, W, 3)`` or grayscale ``(H, W)`` (other dtypes
        as :func:`~mutloc.detect.base.as_bgr` accepts).  ``t``: its time in
        seconds, strictly increasing; default ``frame_index / fps``.
        """
        cur, self._colour = self._to_brightness(image)
        if t is None:
            t = self._frame / self.fps
        else:
            try:
                t = float(t)
            except (TypeError, ValueError):
                raise InputError(f"BlinkTracker.update: t must be a number, got {t!r}") from None
            if not math.isfinite(t):
                raise InputError(f"BlinkTracker.update: t must be finite, got {t}")
        prev = self._prev
        if prev is not None:
            if cur.shape != prev.shape:
                raise InputError(
                    f"BlinkTracker.update: image size changed from {prev.shape[::-1]} to "
                    f"{cur.shape[::-1]} (call reset() between streams)"
                )
            if not t > self._prev_t:
                raise InputError(f"BlinkTracker.update: time {t} does not increase (previous {self._prev_t})")
        if prev is None:
            self._set_scale(min(cur.shape))
        shift = self._motion.update(cur) if self.stabilize else np.zeros(2)
        self._times.append(t)
        if prev is not None:
            self.last_shift = shift
            self._offset = self._offset + shift
            self._step(cur, prev, t, shift)
        self._prev = cur
        self._prev_t = t
        result = self._report(t, cur.shape)
        self._frame += 1
        return result

    # ------------------------------------------------------------- internals

    def _align(self, prev: np.ndarray, shift: np.ndarray) -> tuple[np.ndarray, tuple[int, int]]:
        """The previous frame moved by the camera shift (rounded to whole pixels;
        the morphological differential absorbs the rest)."""
        sx, sy = round(float(shift[0])), round(float(shift[1]))
        if sx == 0 and sy == 0:
            return prev, (0, 0)
        h, w = prev.shape
        m = np.float32([[1, 0, sx], [0, 1, sy]])
        moved = cv2.warpAffine(prev, m, (w, h), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        return moved, (sx, sy)

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
        is_light = np.array([
            self._contrast(turned_on if on else turned_off, c, sp) >= need
            and self._contrast(cur if on else prev, c, sp, 80.0, margin=self._glow_px) >= need
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

    def _step(self, cur: np.ndarray, prev_raw: np.ndarray, t: float, shift: np.ndarray) -> None:
        frame = self._frame
        prev, exposed = self._align(prev_raw, shift)
        cents, lit_now, spread = self._blobs(cur, prev, exposed)
        tracks = self._tracks
        off = self._offset
        for tr in tracks:
            tr.pos = tr.predict(t, self._horizon)

        # --- candidates -> tracks (global nearest neighbour, gated) ---
        # Pairs are taken in order of distance, each candidate and each track
        # at most once: a candidate becomes its track's primary candidate.
        # A candidate right at a track that is already served (the second
        # crescent of a light moving while on, a ragged region split in two)
        # supports that track instead of being handed to some other, distant
        # one; the rest start tracks.  (A global optimum -- Hungarian -- would
        # trade one light's own switch for a far-fetched pair elsewhere.)
        nb, nt = len(cents), len(tracks)
        primary: dict[int, int] = {}
        supported = np.zeros(nt, bool)
        newborn = np.ones(nb, bool)
        if nb and nt:
            pred = np.array([tr.pos for tr in tracks]) + off
            dist = np.linalg.norm(cents[:, None, :] - pred[None, :, :], axis=2)
            gates = np.array([self._gate(tr, t) for tr in tracks])
            # An identified track is known to be a light; an unidentified one
            # may be a stray, so it must be clearly closer to win a candidate.
            penalty = np.array([0.0 if tr.marker is not None else self.gate_px for tr in tracks])
            cost = dist + penalty[None, :]
            nearest = np.argmin(cost, axis=1)
            reach = np.array([self._reach(tr.spread) for tr in tracks], float)
            absorb = dist[np.arange(nb), nearest] <= reach[nearest] + 3.0
            rows, cols = np.nonzero(dist <= gates[None, :])
            taken = np.zeros(nt, bool)
            for k in np.argsort(cost[rows, cols], kind="stable"):
                r, c = int(rows[k]), int(cols[k])
                if not newborn[r] or taken[c]:
                    continue
                if c != nearest[r] and absorb[r]:
                    supported[nearest[r]] = True
                    newborn[r] = False
                    continue
                primary[c] = r
                taken[c] = supported[c] = True
                newborn[r] = False
            for r in np.flatnonzero(newborn & absorb):
                supported[nearest[r]] = True
                newborn[r] = False

        # --- observe every track in this frame ---
        observed: list[tuple[float, int, np.ndarray]] = []  # (jump, index, uv)
        for j, tr in enumerate(tracks):
            centre = tr.pos + off
            event = None
            recentred = False
            if j in primary:
                event = bool(lit_now[primary[j]])
                if event:
                    # Just switched on: the region locates the light better
                    # than a prediction made across the off period.
                    centre = cents[primary[j]]
                    recentred = True
                    tr.spread += 0.3 * (spread[primary[j]] - tr.spread)
            uv = self._observe(tr, cur, prev, centre, event)
            tr.conf = min(1.0, tr.conf + self.boost) if supported[j] else tr.conf * self.decay
            tr.events.append(bool(supported[j]))
            if uv is None:
                continue
            jump = math.hypot(*(uv - off - tr.pos)) if tr.last_on_pos is not None else math.inf
            if not recentred and jump != math.inf and jump > self._gate(tr, t):
                # Bright, but too far from where this light can be: another
                # light passing by, not this one.
                self._not_on(tr)
                continue
            observed.append((jump, j, uv))

        # --- unexplained candidates -> new tracks (nearby ones merged) ---
        born: list[np.ndarray] = []
        for r in np.flatnonzero(newborn):
            c = cents[r]
            if any(math.hypot(*(c - b)) <= self._reach(spread[r]) for b in born):
                continue
            born.append(c)
            tr = _Track(id=self._next_id, pos=c - off, conf=self.boost, born_frame=frame, born_t=t,
                        spread=float(spread[r]),
                        hist=deque(maxlen=self.window), samples=deque(),
                        events=deque([True], maxlen=self.window),
                        last_polarity_on=bool(lit_now[r]))
            self._next_id += 1
            tracks.append(tr)
            uv = self._observe(tr, cur, prev, c, bool(lit_now[r]), backfill=True)
            if uv is not None:
                observed.append((math.inf, len(tracks) - 1, uv))

        # --- one light, one track: when two tracks found the same spot (two
        # lights crossing, a duplicate track), it belongs to the one that
        # predicted it best -- an identified track first, as in the
        # association; the other's light is taken to be off.  Between
        # unidentified tracks that both predicted it well (within a few px)
        # the older wins: a stray track born beside a light must not take
        # over the light's history by a fraction of a pixel. ---
        def claim_order(o: tuple[float, int, np.ndarray]) -> tuple[float, int]:
            tr = tracks[o[1]]
            if tr.marker is not None:
                return o[0], tr.born_frame
            return self.gate_px + max(o[0], 3.0), tr.born_frame

        observed.sort(key=claim_order)
        claimed: list[np.ndarray] = []
        for jump, j, uv in observed:
            tr = tracks[j]
            if any(math.hypot(*(uv - u)) < 1.5 for u in claimed):
                self._not_on(tr)
                continue
            claimed.append(uv)
            self._commit(tr, uv, jump, t, frame)

        # --- background plates of lights that are off now ---
        for tr in tracks:
            if tr.dark and not tr.is_on:
                self._take_plate(tr, frame)

        # --- drop weak, lost and duplicate tracks ---
        h, w = cur.shape
        tracks = [tr for tr in tracks
                  if tr.conf >= self.min_confidence
                  and self._inside(tr.pos + off, (h, w))
                  # Not seen on for long: the light is gone, whatever stray
                  # support the track still gets.
                  and frame - tr.last_seen_frame() <= 2 * self.keep_frames]
        # An unidentified track at the very place of another is a duplicate
        # (born from a stray candidate near a tracked light): drop it.  Keep
        # identified tracks, then those following a light (their prediction
        # was right), then the older.  Two identified tracks are two lights,
        # however close (crossing robots).
        tracks.sort(key=lambda tr: (tr.marker is None, tr.jump > 3.0, tr.born_frame))
        kept: list[_Track] = []
        for tr in tracks:
            if tr.marker is not None or all(math.hypot(*(tr.pos - k.pos)) > 1.0 for k in kept):
                kept.append(tr)
        if len(kept) > self.max_tracks:
            kept.sort(key=lambda tr: (tr.marker is None, -tr.conf))
            kept = kept[: self.max_tracks]
        self._tracks = kept
        self._identify()

    def _gate(self, tr: _Track, t: float) -> float:
        """How far from its prediction a track's light may be at time ``t`` (px)."""
        # Until a track has a motion model its light may be moving at any
        # plausible speed; after that only the model's error grows -- with
        # time, not frames, and faster for a faster light.
        if len(tr.samples) >= 2:
            growth = self.gate_growth + 0.1 * float(np.hypot(*tr.vel))
        else:
            growth = self.max_speed
        since = t - (tr.last_on_t if tr.last_on_pos is not None else tr.born_t)
        return min(self.max_gate_px, self.gate_px + growth * since)

    @staticmethod
    def _inside(uv: np.ndarray, shape: tuple[int, ...]) -> bool:
        return bool(-0.5 <= uv[0] <= shape[1] - 0.5 and -0.5 <= uv[1] <= shape[0] - 0.5)

    def _observe(self, tr: _Track, cur: np.ndarray, prev: np.ndarray, centre: np.ndarray,
                 event_on: bool | None, backfill: bool = False) -> np.ndarray | None:
        """Sample the track's light in this frame: history, levels, on/off.

        ``centre`` is where to look, in image coordinates; ``prev`` is the
        previous frame aligned to this one; ``event_on`` the polarity of the
        candidate associated with the track, if any.  Returns the light's
        centre (image coordinates) if it is on, else None.
        """
        tr.jump = math.inf
        tr.dark = False
        cx, cy = round(float(centre[0])), round(float(centre[1]))
        r = self._reach(tr.spread)
        h, w = cur.shape
        x0, x1, y0, y1 = max(0, cx - r), min(w, cx + r + 1), max(0, cy - r), min(h, cy + r + 1)
        if x0 >= x1 or y0 >= y1:  # predicted out of the image
            tr.hist.append(tr.hist[-1] if tr.hist else 0.0)
            tr.is_on = False
            return None
        patch = cur[y0:y1, x0:x1]
        k = int(np.argmax(patch))
        py, px = divmod(k, x1 - x0)
        peak = float(patch[py, px])
        peak_prev = float(prev[y0:y1, x0:x1].max())
        if backfill:
            tr.hist.append(peak_prev)  # the previous frame is known too
        tr.hist.append(peak)
        if event_on is not None:
            tr.last_polarity_on = event_on
        # A genuine switch changes the window's peak itself; a light merely
        # moving while on (which also makes crescents of change) does not.
        if abs(peak - peak_prev) >= 0.75 * self.diff_threshold:
            hi, lo = max(peak, peak_prev), min(peak, peak_prev)
            if math.isnan(tr.hi):
                tr.hi, tr.lo = hi, lo
            else:
                tr.hi += 0.3 * (hi - tr.hi)
                tr.lo += 0.3 * (lo - tr.lo)
        if not math.isnan(tr.hi) and tr.hi - tr.lo >= 0.5 * self.diff_threshold:
            tr.is_on = peak >= 0.5 * (tr.hi + tr.lo)
        else:
            tr.is_on = tr.last_polarity_on
        if not tr.is_on and 0 <= cx < w and 0 <= cy < h:
            # Clearly off, not partly lit: dim where the light is (the
            # window's peak may be bright background).  What matters is the
            # dark state of lights that clip when on (see _take_plate).
            tr.dark = float(cur[max(0, cy - 1):cy + 2, max(0, cx - 1):cx + 2].max()) \
                <= _CLIP_LEVEL - 2 * self.diff_threshold
        # What is bright must also look like the light -- a spot above its
        # surroundings -- or a track whose light went dark over bright
        # texture would follow the texture.
        if tr.is_on:
            # The ring lies beyond the glow around a saturated light (which
            # on a bright background leaves little contrast just outside it).
            tr.is_on = (self._contrast(cur, np.array([x0 + px, y0 + py], float), tr.spread, 80.0,
                                       margin=self._glow_px)
                        >= 0.5 * self.diff_threshold)
        if not tr.is_on:
            return None  # keep the prediction (or where a new track was born)
        found = self._centroid(cur, x0 + px, y0 + py, peak, self._spot(tr.spread))
        if found is None:
            tr.is_on = False
            return None
        uv, rms = found
        # The lit spot's own size keeps the windows fitted to the light --
        # once the spot is taken to be the light (see _commit).
        tr.measured_spread = rms
        if peak >= _CLIP_LEVEL:
            # A clipped core: its outline depends on the background (see
            # _halo_centre), so the centre comes from the halo if possible.
            rs = self._spot(tr.spread)
            win = cur[max(0, round(float(uv[1])) - rs):round(float(uv[1])) + rs + 1,
                      max(0, round(float(uv[0])) - rs):round(float(uv[0])) + rs + 1]
            tr.clip_radius = math.sqrt(np.count_nonzero(win >= _CLIP_LEVEL) / math.pi)
            better = self._halo_centre(tr, uv)
            if better is not None:
                uv = better
        else:
            tr.clip_radius = math.nan
        return uv

    @staticmethod
    def _not_on(tr: _Track) -> None:
        """What the track saw was not its light: record it as off this frame."""
        tr.is_on = False
        if tr.hist and not math.isnan(tr.lo):
            tr.hist[-1] = tr.lo

    def _commit(self, tr: _Track, uv: np.ndarray, jump: float, t: float, frame: int) -> None:
        """The track's light is on at ``uv`` (image coordinates): update its motion."""
        pos = uv - self._offset
        tr.jump = jump
        tr.pos = pos
        tr.spread += 0.3 * (tr.measured_spread - tr.spread)
        tr.last_on_pos = pos
        tr.last_on_t = t
        tr.last_on_frame = frame
        tr.samples.append((t, pos))
        while tr.samples and tr.samples[0][0] < t - self.fit_window_s:
            tr.samples.popleft()
        self._fit_motion(tr)

    def _fit_motion(self, tr: _Track) -> None:
        """Velocity and acceleration at the last "on" centre, by least squares.

        In motion-compensated coordinates robots move smoothly, so a quadratic
        over the last ``fit_window_s`` predicts across an off period far better
        than a velocity alone (which lags whenever the robot accelerates).
        """
        n = len(tr.samples)
        if n < 2:
            tr.vel, tr.acc = np.zeros(2), np.zeros(2)
            return
        ts = np.array([s[0] for s in tr.samples])
        ps = np.array([s[1] for s in tr.samples])
        tau = ts - ts[-1]
        span = -tau[0]
        # A quadratic needs samples spread over time; else a line.
        if n >= 4 and span * self.fps >= 3.5:
            a = np.column_stack([np.ones(n), tau, 0.5 * tau * tau])
        else:
            a = np.column_stack([np.ones(n), tau])
        coef, *_ = np.linalg.lstsq(a, ps, rcond=None)
        tr.vel = coef[1]
        tr.acc = coef[2] if len(coef) > 2 else np.zeros(2)

    @staticmethod
    def _halo_radius(clip_radius: float) -> int:
        """Half-size of the window over which the halo of a light whose
        clipped core has radius ``clip_radius`` (px) is measured."""
        return math.ceil(1.5 * clip_radius) + 12

    def _take_plate(self, tr: _Track, frame: int) -> None:
        """Keep the neighbourhood of a dark light that clips when on: the
        background its halo will be measured against.

        A few plates are kept, with the light in different places: where the
        dark light hides the background in the newest, an older one may show
        it (a light moving by less than its halo's size per frame).
        """
        if not math.isfinite(tr.clip_radius) or self._colour is None:
            return
        # Room for the light to move before it is on again.
        half = self._halo_radius(tr.clip_radius) + math.ceil(6.0 + 4.0 * float(np.hypot(*tr.vel)) / self.fps)
        centre = tr.pos + self._offset
        cx, cy = round(float(centre[0])), round(float(centre[1]))
        h, w = self._colour.shape[:2]
        x0, x1, y0, y1 = max(0, cx - half), min(w, cx + half + 1), max(0, cy - half), min(h, cy + half + 1)
        if x1 - x0 < 2 or y1 - y0 < 2:
            return
        lin = _SRGB_LUT[self._colour[y0:y1, x0:x1]]
        plate = _Plate(lin, x0, y0, self._offset.copy(), centre.copy(), frame)
        plates = tr.plates
        # The newest plate with the light (nearly) where it is now adds
        # nothing an up-to-date one does not: replace it.
        if plates and math.hypot(*((plates[-1].light - plates[-1].offset) - (centre - self._offset))) \
                < 0.25 * tr.clip_radius + 1.0:
            plates[-1] = plate
        else:
            plates.append(plate)
        max_age = round(self.fps)
        while plates and (len(plates) > _MAX_PLATES or frame - plates[0].frame > max_age):
            plates.pop(0)

    def _halo_centre(self, tr: _Track, uv: np.ndarray) -> np.ndarray | None:
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
        is no plate or too little fits.
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
        cur = _SRGB_LUT[raw]
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
        g = glow[:, :, c]
        unknown = np.isnan(g)
        g = np.where(unknown, np.float32(0.0), g)
        g = cv2.GaussianBlur(g, (5, 5), 1.0)
        unknown |= raw[:, :, c] >= _CLIP_LEVEL
        unknown = cv2.dilate(unknown.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
        g[unknown] = np.nan
        b = bg[:, :, c]
        fin = np.isfinite(b)
        ref = float(np.median(b[fin])) if fin.any() else 0.0
        levels = np.maximum(_HALO_MIN_LEVEL, max(0.1, 1.0 - ref) * np.array(_HALO_LEVELS))
        out = np.empty(5)
        if not _halo_kernel(g, float(uv[0]) - x0, float(uv[1]) - y0, levels, 64, 0.5, float(rmax), 3, out):
            return None
        if out[2] < 16 or out[3] < 3:
            return None
        found = np.array([out[0] + x0, out[1] + y0])
        if math.hypot(*(found - uv)) > max(2.0, 0.5 * r_core):
            return None
        return found

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

    def _basis(self, times: np.ndarray) -> np.ndarray:
        """Orthonormal bases ``(n, 2 * 3F)`` of the zero-mean cos/sin pairs at
        each marker frequency, then half a bin below, then half a bin above.

        Only relative times matter, so at a steady frame rate one basis per
        history length is computed once and cached.
        """
        rel = times - times[-1]
        key = np.round(rel * 1e6).astype(np.int64).tobytes()
        q = self._basis_cache.get(key)
        if q is not None:
            return q
        probes = np.concatenate([self.freqs, self.freqs - self._delta_hz, self.freqs + self._delta_hz])
        cols = []
        for f in probes:
            if f <= 0 or f >= self.fps / 2:
                # Outside the band: a null probe that never beats the marker's.
                cols.append(np.zeros((len(rel), 2)))
                continue
            x = np.column_stack([np.cos(2 * np.pi * f * rel), np.sin(2 * np.pi * f * rel)])
            x -= x.mean(axis=0)  # the DC term of the model
            qf, rf = np.linalg.qr(x)
            # A near-degenerate sine (too short a window): keep what is there.
            qf[:, np.abs(np.diag(rf)) < 1e-6 * max(1.0, float(np.abs(rf).max()))] = 0.0
            cols.append(qf)
        q = np.hstack(cols)
        if len(self._basis_cache) > 64:
            self._basis_cache.clear()
        self._basis_cache[key] = q
        return q

    def _identify(self) -> None:
        """Score every track against every marker frequency; assign (Hungarian)."""
        tracks = self._tracks
        m = len(self.freqs)
        times_all = np.array(self._times)
        scores = np.zeros((len(tracks), m))
        valid = np.zeros((len(tracks), m), bool)
        # Tracks with equally long histories share a basis: score them together.
        groups: dict[int, list[int]] = {}
        for i, tr in enumerate(tracks):
            tr.scores = {}
            if self.min_history <= len(tr.hist) <= len(times_all):
                groups.setdefault(len(tr.hist), []).append(i)
        for n, members in groups.items():
            h = np.array([tracks[i].hist for i in members], dtype=float)
            h -= h.mean(axis=1, keepdims=True)
            total = np.einsum("ij,ij->i", h, h)
            c = h @ self._basis(times_all[-n:])
            e = (c[:, 0::2] ** 2 + c[:, 1::2] ** 2).reshape(len(members), 3, m)
            ratio = e / np.maximum(total, 1e-9)[:, None, None]
            at, below, above = ratio[:, 0], ratio[:, 1], ratio[:, 2]
            # Sinusoid amplitude at the frequency (energy = n a^2 / 2): a light
            # switching by diff_threshold has a fundamental of (2/pi) of that.
            amp = np.sqrt(2.0 * e[:, 0] / n)
            ok = (at >= below) & (at >= above) & (amp >= 0.3 * self.diff_threshold)
            for row, i in enumerate(members):
                scores[i] = at[row]
                valid[i] = ok[row]
                tracks[i].scores = {name: float(s) for name, s in zip(self.marker_names, at[row])}
        # Hysteresis: an identity is kept with a bonus and a lower bar.
        bonus = np.zeros_like(scores)
        bar = np.full_like(scores, self.min_score)
        for i, tr in enumerate(tracks):
            if tr.marker is not None:
                j = self.marker_names.index(tr.marker)
                bonus[i, j] = self._sticky
                bar[i, j] = 0.7 * self.min_score
        dark = np.array([self._frame - tr.last_seen_frame() for tr in tracks])
        # A light blinking at f switches 2 f times a second and each switch
        # is a differential event at the track: a track that saw far fewer
        # (a stray wandering over texture whose brightness happens to look
        # periodic) is not that light.
        n_ev = np.array([sum(tr.events) for tr in tracks], float)
        span = np.array([len(tr.events) for tr in tracks], float) / self.fps
        enough_events = n_ev[:, None] >= 0.5 * 2.0 * self.freqs[None, :] * span[:, None]
        allowed = (valid & (scores >= bar) & enough_events
                   & (dark[:, None] <= self._marker_dark_frames[None, :]))
        for tr in tracks:
            tr.marker, tr.score = None, 0.0
        if not allowed.any():
            return
        cost = np.where(allowed, -(scores + bonus), _FORBIDDEN)
        rows, cols = linear_sum_assignment(cost)
        for r, c in zip(rows, cols):
            if allowed[r, c]:
                tracks[r].marker = self.marker_names[c]
                tracks[r].score = float(scores[r, c])

    # ---------------------------------------------------------------- output

    def _report(self, t: float, shape: tuple[int, ...]) -> DetectionResult:
        res = DetectionResult()
        by_marker = {tr.marker: tr for tr in self._tracks if tr.marker is not None}
        for j, name in enumerate(self.marker_names):
            tr = by_marker.get(name)
            if tr is None or tr.last_on_pos is None:
                res.missing.append(name)
                continue
            uv = tr.predict(t, self._horizon) + self._offset
            if not self._inside(uv, shape):
                res.missing.append(name)
                continue
            res.detections[name] = Detection(
                marker=name, uv=uv, score=tr.score,
                info={"track": tr.id, "on": bool(tr.is_on), "confidence": float(tr.conf),
                      "blink_hz": float(self.freqs[j]),
                      "frames_since_on": int(self._frame - tr.last_on_frame)},
            )
        return res
