"""The fixed-lag smoother of the joint team state (mutloc.core.team_smoother)
against independent references: a plain-NumPy RTS smoother on SE(3) robot by
robot (tests/_oracles.py), and a textbook linear RTS smoother over the whole
window."""

import numpy as np

from _oracles import State, cv_transition, rts_smooth

from mutloc.core.filter import STATE_DIM, MotionNoise
from mutloc.core.geometry import so3_exp, so3_log
from mutloc.core.pose import Pose
from mutloc.core.team_filter import TeamFilter, TeamSnapshot
from mutloc.core.team_smoother import TeamSmoother

NOISE = MotionNoise(angular=0.7, linear=1.3, reference_angular=0.0)  # (the oracle below: each robot's own noise only)


def _spd(rng, n, scale):
    A = rng.normal(size=(n, n))
    return scale * (A @ A.T / n + 0.2 * np.eye(n))


def _set(f: TeamFilter, s: TeamSnapshot) -> None:
    """The filter at snapshot ``s`` (its robots tracked in its order)."""
    f.tracked = list(s.tracked)
    for x, i in enumerate(s.tracked):
        f.R[i], f.t[i], f.vel[i] = s.R[x], s.t[x], s.vel[x]
        f.serial[i] = s.serial[x]
    f.P, f.time = s.P.copy(), s.time


def test_uncorrelated_robots_smooth_as_each_robot_alone_does():
    """Two robots with block-diagonal covariances (no correlation), arbitrary
    posteriors after each prediction, moving and turning: the joint
    smoother's states are each robot's RTS smoothing on its own (the
    reference smoother of tests/_oracles.py), records 0 .. 6 with lag 6."""
    rng = np.random.default_rng(1)
    f = TeamFilter(["r0", "r1", "r2"], "r0", NOISE)
    for name in ("r1", "r2"):
        f.add(name, Pose(so3_exp(rng.normal(size=3)), rng.normal(size=3)), _spd(rng, 6, 0.01),
              velocity=rng.normal(size=6) * 0.5, velocity_covariance=_spd(rng, 6, 0.1))
    f.time = 0.0
    sm = TeamSmoother(lag=6)
    priors, posts = [], []
    for k in range(7):
        f.predict(0.05 * k + 0.01 * (k % 2))
        prior = f.snapshot()
        # an arbitrary posterior per robot: a shifted mean, a smaller covariance, no correlation
        R = np.array([so3_exp(0.02 * rng.normal(size=3)) @ r for r in prior.R])
        P = np.zeros_like(prior.P)
        for x in range(2):
            b = slice(STATE_DIM * x, STATE_DIM * (x + 1))
            P[b, b] = 0.5 * prior.P[b, b] + _spd(rng, STATE_DIM, 1e-4) if k else prior.P[b, b]
        post = TeamSnapshot(prior.time, prior.tracked, prior.serial, R if k else prior.R,
                            prior.t + (0.01 * rng.normal(size=prior.t.shape) if k else 0.0),
                            prior.vel + (0.05 * rng.normal(size=prior.vel.shape) if k else 0.0), P)
        sm.add(prior, post)
        _set(f, post)
        priors.append(prior)
        posts.append(post)
    for x in range(2):
        b = slice(STATE_DIM * x, STATE_DIM * (x + 1))

        def state(s):
            return State(s.time, s.R[x], s.t[x], s.vel[x], s.P[b, b])

        want = rts_smooth([state(s) for s in priors], [state(s) for s in posts])
        for k in range(7):
            got = sm.smoothed(k)
            assert np.allclose(got.R[x], want[k].R, atol=1e-10)
            assert np.allclose(got.t[x], want[k].t, atol=1e-10)
            assert np.allclose(got.vel[x], want[k].vel, atol=1e-10)
            assert np.allclose(got.P[b, b], want[k].P, atol=1e-12)
            other = slice(STATE_DIM * (1 - x), STATE_DIM * (2 - x))
            assert np.abs(got.P[b, other]).max() < 1e-12


def _linear_rts(means, covs, pmeans, pcovs, Fs):
    """The textbook RTS smoother (vectors; ``Fs[k]``: the transition into record k)."""
    out_m, out_P = [means[-1]], [covs[-1]]
    for k in range(len(means) - 2, -1, -1):
        G = covs[k] @ Fs[k + 1].T @ np.linalg.inv(pcovs[k + 1])
        out_m.insert(0, means[k] + G @ (out_m[0] - pmeans[k + 1]))
        out_P.insert(0, covs[k] + G @ (out_P[0] - pcovs[k + 1]) @ G.T)
    return out_m, out_P


def test_a_robot_dropped_within_the_window_is_smoothed_by_what_came_before():
    """r1 measured directly (its position, 1 cm) at every record, r2
    correlated with it at the start and dropped from the state at record 4
    (as a lost track is): the smoother's states equal a linear RTS smoother
    over the full state in which r2 stays (unmeasured) to the end -- both
    robots at every record before the drop, r1 after it.  Rotations stay
    at the identity with no angular velocity and no rotation-translation
    correlation: the model is linear, the comparison exact."""
    rng = np.random.default_rng(4)
    n_rec, drop, dt = 9, 4, 0.05
    f = TeamFilter(["r0", "r1", "r2"], "r0", NOISE)
    f.time = 0.0
    for name in ("r1", "r2"):
        f.add(name, Pose(np.eye(3), rng.normal(size=3)), np.diag([1e-3] * 3 + [0.04] * 3),
              velocity=np.r_[0.0, 0.0, 0.0, rng.normal(size=3)], velocity_covariance=np.diag([0.1] * 3 + [0.25] * 3))
    # r1's and r2's translations correlated (and their velocities)
    for a, b in ((3, 15), (4, 16), (9, 21)):
        f.P[a, b] = f.P[b, a] = 0.5 * np.sqrt(f.P[a, a] * f.P[b, b])
    H = np.zeros((3, 2 * STATE_DIM))
    H[:, 3:6] = np.eye(3)
    Rm = 1e-4 * np.eye(3)

    def vec(s):
        return np.concatenate([np.r_[np.zeros(3), s.t[x], s.vel[x]] for x in range(len(s.tracked))])

    # the reference: the full state kept to the end (linear Kalman filter + RTS)
    m, P = vec(f.snapshot()), f.P.copy()
    full = {"m": [], "P": [], "pm": [], "pP": [], "F": []}
    zs = []
    sm = TeamSmoother(lag=n_rec)
    for k in range(n_rec):
        # ours: the filter's own prediction, then the same update; r2 dropped at `drop`
        f.predict(dt * k)
        prior = f.snapshot()
        F = np.zeros((2 * STATE_DIM,) * 2)
        for x in range(2):
            Fi = cv_transition(np.r_[np.zeros(3), m[STATE_DIM * x + 9:STATE_DIM * x + 12]], dt if k else 0.0)
            F[STATE_DIM * x:STATE_DIM * (x + 1), STATE_DIM * x:STATE_DIM * (x + 1)] = Fi
        pm = F @ m if k else m
        pP = P if not k else None
        if k:
            Q = np.zeros_like(P)
            for x in range(2):
                o = STATE_DIM * x
                for a in range(6):
                    q = NOISE.angular**2 if a < 3 else NOISE.linear**2
                    Q[o + a, o + a] += q * dt**3 / 3
                    Q[o + a, o + a + 6] += q * dt**2 / 2
                    Q[o + a + 6, o + a] += q * dt**2 / 2
                    Q[o + a + 6, o + a + 6] += q * dt
            pP = F @ P @ F.T + Q
        z = rng.normal(size=3) * 0.01 + pm[3:6]
        zs.append(z)
        K = pP @ H.T @ np.linalg.inv(H @ pP @ H.T + Rm)
        m, P = pm + K @ (z - H @ pm), (np.eye(2 * STATE_DIM) - K @ H) @ pP
        for key, v in (("m", m), ("P", P), ("pm", pm), ("pP", pP), ("F", F)):
            full[key].append(v)
        # ours: the same update on the filter's (possibly reduced) state
        q = len(f.tracked)
        Hq = H[:, :STATE_DIM * q]
        x_prior = vec(prior)
        Kq = prior.P @ Hq.T @ np.linalg.inv(Hq @ prior.P @ Hq.T + Rm)
        x_post = x_prior + Kq @ (z - Hq @ x_prior)
        Pq = (np.eye(STATE_DIM * q) - Kq @ Hq) @ prior.P
        xs = x_post.reshape(q, STATE_DIM)
        assert np.abs(xs[:, :3]).max() < 1e-12 and np.abs(xs[:, 6:9]).max() < 1e-12  # rotations stay put
        post = TeamSnapshot(prior.time, prior.tracked, prior.serial, prior.R.copy(), xs[:, 3:6].copy(),
                            xs[:, 6:].copy(), 0.5 * (Pq + Pq.T))
        _set(f, post)
        if k == drop:
            f.drop("r2")
            post = f.snapshot()
        sm.add(prior, post)
    want_m, want_P = _linear_rts(full["m"], full["P"], full["pm"], full["pP"], full["F"])
    for k in range(n_rec):
        got = sm.smoothed(k)
        q = len(got.tracked)
        assert q == (2 if k < drop else 1)
        rows = np.arange(STATE_DIM * q)
        assert np.allclose(vec(got), want_m[k][rows], atol=1e-9), k
        assert np.allclose(got.P, want_P[k][np.ix_(rows, rows)], atol=1e-10), k
        assert all(np.allclose(so3_log(R), 0.0) for R in got.R)
    # and the smoothing did something: r2 before the drop moved by r1's later measurements through the correlation
    assert np.linalg.norm(sm.smoothed(0).t[1] - full["m"][0][STATE_DIM + 3:STATE_DIM + 6]) > 1e-4


def test_the_kernel_rotation_log_is_the_geometry_one():
    """The smoother's compiled rotation log against mutloc.core.geometry.so3_log:
    small, ordinary and near-180-degree rotations."""
    from mutloc.core.team_smoother import _so3_log

    rng = np.random.default_rng(0)
    out = np.empty(3)
    for scale in (1e-9, 1e-4, 0.5, 2.0, np.pi - 1e-4, np.pi - 1e-6):
        for _ in range(20):
            axis = rng.normal(size=3)
            w = scale * axis / np.linalg.norm(axis)
            R = so3_exp(w)
            _so3_log(R, out)
            assert np.allclose(out, so3_log(R), atol=1e-9), (scale, out, so3_log(R))
            assert np.allclose(so3_exp(out), R, atol=1e-9)


def test_with_measured_noise_the_gains_are_the_filters_own():
    """A robot whose filter's gain weighed measured noise below the stated
    (a second, own covariance and noise_scale 4, then back to none at the
    last record): the joint smoother's means, own covariances and reported
    covariances are the reference smoother's of tests/_oracles.py (gains from
    the own covariances, the reported covariance the smaller bound of the
    stated one), records 0 .. 6."""
    rng = np.random.default_rng(6)
    f = TeamFilter(["r0", "r1"], "r0", NOISE)
    f.add("r1", Pose(so3_exp(rng.normal(size=3)), rng.normal(size=3)), _spd(rng, 6, 0.01),
          velocity=rng.normal(size=6) * 0.5, velocity_covariance=_spd(rng, 6, 0.1))
    f.Pg, f.noise_scale, f.time = 0.3 * f.P, 4.0, 0.0
    sm = TeamSmoother(lag=6)
    priors, posts = [], []
    for k in range(7):
        f.predict(0.05 * k + 0.01 * (k % 2))
        prior = f.snapshot()
        assert prior.Pg is not None
        P = 0.5 * prior.P + _spd(rng, STATE_DIM, 1e-4) if k else prior.P
        Pg = (0.4 * prior.Pg + _spd(rng, STATE_DIM, 1e-5) if k < 6 else None) if k else prior.Pg
        post = TeamSnapshot(prior.time, prior.tracked, prior.serial,
                            np.array([so3_exp(0.02 * rng.normal(size=3)) @ prior.R[0]]) if k else prior.R,
                            prior.t + (0.01 * rng.normal(size=prior.t.shape) if k else 0.0),
                            prior.vel + (0.05 * rng.normal(size=prior.vel.shape) if k else 0.0), P, Pg,
                            4.0 if Pg is not None else 1.0)
        sm.add(prior, post)
        f.tracked, f.time = list(post.tracked), post.time
        f.R[1], f.t[1], f.vel[1], f.P, f.Pg, f.noise_scale = (post.R[0], post.t[0], post.vel[0], post.P.copy(),
                                                               None if Pg is None else Pg.copy(), post.noise_scale)
        priors.append(prior)
        posts.append(post)

    def state(s):
        return State(s.time, s.R[0], s.t[0], s.vel[0], s.P, s.Pg, s.noise_scale)

    want = rts_smooth([state(s) for s in priors], [state(s) for s in posts])
    used_scaled = 0
    for k in range(7):
        got = sm.smoothed(k)
        assert np.allclose(got.R[0], want[k].R, atol=1e-10)
        assert np.allclose(got.t[0], want[k].t, atol=1e-10)
        assert np.allclose(got.vel[0], want[k].vel, atol=1e-10)
        assert np.allclose(got.P, want[k].P, atol=1e-12)
        assert (got.Pg is None) == (want[k].Pg is None)
        assert np.allclose(got.own, want[k].own, atol=1e-12)
        used_scaled += k < 6 and np.allclose(got.P, 4.0 * got.own, atol=1e-12)
    assert used_scaled >= 1  # the scaled own bound was the smaller one somewhere
