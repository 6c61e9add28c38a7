"""Identity inheritance stage of the light tracker.

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
