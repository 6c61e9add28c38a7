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
    """Methods of :class:`~mutloc.detect.blink.tracker.LightTracker` for this stage (it holds the state)."""

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

    @staticmethod
    def _spectrum(hists: list, basis: np.ndarray, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
        """Per history (each ``n`` samples): the fraction of its variance at
        each marker's frequency and half a bin below and above ``(k, 3, m)``,
        and the sinusoid amplitude at each marker's frequency ``(k, m)``."""
        h = np.array(hists, dtype=float)
        h -= h.mean(axis=1, keepdims=True)
        total = np.einsum("ij,ij->i", h, h)
        c = h @ basis
        e = (c[:, 0::2] ** 2 + c[:, 1::2] ** 2).reshape(len(h), 3, m)
        # Sinusoid amplitude at the frequency (energy = n a^2 / 2): a light
        # switching by diff_threshold has a fundamental of (2/pi) of that.
        return e / np.maximum(total, 1e-9)[:, None, None], np.sqrt(2.0 * e[:, 0] / n)

    def _peak_ok(self, ratio: np.ndarray, amp: np.ndarray) -> np.ndarray:
        """Whether histories' scores (``ratio[:, 0/1/2]``: at the frequency,
        half a bin below, above) and amplitudes pass the identification
        tests: a local maximum in frequency, loud enough, at least
        ``min_score``."""
        at, below, above = ratio[:, 0], ratio[:, 1], ratio[:, 2]
        return (at >= below) & (at >= above) & (amp >= 0.3 * self.diff_threshold) & (at >= self.min_score)

    def _identify(self) -> None:
        """Score every track against every marker frequency; assign (Hungarian)."""
        tracks = self._tracks
        m = len(self.freqs)
        times_all = np.array(self._times)
        frame = self._frame
        nt = len(tracks)
        scores = np.zeros((nt, m))
        allowed = np.zeros((nt, m), bool)
        held = np.array([[tr.marker == name for name in self.marker_names] for tr in tracks], bool).reshape(nt, m)
        # Tracks with equally long histories share a basis: score them
        # together.  (Scoring a track born dark elsewhere also on its samples
        # since it was first lit named 2 m seed 2's M4 four frames sooner on
        # the tuning sequences, but cost 3 m seed 3 of fresh ones 18 frames
        # and added 2 wrong labels: not kept.)
        groups: dict[int, list[int]] = {}
        for i, tr in enumerate(tracks):
            tr.scores = {}
            if self.min_history <= len(tr.hist) <= len(times_all):
                groups.setdefault(len(tr.hist), []).append(i)
        for n, members in groups.items():
            basis = self._basis(times_all[-n:])
            ratio, amp = self._spectrum([tracks[i].hist for i in members], basis, n, m)
            # A coloured light over bright background of another colour
            # barely changes the brightest channel's peak when it switches
            # (a blue light on a pale wall: 25 grey levels, too faint to be
            # named), and does in its own colour: its own colour's history
            # scores it where that passes the tests and the brightest
            # channel's does not, or scores higher.
            for g in range(len(self._own_groups)):
                if any(len(tracks[i].hist_own[g]) < n for i in members):
                    continue  # a grey stream: no colours sampled
                cols = [j for j in range(m) if self._own_group[j] == g]
                ratio_g, amp_g = self._spectrum([list(tracks[i].hist_own[g])[-n:] for i in members], basis, n, m)
                for j in cols:
                    main_ok = self._peak_ok(ratio[:, :, j], amp[:, j])
                    own_ok = self._peak_ok(ratio_g[:, :, j], amp_g[:, j])
                    use = own_ok & (~main_ok | (ratio_g[:, 0, j] > ratio[:, 0, j]))
                    ratio[use, :, j] = ratio_g[use, :, j]
                    amp[use, j] = amp_g[use, j]
            at, below, above = ratio[:, 0], ratio[:, 1], ratio[:, 2]
            ok = self._peak_ok(ratio, amp)
            # Hysteresis here too: a light moving over changing background
            # (brightness that is not quite periodic) can make a neighbour's
            # score edge past its own for a frame, and a light over background
            # nearly as bright (in its own colour) blinks faintly: an identity
            # is kept unless the peak clearly lies elsewhere or fades further.
            ok_kept = ((at >= 0.8 * below) & (at >= 0.8 * above) & (amp >= 0.2 * self.diff_threshold)
                       & (at >= 0.7 * self.min_score))
            # A light blinking at f switches 2 f times a second and each switch
            # is a differential event at the track: a track that saw far fewer
            # (a stray wandering over texture whose brightness happens to look
            # periodic) is not that light.
            ev = np.array([sum(list(tracks[i].events)[-n:]) for i in members], float)
            span = np.array([min(n, len(tracks[i].events)) for i in members], float) / self.fps
            enough_events = ev[:, None] >= 0.5 * 2.0 * self.freqs[None, :] * span[:, None]
            # ... and was seen lit in part of them: a stray at the image's
            # edge, lit once where the pan uncovered a bright patch for five
            # frames, has a single bump in its history, which fits a slow
            # blink (clutter seed 24, p's view: named M1, reported 480 px off).
            lit = np.array([tracks[i].lit_since(frame - n) for i in members], float)
            enough_events &= (lit >= self.min_lit_fraction * n)[:, None]
            ok_here = np.where(held[members], ok_kept, ok) & enough_events
            for row, i in enumerate(members):
                tracks[i].scores = {name: float(s) for name, s in zip(self.marker_names, at[row])}
                scores[i] = at[row]
                allowed[i] = ok_here[row]
        # Hysteresis: an identity is kept with a bonus.
        bonus = np.where(held, self._sticky, 0.0)
        dark = np.array([frame - tr.last_seen_frame() for tr in tracks]).reshape(nt)
        allowed &= dark[:, None] <= self._marker_dark_frames[None, :]
        before = [tr.marker for tr in tracks]
        for tr in tracks:
            tr.marker, tr.score, tr.blink = None, 0.0, None
        if allowed.any():
            cost = np.where(allowed, -(scores + bonus), FORBIDDEN)
            rows, cols = linear_sum_assignment(cost)
            for r, c in zip(rows, cols):
                if allowed[r, c]:
                    tr = tracks[r]
                    tr.marker = self.marker_names[c]
                    tr.score = float(scores[r, c])
                    tr.blink = self._blink_phase(tr, times_all, float(self.freqs[c]))
        self._confirm(before)

    def _confirm(self, before: list) -> None:
        """Whether each named track's name is reported (see ``BlinkParams.confirm_lit``)."""
        for tr, name in zip(self._tracks, before):
            if tr.marker is None or tr.is_on or not self.confirm_lit:
                tr.unconfirmed = False
            elif tr.marker != name:
                # Named while its light is off: the track coasts on its motion
                # model, and a stray's (fitted to a couple of centres) carried
                # it over background at 220-800 px/s (trust sequences, seeds
                # 0, 6, 7, 8: reports 30-500 px off).  The name stands -- the
                # blink history says which light the track followed, and a
                # track taking over its spot may inherit it -- but is reported
                # only once the light is measured lit at the track, or while
                # where it was last lit still lies within its gate (the
                # report does not rest on the velocity alone; the gate not
                # widened for a light due on, which is for finding it).
                tr.unconfirmed = (tr.last_on_pos is None or math.hypot(*(tr.pos - tr.last_on_pos))
                                  > self._gate(tr, self._times[-1], due_on=False))

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
            if tr is None or tr.last_on_pos is None or tr.unconfirmed:
                res.missing.append(name)
                continue
            uv = tr.predict(t, self._horizon, self._offset) + self._offset
            if tr.is_on:
                uv = uv + tr.report_shift
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
