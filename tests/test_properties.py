"""Property-based tests (hypothesis) of the public API.

* Swapping the roles of p and q (observations and rig) inverts the pose.
* Re-expressing a robot's frame changes the pose by exactly that transform.
  ``solve_bearings`` works on rays from each camera's optical centre, so the
  re-expression keeps the centre fixed: G is a rotation about it (a
  translation would move the rays' origin off the frame origin).  With
  x_p = G x_p' and x_q' = H^T x_q the new rays and markers are
  b' = G^T b, X' = G^T X (and H^T for q), and T_q'p' = H^T T_qp G.
* Bad input of every kind reaches the caller only as a subclass of
  ``mutloc.errors.MutlocError``; when a call does return, its poses are
  finite and put every marker in front of the camera that saw it.

A property checked on an example that ends in an error (the same error in
every form of the problem) or is drawn outside the image checks nothing, so
every property test counts how its examples ended and fails when too few
were checked (:func:`_run_counted`).
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

import mutloc
from mutloc.core.camera import Camera
from mutloc.core.geometry import so3_exp
from mutloc.core.pose import Pose
from mutloc.core.rig import Marker, Rig, Robot
from mutloc.errors import (
    DegenerateGeometryError,
    InputError,
    MutlocError,
    ObservationError,
    RigError,
    TooFewObservationsError,
    UnknownMarkerError,
)
from mutloc.sim.synthetic import USUAL_MARKERS, facing_pose, random_layout

PROPS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])

K_P = np.array([[800.0, 0.0, 479.5], [0.0, 800.0, 269.5], [0.0, 0.0, 1.0]])
K_Q = np.array([[650.0, 0.0, 330.0], [0.0, 660.0, 240.0], [0.0, 0.0, 1.0]])
TOP = np.array([0.0, -0.2, -0.03])


# ---------------------------------------------------------------------------
# scenes
# ---------------------------------------------------------------------------


@st.composite
def scenes(draw):
    """(pose T_qp, markers_p (3, 3), markers_q (3, 3)): facing or random layout, 0.5-5 m."""
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    if draw(st.booleans()):
        d = draw(st.floats(0.5, 5.0))
        yaw_p = math.radians(draw(st.floats(-20, 20)))
        yaw_q = math.radians(draw(st.floats(-20, 20)))
        lateral = draw(st.floats(-0.2, 0.2)) * d
        pose = facing_pose(d, yaw_p, yaw_q, lateral, tilt=rng.normal(scale=math.radians(3.0), size=3))
        base = np.vstack([USUAL_MARKERS, TOP])
        mp = base + rng.normal(scale=0.02, size=(3, 3))
        mq = base + rng.normal(scale=0.02, size=(3, 3))
        return pose, mp, mq
    s = random_layout(rng, 3, 3, (0.5, 5.0))
    return s.pose, s.markers_p, s.markers_q


def _rays(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _perturb(b: np.ndarray, rng: np.random.Generator, sigma: float) -> np.ndarray:
    return _rays(b + rng.normal(scale=sigma, size=b.shape)) if len(b) else b


def bearing_problem(pose: Pose, mp, mq, n_by_p: int, n_by_q: int, sigma: float, seed: int):
    """p sees the first n_by_p of q's markers, q the first n_by_q of p's."""
    rng = np.random.default_rng(seed)
    pq = mq[:n_by_p]
    pp = mp[:n_by_q]
    bp = _perturb(_rays(pose.inverse().apply(pq)), rng, sigma) if n_by_p else np.empty((0, 3))
    bq = _perturb(_rays(pose.apply(pp)), rng, sigma) if n_by_q else np.empty((0, 3))
    return bp, pq.reshape(-1, 3), bq, pp.reshape(-1, 3)


splits = st.tuples(st.integers(0, 3), st.integers(0, 3)).filter(lambda s: s[0] + s[1] >= 3)


def _orthonormal(R) -> np.ndarray:
    U, _, Vt = np.linalg.svd(np.asarray(R, dtype=float))
    return U @ Vt


# Found by hypothesis: cameras 1.35 m apart, nearly facing; p sees three of
# q's markers.  J^T J of this minimal problem has condition number 1.5e12 in
# the p->q parametrisation but 1.8e11 in the q->p one.
NEAR_DEGENERATE_3_0 = (
    Pose(_orthonormal([[-0.998912, 0.0168997, -0.04346503], [0.01768364, 0.99968668, -0.0177152],
                       [0.04315203, -0.01846454, -0.99889787]]), [-0.17928718, 0.0, 1.34557429]),
    np.array([[-0.17606314, -0.03189288, -0.02107251], [0.13926094, -0.03837764, -0.02270855],
              [0.00588265, -0.19943156, -0.01906574]]),
    np.array([[-0.16472908, -0.0532582, -0.03964239], [0.16197692, -0.04920556, -0.03584914],
              [-0.01563817, -0.20514384, -0.02983716]]),
)


def _pose_close(a, b, tol=1e-7) -> bool:
    return (np.linalg.norm(a.R - b.R) <= tol
            and np.linalg.norm(a.t - b.t) <= tol * (1.0 + np.linalg.norm(b.t)))


def _same_sets(A: list, B: list, tol: float) -> bool:
    return all(any(_pose_close(a, b, tol) for b in B) for a in A) and \
        all(any(_pose_close(a, b, tol) for a in A) for b in B)


def _outcome(fn, *args, **kwargs):
    """fn's result, or the class of the MutlocError it raised."""
    try:
        return fn(*args, **kwargs)
    except MutlocError as exc:
        return type(exc)


def _same_failure(*outcomes) -> bool:
    """True (checked) when any outcome is an error: then all must be the same error."""
    errs = [o for o in outcomes if isinstance(o, type)]
    if errs:
        names = [o.__name__ if isinstance(o, type) else "a pose" for o in outcomes]
        assert len(errs) == len(outcomes) and len(set(errs)) == 1, (
            f"the same problem gives different outcomes in its equivalent forms: {names}")
        return True
    return False


def _cheirality(pose, bp, pq, bq, pp) -> bool:
    """Every marker lies in front of its observer along the observed ray."""
    ok = True
    for b, X in zip(bp, pq):
        ok &= float(b @ (pose.R.T @ (X - pose.t))) > 0.0
    for b, X in zip(bq, pp):
        ok &= float(b @ (pose.R @ X + pose.t)) > 0.0
    return bool(ok)


# How the examples of the running property ended: "checked", or why they checked nothing.
_ENDS: Counter = Counter()


def _run_counted(prop, min_checked: float, **max_share: float) -> Counter:
    """Run the hypothesis property ``prop`` (which adds one end per example to
    ``_ENDS``) and assert that at least ``min_checked`` of its examples checked
    the property and each other end stays within its ``max_share``."""
    _ENDS.clear()
    prop()
    ends = Counter(_ENDS)
    total = sum(ends.values())
    print(f"{prop.__name__}: {dict(ends)}")
    assert total > 0
    assert ends["checked"] >= min_checked * total, f"only {ends['checked']} of {total} examples checked: {dict(ends)}"
    for end, n in ends.items():
        if end != "checked":
            assert n <= max_share.get(end.replace(" ", "_"), 0.0) * total, f"{end}: {n} of {total}: {dict(ends)}"
    return ends


# ---------------------------------------------------------------------------
# swapping p and q
# ---------------------------------------------------------------------------


@PROPS
@given(scene=scenes(), split=splits, noisy=st.booleans(), seed=st.integers(0, 2**16))
@example(scene=NEAR_DEGENERATE_3_0, split=(3, 0), noisy=False, seed=0)
def _swapping_p_and_q_bearings(scene, split, noisy, seed):
    pose, mp, mq = scene
    bp, pq, bq, pp = bearing_problem(pose, mp, mq, *split, 1e-3 if noisy else 0.0, seed)
    forward = _outcome(mutloc.solve_bearings, bp, pq, bq, pp)
    backward = _outcome(mutloc.solve_bearings, bq, pp, bp, pq)
    if _same_failure(forward, backward):
        _ENDS["same error"] += 1
        return
    if len(bp) + len(bq) == 3:
        # Minimal: every root fits exactly; the sets must correspond.
        assert _same_sets([c.inverse() for c in forward], backward, 1e-6), (forward, backward)
    else:
        assert _pose_close(forward[0].inverse(), backward[0]), (forward[0], backward[0])
    if not noisy:
        assert any(_pose_close(c, pose, 1e-6) for c in forward)
    _ENDS["checked"] += 1


def test_swapping_p_and_q_inverts_the_pose_bearings():
    _run_counted(_swapping_p_and_q_bearings, 0.9, same_error=0.1)  # measured: all 61 checked


def _rig(mp, mq, swapped: bool) -> Rig:
    """Robots 'p' (camera K_P, markers P0..P2) and 'q' (K_Q, Q0..Q2); with
    ``swapped`` the names 'p' and 'q' are exchanged."""
    a, b = ("q", "p") if swapped else ("p", "q")
    return Rig({
        a: Robot(a, Camera(K_P, None, (960, 540)), {f"P{i}": Marker(f"P{i}", a, x) for i, x in enumerate(mp)}),
        b: Robot(b, Camera(K_Q, None, (660, 480)), {f"Q{i}": Marker(f"Q{i}", b, x) for i, x in enumerate(mq)}),
    })


@PROPS
@given(scene=scenes(), split=splits, sigma=st.sampled_from([0.0, 0.5, 2.0]), seed=st.integers(0, 2**16))
@example(scene=NEAR_DEGENERATE_3_0, split=(3, 0), sigma=0.0, seed=0)
def _swapping_roles(scene, split, sigma, seed):
    pose, mp, mq = scene
    n_by_p, n_by_q = split
    cam_p, cam_q = Camera(K_P, None, (960, 540)), Camera(K_Q, None, (660, 480))
    up = cam_p.project(pose.inverse().apply(mq[:n_by_p])) if n_by_p else np.empty((0, 2))
    uq = cam_q.project(pose.apply(mp[:n_by_q])) if n_by_q else np.empty((0, 2))
    inside = (not n_by_p or np.all(cam_p.in_image(up))) and (not n_by_q or np.all(cam_q.in_image(uq)))
    if not inside:
        _ENDS["outside the image"] += 1
    assume(inside)
    rng = np.random.default_rng(seed)
    up = up + rng.normal(scale=sigma, size=up.shape)
    uq = uq + rng.normal(scale=sigma, size=uq.shape)
    obs_p = {f"Q{i}": tuple(u) for i, u in enumerate(up)}
    obs_q = {f"P{i}": tuple(u) for i, u in enumerate(uq)}
    est = _outcome(mutloc.localize, _rig(mp, mq, False), {"p": obs_p, "q": obs_q}, "p", "q")
    # Same rig, other direction.
    other = _outcome(mutloc.localize, _rig(mp, mq, False), {"p": obs_p, "q": obs_q}, "q", "p")
    # Names swapped: robot 'q' now carries the P markers and camera K_P.
    swapped = _outcome(mutloc.localize, _rig(mp, mq, True), {"q": obs_p, "p": obs_q}, "p", "q")
    if _same_failure(est, other, swapped):
        _ENDS["same error"] += 1
        return
    inv = est.inverse()
    for res in (other, swapped):
        if n_by_p + n_by_q == 3:
            assert _same_sets(res.candidates, inv.candidates, 1e-6)
        else:
            assert _pose_close(res.pose, inv.pose), (res.pose, inv.pose)
            np.testing.assert_allclose(res.covariance, inv.covariance, rtol=1e-4,
                                       atol=1e-6 * np.abs(inv.covariance).max())
    if sigma == 0.0:
        assert any(_pose_close(c, pose, 1e-6) for c in est.candidates)
    _ENDS["checked"] += 1


def test_swapping_roles_in_rig_and_observations_inverts_the_pose():
    # measured: 55 of 84 checked, 23 outside the image, 6 the same error in all three forms
    _run_counted(_swapping_roles, 0.5, same_error=0.2, outside_the_image=0.5)


# ---------------------------------------------------------------------------
# re-expressing a robot's frame
# ---------------------------------------------------------------------------

rotvecs = st.tuples(*[st.floats(-math.pi, math.pi)] * 3).map(np.array)


@PROPS
@given(scene=scenes(), split=splits, noisy=st.booleans(), seed=st.integers(0, 2**16), wg=rotvecs, wh=rotvecs)
@example(scene=NEAR_DEGENERATE_3_0, split=(3, 0), noisy=False, seed=0, wg=np.array([1.5, 0.2, -0.7]),
         wh=np.array([-0.7, 0.2, 1.5]))
def _reexpressing_a_robot_frame(scene, split, noisy, seed, wg, wh):
    pose, mp, mq = scene
    bp, pq, bq, pp = bearing_problem(pose, mp, mq, *split, 1e-3 if noisy else 0.0, seed)
    G, H = so3_exp(wg), so3_exp(wh)  # x_p = G x_p',  x_q = H x_q'
    poses = _outcome(mutloc.solve_bearings, bp, pq, bq, pp)
    moved = _outcome(mutloc.solve_bearings, bp @ G, pq @ H, bq @ H, pp @ G)  # rows: G^T b, H^T X, ...
    if _same_failure(poses, moved):
        _ENDS["same error"] += 1
        return
    expected = [Pose(H.T @ c.R @ G, H.T @ c.t) for c in poses]
    if len(bp) + len(bq) == 3:
        assert _same_sets(expected, moved, 1e-6), (expected, moved)
    else:
        assert _pose_close(moved[0], expected[0]), (moved[0], expected[0])
    if not noisy:
        truth = Pose(H.T @ pose.R @ G, H.T @ pose.t)
        assert any(_pose_close(c, truth, 1e-6) for c in moved)
    _ENDS["checked"] += 1


def test_reexpressing_a_robot_frame_transforms_the_pose():
    _run_counted(_reexpressing_a_robot_frame, 0.9, same_error=0.1)  # measured: all 61 checked


# ---------------------------------------------------------------------------
# bad input only ever raises MutlocError
# ---------------------------------------------------------------------------

RIG_DICT = {
    "robots": {
        "p": {"camera": {"K": K_P.tolist(), "size": [960, 540]},
              "markers": {"M3": {"position": [-0.15, -0.05, -0.03]}, "M4": {"position": [0.15, -0.05, -0.03]}}},
        "q": {"camera": {"K": K_P.tolist(), "size": [960, 540]},
              "markers": {"M1": {"position": [-0.15, -0.05, -0.03]}, "M2": {"position": [0.15, -0.05, -0.03]}}},
    }
}
RIG = mutloc.load_rig(RIG_DICT)
_TRUTH = facing_pose(2.0, 0.1, -0.05, 0.1)
CAM = RIG.robot("p").camera
GOOD = {
    "p": {m: tuple(CAM.project(_TRUTH.inverse().apply(RIG.marker(m).position))) for m in ("M1", "M2")},
    "q": {m: tuple(CAM.project(_TRUTH.apply(RIG.marker(m).position))) for m in ("M3", "M4")},
}

junk_scalars = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**400), 10**400),
    st.text(max_size=4),
    st.none(),
    st.booleans(),
    st.complex_numbers(allow_nan=True, allow_infinity=True),
)
junk = st.recursive(
    junk_scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=3), inner, max_size=3)),
    max_leaves=10,
)
pixels = st.one_of(
    st.tuples(st.floats(-2000, 3000), st.floats(-2000, 3000)),
    st.tuples(st.floats(allow_nan=True, allow_infinity=True), st.floats(allow_nan=True, allow_infinity=True)),
    junk,
)
marker_names = st.one_of(st.sampled_from(["M1", "M2", "M3", "M4"]), st.text(max_size=4))
robot_names = st.one_of(st.sampled_from(["p", "q"]), st.text(max_size=3))
observation_sets = st.one_of(
    st.dictionaries(robot_names, st.one_of(st.dictionaries(marker_names, pixels, max_size=4),
                                           st.lists(pixels, max_size=4), junk), max_size=3),
    junk,
)


def _check_estimate(est) -> None:
    assert np.all(np.isfinite(est.R)) and np.all(np.isfinite(est.t))
    np.testing.assert_allclose(est.R @ est.R.T, np.eye(3), atol=1e-9)
    assert np.all(np.isfinite(est.covariance))


@FUZZ
@given(obs=observation_sets, source=st.one_of(st.none(), robot_names, junk),
       target=st.one_of(st.none(), robot_names, junk), sigma=st.one_of(st.just(1.0), junk))
def test_localize_fuzzed_input_raises_only_mutloc_errors(obs, source, target, sigma):
    try:
        est = mutloc.localize(RIG, obs, source, target, pixel_sigma=sigma)
    except MutlocError:
        return
    _check_estimate(est)


@FUZZ
@given(data=st.data())
def test_localize_with_some_entries_corrupted_raises_only_mutloc_errors(data):
    """A valid observation set with one or two entries replaced by junk."""
    obs = {r: dict(v) for r, v in GOOD.items()}
    for _ in range(data.draw(st.integers(1, 2))):
        robot = data.draw(st.sampled_from(["p", "q"]))
        key = data.draw(marker_names)
        obs[robot][key] = data.draw(pixels)
    try:
        est = mutloc.localize(RIG, obs, "p", "q")
    except MutlocError:
        return
    _check_estimate(est)


arrays = st.one_of(
    st.lists(st.tuples(*[st.floats(-10, 10)] * 3), max_size=5).map(np.array),
    st.lists(st.tuples(*[st.floats(allow_nan=True, allow_infinity=True)] * 3), min_size=1, max_size=4).map(np.array),
    st.lists(st.lists(st.floats(-10, 10), max_size=4), max_size=4),
    junk,
)


@FUZZ
@given(bp=arrays, pq=arrays, bq=arrays, pp=arrays)
def test_solve_bearings_fuzzed_input_raises_only_mutloc_errors(bp, pq, bq, pp):
    try:
        poses = mutloc.solve_bearings(bp, pq, bq, pp)
    except MutlocError:
        return
    assert len(poses) >= 1
    for c in poses:
        assert np.all(np.isfinite(c.R)) and np.all(np.isfinite(c.t))


@FUZZ
@given(scene=scenes(), split=splits, seed=st.integers(0, 2**16), flips=st.lists(st.booleans(), min_size=6, max_size=6),
       garbage=st.booleans())
def _impossible_geometry(scene, split, seed, flips, garbage):
    """Rays reversed (markers behind the camera) or replaced by random
    directions: either MutlocError, or poses that keep every marker in front
    of its observer."""
    pose, mp, mq = scene
    bp, pq, bq, pp = bearing_problem(pose, mp, mq, *split, 0.0, seed)
    rng = np.random.default_rng(seed)
    rays = np.vstack([bp, bq])
    if garbage:
        rays = _rays(rng.normal(size=rays.shape))
    rays = rays * np.where(np.array(flips[: len(rays)]), -1.0, 1.0)[:, None]
    bp, bq = rays[: len(bp)], rays[len(bp):]
    try:
        poses = mutloc.solve_bearings(bp, pq, bq, pp)
    except MutlocError:
        _ENDS["error"] += 1
        return
    for c in poses:
        assert np.all(np.isfinite(c.R)) and np.all(np.isfinite(c.t))
        assert _cheirality(c, bp, pq, bq, pp), f"pose {c} puts a marker behind its observer"
    _ENDS["checked"] += 1


def test_solve_bearings_impossible_geometry():
    _run_counted(_impossible_geometry, 0.2, error=0.8)  # measured: 99 of 200 poses checked, 101 errors


@FUZZ
@given(pix=st.lists(st.tuples(st.floats(0, 959), st.floats(0, 539)), min_size=4, max_size=4))
def _random_pixels(pix):
    """Arbitrary in-image detections: a pose with every marker in front of the
    camera that saw it, or a MutlocError."""
    obs = {"p": {"M1": pix[0], "M2": pix[1]}, "q": {"M3": pix[2], "M4": pix[3]}}
    try:
        est = mutloc.localize(RIG, obs, "p", "q")
    except MutlocError:
        _ENDS["error"] += 1
        return
    _check_estimate(est)
    for m in ("M1", "M2"):
        assert (est.R.T @ (RIG.marker(m).position - est.t))[2] > 0
    for m in ("M3", "M4"):
        assert (est.R @ RIG.marker(m).position + est.t)[2] > 0
    _ENDS["checked"] += 1


def test_localize_random_pixels():
    # Most random pixels fit no pose (measured: 197 of 200 errors, 3 poses checked); at least one must be.
    _run_counted(_random_pixels, 0.005, error=0.995)


@FUZZ
@given(K=st.one_of(st.just(K_P.tolist()), junk,
                   st.lists(st.lists(st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                                               st.integers(-(10**400), 10**400)), min_size=3, max_size=3),
                            min_size=3, max_size=3)),
       dist=st.one_of(st.none(), junk, st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=9)),
       size=st.one_of(st.none(), junk, st.tuples(st.integers(-5, 5000), st.integers(-5, 5000))),
       points=st.one_of(junk, arrays))
def test_camera_fuzzed_input_raises_only_mutloc_errors(K, dist, size, points):
    try:
        cam = Camera(K, dist, size)
    except MutlocError:
        return
    for method in (cam.project, cam.pixels_to_bearings, cam.in_image):
        try:
            method(points)
        except MutlocError:
            pass


# ---------------------------------------------------------------------------
# named bad inputs: each must raise a MutlocError (of the fitting kind)
# ---------------------------------------------------------------------------


def _with(robot: str, marker: str, value):
    obs = {r: dict(v) for r, v in GOOD.items()}
    obs[robot][marker] = value
    return obs


def _without(*pairs):
    obs = {r: dict(v) for r, v in GOOD.items()}
    for r, m in pairs:
        del obs[r][m]
    return obs


def test_good_observations_give_the_truth():
    est = mutloc.localize(RIG, GOOD, "p", "q")
    assert np.linalg.norm(est.t - _TRUTH.t) < 1e-6 and mutloc.rotation_error_deg(est.R, _TRUTH.R) < 1e-5


@pytest.mark.parametrize(
    "obs, kind",
    [
        (_with("p", "M1", (float("nan"), 10.0)), InputError),
        (_with("q", "M3", (10.0, float("inf"))), InputError),
        (_with("p", "M1", (1.0, 2.0, 3.0)), InputError),
        (_with("p", "M1", [[1.0, 2.0]]), InputError),
        (_with("p", "M1", "12"), InputError),
        (_with("p", "M1", None), InputError),
        (_with("p", "M1", (10**400, 5)), InputError),
        (_with("p", "M9", (100.0, 100.0)), UnknownMarkerError),
        (_with("p", "M3", (100.0, 100.0)), ObservationError),  # p observes its own marker
        ({**GOOD, "x": {"M1": (1.0, 1.0)}}, ObservationError),
        (_without(("p", "M1"), ("q", "M3")), TooFewObservationsError),
        ({"p": {}, "q": {}}, TooFewObservationsError),
        ({"p": [GOOD["p"]["M1"]], "q": [GOOD["q"]["M3"]]}, TooFewObservationsError),
        ("p: {M1: [1, 2]}", InputError),
        (_with("p", "M1", (1e7, 1e7)), ObservationError),  # far outside the image
    ],
    ids=["nan", "inf", "three-numbers", "nested", "string", "none", "huge-int", "unknown-marker",
         "own-marker", "unknown-robot", "two-left", "none-left", "two-anonymous", "not-a-mapping", "outside"],
)
def test_localize_bad_observations(obs, kind):
    with pytest.raises(kind):
        mutloc.localize(RIG, obs, "p", "q")


def _rig_dict(**changes) -> dict:
    import copy

    d = copy.deepcopy(RIG_DICT)
    for path, value in changes.items():
        node = d["robots"]
        keys = path.split("__")
        for k in keys[:-1]:
            node = node[k]
        node[keys[-1]] = value
    return d


@pytest.mark.parametrize(
    "rig",
    [
        _rig_dict(q__markers={"M3": {"position": [0.1, 0.0, 0.0]}, "M2": {"position": [0.2, 0.0, 0.0]}}),  # dup name
        _rig_dict(p__markers={"M3": {"position": [0.1, 0.0, 0.0]}, "M4": {"position": [0.1, 0.0, 0.0]}}),  # coincide
        _rig_dict(p__markers={"M3": {"position": [float("nan"), 0.0, 0.0]}}),
        _rig_dict(p__camera={"K": [[0, 0, 1], [0, 0, 1], [0, 0, 1]]}),
        _rig_dict(p__camera={"K": [[800, 0, 1], [0, 800, 1]]}),
        _rig_dict(p__camera={"K": [[10**400, 0, 1], [0, 800, 1], [0, 0, 1]]}),
        _rig_dict(p__camera={"K": K_P.tolist(), "dist": [0.1, 0.2, 0.3]}),
        {"robots": {}},
        {"robot": RIG_DICT["robots"]},
        None,
    ],
    ids=["duplicate-name", "coincident", "nan-position", "zero-focal", "K-shape", "K-huge-int", "dist-length",
         "no-robots", "missing-key", "none"],
)
def test_localize_bad_rig(rig):
    with pytest.raises(RigError):
        mutloc.localize(rig, GOOD, "p", "q")


@pytest.mark.parametrize(
    "kwargs, kind",
    [
        ({"pixel_sigma": -1.0}, InputError),
        ({"pixel_sigma": float("nan")}, InputError),
        ({"pixel_sigma": "1"}, InputError),
        ({"pixel_sigma": None}, InputError),
        ({"source": "p", "target": "p"}, ObservationError),
        ({"source": "z", "target": "q"}, ObservationError),
        ({"source": ["p"], "target": "q"}, ObservationError),
    ],
    ids=["sigma-negative", "sigma-nan", "sigma-string", "sigma-none", "same-robot", "unknown-source",
         "unhashable-source"],
)
def test_localize_bad_arguments(kwargs, kind):
    kw = {"source": "p", "target": "q", **kwargs}
    with pytest.raises(kind):
        mutloc.localize(RIG, GOOD, **kw)


_B = _rays(_TRUTH.inverse().apply(np.array([[-0.15, -0.05, -0.03], [0.15, -0.05, -0.03]])))
_P = np.array([[-0.15, -0.05, -0.03], [0.15, -0.05, -0.03]])
_BQ = _rays(_TRUTH.apply(_P))


@pytest.mark.parametrize(
    "args, kind",
    [
        ((np.array([[np.nan, 0, 1], [0, 0, 1]]), _P, _BQ, _P), InputError),
        ((_B, _P, np.array([[np.inf, 0, 1], [0, 0, 1]]), _P), InputError),
        ((_B[:, :2], _P, _BQ, _P), InputError),
        ((_B, _P[:1], _BQ, _P), InputError),
        ((_B, _P, _BQ[:0], _P[:0]), TooFewObservationsError),
        ((np.zeros((2, 3)), _P, _BQ, _P), InputError),
        ((_B, np.array([_P[0], _P[0]]), _BQ, _P), DegenerateGeometryError),  # coincident markers
        ((_B, _P, [[1, 2, 10**400]], _P[:1]), InputError),
        (("abc", _P, _BQ, _P), InputError),
        # all three rays identical but the markers form a triangle: no pose
        ((np.tile([0.0, 0.0, 1.0], (3, 1)), np.array([[0.0, 0, 0], [0.3, 0, 0], [0, 0.3, 0]]), None, None),
         MutlocError),
    ],
    ids=["nan", "inf", "shape", "length-mismatch", "two-rays", "zero-ray", "coincident", "huge-int", "string",
         "parallel-rays"],
)
def test_solve_bearings_bad_input(args, kind):
    with pytest.raises(kind):
        mutloc.solve_bearings(*args)


@pytest.mark.parametrize(
    "args",
    [
        ([[np.nan, 0, 0], [0, 1, 0], [0, 0, 1]],),
        ([[1, 0, 0], [0, 1, 0]],),
        ([[10**400, 0, 0], [0, 1, 0], [0, 0, 1]],),
        ([[-800, 0, 0], [0, 800, 0], [0, 0, 1]],),
        (K_P, [0.1, 0.2, 0.3]),
        (K_P, [10**400, 0, 0, 0]),
        (K_P, None, [960]),
        (K_P, None, [960.5, 540]),
        ("K",),
    ],
    ids=["nan", "shape", "huge-int", "negative-focal", "dist-length", "dist-huge-int", "size-length",
         "size-fraction", "string"],
)
def test_camera_bad_input(args):
    with pytest.raises(RigError):
        Camera(*args)


@pytest.mark.parametrize("value", [[np.nan, 1.0, 1.0], [1.0, 2.0], "xyz", [10**400, 0, 1]],
                         ids=["nan", "shape", "string", "huge-int"])
def test_camera_project_bad_input(value):
    with pytest.raises(InputError):
        Camera(K_P).project(value)
