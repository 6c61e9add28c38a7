"""Association stage of the light tracker: which measured spot continues which
track (gating on the motion model), and the motion model itself."""

from __future__ import annotations

import math

import numpy as np

from . import measure
from .halo import CLIP_LEVEL
from .state import Track

# Centroid and plateau outline disagreeing by more than this (px): the
# centroid was dragged by bleed (see LightTracker._plateau_circle).
PLATEAU_DISAGREE_PX = 3.0

# A spot found by its colour alone (see LightTracker._colour_contrast) is
# taken for the track's light only this close (px) to where it looked: colour
# confirms a light where it is expected, it does not pull a track elsewhere.
COLOUR_JUMP_PX = 12.0

# An unidentified track whose light turns up more than this many search
# radii from its prediction, without a candidate of its own there, follows
# another object from now on: its history restarts (see _restart).
RESTART_REACHES = 2.0

# A clipped light's centre from its halo is kept only within this (px) of
# its clipped plateau's outline circle (see AssociationStage._observe).
HALO_AGREE_PX = 1.5

# A light just switched on is measured at most this many search reaches
# from its region of change; a spot further off is something else.
SWITCH_REACHES = 2.0

# An identified light's centre measured in its own colour (see
# MeasureStage._own_colour_centre) further than this (px) from the usual
# measurement replaces it: the usual one was dragged by background of
# another colour.
OWN_COLOUR_DISAGREE_PX = 3.0

# The motion model predicts in image coordinates rather than motion-
# compensated ones once its image-frame twin has predicted the light's
# switching on this much better (running mean error; see _commit).
IMAGE_FRAME_ERR = 0.7
IMAGE_FRAME_AFTER = 3  # off periods

# A light tracked in its colour's own image is reported at its centre
# measured in brightness where the two are at most this far apart (px).
REFINE_AGREE_PX = 1.5

# A track without a motion model whose light was lit at most this many
# frames ago may continue from where it was in the image (see _pair_costs).
YOUNG_FRAMES = 2

# Added (px) to the cost of a candidate-track pair that the lights' physics
# makes unlikely (see _pair_costs).
UNLIKELY_PX = 40.0

__all__ = ["AssociationStage"]


class AssociationStage:
    """Methods of :class:`~mutloc.detect.blink.tracker.LightTracker` for this stage (it holds the state)."""

    def _gate(self, tr: Track, t: float, due_on: bool = True) -> float:
        """How far from its prediction a track's light may be at time ``t``
        (px); ``due_on=False``: without the widening for a light due on."""
        # Until a track has a motion model its light may be moving at any
        # plausible speed; after that only the model's error grows -- with
        # time, not frames, and faster for a faster light.
        if len(tr.samples) >= 2:
            growth = self.gate_growth + self.gate_speed * tr.speed()
        else:
            growth = self.max_speed
        since = t - (tr.last_on_t if tr.last_on_pos is not None else tr.born_t)
        gate = self.gate_px + growth * since
        if due_on and tr.expect_on(t) > self.expect_off and since > 1.5 / self.fps:
            # An identified light due on (its fitted blink well inside the
            # "on" half) after an off period: its switching on is expected
            # here, and a fast one may have strayed from the prediction.
            gate *= 2.0
        return min(self.max_gate_px, gate)

    def _pair_costs(self, cents: np.ndarray, lit: np.ndarray, t: float,
                    frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For each candidate (``cents``, image coordinates; ``lit``: a
        switch on) and each track: the distance (px) to where the track's
        light is looked for, the cost of pairing them, and whether the
        candidate lies inside the track's gate."""
        tracks = self._tracks
        off = self._offset
        pred = np.array([tr.pos for tr in tracks]) + off
        dist = np.linalg.norm(cents[:, None, :] - pred[None, :, :], axis=2)
        young: list[int] = []
        if self._meas is not None:
            # A track without a motion model yet may be a light the camera
            # follows (or one moving against the camera's pan, faster in
            # motion-compensated coordinates than in the image: 2-3 m, 12-28
            # px a frame, a new track at every blink and never a name).  In
            # a colour's own image, where little else is bright, it may also
            # continue from where it was in the image (bench/blink_identity.py,
            # 3 m: 0.943 -> 0.993 on the tuning seeds; in the brightness
            # channel strays took names).
            young = [j for j, tr in enumerate(tracks) if len(tr.samples) < 2 and tr.last_on_pos is not None
                     and frame - tr.last_on_frame <= YOUNG_FRAMES]
            if young:
                still = np.array([tracks[j].last_on_pos + tracks[j].last_on_offset for j in young])
                dist[:, young] = np.minimum(dist[:, young],
                                            np.linalg.norm(cents[:, None, :] - still[None, :, :], axis=2))
        gates = np.array([self._gate(tr, t) for tr in tracks])
        inside = dist <= gates[None, :]
        # An identified track is known to be a light; an unidentified one may
        # be a stray, so it must be clearly closer to win a candidate.
        cost = dist + np.array([0.0 if tr.marker is not None else self.gate_px for tr in tracks])[None, :]
        # A light off in the last frame cannot switch off now: a change to
        # dark near it is something else -- the trail of its coloured body,
        # lit or not, moving against the pan (3 m seed 7: taken for the
        # light's own event when the light switched on 15 px away, and a new
        # track born there).  A switch on in its gate is preferred; the
        # change to dark may still support it.  So for a young light lit in
        # the last frame and again in its gate: it moved there, and the
        # change to dark where it was is its trail (2 m seed 7: a new track
        # every frame for a second).
        was_off = np.array([tr.last_on_pos is not None and frame - tr.last_on_frame > 1 for tr in tracks])
        for j in young:
            was_off[j] |= frame - tracks[j].last_on_frame == 1
        prefer_on = was_off & np.any(lit[:, None] & inside, axis=0)
        cost[np.ix_(~lit, prefer_on)] += UNLIKELY_PX
        # A switch on inside the gate of an identified light whose blink says
        # "on" is that light, not an unidentified track without a motion
        # model: a change to dark left where it was born, that the light
        # happened to pass (2 m seed 2: the name then reported at a
        # prediction 17-35 px behind), or the light's coloured body moving
        # while the light is off (1.5 m seed 2).
        due = np.array([tr.marker is not None and tr.expect_on(t) > 0.0 for tr in tracks])
        unmodelled = np.array([tr.marker is None and len(tr.samples) < 2 for tr in tracks])
        if due.any() and unmodelled.any():
            wanted = lit & np.any(inside & due[None, :], axis=1)
            cost[np.ix_(wanted, unmodelled)] += UNLIKELY_PX
        return dist, cost, inside

    @staticmethod
    def _inside(uv: np.ndarray, shape: tuple[int, ...]) -> bool:
        return bool(-0.5 <= uv[0] <= shape[1] - 0.5 and -0.5 <= uv[1] <= shape[0] - 0.5)

    def _observe(self, tr: Track, cur: np.ndarray, prev: np.ndarray, centre: np.ndarray,
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
            tr.push(tr.hist[-1] if tr.hist else 0.0, [d[-1] if d else 0.0 for d in tr.hist_own])
            tr.is_on = False
            return None
        patch = cur[y0:y1, x0:x1]
        k = int(np.argmax(patch))
        py, px = divmod(k, x1 - x0)
        peak = float(patch[py, px])
        peak_prev = float(prev[y0:y1, x0:x1].max())
        if backfill:  # the previous frame is known too
            tr.push(peak_prev, [float(f[y0:y1, x0:x1].max()) for f in self._own_prev] if self._own_prev
                    else [0.0] * len(tr.hist_own))
        tr.push(peak, [float(f[y0:y1, x0:x1].max()) for f in self._own_now])
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
                <= CLIP_LEVEL - 2 * self.diff_threshold
        # What is bright must also look like the light -- a spot above its
        # surroundings -- or a track whose light went dark over bright
        # texture would follow the texture.
        if tr.is_on:
            # The ring lies beyond the glow around a saturated light (which
            # on a bright background leaves little contrast just outside it).
            at = np.array([x0 + px, y0 + py], float)
            con = self._contrast(cur, at, tr.spread, 80.0, margin=self._glow_px)
            tr.is_on = con >= 0.5 * self.diff_threshold
            tr.by_colour = False
            if not tr.is_on and self.colour_contrast > 0 and con >= 0:
                # A light over background nearly as bright in its own colour
                # (a green light on a green poster, both clipping in green)
                # stands out in the other channels instead.
                tr.is_on = tr.by_colour = \
                    self._colour_contrast(at, tr.spread, self._glow_px) >= self.colour_contrast
        if tr.is_on and tr.expect_on(self._times[-1]) < -self.expect_off:
            # An identified light blinks on schedule: now is well inside its
            # "off" half, so what is bright here is something else.
            tr.is_on = False
        if not tr.is_on:
            return None  # keep the prediction (or where a new track was born)
        found = self._centre_in(tr, cur, x0 + px, y0 + py, peak, centre, r, event_on)
        if found is None:
            tr.is_on = False
            return None
        uv, tr.measured_spread, area = found
        tr.report_shift = np.zeros(2)
        if self._meas is not None:
            # The channel is a colour's own image, where the light is told
            # from pale and grey surroundings; its glow and clipped core are
            # modelled in brightness, where they are measured more finely
            # (0.05 px against 0.12 median at 1.2 m, tests/test_detect_blink.py)
            # and reported where the two agree -- the motion keeps the
            # channel's centre.  Where they disagree, one was dragged: by pale
            # background in brightness (trust seed 33), by the coarser colour
            # of a compressed image in the channel (JPEG: 4 px, same test).
            # The one nearer where the light was looked for is kept.
            clip = tr.clip_radius
            fine = self._centre_in(tr, self._meas, x0 + px, y0 + py, float(self._meas[y0 + py, x0 + px]),
                                   centre, r, event_on)
            if fine is not None and math.hypot(*(fine[0] - uv)) <= REFINE_AGREE_PX:
                tr.report_shift, area = fine[0] - uv, fine[2]
                tr.clip_radius = clip
            elif fine is not None and math.hypot(*(fine[0] - centre)) < math.hypot(*(uv - centre)):
                uv, tr.measured_spread, area = fine
            else:
                tr.clip_radius = clip
        elif tr.marker is not None:
            own = self._own_colour_centre(tr.marker, centre, r, self._spot(tr.spread))
            if own is not None and math.hypot(*(own[0] - uv)) > OWN_COLOUR_DISAGREE_PX \
                    and own[1] <= 1.5 * tr.spread and self._own_colour_at(tr.marker, uv) < 0.5 * own[2]:
                # Background as bright as the light in the brightest channel
                # but of another colour (a magenta poster beside a red light:
                # 255 in red for both) dragged the measurement off the light,
                # onto pixels not of its colour; in the light's own colour
                # only the light is bright (a compact spot).
                uv = own[0]
        tr.measured_area = area
        return uv

    def _centre_in(self, tr: Track, img: np.ndarray, px: int, py: int, peak: float, centre: np.ndarray,
                   r: int, event_on: bool | None) -> tuple[np.ndarray, float, float] | None:
        """The lit light's centre in ``img`` from its peak ``(px, py)``:
        ``(uv, rms radius, apparent area)``, or None if what is bright there
        is not the light.  Sets the track's clipped-core radius."""
        found = self._centroid(img, px, py, peak, self._spot(tr.spread))
        if found is None:
            return None
        uv, rms = found
        if peak >= CLIP_LEVEL and math.hypot(*(uv - centre)) > 2 * r and rms > 3.0 * tr.spread:
            # The clipped spot's centroid grew onto a larger bright patch
            # beside it (trust seed 0: 32 px up a lit edge).  Just switched
            # on, ``centre`` (the change region's centroid) locates the
            # light, and the track's spread was just fitted to the region's;
            # else the light's own clipped plateau does.
            if event_on:
                uv, rms = np.asarray(centre, float), tr.spread
            else:
                circle = self._plateau_circle(img, np.array([px, py], float), self._spot(tr.spread))
                if circle is None or math.hypot(*(circle[0] - centre)) > r:
                    return None
                uv, rms = circle[0], tr.spread
        if event_on and math.hypot(*(uv - centre)) > SWITCH_REACHES * r:
            # Just switched on, the region of change locates the light; a
            # spot measured well beyond it is something else bright that the
            # centroid window grew onto.  (Trust seed 3, q's view: a light
            # just named while off took a lit wall 42 px beyond the region,
            # rms 30 px, for itself, and lost its name.)
            return None
        if tr.by_colour and math.hypot(*(uv - centre)) > COLOUR_JUMP_PX:
            return None
        # The lit spot's own size (rms) keeps the windows fitted to the light
        # -- once the spot is taken to be the light (see _commit).
        if peak >= CLIP_LEVEL:
            # A clipped core: its outline depends on the background (see
            # _halo_centre), so the centre comes from the halo if possible.
            rs = self._spot(tr.spread)
            win = img[max(0, round(float(uv[1])) - rs):round(float(uv[1])) + rs + 1,
                      max(0, round(float(uv[0])) - rs):round(float(uv[0])) + rs + 1]
            tr.clip_radius = math.sqrt(np.count_nonzero(win >= CLIP_LEVEL) / math.pi)
            area = math.pi * tr.clip_radius ** 2
            # Beside a bright background the plateau bleeds outwards and the
            # centroid follows by pixels -- more than the halo fit below may
            # correct.  The outline's circle is kept then, for an identified
            # light only: a stray's clipped patch is no disc, and moving it
            # re-routes the association (measured: wrong labels at 1.5 and 3 m,
            # bench/blink_identity.py).
            circle = self._plateau_circle(img, uv, rs) if tr.marker is not None else None
            if circle is not None and math.hypot(*(circle[0] - uv)) > PLATEAU_DISAGREE_PX:
                uv = circle[0]
            better = self._halo_centre(tr, uv)
            if better is None and measure.EDGE_FALLBACK and tr.marker is not None:
                better = self._edge_centre(img, uv, tr.clip_radius)
            if better is not None:
                # The halo is measured against plates taken while the light
                # was off; when the robot has moved since, the dark light
                # and its body in them lie elsewhere and bias the fit (trust
                # seed 12, q's view: 3-4 px on a lit red light over a plain
                # wall, solved frames 5.5-5.8 cm off).  The clipped plateau's
                # outline, measured in this frame alone, must agree.
                if circle is None:
                    circle = self._plateau_circle(img, uv, rs)
                if circle is None or math.hypot(*(better - circle[0])) <= HALO_AGREE_PX:
                    uv = better
        else:
            tr.clip_radius = math.nan
            area = self._spot_area(img, uv, peak, self._spot(tr.spread))
        return uv, rms, area

    @staticmethod
    def _restart(tr: Track, frame: int, t: float) -> None:
        """The track's spot is far from where it looked: another object, so
        what it saw before is not this one's history."""
        for d in [tr.hist, *tr.hist_own]:
            last = d[-1]
            d.clear()
            d.append(last)
        tr.events.clear()
        tr.lit_frames.clear()
        tr.events.append(True)
        tr.samples.clear()
        tr.hi = tr.lo = math.nan
        tr.last_on_pos = None
        tr.miss, tr.misses, tr.stabilised = None, 0, True
        tr.born_frame, tr.born_t = frame, t
        tr.plates.clear()

    @staticmethod
    def _not_on(tr: Track) -> None:
        """What the track saw was not its light: record it as off this frame."""
        tr.is_on = False
        if tr.hist and not math.isnan(tr.lo):
            tr.hist[-1] = tr.lo
            for d in tr.hist_own:
                d[-1] = min(d)

    def _commit(self, tr: Track, uv: np.ndarray, jump: float, t: float, frame: int) -> None:
        """The track's light is on at ``uv`` (image coordinates): update its motion."""
        pos = uv - self._offset
        tr.jump = jump
        tr.pos = pos
        tr.spread += 0.3 * (tr.measured_spread - tr.spread)
        # A spot window that grows with what it measures takes in bright
        # surroundings, grows further and drags the centroid off the light
        # (measured at 3 m: 20 px spreads, reports 15-25 px off).
        tr.spread = min(tr.spread, self.max_spread)
        if math.isfinite(tr.measured_area):
            tr.area = tr.measured_area if not math.isfinite(tr.area) else \
                tr.area + 0.3 * (tr.measured_area - tr.area)
        if tr.last_on_pos is not None and t - tr.last_on_t > 1.5 / self.fps:
            # Back on after an off period: how well did each frame's model
            # predict it?  (Consecutive "on" frames tell the two apart too
            # little to count.)
            stab = tr.predict_in(t, self._horizon, True, self._offset) + self._offset
            img = tr.predict_in(t, self._horizon, False, self._offset) + self._offset
            miss = np.array([math.hypot(*(stab - uv)), math.hypot(*(img - uv))])
            tr.miss = miss if tr.miss is None else tr.miss + 0.5 * (miss - tr.miss)
            tr.misses += 1
            # A young track's first predictions are rough in both frames.
            tr.stabilised = tr.misses < IMAGE_FRAME_AFTER or not tr.miss[1] < IMAGE_FRAME_ERR * tr.miss[0]
        tr.last_on_pos = pos
        tr.last_on_offset = self._offset.copy()
        tr.last_on_t = t
        tr.last_on_frame = frame
        tr.lit_frames.append(frame)
        tr.samples.append((t, pos, tr.last_on_offset))
        while tr.samples and tr.samples[0][0] < t - self.fit_window_s:
            tr.samples.popleft()
        self._fit_motion(tr)

    def _fit_motion(self, tr: Track) -> None:
        """Velocity and acceleration at the last "on" centre, by least squares.

        A quadratic over the last ``fit_window_s`` predicts across an off
        period far better than a velocity alone (which lags whenever the robot
        accelerates).  It is fitted in motion-compensated coordinates, where a
        robot crossing the scene moves smoothly, and in image coordinates,
        where a robot the camera follows does (compensating adds the camera's
        own jerks to it: trust seed 7, p's view, a light drifting 8 px from
        its prediction over an off period); the one that has predicted the
        light better is used (``Track.stabilised``, see :meth:`_commit`).
        """
        n = len(tr.samples)
        if n < 2:
            tr.vel, tr.acc = np.zeros(2), np.zeros(2)
            tr.vel_img, tr.acc_img = np.zeros(2), np.zeros(2)
            return
        ts = np.array([s[0] for s in tr.samples])
        ps = np.array([s[1] for s in tr.samples])
        image = ps + np.array([s[2] for s in tr.samples])
        tau = ts - ts[-1]
        span = -tau[0]
        # A quadratic needs samples spread over time; else a line.
        if n >= 4 and span * self.fps >= 3.5:
            a = np.column_stack([np.ones(n), tau, 0.5 * tau * tau])
        else:
            a = np.column_stack([np.ones(n), tau])
        coef, *_ = np.linalg.lstsq(a, ps, rcond=None)
        coef_img, *_ = np.linalg.lstsq(a, image, rcond=None)
        tr.vel, tr.vel_img = coef[1], coef_img[1]
        tr.acc = coef[2] if len(coef) > 2 else np.zeros(2)
        tr.acc_img = coef_img[2] if len(coef_img) > 2 else np.zeros(2)

