"""Which frame a track's motion model lives in: stabilised or image-fixed.

The tracker predicts lights in motion-compensated ("stabilised") coordinates:
the background's shift is taken out, so a light on a robot moves only as the
robot does.  That is the better frame while the camera pans at a steady rate
past a robot.  But a camera that keeps the other robot in view turns with it:
at the turn the light is nearly still in the image while the background's
shift is still growing, so in stabilised coordinates the light decelerates
from 15 to 5 px a frame within ten frames, and a quadratic fitted over the
last 0.4 s -- through the peak of that speed -- overshoots across an off
period (bench/blink_identity.py, seed 5 at 2 m: 14.2 px at frame 36, four
frames after the light was last seen lit) where a quadratic in image
coordinates, whose speed changes more evenly there, misses by 10.1.

Both quadratics are fitted to the same "on" centres; the one that predicted
the latest centre better (by more than ``IMAGE_FRAME_NOISE_PX``) from the
centres before it (one step ahead, out of sample) is used to predict.  The stabilised fit stays the track's velocity
for its gate and report.
"""

from __future__ import annotations

import numpy as np

from .state import Track

__all__ = ["fit_quadratic", "choose_frame"]

# The image-fixed model must predict the latest centre better by more than a
# centroid's noise (px): the stabilised frame is the one the rest of the
# tracker was tuned in.  Measured on bench/blink_identity.py (seeds 3-5): a
# factor of 0.75 on the miss as well, or of 0.5, gained fewer frames (2 m
# seed 5: 35 of 60 instead of 39; at 0.5 the two wrong labels at 3 m stay).
IMAGE_FRAME_NOISE_PX = 0.3


def fit_quadratic(ts: np.ndarray, ps: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity and acceleration at ``ts[-1]`` by least squares
    (a line when the samples span too little time for a curve)."""
    n = len(ts)
    tau = ts - ts[-1]
    if n >= 4 and -tau[0] * fps >= 3.5:
        a = np.column_stack([np.ones(n), tau, 0.5 * tau * tau])
    else:
        a = np.column_stack([np.ones(n), tau])
    coef, *_ = np.linalg.lstsq(a, ps, rcond=None)
    acc = coef[2] if len(coef) > 2 else np.zeros(2)
    return coef[0], coef[1], acc


def _miss(ts: np.ndarray, ps: np.ndarray, fps: float) -> float:
    """How far the fit to all but the last sample misses the last one (px)."""
    p0, v, a = fit_quadratic(ts[:-1], ps[:-1], fps)
    dt = ts[-1] - ts[-2]
    return float(np.hypot(*(p0 + v * dt + 0.5 * a * dt * dt - ps[-1])))


def choose_frame(tr: Track, ts: np.ndarray, ps: np.ndarray, offsets: np.ndarray | None, fps: float) -> None:
    """Set ``tr.fixed`` to the image-fixed model ``(offset at the last sample,
    velocity, acceleration)`` when it predicts the track's light better, else
    None.  ``ps``: stabilised centres at times ``ts``; ``offsets``: the camera
    offsets at those times (None: unknown)."""
    tr.fixed = None
    if offsets is None or len(ts) < 3:
        return
    img = ps + offsets
    mi, mc = _miss(ts, img, fps), _miss(ts, ps, fps)
    if mc - mi > IMAGE_FRAME_NOISE_PX:
        _, v, a = fit_quadratic(ts, img, fps)
        tr.fixed = (offsets[-1].copy(), v, a)
