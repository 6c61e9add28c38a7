"""A robot's odometry (mutloc.core.odometry): increments against closed forms,
Monte Carlo and the simulator's drifting odometry; bad samples refused."""

import math

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.stats import chi2

from mutloc.core.geometry import se3_exp, se3_log, skew, so3_exp, so3_left_jacobian, so3_log
from mutloc.core.odometry import Odometry, OdometryNoise
from mutloc.core.pose import Pose
from mutloc.errors import OdometryError
from mutloc.sim.odometry import drifting_odometry, odometry_times


def _hat(xi):
    A = np.zeros((4, 4))
    A[:3, :3] = skew(xi[:3])
    A[:3, 3] = xi[3:]
    return A


def _spec_error(est: Pose, true: Pose) -> np.ndarray:
    """(dtheta, dt) with true = (exp(dtheta) R, t + dt): the SPEC's perturbation."""
    return np.concatenate([so3_log(true.R @ est.R.T), true.t - est.t])


def _screw(T0: Pose, xi):
    return lambda t: T0 @ Pose(*se3_exp(np.asarray(xi) * t))


def _stack(fn, times):
    ps = [fn(t) for t in times]
    return Pose(np.array([p.R for p in ps]), np.array([p.t for p in ps]))


@pytest.mark.parametrize("seed", range(4))
def test_se3_exp_is_the_matrix_exponential_and_log_inverts_it(seed):
    rng = np.random.default_rng(seed)
    xi = rng.normal(size=6) * [1, 1, 1, 2, 2, 2]
    if seed == 3:
        xi[:3] *= 1e-9  # the small-angle branch
    R, t = se3_exp(xi)
    E = expm(_hat(xi))
    np.testing.assert_allclose(R, E[:3, :3], atol=1e-12)
    np.testing.assert_allclose(t, E[:3, 3], atol=1e-12)
    np.testing.assert_allclose(se3_log(R, t), xi, atol=1e-9)
    w = rng.normal(size=3)
    np.testing.assert_allclose(so3_left_jacobian(w, inverse=True) @ so3_left_jacobian(w), np.eye(3), atol=1e-12)
    # near pi the inverse Jacobian stays finite and exact
    w = np.array([0.0, 0.0, math.pi - 1e-7])
    np.testing.assert_allclose(so3_left_jacobian(w, inverse=True) @ so3_left_jacobian(w), np.eye(3), atol=1e-6)


def test_interpolation_between_samples_is_the_screw_motion():
    """Samples of a constant-twist motion at irregular stamps: every pose and
    increment in between is the closed form T0 exp(t xi)."""
    rng = np.random.default_rng(1)
    xi = np.array([0.3, -0.5, 0.9, 0.8, 0.1, -0.4])
    truth = _screw(Pose.from_rotvec([0.2, 0.1, -0.3], [1.0, 2.0, 0.5]), xi)
    times = np.cumsum(rng.uniform(0.01, 0.05, 40))
    odo = Odometry(times, _stack(truth, times), max_turn_rate=100.0)
    for t in rng.uniform(times[0], times[-1], 25):
        p = odo.pose_at(t)
        assert np.abs(p.R - truth(t).R).max() < 1e-9 and p.translation_error(truth(t)) < 1e-9
    for t0, t1 in np.sort(rng.uniform(times[0], times[-1], (25, 2)), axis=1):
        inc = odo.increment(t0, t1)
        want = Pose(*se3_exp(xi * (t1 - t0)))
        assert np.abs(inc.pose.R - want.R).max() < 1e-9 and inc.pose.translation_error(want) < 1e-9
    # a chord (linear position, slerp) is not the screw: the check above can tell them apart
    k, s = 10, 0.5
    chord = (1 - s) * odo.poses.t[k] + s * odo.poses.t[k + 1]
    assert np.linalg.norm(chord - truth(times[k] + s * (times[k + 1] - times[k])).t) > 1e-5


def _circle(t):
    """A robot driving a 1 m circle at 1 m/s with its camera swaying."""
    yaw = t
    R = so3_exp([0.0, yaw, 0.0]) @ so3_exp([0.1 * math.sin(3 * t), 0.0, 0.05 * math.cos(2 * t)])
    return Pose(R, [math.cos(t), 0.02 * math.sin(5 * t), math.sin(t)])


def test_increment_covariance_is_the_monte_carlo_one():
    """Each interval's error drawn from the stated noise and composed: the
    spread of the composed increment is its covariance (with the lever arm
    of heading errors on the later path)."""
    from scipy.spatial.transform import Rotation

    noise = OdometryNoise(distance=0.01, deg_per_m=2.0, turn=0.02, floor_m=0.002, floor_deg=0.5)
    times = np.arange(0.0, 3.0, 0.05)
    poses = _stack(_circle, times)
    odo = Odometry(times, poses, noise=noise)
    i, j, n = 5, 45, 4000
    inc = odo.increment(times[i], times[j])
    rng = np.random.default_rng(7)
    R, t = np.repeat(np.eye(3)[None], n, 0), np.zeros((n, 3))
    for k in range(i, j):
        d = poses[k].inverse() @ poses[k + 1]
        q = noise.covariance(float(np.linalg.norm(d.t)), float(np.linalg.norm(so3_log(d.R))),
                             times[k + 1] - times[k])
        e = rng.normal(size=(n, 6)) * np.sqrt(np.diag(q))
        t = np.einsum("nij,nj->ni", R, d.t + e[:, 3:]) + t
        R = R @ (Rotation.from_rotvec(e[:, :3]).as_matrix() @ d.R)
    errs = np.concatenate([Rotation.from_matrix(R @ inc.pose.R.T).as_rotvec(), t - inc.pose.t], 1)
    # the lever arm matters here: the translation spread is many times the summed per-interval noise
    assert inc.covariance[3:, 3:].trace() > 5 * sum(odo._q[k][3:, 3:].trace() for k in range(i, j))
    nees = np.einsum("ni,ij,nj->n", errs, np.linalg.inv(inc.covariance), errs)
    assert 5.8 < nees.mean() < 6.2, nees.mean()
    np.testing.assert_allclose(np.std(errs, axis=0), np.sqrt(np.diag(inc.covariance)), rtol=0.05)


def test_simulated_drift_matches_the_stated_noise_over_many_increments():
    """The simulator's drifting odometry against its truth: the increments'
    errors are as large as their covariance says (NEES about 6 with the
    simulator's noise; well below with the conservative default)."""
    times = odometry_times(0.0, 40.0, 50.0)
    odo_poses = drifting_odometry(_circle, times, drift_pct=1.0, deg_per_m=0.3, seed=3)
    matched = OdometryNoise(distance=0.01, deg_per_m=0.3, turn=0.0, floor_m=1e-7, floor_deg=1e-7)
    odo = Odometry(times, odo_poses, noise=matched, source="sim")
    default = Odometry(times, odo_poses)
    rng = np.random.default_rng(0)
    starts = np.arange(0.0, 39.0, 0.25) + rng.uniform(0, 0.02, 156)
    nees, nees_default = [], []
    for t0 in starts:
        t1 = t0 + rng.uniform(0.1, 0.25)
        truth = _circle(t0).inverse() @ _circle(t1)
        for o, out in ((odo, nees), (default, nees_default)):
            inc = o.increment(t0, t1)
            e = _spec_error(inc.pose, truth)
            out.append(e @ np.linalg.solve(inc.covariance, e))
    nees = np.array(nees)
    # 156 independent increments, 6 dof each: the mean within its 99.9 % band
    lo, hi = chi2.ppf([0.0005, 0.9995], 6 * len(nees)) / len(nees)
    assert lo < nees.mean() < hi, nees.mean()
    assert np.mean(nees > chi2.ppf(0.99, 6)) < 0.03
    assert np.mean(nees_default) < 0.5 * nees.mean()


def test_message_covariance_growth_is_the_increment_noise_and_a_constant_one_falls_back():
    times = np.arange(0.0, 2.0, 0.1)
    poses = Pose(np.repeat(so3_exp([0.0, 0.0, math.pi / 2])[None], len(times), 0),
                 np.tile([0.3, 0.1, 0.0], (len(times), 1)))  # standing still: no lever arm
    C = np.diag([1e-4, 2e-4, 3e-4, 1e-3, 2e-3, 3e-3])
    growing = Odometry(times, poses, np.array([k * C for k in range(len(times))]))
    inc = growing.increment(times[2], times[7])
    # five intervals of growth C in the odometry frame, seen from a robot turned 90 degrees about z
    Rz = so3_exp([0.0, 0.0, math.pi / 2]).T
    J = np.kron(np.eye(2), Rz)
    np.testing.assert_allclose(inc.covariance, 5 * J @ C @ J.T, rtol=1e-9, atol=1e-15)
    constant = Odometry(times, poses, np.repeat(C[None], len(times), 0))
    zero = Odometry(times, poses, np.zeros((len(times), 6, 6)))
    none = Odometry(times, poses)
    np.testing.assert_allclose(constant.increment(0.2, 0.7).covariance, none.increment(0.2, 0.7).covariance)
    np.testing.assert_allclose(zero.increment(0.2, 0.7).covariance, none.increment(0.2, 0.7).covariance)
    d = none.increment(0.2, 0.7)
    n = OdometryNoise()
    np.testing.assert_allclose(d.covariance, n.covariance(0.0, 0.0, 0.5), rtol=1e-9)


def _line(n=50, dt=0.02, v=1.0):
    times = np.arange(n) * dt
    return times, Pose(np.repeat(np.eye(3)[None], n, 0), np.stack([v * times, 0 * times, 0 * times], 1))


def test_bad_samples_are_rejected_counted_and_never_shift_a_pose():
    times, poses = _line()
    R, t = poses.R.copy(), poses.t.copy()
    tt = times.copy()
    t[10] = np.nan                    # invalid
    R[12] = 2 * np.eye(3)             # not a rotation
    tt[20] = tt[19]                   # duplicate stamp
    tt[25] = tt[22]                   # going backwards
    t[30] = [3.0, 0.0, 0.0]           # a spike: the next sample goes on from the last good one
    odo = Odometry(tt, Pose(R, t))
    assert odo.counts == {"invalid": 2, "not_increasing": 2, "jump": 1, "gap": 0}
    for t0, t1 in ((0.15, 0.27), (0.37, 0.45), (0.55, 0.65), (0.1, 0.9)):
        inc = odo.increment(t0, t1)
        assert inc.pose.translation_error(Pose(np.eye(3), [t1 - t0, 0, 0])) < 1e-9
    assert repr(odo).endswith("rejected: 2 invalid, 2 not increasing, 1 jump)")


def test_a_reset_of_the_odometry_frame_is_never_bridged():
    times, poses = _line()
    t = poses.t.copy()
    t[30:] += [5.0, -2.0, 0.0]        # the odometry frame jumps and stays
    odo = Odometry(times, Pose(poses.R, t))
    assert odo.counts["jump"] == 1 and len(odo) == 50
    assert odo.covers(0.1, 0.5) and odo.covers(0.7, 0.9) and not odo.covers(0.5, 0.7)
    with pytest.raises(OdometryError, match=r"odo: no odometry from 0\.5 to 0\.7"):
        Odometry(times, Pose(poses.R, t), source="odo").increment(0.5, 0.7)
    assert odo.increment(0.7, 0.9).pose.translation_error(Pose(np.eye(3), [0.2, 0, 0])) < 1e-9


def test_a_gap_is_not_bridged_and_unusable_input_is_refused():
    times, poses = _line()
    tt = times.copy()
    tt[25:] += 1.0
    odo = Odometry(tt, poses)
    assert odo.counts["gap"] == 1 and not odo.covers(0.4, 1.6) and odo.covers(1.6, 1.9)
    with pytest.raises(OdometryError, match=r"^p\.tum: 3 odometry samples, fewer than 2 usable \(3 invalid\)$"):
        Odometry([0.0, 0.1, 0.2], Pose(np.full((3, 3, 3), np.nan), np.zeros((3, 3))), source="p.tum")
    with pytest.raises(OdometryError, match=r"stamp 5 outside the odometry's \[0, 0\.98\]"):
        Odometry(times, poses).increment(0.1, 5.0)
    with pytest.raises(OdometryError, match="back to"):
        Odometry(times, poses).increment(0.5, 0.1)
    with pytest.raises(OdometryError, match="floor"):
        OdometryNoise(floor_m=0.0)
