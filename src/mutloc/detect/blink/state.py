"""What the light tracker keeps per candidate light: tracks and background plates."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Plate", "Track"]


@dataclass
class Plate:
    """The neighbourhood of a light while it was off: the background its halo
    is measured against when it is on (see LightTracker._halo_centre)."""

    lin: np.ndarray  # float32 (h, w, channels), linear light
    x0: int  # image column of lin[:, 0] then
    y0: int  # image row of lin[0] then
    offset: np.ndarray  # the tracker's cumulative camera offset then
    light: np.ndarray  # where the dark light was (image coordinates then)
    frame: int


@dataclass
class Track:
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
    samples: deque  # (t, pos, camera offset then) of recent "on" centres, for the motion model
    # The motion model, fitted in both frames: motion-compensated coordinates
    # (vel, acc: the light moves smoothly over the scene) and image
    # coordinates (vel_img, acc_img: the camera follows the light, so
    # compensating adds the camera's jerks to its motion).
    vel: np.ndarray = field(default_factory=lambda: np.zeros(2))  # px / s
    acc: np.ndarray = field(default_factory=lambda: np.zeros(2))  # px / s^2
    vel_img: np.ndarray = field(default_factory=lambda: np.zeros(2))
    acc_img: np.ndarray = field(default_factory=lambda: np.zeros(2))
    stabilised: bool = True  # which of the two predicts (see AssociationStage._commit)
    miss: np.ndarray | None = None  # running prediction error (px) of the two, after off periods
    misses: int = 0  # off periods counted in ``miss``
    hi: float = math.nan  # learned peak brightness when on
    lo: float = math.nan  # learned peak brightness when off
    is_on: bool = False
    last_on_pos: np.ndarray | None = None
    last_on_offset: np.ndarray = field(default_factory=lambda: np.zeros(2))  # camera offset then
    last_on_t: float = math.nan
    last_on_frame: int = -1
    last_polarity_on: bool = True
    spread: float = 1.5  # RMS radius of the light's region of change (px): its size
    jump: float = math.inf  # distance from prediction to this frame's measurement (px)
    marker: str | None = None
    score: float = 0.0
    scores: dict[str, float] = field(default_factory=dict)
    measured_spread: float = 1.5  # RMS radius of the spot found this frame (px)
    report_shift: np.ndarray = field(default_factory=lambda: np.zeros(2))  # this frame's finer centre less the tracked one
    dark: bool = False  # this frame: clearly off (a background plate may be taken)
    clip_radius: float = math.nan  # radius (px) of the clipped core when last on
    measured_area: float = math.nan  # apparent area (px^2) of the spot found this frame
    area: float = math.nan  # apparent area of the lit light (px^2), smoothed over "on" frames
    by_colour: bool = False  # this frame: taken for lit by its colour contrast alone
    plates: list[Plate] = field(default_factory=list)  # oldest first
    # The identified light's blink, fitted to its history: (time of the last
    # sample, frequency, cosine and sine amplitudes); None if unidentified.
    blink: tuple[float, float, float, float] | None = None
    inherited: str | None = None  # a name taken over from a lost track (see inherit.py)
    no_inherit: bool = False  # an inherited name was revoked: never inherit again
    unconfirmed: bool = False  # named while coasting, not reported yet (see identity.py)
    # Per colour of the markers (see LightTracker._own_groups), the peak
    # brightness near the light in that colour, in step with ``hist``.
    hist_own: list = field(default_factory=list)
    # Frames (the last ``window`` of them) in which the light was taken to be lit.
    lit_frames: deque = field(default_factory=deque)

    def push(self, peak: float, own: list[float]) -> None:
        """This frame's samples: the peak brightness and, per colour, the peak in that colour."""
        self.hist.append(peak)
        for d, v in zip(self.hist_own, own):
            d.append(v)

    def pop(self) -> None:
        """Take back this frame's samples."""
        self.hist.pop()
        for d in self.hist_own:
            d.pop()

    def expect_on(self, t: float) -> float:
        """How surely the identified light is on at ``t``: the fitted
        fundamental, normalised to [-1, 1] (> 0: on; NaN: unknown).  A 50 %
        square wave's fundamental peaks mid-way through its "on" half."""
        if self.blink is None:
            return math.nan
        t0, f, a, b = self.blink
        amp = math.hypot(a, b)
        if amp <= 0.0:
            return math.nan
        w = 2.0 * math.pi * f * (t - t0)
        return (a * math.cos(w) + b * math.sin(w)) / amp

    def predict(self, t: float, horizon: float, offset: np.ndarray) -> np.ndarray:
        """Position at time ``t`` from the motion model, in stabilised
        coordinates; ``offset`` is the camera offset at ``t``."""
        return self.predict_in(t, horizon, self.stabilised, offset)

    def speed(self) -> float:
        """The light's speed (px / s) in the frame its motion model predicts in."""
        return float(np.hypot(*(self.vel if self.stabilised else self.vel_img)))

    def predict_in(self, t: float, horizon: float, stabilised: bool, offset: np.ndarray) -> np.ndarray:
        """:meth:`predict` by the model of one frame (``stabilised``: the
        motion-compensated one, else the image's)."""
        if self.last_on_pos is None:
            return self.pos
        dt = min(t - self.last_on_t, horizon)  # never extrapolate a curve far
        if stabilised:
            return self.last_on_pos + self.vel * dt + 0.5 * self.acc * dt * dt
        step = self.vel_img * dt + 0.5 * self.acc_img * dt * dt
        return self.last_on_pos + self.last_on_offset + step - offset

    def lit_since(self, frame: int) -> int:
        """How many frames after ``frame`` the light was taken to be lit in."""
        return sum(1 for f in self.lit_frames if f > frame)

    def last_seen_frame(self) -> int:
        return self.last_on_frame if self.last_on_frame >= 0 else self.born_frame


