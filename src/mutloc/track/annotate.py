"""Annotated views: both robots' images side by side with the detections,
the status and the pose, as a video (``mutloc track --annotate``) or a still."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..errors import MutlocError

__all__ = ["draw_pair", "Annotator"]


def draw_pair(img_s: np.ndarray, img_t: np.ndarray, row: Any, source: str, target: str) -> np.ndarray:
    """One annotated frame: ``row`` is a :class:`~mutloc.track.tracker.TrackRow`."""
    views = []
    for robot, img in ((source, img_s), (target, img_t)):
        canvas = img.copy()
        det = row.detections.get(robot)
        if det is not None:
            for name, d in det.detections.items():
                u, v = float(d.uv[0]), float(d.uv[1])
                cv2.circle(canvas, (int(round(u)), int(round(v))), 8, (0, 255, 255), 2, cv2.LINE_AA)
                cv2.putText(canvas, name, (int(u) + 10, int(v) - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                            (0, 255, 255), 1, cv2.LINE_AA)
        cv2.putText(canvas, f"{robot}  t={row.t:.3f}s", (10, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6,
                    (255, 255, 255), 2, cv2.LINE_AA)
        views.append(canvas)
    h = max(v.shape[0] for v in views)
    views = [cv2.copyMakeBorder(v, 0, h - v.shape[0], 0, 0, cv2.BORDER_CONSTANT) for v in views]
    frame = np.hstack(views)
    text = f"{row.status}: {row.reason}" if row.reason else str(row.status)
    if row.estimate is not None:
        t = row.estimate.t
        text = f"{source} in {target}: t=({t[0]:+.3f}, {t[1]:+.3f}, {t[2]:+.3f}) m  rms {row.estimate.reprojection_rms_px:.2f}px"
    cv2.putText(frame, text, (10, h - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 255, 0), 2, cv2.LINE_AA)
    return frame


class Annotator:
    """Writes annotated frames to an mp4 video at the stream's frame rate
    (the folder is created if missing)."""

    def __init__(self, path: str | Path, fps: float = 30.0):
        self.path = Path(path)
        self.fps = float(fps)
        self.vw: cv2.VideoWriter | None = None

    def write(self, img_s: np.ndarray, img_t: np.ndarray, row: Any, source: str, target: str) -> None:
        frame = draw_pair(img_s, img_t, row, source, target)
        if self.vw is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.vw = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*"mp4v"), self.fps,
                                      (frame.shape[1], frame.shape[0]))
            if not self.vw.isOpened():
                raise MutlocError(f"{self.path}: cannot write the annotated video")
        self.vw.write(frame)

    def close(self) -> None:
        if self.vw is not None:
            self.vw.release()
