"""The minimal (three-observation) solver against independent ground truth.

Ground truth is the synthetic pose the observations were generated from, an
independent peer (OpenCV's P3P) for the 3-0 and 0-3 splits, and, for noisy
data, the exact root of the noisy distance equations reached by Newton's
method started at the true ranges (an independent numpy implementation of
the paper's eq. solvescale).

Geometry families (cameras 0.5-5 m apart unless said otherwise):

* ``usual``: cameras roughly facing each other (``usual_mounting``), markers
  left and right of each camera; the 3-0/0-3 splits need a third marker on
  the observed robot, which sits centred above the camera.
* ``facing``: relative rotation *exactly* 180 degrees about y (R =
  diag(-1, 1, -1), no rounding), half of them on the optical axis with
  exactly symmetric markers, half offset with jittered markers.
* ``random``: ``random_layout`` with three markers per robot.

A split ``(s0, s1, s2)`` lists who saw each of the three observations
(0 = p saw a marker of q, 1 = q saw a marker of p).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from mutloc.core.batch import solve_minimal_batch
from mutloc.core.minimal import solve_minimal
from mutloc.sim.synthetic import USUAL_MARKERS, random_layout, usual_mounting

CONFIGS = {"3-0": (0, 0, 0), "2-1": (0, 0, 1), "1-2": (0, 1, 1), "0-3": (1, 1, 1)}
N_CASES = 5000
MAX_FAILURES = math.floor(1e-4 * N_CASES)  # 0 at 5,000
TOL_T = 1e-6  # metres
TOL_DEG = 1e-5  # degrees

TOP = np.array([0.0, -0.2, -0.03])  # third marker: centred above the camera
MARKERS3 = np.vstack([USUAL_MARKERS, TOP])
RY180 = np.diag([-1.0, 1.0, -1.0])  # exactly 180 degrees about y

F = 800.0  # focal length (px) that defines "1 px" of bearing noise


# ---------------------------------------------------------------------------
# geometry
# ---------------------------------------------------------------------------


def _usual(rng: np.random.Generator, n: int, distance=(0.5, 5.0), max_yaw_deg: float = 20.0):
    out = []
    for _ in range(n):
        s = usual_mounting(rng, distance, max_yaw_deg=max_yaw_deg)
        mp = np.vstack([s.markers_p, TOP + rng.normal(scale=0.02, size=3)])
        mq = np.vstack([s.markers_q, TOP + rng.normal(scale=0.02, size=3)])
        out.append((s.pose.R, s.pose.t, mp, mq))
    return out


def _facing(rng: np.random.Generator, n: int, distance=(0.5, 5.0)):
    out = []
    for i in range(n):
        d = rng.uniform(*distance)
        if i % 2 == 0:
            t = np.array([0.0, 0.0, d])
            mp, mq = MARKERS3.copy(), MARKERS3.copy()
        else:
            t = np.array([rng.uniform(-0.2, 0.2) * d, rng.uniform(-0.1, 0.1) * d, d])
            mp = MARKERS3 + rng.normal(scale=0.02, size=(3, 3))
            mq = MARKERS3 + rng.normal(scale=0.02, size=(3, 3))
        out.append((RY180.copy(), t, mp, mq))
    return out


def _random(rng: np.random.Generator, n: int):
    out = []
    for _ in range(n):
        s = random_layout(rng, 3, 3, (0.5, 5.0))
        out.append((s.pose.R, s.pose.t, s.markers_p, s.markers_q))
    return out


FAMILIES = {"usual": _usual, "facing": _facing, "random": _random}
FAMILY_SEEDS = {"usual": 101, "facing": 202, "random": 303}


def _problems(geoms, side):
    """Exact bearings (N, 3, 3) and marker positions (N, 3, 3) for a split.

    Observation k seen by p is q's next marker (in q's frame), seen by q is
    p's next marker; the bearing is the unit ray from the observer's centre.
    """
    n = len(geoms)
    B = np.empty((n, 3, 3))
    P = np.empty((n, 3, 3))
    for i, (R, t, mp, mq) in enumerate(geoms):
        iq = ip = 0
        for k, s in enumerate(side):
            if s == 0:
                X = mq[iq]
                iq += 1
                v = R.T @ (X - t)
            else:
                X = mp[ip]
                ip += 1
                v = R @ X + t
            B[i, k] = v / np.linalg.norm(v)
            P[i, k] = X
    return B, P


def _rot_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle between rotations (degrees), accurate for tiny angles:
    ||Ra - Rb||_F = 2 sqrt(2) sin(theta / 2)."""
    fro = np.linalg.norm(Ra - Rb, axis=(-2, -1))
    return np.degrees(2.0 * np.arcsin(np.clip(fro / (2.0 * math.sqrt(2.0)), 0.0, 1.0)))


def _truth(geoms):
    return np.array([g[0] for g in geoms]), np.array([g[1] for g in geoms])


def _candidate_errors(res, Rt, tt):
    """Translation (m) and rotation (deg) error of every candidate slot (inf if unused)."""
    dt = np.linalg.norm(res.t - tt[:, None, :], axis=2)
    da = _rot_deg(res.R, Rt[:, None])
    unused = np.arange(res.R.shape[1])[None, :] >= res.count[:, None]
    dt[unused] = np.inf
    da[unused] = np.inf
    return dt, da


# ---------------------------------------------------------------------------
# noise-free: the true pose is always among the candidates
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("family", list(FAMILIES))
@pytest.mark.parametrize("config", list(CONFIGS))
def test_true_pose_among_candidates(config, family):
    side = CONFIGS[config]
    rng = np.random.default_rng(FAMILY_SEEDS[family] + 7 * list(CONFIGS).index(config))
    geoms = FAMILIES[family](rng, N_CASES)
    B, P = _problems(geoms, side)
    res = solve_minimal_batch(np.array(side), B, P)
    assert len(res) == N_CASES
    Rt, tt = _truth(geoms)
    dt, da = _candidate_errors(res, Rt, tt)
    found = np.any((dt <= TOL_T) & (da <= TOL_DEG), axis=1)
    bad = np.flatnonzero(~found)
    # For the report: how far the nearest candidate is in the failing cases.
    near = np.argmin(dt + da * 1e-3, axis=1)
    detail = [
        f"case {i}: |t|={np.linalg.norm(tt[i]):.3f} m, {res.count[i]} candidates, nearest "
        f"{dt[i, near[i]]:.2e} m / {da[i, near[i]]:.2e} deg"
        for i in bad[:8]
    ]
    print(f"{config} {family}: {len(bad)} / {N_CASES} cases without the true pose to "
          f"{TOL_T:g} m and {TOL_DEG:g} deg")
    assert len(bad) <= MAX_FAILURES, (
        f"{config} {family}: true pose missing in {len(bad)} of {N_CASES} cases "
        f"(allowed {MAX_FAILURES}):\n" + "\n".join(detail)
    )


def test_batch_matches_single_solver():
    """The batch API and solve_minimal are the same solver."""
    rng = np.random.default_rng(5)
    geoms = _usual(rng, 50) + _random(rng, 50)
    for side in CONFIGS.values():
        B, P = _problems(geoms, side)
        res = solve_minimal_batch(np.array(side), B, P)
        for i in range(len(geoms)):
            R, t = solve_minimal(side, B[i], P[i])
            assert len(R) == res.count[i]
            np.testing.assert_allclose(R, res.R[i, : res.count[i]], atol=1e-12)
            np.testing.assert_allclose(t, res.t[i, : res.count[i]], atol=1e-12)


# ---------------------------------------------------------------------------
# P3P splits against OpenCV
# ---------------------------------------------------------------------------


def _cv_p3p(points: np.ndarray, bearings: np.ndarray):
    """OpenCV's P3P on normalized image points; poses object -> camera."""
    img = np.ascontiguousarray((bearings[:, :2] / bearings[:, 2:]).reshape(3, 1, 2))
    obj = np.ascontiguousarray(points.reshape(3, 1, 3))
    _, rvecs, tvecs = cv2.solveP3P(obj, img, np.eye(3), None, cv2.SOLVEPNP_P3P)
    return [(cv2.Rodrigues(r)[0], np.asarray(t, float).ravel()) for r, t in zip(rvecs, tvecs)]


P3P_CASES = 3000


@pytest.mark.parametrize("family", list(FAMILIES))
@pytest.mark.parametrize("config", ["3-0", "0-3"])
def test_p3p_agrees_with_opencv(config, family):
    """Every solution OpenCV's P3P returns is one of mutloc's candidates (to 1e-6).

    3-0: p saw three of q's markers, so OpenCV's object frame is q and its
    camera is p: x_p = Rc x_q + tc, i.e. T_qp = (Rc^T, -Rc^T tc).  0-3: the
    object is p and the camera q, so T_qp = (Rc, tc).  OpenCV may drop
    solutions mutloc keeps; only OpenCV's solutions are required.
    """
    side = CONFIGS[config]
    rng = np.random.default_rng(FAMILY_SEEDS[family] + 1000 + (config == "0-3"))
    geoms = FAMILIES[family](rng, P3P_CASES)
    B, P = _problems(geoms, side)
    res = solve_minimal_batch(np.array(side), B, P)
    compared = 0
    missing = []
    for i in range(len(geoms)):
        if np.any(B[i, :, 2] < 0.05):  # OpenCV needs points in front of its pinhole
            continue
        cv_sols = _cv_p3p(P[i], B[i])
        if not cv_sols:
            continue
        c = res.count[i]
        for Rc, tc in cv_sols:
            # OpenCV's own solution must be exact (else it is no ground truth).
            Xc = P[i] @ Rc.T + tc
            bc = Xc / np.linalg.norm(Xc, axis=1, keepdims=True)
            if np.max(np.linalg.norm(bc - B[i], axis=1)) > 1e-8:
                continue
            R, t = (Rc.T, -Rc.T @ tc) if config == "3-0" else (Rc, tc)
            compared += 1
            d = np.linalg.norm(res.t[i, :c] - t, axis=1) + np.linalg.norm(res.R[i, :c] - R, axis=(1, 2))
            dmin = float(d.min()) if c else np.inf
            if dmin > 1e-6:
                missing.append((i, dmin))
    print(f"{config} {family}: {compared} OpenCV solutions compared, {len(missing)} not matched to 1e-6")
    assert compared >= 2 * P3P_CASES  # P3P has 2-4 solutions: the comparison is not vacuous
    assert not missing, (
        f"{config} {family}: {len(missing)} of {compared} OpenCV P3P solutions have no mutloc candidate "
        f"within 1e-6; worst cases (index, distance): {sorted(missing, key=lambda m: -m[1])[:6]}"
    )


@pytest.mark.parametrize("family", list(FAMILIES))
@pytest.mark.parametrize("config", ["3-0", "0-3"])
def test_p3p_at_most_four_candidates(config, family):
    """A P3P problem has at most four solutions with positive depths; more
    candidates means spurious or duplicated ones."""
    side = CONFIGS[config]
    rng = np.random.default_rng(FAMILY_SEEDS[family] + 2000 + (config == "0-3"))
    geoms = FAMILIES[family](rng, N_CASES)
    B, P = _problems(geoms, side)
    res = solve_minimal_batch(np.array(side), B, P)
    over = np.flatnonzero(res.count > 4)
    print(f"{config} {family}: {len(over)} / {N_CASES} cases with more than 4 candidates "
          f"(histogram of counts {np.bincount(res.count, minlength=9).tolist()})")
    assert len(over) == 0, (
        f"{config} {family}: {len(over)} of {N_CASES} P3P problems return more than four candidates, "
        f"e.g. cases {over[:8].tolist()} with counts {res.count[over[:8]].tolist()}"
    )


# ---------------------------------------------------------------------------
# noisy: the true solution never vanishes into a complex pair
# ---------------------------------------------------------------------------


def _noisy_bearings(B: np.ndarray, rng: np.random.Generator, sigma_px: float) -> np.ndarray:
    """Bearings through a pinhole with focal F, sigma_px pixel noise added."""
    x = B[..., :2] / B[..., 2:] * F + rng.normal(scale=sigma_px, size=B.shape[:-1] + (2,))
    v = np.concatenate([x / F, np.ones(B.shape[:-1] + (1,))], axis=-1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _distance_equations(s, side, b, X):
    """Paper eq. solvescale: the three inter-marker distances agree in both frames."""
    Yp = np.where((np.asarray(side) == 0)[:, None], s[:, None] * b, X)
    Yq = np.where((np.asarray(side) == 1)[:, None], s[:, None] * b, X)
    f = np.empty(3)
    for n, (k, l) in enumerate(((0, 1), (0, 2), (1, 2))):
        f[n] = np.sum((Yp[k] - Yp[l]) ** 2) - np.sum((Yq[k] - Yq[l]) ** 2)
    return f, Yp, Yq


def _newton_root(s0, side, b, X):
    """The root of the distance equations reached by Newton from s0 (analytic Jacobian)."""
    side = np.asarray(side)
    s = s0.astype(float).copy()
    pairs = ((0, 1), (0, 2), (1, 2))
    for _ in range(60):
        f, Yp, Yq = _distance_equations(s, side, b, X)
        J = np.zeros((3, 3))
        for n, (k, l) in enumerate(pairs):
            for m, sign in ((k, 1.0), (l, -1.0)):
                if side[m] == 0:
                    J[n, m] += 2.0 * sign * (Yp[k] - Yp[l]) @ b[m]
                else:
                    J[n, m] -= 2.0 * sign * (Yq[k] - Yq[l]) @ b[m]
        ds = np.linalg.solve(J, -f)
        s += ds
        if np.linalg.norm(ds) <= 1e-15 * np.linalg.norm(s):
            break
    f, Yp, Yq = _distance_equations(s, side, b, X)
    return s, float(np.max(np.abs(f))), Yp, Yq


def _kabsch(A: np.ndarray, Bm: np.ndarray):
    """(R, t) with Bm[i] ~ R A[i] + t (Arun et al.)."""
    ca, cb = A.mean(0), Bm.mean(0)
    U, _, Vt = np.linalg.svd((A - ca).T @ (Bm - cb))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cb - R @ ca


def _so3_exp(w):
    th = np.linalg.norm(w)
    W = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    if th < 1e-12:
        return np.eye(3) + W
    return np.eye(3) + np.sin(th) / th * W + (1 - np.cos(th)) / th**2 * W @ W


def _tangent_residuals(R, t, side, b, X):
    """Gnomonic tangent-plane error of each predicted ray around the observed one."""
    r = np.empty(6)
    for k in range(3):
        v = R.T @ (X[k] - t) if side[k] == 0 else R @ X[k] + t
        a = np.eye(3)[np.argmin(np.abs(b[k]))]
        e1 = np.cross(b[k], a)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(b[k], e1)
        den = v @ b[k]
        r[2 * k], r[2 * k + 1] = v @ e1 / den, v @ e2 / den
    return r


def _first_order_error(R, t, side, b, X):
    """Linearised pose error (left rotvec, translation) of the exact solution
    of the noisy minimal problem, around the truth (R, t)."""
    r0 = _tangent_residuals(R, t, side, b, X)
    J = np.empty((6, 6))
    h = 1e-7
    for j in range(6):
        d = np.zeros(6)
        d[j] = h
        rp = _tangent_residuals(_so3_exp(d[:3]) @ R, t + d[3:], side, b, X)
        rm = _tangent_residuals(_so3_exp(-d[:3]) @ R, t - d[3:], side, b, X)
        J[:, j] = (rp - rm) / (2 * h)
    return -np.linalg.solve(J, r0)


def _near_180(rng: np.random.Generator, n: int):
    """Usual mounting near 180 degrees, 1-3 m: a quarter exactly facing on axis
    with symmetric markers, the rest within 5 degrees of yaw (3 degrees tilt)."""
    out = []
    for i in range(n):
        if i % 4 == 0:
            out.append((RY180.copy(), np.array([0.0, 0.0, rng.uniform(1.0, 3.0)]), MARKERS3.copy(), MARKERS3.copy()))
        else:
            out.extend(_usual(rng, 1, (1.0, 3.0), max_yaw_deg=5.0))
    return out


N_NOISY = 2000


@pytest.mark.parametrize("config", ["2-1", "1-2"])
def test_noisy_true_root_never_vanishes(config):
    """sigma = 1 px bearing noise, usual mounting near 180 degrees at 1-3 m.

    The noisy system still has an exact solution next to the truth (found
    independently by Newton's method from the true ranges); it must be among
    the candidates in every trial (not lost to a complex pair), and the
    candidate closest to the truth must be as far off as the noise implies
    (first-order propagation of the noise through the minimal problem).
    """
    side = CONFIGS[config]
    rng = np.random.default_rng(77 + (config == "1-2"))
    geoms = _near_180(rng, N_NOISY)
    B, P = _problems(geoms, side)
    assert np.all(B[..., 2] > 0.5)  # every marker well inside the observing camera's view
    Bn = _noisy_bearings(B, rng, 1.0)
    res = solve_minimal_batch(np.array(side), Bn, P)
    Rt, tt = _truth(geoms)
    dt, da = _candidate_errors(res, Rt, tt)

    lost = []
    inconsistent = []
    literal_ok = 0
    for i, (R, t, _, _) in enumerate(geoms):
        s_true = np.array([
            np.linalg.norm(R.T @ (P[i, k] - t)) if side[k] == 0 else np.linalg.norm(R @ P[i, k] + t)
            for k in range(3)
        ])
        s, fres, Yp, Yq = _newton_root(s_true, side, Bn[i], P[i])
        assert fres < 1e-12 and np.all(s > 0), f"trial {i}: no exact root near the truth (residual {fres:.1e})"
        Rn, tn = _kabsch(Yp, Yq)
        c = res.count[i]
        gap = np.min(np.linalg.norm(res.t[i, :c] - tn, axis=1) + np.linalg.norm(res.R[i, :c] - Rn, axis=(1, 2))) \
            if c else np.inf
        if not gap <= 1e-9 * (1.0 + np.linalg.norm(tn)):
            lost.append((i, float(gap)))
        j = int(np.argmin(dt[i] / 0.1 + da[i] / 3.0))
        lin = _first_order_error(R, t, side, Bn[i], P[i])
        pred_t = np.linalg.norm(lin[3:])
        pred_deg = np.degrees(np.linalg.norm(lin[:3]))
        if not (dt[i, j] <= 2.5 * pred_t + 1e-3 and da[i, j] <= 2.5 * pred_deg + 0.02):
            inconsistent.append((i, dt[i, j], pred_t, da[i, j], pred_deg))
        literal_ok += dt[i, j] < 0.10 and da[i, j] < 3.0
    closest_t = np.min(dt, axis=1)
    print(f"{config}: root lost in {len(lost)}/{N_NOISY}; closest candidate: median "
          f"{np.median(closest_t) * 100:.2f} cm, max {closest_t.max() * 100:.1f} cm; "
          f"within 10 cm and 3 deg in {literal_ok}/{N_NOISY}")
    assert not lost, f"{config}: the exact noisy root near the truth is missing in {len(lost)} trials: {lost[:8]}"
    assert not inconsistent, (
        f"{config}: closest candidate farther than the noise implies in {len(inconsistent)} trials "
        f"(index, err m, predicted m, err deg, predicted deg): {inconsistent[:5]}"
    )
