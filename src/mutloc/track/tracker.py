"""``mutloc track``: two image streams in, a trajectory of T_qp out.

Streams are paired by timestamp within a tolerance.  Every frame gets a
status; a frame with too few markers, a corrupt image or no partner is
reported as such and never guessed.  What was computed is kept whatever
happens later in the files.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping

import cv2
import numpy as np
from tqdm import tqdm

from ..api import Estimate, localize
from ..core.geometry import quaternion_xyzw_from_matrix
from ..core.rig import Rig
from ..detect.base import DetectionResult
from ..errors import MutlocError
from .frames import detect_markers, prepare_pair
from .sources import Frame

__all__ = ["TrackRow", "Trajectory", "pair_streams", "track"]


@dataclass
class TrackRow:
    """One paired frame (or one that could not be paired or solved)."""

    t: float
    t_source: float | None
    t_target: float | None
    status: str
    estimate: Estimate | None = None
    detections: dict[str, DetectionResult] = field(default_factory=dict)


@dataclass
class Trajectory:
    source: str
    target: str
    rows: list[TrackRow]

    @property
    def solved(self) -> list[TrackRow]:
        return [r for r in self.rows if r.estimate is not None]

    def write_tum(self, path: str | Path) -> None:
        """TUM format: ``timestamp tx ty tz qx qy qz qw``, p's pose in q's frame."""
        with open(path, "w") as f:
            f.write(f"# mutloc: pose of {self.source} in {self.target}'s camera frame (T_qp)\n")
            for r in self.solved:
                q = quaternion_xyzw_from_matrix(r.estimate.R)
                t = r.estimate.t
                f.write(f"{r.t:.9f} {t[0]:.9f} {t[1]:.9f} {t[2]:.9f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}\n")

    def write_csv(self, path: str | Path) -> None:
        """Every frame with its status; pose columns empty where unsolved."""
        cols = ["t", "t_source", "t_target", "status", "tx", "ty", "tz", "qx", "qy", "qz", "qw",
                "reprojection_rms_px", "markers_used"]
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(cols)
            for r in self.rows:
                row: list[Any] = [f"{r.t:.9f}", "" if r.t_source is None else f"{r.t_source:.9f}",
                                  "" if r.t_target is None else f"{r.t_target:.9f}", r.status]
                if r.estimate is not None:
                    q = quaternion_xyzw_from_matrix(r.estimate.R)
                    row += [f"{x:.9f}" for x in r.estimate.t] + [f"{x:.9f}" for x in q]
                    row += [f"{r.estimate.reprojection_rms_px:.4f}", " ".join(r.estimate.markers_used)]
                else:
                    row += [""] * 9
                w.writerow(row)


def pair_streams(a: Iterator[Frame], b: Iterator[Frame], tolerance: float) -> Iterator[tuple[Frame | None, Frame | None]]:
    """Merge two time-ordered streams: pairs within ``tolerance`` seconds,
    and each frame left without a partner on its own."""
    fa = next(a, None)
    fb = next(b, None)
    while fa is not None or fb is not None:
        if fa is None:
            yield None, fb
            fb = next(b, None)
        elif fb is None:
            yield fa, None
            fa = next(a, None)
        elif abs(fa.t - fb.t) <= tolerance:
            # Prefer the closest partner when the next frame of either is closer.
            na = next(a, None)
            if na is not None and abs(na.t - fb.t) < abs(fa.t - fb.t):
                yield fa, None
                fa = na
                continue
            yield fa, fb
            fa, fb = na, next(b, None)
        elif fa.t < fb.t:
            yield fa, None
            fa = next(a, None)
        else:
            yield None, fb
            fb = next(b, None)


class _Detector:
    """Per-observer detection, keeping blinking-light trackers across frames."""

    def __init__(self, rig: Rig, observer: str, other: str, fps: float):
        self.rig, self.observer, self.other = rig, observer, other
        markers = rig.robot(other).markers
        self.blink = None
        lights = {n: m for n, m in markers.items() if m.blink_hz is not None}
        if lights:
            from ..detect.blink import BlinkTracker

            self.blink = BlinkTracker(lights, fps)
        self.last_blink: DetectionResult | None = None

    def feed(self, frame: Frame) -> None:
        """Every frame of the stream, paired or not, drives the light tracker."""
        if self.blink is not None and frame.image is not None:
            self.last_blink = self.blink.update(frame.image, frame.t)

    def detect(self, frame: Frame) -> DetectionResult:
        res = detect_markers(self.rig, self.observer, frame.image, targets=[self.other])
        if self.last_blink is not None:
            res.detections.update(self.last_blink.detections)
            res.missing = [m for m in res.missing if m not in self.last_blink.detections]
        return res


def track(rig: Any, streams: Mapping[str, Iterator[Frame]], source: str | None = None, target: str | None = None, *,
          tolerance: float = 0.005, pixel_sigma: float = 1.0, fps: float | None = None,
          annotate: str | Path | None = None, progress: bool = True, total: int | None = None) -> Trajectory:
    """Localize over two streams (``{robot: frames}``)."""
    rig, source, target = prepare_pair(rig, streams, source, target, "stream")
    rate = fps or 30.0
    dets = {source: _Detector(rig, source, target, rate), target: _Detector(rig, target, source, rate)}
    writer = _Annotator(annotate) if annotate else None
    rows: list[TrackRow] = []
    pairs = pair_streams(streams[source], streams[target], tolerance)
    bar = tqdm(pairs, total=total, unit="frame", disable=not progress, desc="track")
    try:
        for fs, ft in bar:
            for robot, fr in ((source, fs), (target, ft)):
                if fr is not None:
                    dets[robot].feed(fr)
            t = np.mean([f.t for f in (fs, ft) if f is not None])
            row = TrackRow(float(t), fs.t if fs else None, ft.t if ft else None, "ok")
            if fs is None or ft is None:
                row.status = f"unpaired ({'no ' + source if fs is None else 'no ' + target} frame within {tolerance}s)"
            elif fs.image is None or ft.image is None:
                row.status = fs.status if fs.image is None else ft.status
            else:
                try:
                    row.detections = {source: dets[source].detect(fs), target: dets[target].detect(ft)}
                    obs = {r: d.pixels() for r, d in row.detections.items()}
                    n = sum(len(v) for v in obs.values())
                    if n < 3:
                        row.status = f"too few markers ({n})"
                    else:
                        row.estimate = localize(rig, obs, source, target, pixel_sigma=pixel_sigma)
                except MutlocError as exc:
                    row.status = " ".join(str(exc).split())
            rows.append(row)
            if writer is not None and fs is not None and ft is not None and fs.image is not None \
                    and ft.image is not None:
                writer.write(fs.image, ft.image, row, source, target)
    finally:
        bar.close()
        if writer is not None:
            writer.close()
    return Trajectory(source, target, rows)


class _Annotator:
    """Side-by-side video of both views with detections and the pose."""

    def __init__(self, path: str | Path, fps: float = 30.0):
        self.path = str(path)
        self.fps = fps
        self.vw: cv2.VideoWriter | None = None

    def write(self, img_s: np.ndarray, img_t: np.ndarray, row: TrackRow, source: str, target: str) -> None:
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
        text = row.status
        if row.estimate is not None:
            t = row.estimate.t
            text = f"{source} in {target}: t=({t[0]:+.3f}, {t[1]:+.3f}, {t[2]:+.3f}) m  rms {row.estimate.reprojection_rms_px:.2f}px"
        cv2.putText(frame, text, (10, h - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 255, 0), 2, cv2.LINE_AA)
        if self.vw is None:
            self.vw = cv2.VideoWriter(self.path, cv2.VideoWriter_fourcc(*"mp4v"), self.fps,
                                      (frame.shape[1], frame.shape[0]))
            if not self.vw.isOpened():
                raise MutlocError(f"{self.path}: cannot write the annotated video")
        self.vw.write(frame)

    def close(self) -> None:
        if self.vw is not None:
            self.vw.release()
