"""Identity stage of the light tracker: which track is which light, by its
blink (frequency and phase) alone, and the detections reported."""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import linear_sum_assignment

from ...core.sphere import sphere_centre_pixel
from ..base import Detection, DetectionResult
from .halo import FORBIDDEN

__all__ = ["IdentityStage"]


class IdentityStage:
    """Methods of :class:`~mutloc.detect.blink.BlinkTracker` for this stage (it holds the state)."""

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
            loud = amp >= 0.3 * self.diff_threshold
            ok = (at >= below) & (at >= above) & loud
            # Hysteresis here too: a light moving over changing background
            # (brightness that is not quite periodic) can make a neighbour's
            # score edge past its own for a frame, and a light over background
            # nearly as bright (in its own colour) blinks faintly: an identity
            # is kept unless the peak clearly lies elsewhere or fades further.
            ok_kept = (at >= 0.8 * below) & (at >= 0.8 * above) & (amp >= 0.2 * self.diff_threshold)
            for row, i in enumerate(members):
                scores[i] = at[row]
                valid[i] = ok[row]
                if tracks[i].marker is not None:
                    j = self.marker_names.index(tracks[i].marker)
                    valid[i, j] = ok_kept[row, j]
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
        if self.name_when_lit:
            # A name is first taken in a frame where the track's light is
            # measured lit at it: a stray off since long ago is coasting on
            # its motion model over background (measured on the trust
            # sequences, seeds 0, 6, 8: 220-800 px/s), and what it sampled there is not one
            # light's blink, however well it happens to fit.
            held = np.array([[tr.marker == name for name in self.marker_names] for tr in tracks], bool)
            lit = np.array([tr.is_on for tr in tracks], bool)
            allowed &= held | lit[:, None]
        for tr in tracks:
            tr.marker, tr.score, tr.blink = None, 0.0, None
        if not allowed.any():
            return
        cost = np.where(allowed, -(scores + bonus), FORBIDDEN)
        rows, cols = linear_sum_assignment(cost)
        for r, c in zip(rows, cols):
            if allowed[r, c]:
                tr = tracks[r]
                tr.marker = self.marker_names[c]
                tr.score = float(scores[r, c])
                tr.blink = self._blink_phase(tr, times_all, float(self.freqs[c]))

    @staticmethod
    def _blink_phase(tr, times_all: np.ndarray, f: float) -> tuple[float, float, float, float]:
        """The track's brightness history fitted by DC + cosine + sine at ``f``
        (times relative to the last sample): when its light is on."""
        h = np.asarray(tr.hist, float)
        rel = times_all[-len(h):] - times_all[-1]
        x = np.column_stack([np.ones(len(h)), np.cos(2 * np.pi * f * rel), np.sin(2 * np.pi * f * rel)])
        coef, *_ = np.linalg.lstsq(x, h, rcond=None)
        return float(times_all[-1]), f, float(coef[1]), float(coef[2])

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
            spot = uv
            if self.camera is not None and self._sphere[name] and math.isfinite(tr.area):
                # The spot's centre is the centre of the sphere's image; the
                # pose needs the projection of the sphere's centre.
                uv = sphere_centre_pixel(self.camera, uv, tr.area)
            res.detections[name] = Detection(
                marker=name, uv=uv, score=tr.score, predicted=not tr.is_on,
                info={"track": tr.id, "on": bool(tr.is_on), "confidence": float(tr.conf),
                      "blink_hz": float(self.freqs[j]),
                      "frames_since_on": int(self._frame - tr.last_on_frame),
                      "spot_uv": spot.tolist()},
            )
        return res
