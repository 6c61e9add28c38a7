"""Annotated views: both robots' images side by side with the detections,
the status and the pose, as a video (``mutloc track --annotate``) or a
still; for a team, every robot's camera tiled with one status line per robot."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np


__all__ = ["draw_pair", "draw_team", "label", "Annotator", "STATUS_COLOURS"]


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
        _draw_detections(canvas, row.detections.get(robot))
        label(canvas, f"{robot}  t={row.t:.3f}s", (10, 22), (255, 255, 255))
        views.append(canvas)
    h = max(v.shape[0] for v in views)
    views = [cv2.copyMakeBorder(v, 0, h - v.shape[0], 0, 0, cv2.BORDER_CONSTANT) for v in views]
    frame = np.hstack(views)
    text, colour = _pose_text(row, source, target)
    if row.reason:
        label(frame, row.reason[:160], (10, h - 40), colour, 0.5)
    label(frame, text, (10, h - 12), colour, 0.6, 2)
    return frame


def _pose_text(row: Any, source: str, target: str) -> tuple[str, tuple[int, int, int]]:
    """A row's status line (upper-case status, pose, rms) and its colour."""
    status = str(row.status)
    text = status.upper()
    if row.estimate is not None:
        t = row.estimate.t
        text += f"  {source} in {target}: t=({t[0]:+.3f}, {t[1]:+.3f}, {t[2]:+.3f}) m"
        rms = getattr(row.estimate, "reprojection_rms_px", None)
        if rms is not None and np.isfinite(rms) and status in ("solved", "unverified"):
            text += f"  rms {rms:.2f}px"
    return text, STATUS_COLOURS.get(status, _NO_POSE_COLOUR)


def _draw_detections(canvas: np.ndarray, det: Any) -> None:
    if det is None:
        return
    for name, d in det.detections.items():
        u, v = float(d.uv[0]), float(d.uv[1])
        cv2.circle(canvas, (int(round(u)), int(round(v))), 8, (0, 255, 255), 2, cv2.LINE_AA)
        label(canvas, name, (int(u) + 10, int(v) - 10), (0, 255, 255), 0.45)


#: Height (px) of one robot's status line under a team's tiled views.
TEAM_LINE = 26


def team_layout(sizes: dict[str, tuple[int, int]], robots: int) -> tuple[int, int, int, int]:
    """A team view's grid for cameras of ``sizes`` (``(width, height)`` per
    robot) and ``robots`` status lines: ``(columns, cell width, cell
    height, frame height)`` (up to three cameras a row; under them the
    record's time and the robots' lines)."""
    cols = min(len(sizes), 3)
    rows = -(-len(sizes) // cols)
    w = max(s[0] for s in sizes.values())
    h = max(s[1] for s in sizes.values())
    return cols, w, h, rows * h + (robots + 1) * TEAM_LINE + 8


def draw_team(images: dict[str, tuple[np.ndarray | None, float | None]], rows: dict[str, Any], reference: str,
              sizes: dict[str, tuple[int, int]]) -> np.ndarray:
    """One annotated record of a team: every robot's camera (``images``:
    per robot its latest image and that frame's time, None before its
    first; ``sizes``: each camera's ``(width, height)``) in a grid, with the
    detections of the cameras whose frame is in the record, and under it one
    line per robot of ``rows`` (:class:`~mutloc.track.tracker.TrackRow` per
    robot but the reference): its status (coloured: :data:`STATUS_COLOURS`),
    its pose in the reference's frame and the reason."""
    cols, cw, ch, H = team_layout(sizes, len(rows))
    n_rows = -(-len(sizes) // cols)
    frame = np.zeros((H, cols * cw, 3), np.uint8)
    any_row = next(iter(rows.values()), None)
    detections = getattr(any_row, "detections", None) or {}
    t_rec = any_row.t if any_row is not None else 0.0
    for k, robot in enumerate(sizes):
        x, y = (k % cols) * cw, (k // cols) * ch
        w, h = sizes[robot]
        img, t = images.get(robot, (None, None))
        if img is None:
            canvas = np.full((h, w, 3), 40, np.uint8)
            label(canvas, f"{robot}  no frame yet", (10, 22), (160, 160, 160))
        else:
            canvas = img if img.ndim == 3 else cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
            canvas = canvas.copy() if canvas.shape[:2] == (h, w) else cv2.resize(canvas, (w, h))
            fresh = robot in detections
            if fresh:
                _draw_detections(canvas, detections[robot])
            what = f"t={t:.3f}s" if fresh else f"last frame t={t:.3f}s"
            label(canvas, f"{robot}  {what}" + ("  (reference)" if robot == reference else ""), (10, 22),
                  (255, 255, 255) if fresh else (160, 160, 160))
        frame[y:y + h, x:x + w] = canvas
    y0 = n_rows * ch + TEAM_LINE - 6
    label(frame, f"record t={t_rec:.3f}s (poses in {reference}'s frame)", (10, y0), (255, 255, 255), 0.5)
    for j, (robot, row) in enumerate(rows.items(), start=1):
        text, colour = _pose_text(row, robot, reference)
        if row.reason:
            text += f"  | {row.reason[:110]}"
        label(frame, text, (10, y0 + j * TEAM_LINE), colour, 0.5, 1)
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
        self._write(draw_pair(img_s, img_t, row, source, target))

    def write_team(self, images: dict[str, tuple[np.ndarray | None, float | None]], rows: dict[str, Any],
                   reference: str, sizes: dict[str, tuple[int, int]]) -> None:
        """One record of a team (see :func:`draw_team`)."""
        self._write(draw_team(images, rows, reference, sizes))

    def _write(self, frame: np.ndarray) -> None:
        if self.vw is None:
            from ..io.video import VideoWriter

            self.vw = VideoWriter(self.path, fps=self.fps)
        self.vw.write(frame)

    def close(self) -> None:
        if self.vw is not None:
            self.vw.close()
