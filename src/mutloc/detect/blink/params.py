"""Tuning of the blinking-light tracker, in one frozen dataclass with
documented defaults (validated by :class:`~mutloc.detect.blink.BlinkTracker`,
which also needs the frame rate and the lights' frequencies to check them)."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["BlinkParams"]


@dataclass(frozen=True)
class BlinkParams:
    """How the light tracker finds, follows and identifies lights."""

    #: Minimum brightness change (0-255) between consecutive frames that counts
    #: as a light switching.
    diff_threshold: int = 40
    #: Factor applied to a track's confidence in each frame without support.
    decay: float = 0.8
    #: Added to a track's confidence (capped at 1) in each frame with support;
    #: also a new track's confidence.
    boost: float = 0.5
    #: Tracks below it are dropped.  None: low enough that a track survives 1.5
    #: half-periods of the slowest marker without support (a light only produces
    #: a differential when it switches).
    min_confidence: float | None = None
    #: Length (s) of the brightness history used to estimate frequency.  None:
    #: long enough to resolve the two closest marker frequencies (1 / spacing)
    #: and to hold two periods of the slowest, at least 1 s, at most 10 s.
    window_s: float | None = None
    #: History (s) a track needs before it may be given an identity (None: 0.7 window_s).
    min_history_s: float | None = None
    #: A track is named only if its light was taken to be lit in at least this
    #: fraction of the history scored (a light blinking half the time is lit
    #: in about half; a stray lit once is not a light).  0 disables it.
    min_lit_fraction: float = 0.25
    #: Minimum fraction of a track's brightness variance explained at a
    #: marker's frequency for the track to be that marker.
    min_score: float = 0.45
    #: Estimate and compensate the camera's global image translation.
    stabilize: bool = True
    #: Residual image motion (px per frame) of static things that must not
    #: register as a light switching.
    motion_radius: int = 2
    #: Half-size of the window, around a track's prediction, searched for its light's peak.
    search_radius: int = 6
    #: Half-size of the window, around the peak, over which the centroid is
    #: computed (must hold the light's bright spot).
    spot_radius: int = 5
    #: Pixels weigh in the centroid by how much they exceed
    #: ``background + centroid_level * (peak - background)``; the threshold keeps
    #: textured background out of it.
    centroid_level: float = 0.3
    #: A candidate may join a track, and a bright spot near it counts as its
    #: light, only within ``gate_px + growth * seconds_since_last_on`` pixels of
    #: its prediction (capped at ``max_gate_px``); the growth (px/s) is
    #: ``gate_growth`` plus ``gate_speed`` times the light's image speed, or ``max_speed``
    #: (the fastest image motion assumed, px/s; None: from the image size) while
    #: a track has no motion model yet.
    gate_px: float = 6.0
    gate_growth: float = 30.0
    max_speed: float | None = None
    max_gate_px: float = 40.0
    #: Fraction of a light's image speed added to its gate's growth: a fast
    #: light's prediction across an off period errs more (its motion in the
    #: motion-compensated image is not quite smooth when the camera pans; a
    #: tenth let a light at 1.5 m on a 4 s path escape its gate).
    gate_speed: float = 0.3
    #: An identified light's blink is fitted (phase and all) to its history;
    #: while the fit's fundamental is below ``-expect_off`` (well inside the
    #: "off" half) a bright spot at the light is taken for something else,
    #: and while above ``expect_off`` after an off period (due on) its gate
    #: is doubled.  1 disables both.  Just under 0.5: a 5 Hz light at 30 fps
    #: is off for three frames, the first and last at -0.5 exactly, and its
    #: red body (red in its own image whether lit or not) was taken for the
    #: lit light 10-15 px off in such frames (bench/blink_identity.py, 2 m
    #: seeds 7 and 14); lit frames sit at +0.5 and above.
    expect_off: float = 0.45
    #: A bright spot that fails the brightness-contrast test is still taken
    #: for a lit light if it has the colour of one of the lights (``color``,
    #: default white; each channel within ``colour_match`` of it, channels
    #: scaled to a brightest of 1) and that colour differs from the median of
    #: its surroundings by at least ``colour_contrast`` grey levels in some
    #: channel: a green light over a green poster barely changes the
    #: brightest channel but empties the others.  0 disables it.
    colour_contrast: float = 40.0
    colour_match: float = 0.25
    #: Lights of each colour (``color`` not white) are tracked in that
    #: colour's own image -- the least of its own channels less the largest
    #: of the others -- one channel per colour, white lights in the
    #: brightness channel (see :mod:`mutloc.detect.blink.channels`): pale and
    #: grey things, and lights of other colours, are dark there.  A grey
    #: stream has one channel.  False: every light in the brightness channel.
    by_colour: bool = True
    #: With ``by_colour`` False: lights of a colour are also sampled in their
    #: own colour -- the least of their own channels less the largest of the
    #: others -- to name them (a blue light over a pale wall barely changes
    #: the brightest channel when it switches) and to measure them where
    #: background of another colour drags the usual centre.  False: the
    #: brightest channel only.
    own_colour: bool = True
    #: A track born when its light switches off starts with a velocity,
    #: measured in the two frames before (where the light was lit; see
    #: :mod:`mutloc.detect.blink.birth`).  False: none until it is seen on.
    birth_motion: bool = True
    #: A light's name, just lost by its track, is handed at once to the
    #: unidentified track that took over its spot if that track's on / off
    #: history agrees with the light's fitted blink; revoked if it later
    #: disagrees (see :mod:`mutloc.detect.blink.inherit`).
    inherit_identity: bool = True
    #: A track given a name (or a new one) while its light is off, and that
    #: has moved since it was last seen lit, has its name reported only once
    #: the light is measured lit at it (a stray coasting over background was
    #: named; see :mod:`mutloc.detect.blink.identity`).  False: at once.
    confirm_lit: bool = True
    #: "On" centres of the last this many seconds feed the motion model.
    fit_window_s: float = 0.4
    #: Larger changed regions (a light switched in the room, a passing object),
    #: or more spread out ones (RMS radius in px), are not lights (None: from
    #: the image size).
    max_blob_area: int | None = None
    max_blob_std: float | None = None
    #: Cap on simultaneous tracks (identified, then confident ones kept).
    max_tracks: int = 128
    #: ``"max"`` (HSV value; coloured LEDs) or ``"gray"`` (luma).
    brightness: str = "max"
