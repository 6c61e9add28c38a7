"""Identity inheritance stage of the light tracker (and the hand-over of a
lost light's spot between unidentified tracks, :meth:`InheritStage._hand_over`).

When an identified track loses its light (a mis-prediction over fast motion)
an unidentified track usually takes over the spot at once, but it would be
named only after ``min_history`` of blink history.  Here a light's name left
unassigned is handed at once to an unidentified track at the spot the lost
track predicted (within its gate) whose on/off history agrees with the lost
light's fitted blink (phase and frequency); the name is revoked as soon as the
track's blink disagrees, or the identity stage names someone else.
"""

from __future__ import annotations

import numpy as np

from .state import Track

__all__ = ["InheritStage"]

#: How long (frames) after a light's name was last held it may be inherited.
_MEMORY_FRAMES = 20
#: Only samples where the fitted blink is this sure of on / off are checked.
_SURE = 0.5
#: Minimum correlation of the brightness history with the fitted blink.
_CORR = 0.6
#: A lit spot taken by a track never lit before goes to an unidentified
#: track that lost its light within this many of its gates (0: never) ...
HAND_OVER_GATES = 1.5
#: ... and whose motion model was fitted to at least this many lit centres.
HAND_OVER_SAMPLES = 3


class InheritStage:
    """Methods of :class:`~mutloc.detect.blink.tracker.LightTracker` for this stage (it holds the state)."""

    def _blink_agrees(self, tr: Track, blink: tuple[float, float, float, float], name: str) -> bool:
        """Whether ``tr``'s brightness history -- or its history in light
        ``name``'s own colour -- read as on / off, matches ``blink`` wherever
        the fit is sure, with at least one sure "on" and one sure "off"
        sample seen."""
        g = self._own_group[self.marker_names.index(name)]
        hists = [tr.hist] + ([tr.hist_own[g]] if g >= 0 and tr.hist_own else [])
        return any(self._history_agrees(h, blink) for h in hists)

    def _history_agrees(self, hist, blink: tuple[float, float, float, float]) -> bool:
        h = np.asarray(hist, float)
        if len(h) < 4:
            return False
        times = np.asarray(self._times, float)[-len(h):]
        t0, f, a, b = blink
        amp = float(np.hypot(a, b))
        if amp <= 0.0:
            return False
        w = 2.0 * np.pi * f * (times - t0)
        e = (a * np.cos(w) + b * np.sin(w)) / amp
        sure_on, sure_off = e >= _SURE, e <= -_SURE
        if not sure_on.any() or not sure_off.any():
            return False
        # Brightness levels differ (glow over a pale wall keeps "off" bright):
        # the history must rise and fall with the blink, clearly.
        if float(h[sure_on].mean() - h[sure_off].mean()) < 0.5 * self.diff_threshold:
            return False
        if float(h.std()) <= 0.0:
            return False
        return bool(np.corrcoef(h, e)[0, 1] >= _CORR)

    def _hand_over(self, observed: list, t: float) -> list:
        """``observed`` (jump, track index, uv: this frame's lit spots) with
        each spot taken by a track never lit before handed to the nearest
        unidentified track that found nothing this frame and whose motion
        puts its light there (within ``HAND_OVER_GATES`` gates); the
        newcomer, whose history was sampled where the light was not, is
        dropped.

        A light reversing at the end of its path switches on just outside
        its track's gate, beside a track born on a change to dark (1.5 m
        seed 21 of bench/blink_identity.py: 15.6 px from a 15 px gate; the
        newcomer was named 0.8 s late).  Identified tracks are left to
        inheritance (handing them spots too added wrong labels on the
        tuning sequences), and a motion model fitted to two centres, one of
        them a stray's, is no model (1.5 m seed 20: such a track took the
        light and lost it three frames later).
        """
        tracks = self._tracks
        seen = {j for _, j, _ in observed}
        out = []
        for jump, j, uv in observed:
            tr = tracks[j]
            best, best_d = None, np.inf
            if tr.last_on_pos is None and HAND_OVER_GATES > 0:
                pos = uv - self._offset
                for k, old in enumerate(tracks):
                    if (k in seen or old.marker is not None or old.last_on_pos is None
                            or len(old.samples) < HAND_OVER_SAMPLES):
                        continue
                    d = float(np.hypot(*(pos - old.pos)))
                    if d <= HAND_OVER_GATES * self._gate(old, t) and d < best_d:
                        best, best_d = k, d
            if best is None:
                out.append((jump, j, uv))
                continue
            old = tracks[best]
            old.hist[-1] = tr.hist[-1]
            for a, b in zip(old.hist_own, tr.hist_own):
                a[-1] = b[-1]
            old.is_on, old.dark, old.by_colour = True, False, tr.by_colour
            old.measured_spread, old.measured_area = tr.measured_spread, tr.measured_area
            old.report_shift, old.clip_radius = tr.report_shift, tr.clip_radius
            old.last_polarity_on = tr.last_polarity_on
            if tr.events and tr.events[-1] and old.events:
                old.events[-1] = True
            old.conf = max(old.conf, tr.conf)
            tr.conf, tr.is_on = 0.0, False
            seen.add(best)
            out.append((best_d, best, uv))
        return out

    def _where_lost(self, tr: Track, lost: Track) -> float:
        """Distance (px) from where ``lost`` was last seen lit to where ``tr``
        was lit about then, inf if farther than that light could have moved
        (a mis-predicted track loses its light where another picks it up)."""
        if lost.last_on_pos is None:
            return np.inf
        best = np.inf
        for ts, ps, _ in tr.samples:
            dt = abs(ts - lost.last_on_t)
            if dt <= 0.15:
                d = float(np.hypot(*(ps - lost.last_on_pos)))
                if d <= 2.0 * self.gate_px + lost.speed() * dt:
                    best = min(best, d)
        return best

    def _inherit(self) -> None:
        """Keep inherited names that still agree; hand names just lost to the
        track that took over their light's spot."""
        if not self._times:
            return
        t, frame = self._times[-1], self._frame
        tracks = self._tracks
        held = {tr.marker for tr in tracks if tr.marker is not None}
        # Inherited names the identity stage did not confirm: kept while the
        # blink agrees and nobody else holds the name.
        for tr in tracks:
            name = tr.inherited
            if name is None:
                continue
            if tr.marker is not None:
                tr.inherited = None  # named on its own (or renamed)
                continue
            info = self._holders.get(name)
            if (name in held or info is None or tr.last_on_pos is None
                    or frame - tr.last_seen_frame() > self._marker_dark_frames[self.marker_names.index(name)]
                    or not self._blink_agrees(tr, info[1], name)):
                tr.inherited = None
                tr.no_inherit = True
                continue
            tr.marker, tr.score, tr.blink = name, info[2], info[1]
            held.add(name)
        for name in self.marker_names:
            if name in held:
                continue
            info = self._holders.get(name)
            if info is None or frame - info[3] > _MEMORY_FRAMES:
                continue
            lost, blink, score, _ = info
            pred = lost.predict(t, self._horizon, self._offset)
            gate = self._gate(lost, t)
            best, best_d = None, np.inf
            for tr in tracks:
                if (tr is lost or tr.marker is not None or tr.no_inherit or not tr.is_on
                        or tr.last_on_pos is None):
                    continue
                d = float(np.hypot(*(tr.pos - pred)))
                if d > gate:
                    d = self._where_lost(tr, lost)
                if d < best_d and self._blink_agrees(tr, blink, name):
                    best, best_d = tr, d
            if best is not None:
                best.marker, best.score, best.blink, best.inherited = name, score, blink, name
                held.add(name)
        for tr in tracks:
            if tr.marker is not None and tr.blink is not None:
                self._holders[tr.marker] = (tr, tr.blink, tr.score, frame)
