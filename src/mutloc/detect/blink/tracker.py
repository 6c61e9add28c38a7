"""Blinking-light markers, found and told apart over a video stream.

The paper (Section IV) detects its blinking lights with "a simple thresholding
strategy on the time differential of images ... coupled with decaying
confidence tracking".  :class:`LightTracker` does that and adds identity:

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
   gated; the gate widens the longer a light has been off).  A light off
   cannot switch off, so a track whose light was off prefers a switch on in
   its gate; a switch on in the gate of an identified light due on is that
   light's before it is a track's without a motion model
   (``AssociationStage._pair_costs``).  A track's
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
   crosses a few levels (:meth:`LightTracker._halo_centre`).  Positions are kept in
   camera-motion-compensated coordinates, where robots move smoothly: the
   prediction is a quadratic fitted to the last ``fit_window_s`` of "on"
   centres -- fitted in image coordinates too, which predict instead once
   they have predicted the light's switching on clearly better (a camera
   following the light; ``AssociationStage._commit``).  In a colour's own
   image (:mod:`~mutloc.detect.blink.channels`) a track without a motion
   model, lit at most ``YOUNG_FRAMES`` ago, may also continue from where it
   was in the image (a light fast against the camera's pan).
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
   must not have been dark for longer than the light ever is, and must have
   been seen lit in ``min_lit_fraction`` of the history.  Tracks are
   assigned to markers by the Hungarian method on the scores (one track per
   marker), with a small bonus that keeps an established identity.  A
   light of a colour is also sampled in that colour (the least of its own
   channels less the largest of the others): a blue light over a pale wall
   barely moves the brightest channel's peak, but its own colour's history
   blinks loudly and names it (``BlinkParams.own_colour``).  An
   identified light's blink is then known in phase too (its history fitted
   at its frequency): inside its "off" half a bright spot at it is something
   else, and when it is due on after an off period its gate is doubled (a
   fast light strays further from a prediction made across the off period).
4. **Camera model.**  Given the camera, a light with a ``radius`` is
   reported at the projection of its sphere's centre rather than at the
   centre of its (elliptical) image, see :mod:`mutloc.core.sphere`.  Any
   lens (pinhole, fisheye, omni): the tracker works on the raw image, so its
   state (tracks, histories, the camera's motion) is one per camera and its
   positions are raw pixels.  A light is a spot a few pixels across, over
   which even a fisheye's rim is nearly affine, so the time differential, the
   centroid and the halo fit need no rectification; only the sphere's
   correction goes through the lens model (the spot's outline is the lens's
   image of the sphere's rim cone).

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
from typing import Any

import cv2
import numpy as np

from ...core.camera import Camera
from ...core.lenses import Lens
from ...core.rig import Marker
from ...errors import InputError
from ..base import DetectionResult
from .association import RESTART_REACHES, AssociationStage
from .birth import BirthStage
from .frames import FrameStage
from .identity import IdentityStage
from .inherit import InheritStage
from .measure import MeasureStage
from .motion import GlobalMotion
from .params import BlinkParams
from .state import Track

__all__ = ["LightTracker"]

# See _step: when two tracks found the same lit spot, an unidentified one
# without a motion model claims it as if this much (px) further away.
UNMODELLED_CLAIM_PX = 40.0

# See _step: in a colour's own image a light lit in the last frame, with a
# motion model, is looked for at its prediction, not at a change to bright
# beside it.
LIT_KEEPS_PREDICTION = True


class LightTracker(FrameStage, MeasureStage, AssociationStage, IdentityStage, BirthStage, InheritStage):
    """Streaming detector of blinking-light markers, told apart by ``blink_hz``,
    in one brightness channel (:class:`~mutloc.detect.blink.BlinkTracker`
    runs one per colour of light).

    :meth:`update` takes a frame, as the public tracker's does; the
    parameters are the public tracker's (``markers``, ``fps``, ``params``,
    ``camera``), which documents them.
    """

    def __init__(
        self,
        markers: Mapping[str, Marker],
        fps: float,
        *,
        params: BlinkParams | None = None,
        camera: Camera | None = None,
    ) -> None:
        p = params if params is not None else BlinkParams()
        if camera is not None and not isinstance(camera, Lens):
            raise InputError("BlinkTracker: camera must be a Camera, FisheyeCamera or OmniCamera, got "
                             f"{type(camera).__name__}")
        self.camera = camera
        if not isinstance(p, BlinkParams):
            raise InputError(f"BlinkTracker: params must be BlinkParams, got {type(p).__name__}")
        diff_threshold = p.diff_threshold
        decay = p.decay
        boost = p.boost
        min_confidence = p.min_confidence
        window_s = p.window_s
        min_history_s = p.min_history_s
        min_score = p.min_score
        stabilize = p.stabilize
        motion_radius = p.motion_radius
        search_radius = p.search_radius
        spot_radius = p.spot_radius
        centroid_level = p.centroid_level
        gate_px = p.gate_px
        gate_growth = p.gate_growth
        max_speed = p.max_speed
        max_gate_px = p.max_gate_px
        fit_window_s = p.fit_window_s
        max_blob_area = p.max_blob_area
        max_blob_std = p.max_blob_std
        max_tracks = p.max_tracks
        brightness = p.brightness
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
        colours: list[np.ndarray] = []
        # Per marker: a sphere (has a radius), whose image centre needs the camera's correction.
        self._sphere: dict[str, bool] = {}
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
            radius = m.extra.get("radius") if isinstance(getattr(m, "extra", None), Mapping) else None
            if radius is not None:
                try:
                    radius = float(radius)
                except (TypeError, ValueError):
                    raise InputError(f"marker {name!r}: radius must be a number, got {radius!r}") from None
                if not (math.isfinite(radius) and radius > 0):
                    raise InputError(f"marker {name!r}: radius must be positive, got {radius}")
            names.append(str(name))
            freqs.append(hz)
            # The lit colour, BGR scaled to a brightest channel of 1 (a light
            # of unknown colour: white).
            rgb = np.asarray(m.color if getattr(m, "color", None) is not None else (255, 255, 255), float)[::-1]
            colours.append(rgb / max(float(rgb.max()), 1.0))
            self._sphere[str(name)] = radius is not None
        if not names:
            raise InputError("BlinkTracker: no marker has a blink_hz")
        self.marker_names = names
        self.freqs = np.array(freqs)
        self._lit_colours = np.array(colours)
        # The distinct colours among the lights that have one (white has
        # none), as masks of their own channels (see MeasureStage._own_frames):
        # light j's colour is _own_groups[_own_group[j]] (-1: none).
        self._own_groups: list[np.ndarray] = []
        self._own_group: list[int] = []
        for own in self._lit_colours >= 0.5:
            if own.all() or not p.own_colour:
                self._own_group.append(-1)
                continue
            k = next((g for g, o in enumerate(self._own_groups) if np.array_equal(o, own)), None)
            if k is None:
                self._own_groups.append(own)
                k = len(self._own_groups) - 1
            self._own_group.append(k)

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
        self.min_lit_fraction = number("min_lit_fraction", p.min_lit_fraction, 0.0, 1.0, lo_open=False)
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
        self.gate_speed = float(number("gate_speed", p.gate_speed, 0.0, math.inf, lo_open=False))
        self.expect_off = float(number("expect_off", p.expect_off, 0.0, 1.0, lo_open=False))
        self.birth_motion = bool(p.birth_motion)
        self.confirm_lit = bool(p.confirm_lit)
        self.inherit_identity = bool(p.inherit_identity)
        self.colour_contrast = float(number("colour_contrast", p.colour_contrast, 0.0, 255.0, lo_open=False))
        self.colour_match = float(number("colour_match", p.colour_match, 0.0, 1.0, lo_open=False))
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
        self._prev2: np.ndarray | None = None  # the frame before that (see BirthStage)
        self._prev_shift = np.zeros(2)  # camera shift from the frame before to the previous one
        self._colour: np.ndarray | None = None  # the current frame, (H, W, channels) uint8
        self._cur: np.ndarray | None = None  # the current frame's channel (see _advance)
        self._meas: np.ndarray | None = None  # its brightness, if the channel is a colour's
        # The current and previous frames in each of the lights' colours (see _own_frames).
        self._own_now: list[np.ndarray] = []
        self._own_prev: list[np.ndarray] = []
        self._prev_colour: np.ndarray | None = None  # the previous one, as it was (not aligned)
        self._prev_t = math.nan
        self._frame = 0
        self._times: deque[float] = deque(maxlen=self.window)
        self._tracks: list[Track] = []
        self._holders: dict = {}  # name -> (last holder, its blink, score, frame): InheritStage
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
        self.max_spread = 10.0 * scale  # px; see AssociationStage._commit
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

    def update(self, image: Any, t: float | None = None) -> DetectionResult:
        """Process the next frame; return the markers seen in it.

        ``image``: uint8 BGR ``(H, W, 3)`` or grayscale ``(H, W)`` (other dtypes
        as :func:`~mutloc.detect.base.as_bgr` accepts).  ``t``: its time in
        seconds, strictly increasing; default ``frame_index / fps``.
        """
        cur, colour = self._to_brightness(image)
        t = self._check_frame(cur, t)
        shift = self._motion.update(cur) if self.stabilize else np.zeros(2)
        return self._advance(cur, colour, t, shift)

    def _advance(self, cur: np.ndarray, colour: np.ndarray, t: float, shift: np.ndarray,
                 measure: np.ndarray | None = None) -> DetectionResult:
        """One frame (checked by :meth:`_check_frame`): brightness ``cur``,
        the image as (H, W, channels) ``colour``, the camera's ``shift`` since
        the previous frame.  ``measure``: where ``cur`` is one colour's own
        image (:mod:`~mutloc.detect.blink.channels`), the brightness image in
        which lit lights are measured (their glow and clipped cores are
        modelled in brightness, not in a difference of channels)."""
        self._cur, self._meas = cur, measure
        self._prev_colour, self._colour = self._colour, colour
        self._own_prev, self._own_now = self._own_now, self._own_frames(colour)
        prev = self._prev
        if prev is None:
            self._set_scale(min(cur.shape))
        self._times.append(t)
        if prev is not None:
            self._prev_shift, self.last_shift = self.last_shift, shift
            self._offset = self._offset + shift
            self._step(cur, prev, t, shift)
        self._prev2, self._prev = prev, cur
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

    def _step(self, cur: np.ndarray, prev_raw: np.ndarray, t: float, shift: np.ndarray) -> None:
        frame = self._frame
        prev, exposed = self._align(prev_raw, shift)
        cents, lit_now, spread = self._blobs(cur, prev, exposed)
        tracks = self._tracks
        off = self._offset
        for tr in tracks:
            tr.pos = tr.predict(t, self._horizon, off)

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
            dist, cost, inside = self._pair_costs(cents, lit_now.astype(bool), t, frame)
            nearest = np.argmin(cost, axis=1)
            reach = np.array([self._reach(tr.spread) for tr in tracks], float)
            absorb = dist[np.arange(nb), nearest] <= reach[nearest] + 3.0
            rows, cols = np.nonzero(inside)
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
                if (LIT_KEEPS_PREDICTION and event and self._meas is not None and tr.last_on_frame == frame - 1
                        and len(tr.samples) >= 2):
                    # Lit in the last frame, and predicted by its motion: a
                    # change to bright beside it in its colour's image is not
                    # its switching on (an edge moving past; trust seeds 45,
                    # 63: recentred 6.6 px off frame after frame, and measured
                    # there).  (In the brightness channel, where neighbours
                    # drag centroids, the change's region helps find the
                    # light: tests/test_blink_inherit.py.)
                    event = None
                if event:
                    # Just switched on: the region locates the light better
                    # than a prediction made across the off period.
                    centre = cents[primary[j]]
                    recentred = True
                    tr.spread += 0.3 * (spread[primary[j]] - tr.spread)
            uv = self._observe(tr, cur, prev, centre, event)
            if uv is None and recentred and tr.marker is not None:
                # No lit spot at the candidate (a change beside the light; 3 m seed 1 of
                # bench/blink_identity.py, frame 30): look where the light is predicted.
                # (For unidentified tracks too: wrong labels, tests/test_blink_colour.py.)
                tr.pop()
                uv = self._observe(tr, cur, prev, tr.pos + off, event)
                recentred = False
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
            if (tr.marker is None and not recentred and jump != math.inf
                    and jump > RESTART_REACHES * self._reach(tr.spread)):
                self._restart(tr, frame, t)
            observed.append((jump, j, uv))

        # --- unexplained candidates -> new tracks (nearby ones merged) ---
        born: list[np.ndarray] = []
        for r in np.flatnonzero(newborn):
            c = cents[r]
            if any(math.hypot(*(c - b)) <= self._reach(spread[r]) for b in born):
                continue
            born.append(c)
            tr = Track(id=self._next_id, pos=c - off, conf=self.boost, born_frame=frame, born_t=t,
                        spread=float(spread[r]),
                        hist=deque(maxlen=self.window), samples=deque(),
                        hist_own=[deque(maxlen=self.window) for _ in self._own_groups],
                        events=deque([True], maxlen=self.window), lit_frames=deque(maxlen=self.window),
                        last_polarity_on=bool(lit_now[r]))
            self._next_id += 1
            if self.birth_motion and not lit_now[r]:
                self._motion_at_birth(tr, c, prev_raw, cur, shift)
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
        # over the light's history by a fraction of a pixel.  A track
        # without a motion model predicted nothing: it yields to one with
        # (1.5 m seed 2: one born on the light's body while the light was
        # off took the light from its identified track 17 px behind). ---
        def claim_order(o: tuple[float, int, np.ndarray]) -> tuple[float, int]:
            tr = tracks[o[1]]
            if tr.marker is not None:
                return o[0], tr.born_frame
            lag = self.gate_px if len(tr.samples) >= 2 else UNMODELLED_CLAIM_PX
            return lag + max(o[0], 3.0), tr.born_frame

        # A spot a newcomer took where a lost light's track predicted it goes
        # to that track (inherit.py).
        observed = self._hand_over(observed, t)
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
        kept: list[Track] = []
        for tr in tracks:
            if tr.marker is not None or all(math.hypot(*(tr.pos - k.pos)) > 1.0 for k in kept):
                kept.append(tr)
        if len(kept) > self.max_tracks:
            kept.sort(key=lambda tr: (tr.marker is None, -tr.conf))
            kept = kept[: self.max_tracks]
        self._tracks = kept
        self._identify()
        if self.inherit_identity:
            self._inherit()

