"""SO(3)/SE(3) helpers against SciPy's Rotation (an independent implementation)."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from mutloc.core.pose import Pose
from mutloc.core.geometry import (
    matrix_from_quaternion_xyzw,
    quaternion_xyzw_from_matrix,
    rotation_error_deg,
    skew,
    so3_exp,
    so3_log,
)

vec3 = st.lists(st.floats(-10, 10, allow_nan=False), min_size=3, max_size=3).map(np.array)


@settings(max_examples=200, deadline=None)
@given(vec3)
def test_exp_matches_scipy(w):
    np.testing.assert_allclose(so3_exp(w), Rotation.from_rotvec(w).as_matrix(), atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_log_inverts_exp_including_near_pi(seed):
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    for angle in (rng.uniform(0, np.pi), np.pi - 10 ** rng.uniform(-9, -2), 1e-9, np.pi):
        R = Rotation.from_rotvec(angle * axis).as_matrix()
        np.testing.assert_allclose(so3_exp(so3_log(R)), R, atol=1e-9)


def test_skew_is_cross_product():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(2, 3))
    np.testing.assert_allclose(skew(a) @ b, np.cross(a, b))


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_quaternion_roundtrip_and_scipy_order(seed):
    R = Rotation.random(random_state=seed).as_matrix()
    q = quaternion_xyzw_from_matrix(R)
    assert q[3] >= 0
    ref = Rotation.from_matrix(R).as_quat()  # scipy: (x, y, z, w)
    ref = -ref if ref[3] < 0 else ref
    np.testing.assert_allclose(q, ref, atol=1e-12)
    np.testing.assert_allclose(matrix_from_quaternion_xyzw(q), R, atol=1e-12)


def test_rotation_error_is_the_angle_and_clipped():
    R = Rotation.from_rotvec([0, 0.3, 0]).as_matrix()
    assert rotation_error_deg(R, np.eye(3)) == pytest.approx(np.degrees(0.3))
    # Slightly non-orthonormal input would put the arccos argument above 1.
    assert rotation_error_deg(np.eye(3) * (1 + 1e-12), np.eye(3)) == 0.0


def test_pose_compose_inverse_apply():
    rng = np.random.default_rng(1)
    A = Pose(Rotation.random(random_state=1).as_matrix(), rng.normal(size=3))
    B = Pose(Rotation.random(random_state=2).as_matrix(), rng.normal(size=3))
    x = rng.normal(size=(5, 3))
    np.testing.assert_allclose((A @ B).apply(x), A.apply(B.apply(x)))
    np.testing.assert_allclose((A.inverse() @ A).as_matrix(), np.eye(4), atol=1e-12)
