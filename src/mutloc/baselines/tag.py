"""One-sided pose from a printed square tag: the ARToolKit-like baseline.

The observer's camera finds the other robot's tag with OpenCV's ArUco /
AprilTag detector (sub-pixel corners) and solves the tag's pose with OpenCV's
square-marker PnP (``SOLVEPNP_IPPE_SQUARE``); the tag's known mounting on its
robot then gives the robot's camera pose.  Only one camera is used.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..core.camera import Camera
from ..core.pose import Pose
from ..core.rig import Marker
from ..errors import NoSolutionError, ObservationError

__all__ = ["tag_pose", "detect_tag_corners"]

# OpenCV's IPPE_SQUARE frame is x right, y up, z out of the printed side;
# mutloc's tag frame is x right, y down, z into the tag (see detect.tags).
_FLIP = np.diag([1.0, -1.0, -1.0])


def detect_tag_corners(image: np.ndarray, marker: Marker) -> np.ndarray:
    """The four corners (4, 2) of ``marker``'s tag in ``image`` by OpenCV's
    own detector with sub-pixel refinement (ObservationError if not seen)."""
    from ..detect.tags import detect_tags

    res = detect_tags(image, {marker.name: marker}, refine="subpix")
    det = res.detections.get(marker.name)
    if det is None or det.corners is None:
        raise ObservationError(f"tag {marker.name!r} not found in the image")
    return np.asarray(det.corners, float)


def tag_pose(image: np.ndarray, marker: Marker, camera: Camera) -> Pose:
    """Pose of the tag's robot (its camera frame) in the observer's camera
    frame, from ``image`` alone: ``T_observer_robot``.

    ``marker`` is a tag marker whose ``tag.rotation`` gives its orientation
    on the robot.  Raises :class:`ObservationError` when the tag is not found
    and :class:`NoSolutionError` when PnP fails.
    """
    from ..detect.tags import tag_rotation, tag_spec

    _family, _tid, size = tag_spec(marker)
    R_rt = tag_rotation(marker)
    if R_rt is None:
        raise ObservationError(f"tag {marker.name!r} has no rotation in the rig: its pose on the robot is unknown")
    corners = detect_tag_corners(image, marker)
    h = 0.5 * size
    obj = np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])
    ok, rvec, tvec = cv2.solvePnP(obj, corners.reshape(4, 1, 2), camera.K, np.asarray(camera.dist, float),
                                  flags=cv2.SOLVEPNP_IPPE_SQUARE)
    if not ok or not np.all(np.isfinite(rvec)) or not np.all(np.isfinite(tvec)):
        raise NoSolutionError(f"square-marker PnP failed for tag {marker.name!r}")
    T_ct = Pose(cv2.Rodrigues(rvec)[0], tvec.ravel())
    T_rt = Pose(R_rt @ _FLIP, np.asarray(marker.position, float))
    return T_ct @ T_rt.inverse()

