"""Birth stage of the light tracker: a track born when its light switches
off starts with a motion model, measured in the two frames before.

A light is first seen when it switches.  A track born when it switches on
gets its motion model from the following "on" frames; one born when it
switches off has none until the light comes back on half a period later,
so its prediction stays where the light was -- in motion-compensated
coordinates, which move by the camera's pan (up to ~10 px a frame) while a
light the camera keeps in view stays nearly still in the image.  It then
drifts off its light, which switches on outside the track's window, and the
light is named only by a later track, the identification history (0.7 s)
after that one's birth (trust sequences seeds 0 and 6, robot p's view of
q's lights: 2 of 11 solvable frames solved).  But the light was lit in the
two frames before it switched off: measured there, it gives the track two
"on" samples, hence a velocity, at birth.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from .state import Track

__all__ = ["BirthStage"]


class BirthStage:
    """Methods of :class:`~mutloc.detect.blink.tracker.LightTracker` for this stage (it holds the state)."""

    def _lit_spot_near(self, img: np.ndarray, uv: np.ndarray, r: int,
                       spread: float) -> tuple[np.ndarray, float] | None:
        """The brightest spot within ``r`` px of ``uv`` in ``img``: (centre, peak)."""
        h, w = img.shape
        cx, cy = round(float(uv[0])), round(float(uv[1]))
        x0, x1, y0, y1 = max(0, cx - r), min(w, cx + r + 1), max(0, cy - r), min(h, cy + r + 1)
        if x1 - x0 < 3 or y1 - y0 < 3:
            return None
        patch = img[y0:y1, x0:x1]
        py, px = divmod(int(np.argmax(patch)), x1 - x0)
        peak = float(patch[py, px])
        found = self._centroid(img, x0 + px, y0 + py, peak, self._spot(spread))
        return None if found is None else (found[0], peak)

    def _motion_at_birth(self, tr: Track, cand: np.ndarray, prev_raw: np.ndarray, cur: np.ndarray,
                         shift: np.ndarray) -> None:
        """Give ``tr`` (just born at ``cand``, image coordinates, from a light
        switching off) two "on" samples from the previous two frames.

        Nothing is set unless the frame before the previous one holds a spot
        as bright as the light was, clearly brighter than the light is now
        (off), within a frame's plausible motion: otherwise the light was
        off then too, or something else is brighter there.
        """
        prev2 = self._prev2
        if prev2 is None or len(self._times) < 3:
            return
        dark = float(cur[max(0, round(float(cand[1])) - 1):round(float(cand[1])) + 2,
                         max(0, round(float(cand[0])) - 1):round(float(cand[0])) + 2].max(initial=0))
        # Where the light was in the previous frame, as it was (not aligned).
        one = self._lit_spot_near(prev_raw, cand - shift, self._reach(tr.spread), tr.spread)
        if one is None:
            return
        uv1, peak1 = one
        if math.hypot(*(uv1 - (cand - shift))) > self._reach(tr.spread):
            return  # the centroid wandered onto a larger bright patch: not the light's spot
        step = self.max_speed / self.fps  # the fastest image motion assumed, px per frame
        two = self._lit_spot_near(prev2, uv1 - self._prev_shift, math.ceil(step) + 1, tr.spread)
        if two is None:
            return
        uv2, peak2 = two
        if (abs(peak2 - peak1) > 0.5 * self.diff_threshold
                or min(peak1, peak2) - dark < 0.75 * self.diff_threshold
                or math.hypot(*(uv2 - (uv1 - self._prev_shift))) > step):
            return
        off1 = self._offset - shift  # the cumulative camera offset in the previous frame
        pos1 = uv1 - off1
        for other in self._tracks:
            # A light some track saw lit right there in the previous frame is
            # that track's: a duplicate born from its switching off must not
            # out-predict it for its next "on" candidate (measured: 1.5 m
            # seed 2 of bench/blink_identity.py lost its identified M3).
            if (other is not tr and other.last_on_pos is not None and other.last_on_frame == self._frame - 1
                    and math.hypot(*(other.last_on_pos - pos1)) <= self._reach(other.spread)):
                return
        off2 = off1 - self._prev_shift
        t1, t2 = self._times[-2], self._times[-3]
        # One sample: the velocity predicts, while the gate stays as wide as
        # for a track without a motion model (two frames' velocity is rough).
        tr.samples = deque([(t1, pos1, off1)])
        tr.last_on_pos = pos1
        tr.last_on_offset = off1
        tr.last_on_t = t1
        tr.vel = (pos1 - (uv2 - off2)) / (t1 - t2)
        tr.vel_img = (uv1 - uv2) / (t1 - t2)
