"""Synthetic two-robot geometries with ground truth (no rendering).

Used by the tests, the benchmarks and the demo.  A scene holds ``T_qp`` and
each robot's marker positions in its own camera frame; observations are exact
bearings or pixels, optionally with Gaussian pixel noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.geometry import so3_exp
from ..core.pose import Pose

__all__ = ["Scene", "facing_pose", "looking_pose", "usual_mounting", "random_layout", "USUAL_MARKERS"]

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


def looking_pose(position: np.ndarray, look: np.ndarray) -> Pose:
    """Pose (in a frame whose y is down, like q's) of a level camera at
    ``position`` with optical axis ``look``: its y axis stays in the plane of
    ``look`` and the frame's y."""
    look = np.asarray(look, float) / np.linalg.norm(look)
    right = np.cross([0.0, 1.0, 0.0], look)
    right /= np.linalg.norm(right)
    return Pose(np.column_stack([right, np.cross(look, right), look]), np.asarray(position, float))


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


def _rot_y(angles: np.ndarray) -> np.ndarray:
    c, s = np.cos(angles), np.sin(angles)
    R = np.zeros(angles.shape + (3, 3))
    R[..., 0, 0] = c
    R[..., 0, 2] = s
    R[..., 1, 1] = 1.0
    R[..., 2, 0] = -s
    R[..., 2, 2] = c
    return R


def _rotvec_to_matrix(w: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(w.reshape(-1, 3)).as_matrix().reshape(w.shape[:-1] + (3, 3))


def batch_scenes(rng: np.random.Generator, n: int, kind: str = "usual", n_p: int = 2, n_q: int = 2,
                 distance: tuple[float, float] = (0.5, 5.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``n`` random scenes at once: (R (n,3,3), t (n,3), markers_p (n,n_p,3), markers_q (n,n_q,3)).

    ``kind``: ``"usual"`` (facing cameras, yaw up to 20 degrees, markers left
    and right), ``"facing"`` (exactly 180 degrees, symmetric markers) or
    ``"random"`` (random layouts within 0.3 m; every marker in front of the
    camera that sees it).
    """
    d = rng.uniform(*distance, size=n)
    if kind in ("usual", "facing"):
        base = np.resize(USUAL_MARKERS, (max(n_p, n_q), 3))
        base[2:, 1] += 0.1 * np.arange(1, max(n_p, n_q) - 1)[:, None].ravel() if max(n_p, n_q) > 2 else 0.0
        mp = np.broadcast_to(base[:n_p], (n, n_p, 3)).copy()
        mq = np.broadcast_to(base[:n_q], (n, n_q, 3)).copy()
        if kind == "facing":
            R = np.broadcast_to(_rot_y(np.array(np.pi)), (n, 3, 3)).copy()
            t = np.zeros((n, 3))
            t[:, 2] = d
            return R, t, mp, mq
        mp += rng.normal(scale=0.02, size=mp.shape)
        mq += rng.normal(scale=0.02, size=mq.shape)
        yaw = np.radians(20.0)
        Rp = _rot_y(np.pi + rng.uniform(-yaw, yaw, n)) @ _rotvec_to_matrix(rng.normal(scale=np.radians(3.0), size=(n, 3)))
        Rq = _rot_y(-rng.uniform(-yaw, yaw, n))
        t0 = np.stack([rng.uniform(-0.2, 0.2, n) * d, np.zeros(n), d], axis=1)
        return Rq @ Rp, np.einsum("nij,nj->ni", Rq, t0), mp, mq
    if kind != "random":
        raise ValueError(f"unknown scene kind {kind!r}")
    out_R, out_t, out_p, out_q = [], [], [], []
    have = 0
    while have < n:
        m = 2 * (n - have) + 16
        mp = rng.uniform(-0.3, 0.3, size=(m, n_p, 3))
        mq = rng.uniform(-0.3, 0.3, size=(m, n_q, 3))
        dd = rng.uniform(*distance, size=m)
        dirq = rng.normal(size=(m, 3))
        dirq[:, 2] = np.abs(dirq[:, 2]) + 1.0
        dirq /= np.linalg.norm(dirq, axis=1, keepdims=True)
        t = dd[:, None] * dirq
        look = -dirq + rng.normal(scale=0.3, size=(m, 3))
        look /= np.linalg.norm(look, axis=1, keepdims=True)
        x = np.cross(rng.normal(size=(m, 3)), look)
        x /= np.linalg.norm(x, axis=1, keepdims=True)
        y = np.cross(look, x)
        R = np.stack([x, y, look], axis=2)
        in_q = np.einsum("mij,mkj->mki", R, mp) + t[:, None, :]
        in_p = np.einsum("mji,mkj->mki", R, mq - t[:, None, :])
        ok = np.all(in_q[..., 2] > 0, axis=1) & np.all(in_p[..., 2] > 0, axis=1)
        out_R.append(R[ok]), out_t.append(t[ok]), out_p.append(mp[ok]), out_q.append(mq[ok])
        have += int(ok.sum())
    cat = lambda parts: np.concatenate(parts)[:n]  # noqa: E731
    return cat(out_R), cat(out_t), cat(out_p), cat(out_q)


def batch_minimal_problems(R: np.ndarray, t: np.ndarray, markers_p: np.ndarray, markers_q: np.ndarray,
                           n_seen_by_p: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimal problems from :func:`batch_scenes`: p sees the first
    ``n_seen_by_p`` of q's markers, q sees the first ``3 - n_seen_by_p`` of p's.

    Returns (side (3,), bearings (n,3,3), points (n,3,3)).
    """
    k = n_seen_by_p
    in_p = np.einsum("nji,nkj->nki", R, markers_q[:, :k] - t[:, None, :])
    in_q = np.einsum("nij,nkj->nki", R, markers_p[:, : 3 - k]) + t[:, None, :]
    bearings = np.concatenate([in_p, in_q], axis=1)
    bearings /= np.linalg.norm(bearings, axis=2, keepdims=True)
    points = np.concatenate([markers_q[:, :k], markers_p[:, : 3 - k]], axis=1)
    side = np.array([0] * k + [1] * (3 - k), dtype=np.int64)
    return side, np.ascontiguousarray(bearings), np.ascontiguousarray(points)
