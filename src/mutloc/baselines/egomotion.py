"""Relative camera pose from the shared scene: the Bundler-like baseline.

SIFT features in both images, Lowe's ratio test and a mutual-consistency
check, then OpenCV's five-point essential-matrix solver inside RANSAC and
the cheirality test (``recoverPose``).  Two views fix the translation only up
to scale: the experiments hand the true camera distance in (an oracle that
favours this baseline).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..core.camera import Camera
from ..core.pose import Pose
from ..errors import InputError, NoSolutionError

__all__ = ["Matches", "match_features", "essential_inliers", "egomotion_pose", "MIN_INLIERS"]

# Fewer RANSAC inliers than this and the two-view geometry is not trusted
# (Bundler's default for an image pair is 16 matches).
MIN_INLIERS = 16
RATIO = 0.8


@dataclass
class Matches:
    """Matched pixels: ``uv_a[i]`` in image a is ``uv_b[i]`` in image b."""

    uv_a: np.ndarray
    uv_b: np.ndarray

    def __len__(self) -> int:
        return len(self.uv_a)


def _gray(image: np.ndarray) -> np.ndarray:
    if image.ndim == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return image


def match_features(image_a: np.ndarray, image_b: np.ndarray, *, max_features: int = 0,
                   ratio: float = RATIO, mask_a: np.ndarray | None = None,
                   mask_b: np.ndarray | None = None) -> Matches:
    """SIFT matches between two images (ratio test + mutual best match)."""
    sift = cv2.SIFT_create(nfeatures=int(max_features))
    ka, da = sift.detectAndCompute(_gray(image_a), mask_a)
    kb, db = sift.detectAndCompute(_gray(image_b), mask_b)
    if da is None or db is None or len(ka) < 2 or len(kb) < 2:
        return Matches(np.empty((0, 2)), np.empty((0, 2)))
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    ab = matcher.knnMatch(da, db, k=2)
    ba = {m[0].queryIdx: m[0].trainIdx for m in matcher.knnMatch(db, da, k=1) if m}
    keep = [m[0] for m in ab if len(m) == 2 and m[0].distance < ratio * m[1].distance
            and ba.get(m[0].trainIdx) == m[0].queryIdx]
    uv_a = np.array([ka[m.queryIdx].pt for m in keep], float).reshape(-1, 2)
    uv_b = np.array([kb[m.trainIdx].pt for m in keep], float).reshape(-1, 2)
    return Matches(uv_a, uv_b)


def _normalized(camera: Camera, uv: np.ndarray) -> np.ndarray:
    # Undistorted normalized coordinates: the cameras may differ.
    x = camera.pixels_to_bearings(uv)
    return x[:, :2] / x[:, 2:]


def essential_inliers(matches: Matches, camera_a: Camera, camera_b: Camera, *, threshold_px: float = 1.0,
                      seed: int = 0) -> tuple[np.ndarray | None, np.ndarray]:
    """OpenCV's five-point essential matrix in RANSAC over ``matches`` and its
    inlier mask (E is None, mask all False, when there is none)."""
    none = np.zeros(len(matches), bool)
    if len(matches) < 5:
        return None, none
    f = 0.5 * (camera_a.K[0, 0] + camera_b.K[0, 0])
    cv2.setRNGSeed(int(seed))
    E, mask = cv2.findEssentialMat(_normalized(camera_a, matches.uv_a), _normalized(camera_b, matches.uv_b),
                                   np.eye(3), method=cv2.RANSAC, prob=0.999, threshold=threshold_px / f)
    if E is None or mask is None or E.shape != (3, 3):
        return None, none
    return E, mask.ravel() > 0


def egomotion_pose(image_a: np.ndarray, image_b: np.ndarray, camera_a: Camera, camera_b: Camera,
                   scale: float, *, threshold_px: float = 1.0, seed: int = 0,
                   matches: Matches | None = None) -> tuple[Pose, np.ndarray]:
    """``T_ba`` (camera a's frame into camera b's) from the two images, with
    ``|t| = scale``; returns the pose and which matches are its inliers
    (boolean mask over ``matches``, or over :func:`match_features`' result).

    Raises :class:`NoSolutionError` when fewer than :data:`MIN_INLIERS`
    matches agree on an essential matrix.
    """
    if not (np.isfinite(scale) and scale > 0):
        raise InputError(f"scale must be a positive number, got {scale!r}")
    m = matches if matches is not None else match_features(image_a, image_b)
    if len(m) < MIN_INLIERS:
        raise NoSolutionError(f"only {len(m)} feature matches between the two views (need {MIN_INLIERS})")
    E, inliers = essential_inliers(m, camera_a, camera_b, threshold_px=threshold_px, seed=seed)
    if E is None:
        raise NoSolutionError("no essential matrix from the feature matches")
    n, R, t, mask2 = cv2.recoverPose(E, _normalized(camera_a, m.uv_a), _normalized(camera_b, m.uv_b), np.eye(3),
                                     mask=inliers.astype(np.uint8).reshape(-1, 1))
    if int(n) < MIN_INLIERS:
        raise NoSolutionError(f"only {int(n)} matches agree on a relative pose (need {MIN_INLIERS})")
    t = t.ravel()
    return Pose(R, scale * t / np.linalg.norm(t)), mask2.ravel() > 0
