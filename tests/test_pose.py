"""The Pose type (one transform or a stack) against SciPy's Rotation and
plain 4x4 matrix algebra, both independent of mutloc."""

import pickle

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from mutloc.core.pose import Pose
from mutloc.errors import InputError


def _random(n, seed):
    rng = np.random.default_rng(seed)
    R = Rotation.random(n, random_state=seed).as_matrix()
    return Pose(R, rng.normal(size=(n, 3)))


def test_stack_algebra_matches_matrices():
    A, B = _random(7, 1), _random(7, 2)
    C = A @ B
    np.testing.assert_allclose(C.as_matrix(), A.as_matrix() @ B.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(A.inverse().as_matrix(), np.linalg.inv(A.as_matrix()), atol=1e-12)
    x = np.random.default_rng(3).normal(size=(7, 3))
    h = np.einsum("nij,nj->ni", A.as_matrix(), np.c_[x, np.ones(7)])[:, :3]
    np.testing.assert_allclose(A.apply(x), h, atol=1e-12)


def test_single_broadcasts_over_stack():
    A, B = _random(1, 4)[0], _random(5, 5)
    np.testing.assert_allclose((A @ B).as_matrix(), A.as_matrix()[None] @ B.as_matrix(), atol=1e-12)
    np.testing.assert_allclose((B @ A).as_matrix(), B.as_matrix() @ A.as_matrix()[None], atol=1e-12)


def test_views_match_scipy():
    P = _random(6, 7)
    rot = Rotation.from_matrix(P.R)
    np.testing.assert_allclose(P.rotvec, rot.as_rotvec(), atol=1e-10)
    q = rot.as_quat()
    q[q[:, 3] < 0] *= -1
    np.testing.assert_allclose(P.quaternion_xyzw, q, atol=1e-10)
    back = Pose.from_quaternion_xyzw(P.quaternion_xyzw, P.t)
    np.testing.assert_allclose(back.R, P.R, atol=1e-10)
    back = Pose.from_rotvec(P.rotvec, P.t)
    np.testing.assert_allclose(back.R, P.R, atol=1e-10)


def test_indexing_iteration_and_errors():
    P = _random(4, 8)
    assert len(P) == 4 and P.shape == (4,) and not P.single
    assert P[2].single and np.allclose(P[2].R, P.R[2])
    assert len(P[1:3]) == 2
    assert [p.t.tolist() for p in P] == P.t.tolist()
    d = P[0].translation_error(P[1])
    assert d == pytest.approx(np.linalg.norm(P.t[0] - P.t[1]))
    errs = P.rotation_error_deg(P[0])
    assert errs.shape == (4,) and errs[0] == pytest.approx(0.0, abs=1e-5)
    ang = np.degrees(np.linalg.norm(Rotation.from_matrix(P.R[0].T @ P.R[1]).as_rotvec()))
    assert errs[1] == pytest.approx(ang, abs=1e-6)
    with pytest.raises(TypeError):
        len(P[0])
    with pytest.raises(TypeError):
        list(P[0])
    with pytest.raises(InputError):
        Pose(np.eye(3), np.zeros(2))
    with pytest.raises(InputError):
        Pose(np.zeros((2, 3, 3)), np.zeros((3, 3)))
    with pytest.raises(AttributeError):
        P.t = np.zeros(3)


def test_identity_concatenate_pickle_and_nan_padding():
    I = Pose.identity(3)
    assert I.shape == (3,) and np.allclose(I.R, np.eye(3))
    C = Pose.concatenate([Pose.identity(), _random(2, 9)])
    assert len(C) == 3
    assert pickle.loads(pickle.dumps(C)).as_matrix().tolist() == C.as_matrix().tolist()
    pad = Pose(np.full((2, 3, 3), np.nan), np.full((2, 3), np.nan))
    assert not pad.isfinite().any() and Pose.identity().isfinite()
    assert len(Pose.concatenate([])) == 0


rotvecs = st.lists(st.floats(-3, 3, allow_nan=False), min_size=3, max_size=3).map(np.array)


@settings(max_examples=100, deadline=None)
@given(rotvecs, rotvecs, rotvecs)
def test_inverse_composition_is_identity(w, t, x):
    P = Pose.from_rotvec(w, t)
    np.testing.assert_allclose((P @ P.inverse()).as_matrix(), np.eye(4), atol=1e-10)
    np.testing.assert_allclose(P.inverse().apply(P.apply(x)), x, atol=1e-9)
