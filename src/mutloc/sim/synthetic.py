"""Synthetic two-robot geometries with ground truth (no rendering).

Used by the tests, the benchmarks and the demo.  A scene holds ``T_qp`` and
each robot's marker positions in its own camera frame; observations are exact
bearings or pixels, optionally with Gaussian pixel noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.geometry import Pose, so3_exp

__all__ = ["Scene", "facing_pose", "usual_mounting", "random_layout", "USUAL_MARKERS"]

# Two balls left and right of the camera, a little below and behind it.
USUAL_MARKERS = np.array([[-0.15, -0.05, -0.03], [0.15, -0.05, -0.03]])


@dataclass
class Scene:
    """Ground truth: ``pose`` is T_qp; markers are in their own robot's frame."""

    pose: Pose
    markers_p: np.ndarray
    markers_q: np.ndarray

    def points_p_in_q(self) -> np.ndarray:
        return self.pose.apply(self.markers_p)

    def points_q_in_p(self) -> np.ndarray:
        return self.pose.inverse().apply(self.markers_q)

    def bearings_p(self) -> np.ndarray:
        """Unit rays in p's frame towards q's markers."""
        v = self.points_q_in_p()
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    def bearings_q(self) -> np.ndarray:
        """Unit rays in q's frame towards p's markers."""
        v = self.points_p_in_q()
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    def all_in_front(self) -> bool:
        return bool(np.all(self.points_q_in_p()[:, 2] > 0) and np.all(self.points_p_in_q()[:, 2] > 0))


def facing_pose(distance: float, yaw_p: float = 0.0, yaw_q: float = 0.0, lateral: float = 0.0,
                tilt: np.ndarray | None = None) -> Pose:
    """T_qp for p placed ``distance`` in front of q, both facing each other.

    ``yaw_p``/``yaw_q`` (radians) turn each camera away from the line of
    sight about its y axis; ``lateral`` shifts p sideways in q's frame.
    ``tilt`` is an extra small rotation vector applied to p.
    """
    # p's frame seen from q: rotated 180 degrees about y, then p's own yaw.
    R = so3_exp([0.0, np.pi + yaw_p, 0.0])
    if tilt is not None:
        R = R @ so3_exp(tilt)
    t = np.array([lateral, 0.0, distance])
    T_q_p = Pose(R, t)
    # q's own yaw rotates q's frame: x_q' = Ry(-yaw_q) x_q.
    return Pose(so3_exp([0.0, -yaw_q, 0.0]), np.zeros(3)) @ T_q_p


def usual_mounting(rng: np.random.Generator, distance: tuple[float, float] = (0.5, 5.0),
                   jitter: float = 0.02, max_yaw_deg: float = 20.0, exact_facing: bool = False) -> Scene:
    """Cameras facing each other, two markers left and right of each camera."""
    d = rng.uniform(*distance)
    mp = USUAL_MARKERS + rng.normal(scale=jitter, size=(2, 3))
    mq = USUAL_MARKERS + rng.normal(scale=jitter, size=(2, 3))
    if exact_facing:
        return Scene(facing_pose(d), USUAL_MARKERS.copy(), USUAL_MARKERS.copy())
    yaw = np.radians(max_yaw_deg)
    pose = facing_pose(d, rng.uniform(-yaw, yaw), rng.uniform(-yaw, yaw), rng.uniform(-0.2, 0.2) * d,
                       tilt=rng.normal(scale=np.radians(3.0), size=3))
    return Scene(pose, mp, mq)


def random_layout(rng: np.random.Generator, n_p: int = 2, n_q: int = 2, distance: tuple[float, float] = (0.5, 5.0),
                  marker_radius: float = 0.3, max_tries: int = 1000) -> Scene:
    """Random markers within ``marker_radius`` of each camera, random relative
    pose at the given distance, every marker in front of the camera seeing it."""
    for _ in range(max_tries):
        mp = rng.uniform(-marker_radius, marker_radius, size=(n_p, 3))
        mq = rng.uniform(-marker_radius, marker_radius, size=(n_q, 3))
        d = rng.uniform(*distance)
        # p's centre somewhere in q's forward cone, p looking roughly back.
        dirq = rng.normal(size=3)
        dirq[2] = abs(dirq[2]) + 1.0
        dirq /= np.linalg.norm(dirq)
        t = d * dirq
        look = -t / d  # p's z axis (in q's frame) points at q, perturbed
        look = look + rng.normal(scale=0.3, size=3)
        look /= np.linalg.norm(look)
        x = np.cross(rng.normal(size=3), look)
        x /= np.linalg.norm(x)
        y = np.cross(look, x)
        R = np.column_stack([x, y, look])  # columns: p's axes in q's frame
        scene = Scene(Pose(R, t), mp, mq)
        if scene.all_in_front():
            return scene
    raise RuntimeError("could not sample a valid random layout")
