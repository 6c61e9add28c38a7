"""Annotated views: both robots' images side by side with the detections,
the status and the pose, as a video (``mutloc track --annotate``) or a still."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np


__all__ = ["draw_pair", "label", "Annotator", "STATUS_COLOURS"]


#: Colour (BGR) of each frame status in the annotated views: green when the
#: frame's own markers gave a pose, amber when the pose is the filter's
#: (a prediction, or a few markers through the filter), red when nothing.
STATUS_COLOURS = {"solved": (80, 200, 80), "unverified": (0, 200, 255), "partial": (0, 170, 255),
                  "predicted": (0, 170, 255)}
_NO_POSE_COLOUR = (60, 60, 230)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def label(canvas: np.ndarray, text: str, org: tuple[int, int], colour: tuple[int, int, int],
          scale: float = 0.6, thickness: int = 1) -> None:
    """``text`` with its baseline-left at ``org``, on a filled dark box
    (readable on any image), in place; the box is kept inside the canvas."""
    (w, h), base = cv2.getTextSize(text, _FONT, scale, thickness)
    pad = 4
    H, W = canvas.shape[:2]
    x = int(min(max(org[0], pad), max(W - w - pad, pad)))
    y = int(min(max(org[1], h + pad), H - base - pad))
    cv2.rectangle(canvas, (x - pad, y - h - pad), (x + w + pad, y + base + pad), (20, 20, 20), cv2.FILLED)
    cv2.putText(canvas, text, (x, y), _FONT, scale, colour, thickness, cv2.LINE_AA)


def draw_pair(img_s: np.ndarray, img_t: np.ndarray, row: Any, source: str, target: str) -> np.ndarray:
    """One annotated frame: ``row`` is a :class:`~mutloc.track.tracker.TrackRow`.
    The detections, each view's robot and time, and at the bottom the
    frame's status (coloured: :data:`STATUS_COLOURS`), its pose and reason."""
    views = []
    for robot, img in ((source, img_s), (target, img_t)):
        canvas = img.copy()
        det = row.detections.get(robot)
        if det is not None:
            for name, d in det.detections.items():
                u, v = float(d.uv[0]), float(d.uv[1])
                cv2.circle(canvas, (int(round(u)), int(round(v))), 8, (0, 255, 255), 2, cv2.LINE_AA)
                label(canvas, name, (int(u) + 10, int(v) - 10), (0, 255, 255), 0.45)
        label(canvas, f"{robot}  t={row.t:.3f}s", (10, 22), (255, 255, 255))
        views.append(canvas)
    h = max(v.shape[0] for v in views)
    views = [cv2.copyMakeBorder(v, 0, h - v.shape[0], 0, 0, cv2.BORDER_CONSTANT) for v in views]
    frame = np.hstack(views)
    status = str(row.status)
    text = status.upper()
    if row.estimate is not None:
        t = row.estimate.t
        text += f"  {source} in {target}: t=({t[0]:+.3f}, {t[1]:+.3f}, {t[2]:+.3f}) m"
        rms = getattr(row.estimate, "reprojection_rms_px", None)
        if rms is not None and np.isfinite(rms) and status in ("solved", "unverified"):
            text += f"  rms {rms:.2f}px"
    colour = STATUS_COLOURS.get(status, _NO_POSE_COLOUR)
    if row.reason:
        label(frame, row.reason[:160], (10, h - 40), colour, 0.5)
    label(frame, text, (10, h - 12), colour, 0.6, 2)
    return frame


class Annotator:
    """Writes annotated frames to an mp4 video at the stream's frame rate,
    each frame flushed as it comes (:class:`mutloc.io.video.VideoWriter`: a
    killed run leaves a video that plays); the folder is created if missing."""

    def __init__(self, path: str | Path, fps: float = 30.0):
        self.path = Path(path)
        self.fps = float(fps)
        self.vw: Any = None

    def write(self, img_s: np.ndarray, img_t: np.ndarray, row: Any, source: str, target: str) -> None:
        frame = draw_pair(img_s, img_t, row, source, target)
        if self.vw is None:
            from ..io.video import VideoWriter

            self.vw = VideoWriter(self.path, fps=self.fps)
        self.vw.write(frame)

    def close(self) -> None:
        if self.vw is not None:
            self.vw.close()
