"""Lights tracked per colour: :class:`BlinkTracker`, the public light detector.

A blue light over a pale wall barely changes the brightest channel when it
switches, and a yellow poster is as bright as a yellow light in it.  In the
light's own colour -- the least of its own channels less the largest of the
others (:func:`~mutloc.detect.blink.measure.own_colour_image`) -- pale and
grey things are dark and only things of that colour are bright.  So each
colour of light gets its own :class:`~mutloc.detect.blink.tracker.LightTracker`
on its own image, white lights one on the brightness channel, and all share
one estimate of the camera's motion (made on the brightness channel, where
the scene has its texture).  Measured on the varied-motion benches
(``bench/trust_sequences.py``, docs/benchmarks.md): frames that correct detections
solve, solved on fresh seeds 30-39, from 69 % with every light in the
brightness channel to 95 % and more.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np

from ...core.camera import Camera
from ...core.rig import Marker
from ...errors import InputError
from ..base import DetectionResult, as_bgr
from .measure import own_colour_image
from .motion import GlobalMotion
from .params import BlinkParams
from .tracker import LightTracker

__all__ = ["BlinkTracker", "colour_groups"]


def colour_groups(markers: Mapping[str, Marker]) -> list[tuple[np.ndarray | None, dict[str, Marker]]]:
    """The blinking lights by colour: ``[(own, {name: marker})]`` with
    ``own`` the mask of the colour's own channels (BGR; a channel counts if
    it is at least half the brightest), None for white lights (or no ``color``)."""
    groups: dict[tuple[bool, ...] | None, dict[str, Marker]] = {}
    for name, m in markers.items():
        if getattr(m, "blink_hz", None) is None:
            continue
        color = getattr(m, "color", None)
        own: tuple[bool, ...] | None = None
        if color is not None:
            bgr = np.asarray(color, float)[::-1]
            mask = bgr >= 0.5 * max(float(bgr.max()), 1.0)
            own = None if mask.all() else tuple(bool(x) for x in mask)
        groups.setdefault(own, {})[name] = m
    return [(None if own is None else np.array(own), ms) for own, ms in groups.items()]


class BlinkTracker:
    """Streaming detector of blinking-light markers, told apart by ``blink_hz``.

    Call :meth:`update` once per frame; it returns a
    :class:`~mutloc.detect.base.DetectionResult` with a detection for every
    marker confidently tracked and identified, and the others in ``missing``.
    How: :mod:`mutloc.detect.blink.tracker` (one channel) and this module
    (one channel per colour of light, ``BlinkParams.by_colour``).

    Parameters
    ----------
    markers:
        The markers to look for, ``{name: Marker}`` (e.g. ``rig.robot("q").markers``:
        what one camera can see).  Markers without ``blink_hz`` are ignored; at
        least one must have it, and no two may blink at frequencies the window
        cannot resolve.
    fps:
        Nominal frame rate; frame ``k`` is at ``k / fps`` seconds unless
        :meth:`update` is given the time.  Every ``blink_hz`` must be below
        ``fps / 2`` (Nyquist).
    params:
        The tuning, :class:`~mutloc.detect.blink.params.BlinkParams` (each value
        documented there); default ``BlinkParams()``.
    camera:
        The camera's model, optional: any lens (:class:`~mutloc.core.camera.Camera`,
        :class:`~mutloc.core.lenses.FisheyeCamera`, :class:`~mutloc.core.lenses.OmniCamera`).
        The tracker works on the raw image whatever the lens (one tracker per
        camera; positions are the raw image's pixels).
        With it, a light whose marker has a ``radius`` (rig key, metres: a
        diffusing sphere) is reported at the projection of its centre, not at
        the centre of its image: a sphere images as an ellipse whose centre
        lies outward of that projection (see :mod:`mutloc.core.sphere`; the
        angular radius comes from the lit spot's apparent area).
    """

    def __init__(self, markers: Mapping[str, Marker], fps: float, *, params: BlinkParams | None = None,
                 camera: Camera | None = None) -> None:
        # All the lights in one channel: checks every marker, the frame rate
        # and the frequencies' spacing, fixes the window -- and tracks a grey
        # stream, which has no colours to tell apart.
        self._whole = LightTracker(markers, fps, params=params, camera=camera)
        p = params if params is not None else BlinkParams()
        self.params = p
        self._channels: list[tuple[np.ndarray | None, LightTracker]] = []
        groups = colour_groups(markers) if p.by_colour else []
        if any(own is not None for own, _ in groups):
            # One window for all: each channel must tell its lights' blink
            # from the other colours' frequencies as well as the whole would.
            sub = dataclasses.replace(p, window_s=self._whole.window_s, own_colour=False)
            for own, ms in groups:
                self._channels.append((own, LightTracker(ms, fps, params=sub, camera=camera)))
        self._motion = GlobalMotion()
        self.reset()

    # The whole's figures are every channel's (one window, one frame rate).
    @property
    def marker_names(self) -> list[str]:
        return self._whole.marker_names

    @property
    def freqs(self) -> np.ndarray:
        return self._whole.freqs

    @property
    def window_s(self) -> float:
        return self._whole.window_s

    @property
    def min_history(self) -> int:
        return self._whole.min_history

    @property
    def fps(self) -> float:
        return self._whole.fps

    def reset(self) -> None:
        """Forget every track and the previous frame (e.g. after a cut)."""
        self._whole.reset()
        for _, ch in self._channels:
            ch.reset()
        self._motion.reset()
        self._grey: bool | None = None  # decided by the stream's first frame
        self.last_shift = np.zeros(2)

    def track_states(self) -> list[dict[str, Any]]:
        """A snapshot of the current tracks in image coordinates (debugging,
        display); ``channel``: the colour's own channels (BGR mask), None for
        the brightness channel."""
        if self._grey or not self._channels:
            return [dict(s, channel=None) for s in self._whole.track_states()]
        return [dict(s, channel=None if own is None else own.tolist())
                for own, ch in self._channels for s in ch.track_states()]

    def update(self, image: Any, t: float | None = None) -> DetectionResult:
        """Process the next frame; return the markers seen in it.

        ``image``: uint8 BGR ``(H, W, 3)`` or grayscale ``(H, W)`` (other dtypes
        as :func:`~mutloc.detect.base.as_bgr` accepts).  ``t``: its time in
        seconds, strictly increasing; default ``frame_index / fps``.
        """
        if not self._channels:
            res = self._whole.update(image, t)
            self.last_shift = self._whole.last_shift
            return res
        grey = isinstance(image, np.ndarray) and (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 1))
        if self._grey is not None and grey != self._grey:
            raise InputError("BlinkTracker.update: the stream changed between colour and grey images "
                             "(call reset() between streams)")
        if grey:
            res = self._whole.update(image, t)
            self._grey = True
            self.last_shift = self._whole.last_shift
            return res
        bgr = as_bgr(image, "BlinkTracker.update image")
        bright, _ = self._whole._to_brightness(bgr)
        lead = self._channels[0][1]
        t = lead._check_frame(bright, t)
        shift = self._motion.update(bright) if self.params.stabilize else np.zeros(2)
        self.last_shift = shift
        chans = cv2.split(bgr)
        res = DetectionResult()
        for own, ch in self._channels:
            if own is None:
                r = ch._advance(bright, bgr, t, shift)
            else:
                r = ch._advance(own_colour_image(chans, own), bgr, t, shift, measure=bright)
            res.merge(r)
        order = {n: i for i, n in enumerate(self.marker_names)}
        res.missing.sort(key=order.__getitem__)
        self._grey = False
        return res
