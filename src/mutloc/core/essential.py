"""Five or more observations: the relative pose through the essential matrix.

The paper's alternative initializer (section III-E, eq. 5RTeq/essentialmatrix).
Each observation pairs a direction in p's frame with one in q's frame:

    side 0 (p saw q's marker Q_k along b_k):  x_p = b_k,  x_q = Q_k
    side 1 (q saw p's marker P_k along b_k):  x_p = P_k,  x_q = b_k

and the true 3-D points satisfy X_q = R X_p + t, so ``x_q^T E x_p = 0`` with
``E = [t]x R``.  The constraint is homogeneous, so only the *line* through
each vector matters.  Unlike classical two-view geometry the marker
positions are metric, which fixes the scale of ``t``.

OpenCV's five-point solver wants normalized image points, i.e. vectors with
positive ``z``.  Marker positions around a camera point in every direction,
so each set of vectors is first rotated so that the plane ``z = 0`` stays as
far as possible from all of them, then signs are flipped; the rotation is
undone on ``E``.

Sample selection is done here rather than by OpenCV's RANSAC/LMEDS: with the
handful of observations this problem has (n < 10), LMEDS's median is taken
over residuals of which at least half are the five exactly fitted ones, so
every solution of a sample scores zero; and RANSAC needs a threshold in units
the caller does not know.  Instead every (or a deterministic sample of)
five-subset is solved exactly and all its E's are kept; the metric poses are
then ranked by the angular error of all observations.
"""

from __future__ import annotations

from itertools import combinations

import cv2
import numpy as np

__all__ = ["essential_candidates", "pose_residuals"]

# Five-subsets solved at most; with noise-free data any one suffices, with
# noise more of them give the ranking a better pose to pick.
MAX_SUBSETS = 30
# Poses returned at most (best first); the caller refines them.
MAX_CANDIDATES = 12
# Smallest |z| (of a unit vector) accepted after alignment: below it the
# normalized point is too far out for the five-point solver to be trusted.
_MIN_Z = 1e-3
# Candidates from different five-subsets of noisy data are the same pose up
# to noise; closer than this (rotation angle, translation relative to its
# length) they would refine to the same optimum, so only the better is kept.
_SAME_ROT_DEG = 2.0
_SAME_T_REL = 0.03


def _hemisphere_directions(m: int = 400) -> np.ndarray:
    """Nearly uniform unit vectors with z >= 0 (a Fibonacci lattice)."""
    i = np.arange(m) + 0.5
    z = 1.0 - i / m
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


_DIRS = _hemisphere_directions()


def _alignment(x: np.ndarray) -> np.ndarray | None:
    """Rotation A such that every line in ``x`` (unit rows) has |(A x)_z| maximal in the worst case.

    Lines, not vectors: the sign of each row is free.  Returns None if no
    direction keeps all of them away from the plane z = 0.
    """
    # The principal axis is the natural choice for a narrow cone of rays;
    # the lattice covers the spread-out marker directions.
    axis = np.linalg.eigh(x.T @ x)[1][:, 2]
    worst_axis = np.abs(x @ axis).min()
    worst = np.abs(_DIRS @ x.T).min(axis=1)
    k = int(np.argmax(worst))
    d = axis if worst_axis >= worst[k] else _DIRS[k]
    if max(worst_axis, worst[k]) < _MIN_Z:
        return None
    # Any orthonormal completion works; start from the axis least parallel to d.
    e = np.zeros(3)
    e[int(np.argmin(np.abs(d)))] = 1.0
    e1 = e - (e @ d) * d
    e1 /= np.linalg.norm(e1)
    e2 = _cross(d, e1)
    return np.vstack([e1, e2, d])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two 3-vectors (np.cross is slow on single vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _normalized(x: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Rotate the lines ``x`` by ``A`` and express them as points on z = 1."""
    y = x @ A.T
    return np.ascontiguousarray(y[:, :2] / y[:, 2:3])


def _five_point(xp: np.ndarray, xq: np.ndarray) -> list[np.ndarray]:
    """Every essential matrix (x_q^T E x_p = 0) through five line pairs."""
    Ap, Aq = _alignment(xp), _alignment(xq)
    if Ap is None or Aq is None:
        return []
    pts_p, pts_q = _normalized(xp, Ap), _normalized(xq, Aq)
    # findEssentialMat(points1, points2) returns E with points2^T E points1 = 0;
    # with exactly five points it skips sampling and returns every root.
    try:
        E, _ = cv2.findEssentialMat(pts_p, pts_q, cameraMatrix=np.eye(3), method=cv2.RANSAC,
                                    prob=0.999, threshold=1e-3)
    except cv2.error:
        return []
    if E is None or E.size == 0 or E.shape[0] % 3 or not np.all(np.isfinite(E)):
        return []
    return [Aq.T @ E[i:i + 3] @ Ap for i in range(0, E.shape[0], 3)]


def _eight_point(xp: np.ndarray, xq: np.ndarray) -> np.ndarray | None:
    """Linear least-squares E from eight or more unit line pairs, projected onto the essential manifold."""
    M = (xq[:, :, None] * xp[:, None, :]).reshape(-1, 9)
    _, sv, Vt = np.linalg.svd(M)
    # With exactly eight rows the ninth singular value is an implicit zero.
    sv = np.concatenate([sv, np.zeros(9 - len(sv))])
    if sv[7] <= 1e-12 * sv[0]:
        return None  # null space of dimension >= 2: E not determined
    U, _, Wt = np.linalg.svd(Vt[-1].reshape(3, 3))
    return U @ np.diag([1.0, 1.0, 0.0]) @ Wt


def _decompose(Es: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two rotations and the translation direction of each E: (2m, 3, 3), (2m, 3)."""
    U, _, Vt = np.linalg.svd(Es)
    # E is defined up to sign, so flipping U or Vt to proper rotations is free.
    U = U * np.sign(np.linalg.det(U))[:, None, None]
    Vt = Vt * np.sign(np.linalg.det(Vt))[:, None, None]
    W = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    Rs = np.concatenate([U @ W @ Vt, U @ W.T @ Vt])
    th = np.concatenate([U[:, :, 2], U[:, :, 2]])
    return Rs, th


def _rays_and_anchors(side: np.ndarray, points: np.ndarray, bearings: np.ndarray,
                      Rs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pose and observation, in q's frame: ray u, anchor a and sign σ with a + σ t = s u.

    side 0: Q_k - t = s_k R b_k;  side 1: R P_k + t = s_k b_k.
    """
    s0 = (side == 0)[None, :, None]
    Rb = np.einsum("mij,nj->mni", Rs, bearings)
    RP = np.einsum("mij,nj->mni", Rs, points)
    u = np.where(s0, Rb, bearings[None])
    a = np.where(s0, points[None], RP)
    sigma = np.where(side == 0, -1.0, 1.0)
    return u, a, sigma


def _metric_translation(side: np.ndarray, points: np.ndarray, bearings: np.ndarray,
                        Rs: np.ndarray, th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares t = λ t̂ and ranges s (m, n) for each rotation and direction.

    Jointly in λ and the ranges: the ranges are eliminated exactly (each is
    the projection onto its ray), leaving a 1-D problem in λ on the parts
    orthogonal to the rays.  The sign of λ absorbs the sign of t̂.
    """
    u, a, sigma = _rays_and_anchors(side, points, bearings, Rs)

    def perp(v: np.ndarray) -> np.ndarray:
        return v - u * np.einsum("mni,mni->mn", u, v)[..., None]

    g = perp(np.broadcast_to(th[:, None, :], u.shape))
    h = perp(a)
    den = np.einsum("mni,mni->m", g, g)
    num = -np.einsum("n,mni,mni->m", sigma, g, h)
    lam = np.where(den > 1e-300, num / np.where(den > 1e-300, den, 1.0), np.nan)
    t = lam[:, None] * th
    s = np.einsum("mni,mni->mn", u, a + sigma[None, :, None] * t[:, None, :])
    return t, s


def pose_residuals(side: np.ndarray, points: np.ndarray, bearings: np.ndarray,
                   Rs: np.ndarray, ts: np.ndarray) -> np.ndarray:
    """Sum over observations of the squared chordal distance between measured and predicted rays, per pose."""
    u, a, sigma = _rays_and_anchors(side, points, bearings, Rs)
    w = a + sigma[None, :, None] * ts[:, None, :]
    w = w / np.maximum(np.linalg.norm(w, axis=2, keepdims=True), 1e-300)
    return np.sum((w - u) ** 2, axis=(1, 2))


def _subsets(n: int, max_subsets: int) -> list[tuple[int, ...]]:
    """All five-subsets of n observations, or a fixed random sample of them."""
    combos = list(combinations(range(n), 5))
    if len(combos) <= max_subsets:
        return combos
    pick = np.random.default_rng(0).choice(len(combos), size=max_subsets, replace=False)
    return [combos[i] for i in np.sort(pick)]


def essential_candidates(side: np.ndarray, points: np.ndarray, bearings: np.ndarray, *,
                         max_subsets: int = MAX_SUBSETS,
                         max_candidates: int = MAX_CANDIDATES) -> tuple[np.ndarray, np.ndarray]:
    """Candidate poses T_qp (x_q = R x_p + t) from n >= 5 observations via the essential matrix.

    ``side`` (n,): 0 if p saw the marker, 1 if q did; ``points`` (n, 3): the
    marker in its owner's frame; ``bearings`` (n, 3): the ray in the
    observer's frame.  Returns ``R`` (k, 3, 3) and ``t`` (k, 3), best first
    by angular error, only poses that put every marker in front of its
    observer; empty arrays for n < 5 or a degenerate configuration.
    """
    side = np.asarray(side, dtype=np.int64).reshape(-1)
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    bearings = np.asarray(bearings, dtype=float).reshape(-1, 3)
    empty = (np.empty((0, 3, 3)), np.empty((0, 3)))
    n = side.shape[0]
    if n < 5 or points.shape[0] != n or bearings.shape[0] != n:
        return empty
    # A zero ray stays zero and so fails the range test below.
    bearings = bearings / np.maximum(np.linalg.norm(bearings, axis=1, keepdims=True), 1e-300)

    s0 = (side == 0)[:, None]
    xp = np.where(s0, bearings, points)
    xq = np.where(s0, points, bearings)
    norm_p, norm_q = np.linalg.norm(xp, axis=1), np.linalg.norm(xq, axis=1)
    # A marker exactly at its owner's optical centre defines no line there.
    usable = np.flatnonzero((norm_p > 1e-12) & (norm_q > 1e-12))
    if usable.size < 5:
        return empty
    xp = xp[usable] / norm_p[usable, None]
    xq = xq[usable] / norm_q[usable, None]

    Es: list[np.ndarray] = []
    for idx in _subsets(len(usable), max_subsets):
        Es.extend(_five_point(xp[list(idx)], xq[list(idx)]))
    if len(usable) >= 8:
        E8 = _eight_point(xp, xq)
        if E8 is not None:
            Es.append(E8)
    if not Es:
        return empty

    Rs, th = _decompose(np.array(Es))
    ts, ranges = _metric_translation(side, points, bearings, Rs, th)
    ok = np.all(np.isfinite(ts), axis=1) & np.all(ranges > 0.0, axis=1)
    Rs, ts = Rs[ok], ts[ok]
    if len(Rs) == 0:
        return empty

    order = np.argsort(pose_residuals(side, points, bearings, Rs, ts), kind="stable")
    cos_same = 1.0 + 2.0 * np.cos(np.radians(_SAME_ROT_DEG))
    keep: list[int] = []
    for i in order:
        if not keep:
            keep.append(int(i))
            continue
        K = np.array(keep)
        same = ((np.einsum("kij,ij->k", Rs[K], Rs[i]) > cos_same)
                & (np.linalg.norm(ts[K] - ts[i], axis=1) < _SAME_T_REL * np.linalg.norm(ts[K], axis=1)))
        if not np.any(same):
            keep.append(int(i))
            if len(keep) >= max_candidates:
                break
    return Rs[keep], ts[keep]
