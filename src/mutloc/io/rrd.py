"""A track as a Rerun recording (``.rrd`` file; the Rerun SDK, no viewer).

Entities (time line ``time``, seconds):

- ``world`` -- the target robot's camera frame (OpenCV axes: right, down,
  forward); ``world/TARGET`` its axes (static);
- ``world/SOURCE`` -- the source robot's camera frame: a ``Transform3D``
  (T_qp) per frame with a pose, drawn as axes;
- ``world/SOURCE_uncertainty`` -- the 3-sigma ellipsoid of its position
  (eigen-decomposition of the translation covariance);
- ``world/trajectory`` -- every position of the track, one line strip
  (static, written at the end);
- ``status`` -- each frame's status and reason (``TextLog``);
- a team (``source`` None): per robot ``world/ROBOT``,
  ``world/ROBOT_uncertainty``, ``world/trajectory_ROBOT`` and ``status/ROBOT``;
- ``images/ROBOT`` and ``images/ROBOT/detections`` -- when tracking from
  images: each camera's image (JPEG, quality :data:`JPEG_QUALITY`:
  ``EncodedImage``; raw frames would take 1.5 MB each at 960x540) and the
  detected markers, labelled with their names (``Points2D``).

Read it back with ``rerun.chunk.RrdReader(path)``, or open it in the viewer
(``rerun FILE.rrd``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .._extras import require
from ..core.pose import Pose
from ..errors import FileFormatError
from ._files import PathLike, one_line, writable_path
from .streaming import StreamWriter

__all__ = ["RerunWriter", "SIGMA_SCALE", "JPEG_QUALITY"]

#: Ellipsoid half-axes in standard deviations.
SIGMA_SCALE = 3.0

#: JPEG quality of the images in a recording.
JPEG_QUALITY = 85


class RerunWriter(StreamWriter):
    """Streams one track into an ``.rrd`` file, flushed to the file after
    each frame (see :mod:`mutloc.io.streaming`: the recording of a killed run
    opens with every frame written, without the ``world/trajectory`` line
    strips, which :meth:`close` writes); use as a context manager."""

    def __init__(self, path: PathLike, source: str | None, target: str, application_id: str = "mutloc") -> None:
        rr = require("rerun", "a Rerun recording")
        self.rr = rr
        self.path = writable_path(path, "the Rerun recording")
        self.paths = (self.path,)
        self.source, self.target = source, target
        self.rec = rr.RecordingStream(application_id)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.rec.save(str(self.path))
        except (OSError, RuntimeError) as exc:
            raise FileFormatError(f"{self.path}: cannot be written: {one_line(exc)}") from None
        self.positions: dict[str, list[np.ndarray]] = {}
        self.rec.log("world", rr.ViewCoordinates.RDF, static=True)
        self.rec.log(f"world/{target}", rr.TransformAxes3D(0.2), static=True)
        self.rec.flush()

    def frame(self, t: float, status: str, reason: str = "", pose: Pose | None = None,
              covariance: np.ndarray | None = None,
              images: Mapping[str, tuple[np.ndarray, Mapping[str, Any]]] | None = None,
              robot: str | None = None) -> None:
        """One frame at time ``t``: its status, the pose and covariance (SPEC
        order) if it has one, and ``images`` ``{robot: (BGR image,
        {marker: (u, v)})}`` if tracking from images.  ``robot``: whose pose
        it is, for a team (entities ``world/ROBOT``, ``status/ROBOT``,
        ``world/trajectory_ROBOT``); default the source robot."""
        rr, rec = self.rr, self.rec
        name = robot if robot is not None else self.source
        rec.set_time("time", duration=float(t))
        rec.log("status" if robot is None else f"status/{robot}",
                rr.TextLog(f"{status}: {reason}" if reason else str(status)))
        if pose is not None and pose.isfinite() and name is not None:
            rec.log(f"world/{name}", rr.Transform3D(translation=pose.t, mat3x3=pose.R),
                    rr.TransformAxes3D(0.2))
            self.positions.setdefault(name, []).append(np.asarray(pose.t, float).copy())
            if covariance is not None and np.all(np.isfinite(covariance)):
                w, V = np.linalg.eigh(np.asarray(covariance, float)[3:, 3:])
                if np.linalg.det(V) < 0:
                    V[:, 2] = -V[:, 2]
                q = Pose(V, np.zeros(3)).quaternion_xyzw
                rec.log(f"world/{name}_uncertainty",
                        rr.Ellipsoids3D(centers=[pose.t], half_sizes=[SIGMA_SCALE * np.sqrt(np.maximum(w, 0.0))],
                                        quaternions=[q], labels=[f"{status}"]))
        for robot, (image, detections) in (images or {}).items():
            rec.log(f"images/{robot}", self._jpeg(image))
            names = list(detections)
            pts = np.array([detections[n] for n in names], float).reshape(-1, 2)
            rec.log(f"images/{robot}/detections", rr.Points2D(pts, labels=names, radii=6.0, show_labels=True))
        rec.flush()
        self.rows += 1

    def _jpeg(self, image: np.ndarray) -> Any:
        """A BGR (or grey) image as a JPEG ``EncodedImage``."""
        import cv2

        ok, data = cv2.imencode(".jpg", np.ascontiguousarray(image), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:
            return self.rr.Image(image, color_model="BGR" if image.ndim == 3 else "L")
        return self.rr.EncodedImage(contents=data.tobytes(), media_type="image/jpeg")

    def write(self, t: float, status: str, reason: str = "", pose: Pose | None = None,
              covariance: np.ndarray | None = None,
              images: Mapping[str, tuple[np.ndarray, Mapping[str, Any]]] | None = None,
              robot: str | None = None) -> bool:
        """:meth:`frame` under the common writer interface."""
        self.frame(t, status, reason, pose, covariance, images, robot)
        return True

    def _close(self) -> None:
        """Write the whole trajectory and close the file."""
        for name, pos in self.positions.items():
            path = "world/trajectory" if name == self.source else f"world/trajectory_{name}"
            self.rec.log(path, self.rr.LineStrips3D([np.array(pos)]), static=True)
        self.rec.flush()
        self.rec.disconnect()
