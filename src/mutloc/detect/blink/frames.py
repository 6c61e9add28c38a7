"""Frame intake of the light tracker: the brightness channel, and the checks
every frame passes (size, time) before it is tracked."""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

from ...errors import InputError
from ..base import as_bgr

__all__ = ["FrameStage"]


class FrameStage:
    """Methods of :class:`~mutloc.detect.blink.tracker.LightTracker` for this stage (it holds the state)."""

    def _to_brightness(self, image: Any) -> tuple[np.ndarray, np.ndarray]:
        """The brightness channel, and the image as (H, W, channels) uint8
        (BGR, or the grey image itself) for measuring lit lights."""
        if isinstance(image, np.ndarray) and image.ndim == 2 and image.dtype == np.uint8:
            if image.shape[0] < 2 or image.shape[1] < 2:
                raise InputError(f"BlinkTracker.update: image too small, shape {image.shape}")
            cur = np.ascontiguousarray(image)
            return cur, cur[:, :, None]
        bgr = as_bgr(image, "BlinkTracker.update image")
        if self.brightness == "gray":
            return cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY), bgr
        return cv2.max(cv2.max(bgr[:, :, 0], bgr[:, :, 1]), bgr[:, :, 2]), bgr

    def _check_frame(self, cur: np.ndarray, t: float | None) -> float:
        """The frame's time (validated); the frame's size checked against the stream's."""
        if t is None:
            t = self._frame / self.fps
        else:
            try:
                t = float(t)
            except (TypeError, ValueError):
                raise InputError(f"BlinkTracker.update: t must be a number, got {t!r}") from None
            if not math.isfinite(t):
                raise InputError(f"BlinkTracker.update: t must be finite, got {t}")
        prev = self._prev
        if prev is not None:
            if cur.shape != prev.shape:
                raise InputError(
                    f"BlinkTracker.update: image size changed from {prev.shape[::-1]} to "
                    f"{cur.shape[::-1]} (call reset() between streams)"
                )
            if not t > self._prev_t:
                raise InputError(f"BlinkTracker.update: time {t} does not increase (previous {self._prev_t})")
        elif self.camera is not None and self.camera.size is not None \
                and tuple(self.camera.size) != (cur.shape[1], cur.shape[0]):
            raise InputError(f"BlinkTracker.update: image size {cur.shape[::-1]} is not the camera's "
                             f"{tuple(self.camera.size)}")
        return t
