"""Camera model checked against OpenCV and finite differences (independent ground truth)."""

from __future__ import annotations

import cv2
import numba
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from mutloc.core.camera import Camera, project_jac_kernel, project_kernel, undistort_kernel
from mutloc.errors import InputError, MutlocError, RigError

W, H = 960, 540
CX, CY = (W - 1) / 2.0, (H - 1) / 2.0  # 479.5, 269.5: the image centre with pixel-centre origin

# Strong barrel lens: with f = 800 the image corners sit at distorted radius
# 0.689, just inside the fold of r (1 - 0.3 r^2) at 0.7027.
STRONG_K1 = [-0.3, 0.0, 0.0, 0.0]
STRONG_8 = [-0.3, 0.08, 0.001, -0.0015, -0.01, 0.05, 0.01, 0.002]
MILD_8 = [-0.05, 0.01, 0.0005, -0.0003, -0.002, 0.001, 0.0005, 0.0002]

DISTS = {
    "none": [],
    "k1_strong_4": STRONG_K1,
    "k1k2_p_4": [-0.12, 0.03, 0.0012, -0.0008],
    "k3_5": [-0.3, 0.09, 0.0007, 0.0011, -0.012],
    "rational_8": STRONG_8,
    "rational_pos_8": [0.4, -0.1, -0.002, 0.003, 0.02, 0.3, -0.05, 0.01],
}


def _K(fx: float = 800.0, fy: float = 800.0, cx: float = CX, cy: float = CY, skew: float = 0.0) -> np.ndarray:
    return np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _random_K(rng: np.random.Generator) -> np.ndarray:
    return _K(rng.uniform(500, 1500), rng.uniform(500, 1500), rng.uniform(400, 560), rng.uniform(200, 340))


def _random_points(rng: np.random.Generator, n: int, max_tan: float = 0.6) -> np.ndarray:
    """Points in front of the camera with |x/z|, |y/z| <= max_tan."""
    z = rng.uniform(0.3, 20.0, n)
    xy = rng.uniform(-max_tan, max_tan, (n, 2)) * z[:, None]
    return np.column_stack([xy, z])


def _cv_project(X: np.ndarray, K: np.ndarray, dist) -> tuple[np.ndarray, np.ndarray]:
    d = np.asarray(dist, dtype=np.float64)
    uv, jac = cv2.projectPoints(X.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, d if d.size else None)
    return uv.reshape(-1, 2), jac


def _pixel_grid(n: int = 41) -> np.ndarray:
    """Pixels covering the whole image, edges and corners included."""
    u = np.linspace(-0.5, W - 0.5, n)
    v = np.linspace(-0.5, H - 0.5, n)
    return np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)


def _cv_undistort(uv: np.ndarray, K: np.ndarray, dist) -> np.ndarray:
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    src = uv.reshape(-1, 1, 2)
    d = np.asarray(dist, dtype=np.float64)
    # OpenCV 4 exposes the criteria overload as undistortPointsIter; OpenCV 5
    # folds it into undistortPoints.
    if hasattr(cv2, "undistortPointsIter"):
        out = cv2.undistortPointsIter(src, K, d, None, None, crit)
    else:
        out = cv2.undistortPoints(src, K, d, criteria=crit)
    return out.reshape(-1, 2)


# ---------------------------------------------------------------------------
# projection
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(DISTS))
def test_project_matches_opencv(name: str) -> None:
    rng = np.random.default_rng(list(DISTS).index(name))
    dist = DISTS[name]
    for _ in range(5):
        K = _random_K(rng)
        cam = Camera(K, dist)
        X = _random_points(rng, 200)
        expected, _ = _cv_project(X, K, dist)
        np.testing.assert_allclose(cam.project(X), expected, rtol=0, atol=1e-9)


def test_project_single_point_and_behind_camera() -> None:
    cam = Camera(_K(), STRONG_8)
    assert cam.project([0.0, 0.0, 2.0]).shape == (2,)
    np.testing.assert_allclose(cam.project([0.0, 0.0, 2.0]), [CX, CY], atol=1e-12)
    X = np.array([[0.1, 0.2, 1.0], [0.1, 0.2, 0.0], [0.1, 0.2, -1.0], [0.0, 0.0, -0.0]])
    uv = cam.project(X)
    assert np.all(np.isfinite(uv[0]))
    assert np.all(np.isnan(uv[1:]))
    uv2, J = cam.project_jacobian(X)
    np.testing.assert_array_equal(uv2, uv)
    assert np.all(np.isfinite(J[0])) and np.all(np.isnan(J[1:]))
    assert cam.project(np.zeros((0, 3))).shape == (0, 2)


def test_skew_follows_the_documented_model() -> None:
    # cv2.projectPoints ignores K[0,1], so check skew against the formula directly.
    rng = np.random.default_rng(7)
    skew = 3.5
    cam = Camera(_K(900, 880, skew=skew), STRONG_8)
    X = _random_points(rng, 100)
    no_skew, _ = _cv_project(X, _K(900, 880), STRONG_8)
    yd = (no_skew[:, 1] - CY) / 880
    expected = no_skew + np.column_stack([skew * yd, np.zeros_like(yd)])
    np.testing.assert_allclose(cam.project(X), expected, rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", list(DISTS))
def test_project_jacobian_matches_finite_differences_and_opencv(name: str) -> None:
    rng = np.random.default_rng(100 + list(DISTS).index(name))
    dist = DISTS[name]
    K = _random_K(rng)
    K[0, 1] = 0.0
    cam = Camera(K, dist)
    X = _random_points(rng, 50)
    uv, J = cam.project_jacobian(X)
    np.testing.assert_allclose(uv, cam.project(X), rtol=0, atol=1e-12)

    h = 1e-6
    J_fd = np.empty_like(J)
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        J_fd[:, :, k] = (cam.project(X + e) - cam.project(X - e)) / (2 * h)
    scale = np.abs(J).max(axis=(1, 2), keepdims=True)
    assert np.all(np.abs(J - J_fd) <= 1e-6 * scale)

    # With rvec = 0 the camera-frame point is X + tvec, so OpenCV's d(uv)/d(tvec)
    # columns (3:6) are exactly d(uv)/dX.
    _, jac = _cv_project(X, K, dist)
    J_cv = jac[:, 3:6].reshape(-1, 2, 3)
    assert np.all(np.abs(J - J_cv) <= 1e-9 * scale)


def test_project_jacobian_with_skew_matches_finite_differences() -> None:
    rng = np.random.default_rng(11)
    cam = Camera(_K(900, 880, skew=-4.0), STRONG_8)
    X = _random_points(rng, 50)
    _, J = cam.project_jacobian(X)
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        col = (cam.project(X + e) - cam.project(X - e)) / (2 * h)
        np.testing.assert_allclose(J[:, :, k], col, rtol=0, atol=1e-6 * np.abs(J).max())


def test_bearings_to_pixels_is_projection_of_directions() -> None:
    rng = np.random.default_rng(3)
    cam = Camera(_random_K(rng), STRONG_8)
    X = _random_points(rng, 30)
    b = X / np.linalg.norm(X, axis=1, keepdims=True)
    np.testing.assert_allclose(cam.bearings_to_pixels(b), cam.project(X), rtol=0, atol=1e-9)
    assert np.all(np.isnan(cam.bearings_to_pixels([0.0, 0.1, -1.0])))


# ---------------------------------------------------------------------------
# undistortion
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("dist", [STRONG_K1, STRONG_8, DISTS["k3_5"]], ids=["k1_strong", "rational_8", "k3_5"])
def test_pixels_to_bearings_round_trips_over_whole_image(dist) -> None:
    cam = Camera(_K(800, 800), dist, (W, H))
    uv = _pixel_grid()
    b = cam.pixels_to_bearings(uv)
    assert b.shape == (len(uv), 3)
    np.testing.assert_allclose(np.linalg.norm(b, axis=1), 1.0, rtol=0, atol=1e-15)
    assert np.all(b[:, 2] > 0)
    np.testing.assert_allclose(cam.project(b), uv, rtol=0, atol=1e-9)
    # Going the other way too: points to pixels to bearings.  Stay inside the
    # fold radius (1.054 for k1 = -0.3, larger for the others): beyond it two
    # rays share a pixel and the inner one is the right answer.
    rng = np.random.default_rng(5)
    r = 1.0 * np.sqrt(rng.uniform(0, 1, 500))
    phi = rng.uniform(0, 2 * np.pi, 500)
    X = np.column_stack([r * np.cos(phi), r * np.sin(phi), np.ones(500)])
    b_true = X / np.linalg.norm(X, axis=1, keepdims=True)
    np.testing.assert_allclose(cam.pixels_to_bearings(cam.project(X)), b_true, rtol=0, atol=1e-12)


def test_pixels_to_bearings_with_skew_round_trips() -> None:
    cam = Camera(_K(820, 790, skew=2.0), STRONG_8, (W, H))
    uv = _pixel_grid(21)
    np.testing.assert_allclose(cam.project(cam.pixels_to_bearings(uv)), uv, rtol=0, atol=1e-9)


@pytest.mark.parametrize("dist", [MILD_8, [-0.05, 0.01, 0.0005, -0.0003], [0.04, -0.01, 0.0, 0.0, 0.002]])
def test_pixels_to_bearings_matches_opencv_undistort(dist) -> None:
    K = _K(700, 710)
    cam = Camera(K, dist, (W, H))
    rng = np.random.default_rng(2)
    uv = np.vstack([_pixel_grid(15), rng.uniform([-0.5, -0.5], [W - 0.5, H - 0.5], (500, 2))])
    b = cam.pixels_to_bearings(uv)
    ours = b[:, :2] / b[:, 2:]
    np.testing.assert_allclose(ours, _cv_undistort(uv, K, dist), rtol=0, atol=1e-8)


def test_pixel_outside_invertible_region_is_rejected() -> None:
    cam = Camera(_K(800, 800), STRONG_K1, (W, H))
    # r (1 - 0.3 r^2) peaks at 0.7027: a distorted radius of 0.75 has no pre-image.
    bad = [CX + 800 * 0.75, CY]
    with pytest.raises(InputError, match=r"pixel \(1079\.5, 269\.5\)"):
        cam.pixels_to_bearings([[CX, CY], bad])
    b = np.empty(3)
    assert not undistort_kernel(cam.K, cam.dist, np.array(bad), b)
    assert np.all(np.isnan(b))
    # Just inside the fold the answer must be the inner branch (r < 1/sqrt(0.9)),
    # not the outer pre-image of the same pixel.
    near = np.array([CX + 800 * 0.70, CY])
    b = cam.pixels_to_bearings(near)
    r = np.hypot(b[0], b[1]) / b[2]
    assert r < 1 / np.sqrt(0.9)
    np.testing.assert_allclose(cam.project(b), near, rtol=0, atol=1e-9)


def test_pixel_centre_convention() -> None:
    cam = Camera(_K(800, 800), STRONG_8, (W, H))
    np.testing.assert_array_equal(cam.pixels_to_bearings([479.5, 269.5]), [0.0, 0.0, 1.0])
    np.testing.assert_allclose(cam.project([0.0, 0.0, 1.0]), [479.5, 269.5], atol=0)
    inside = np.array([[-0.5, -0.5], [W - 0.5, H - 0.5], [0.0, 0.0], [CX, CY]])
    outside = np.array([[-0.5001, 0.0], [W - 0.4999, 0.0], [0.0, -0.5001], [0.0, H - 0.4999], [np.nan, 1.0]])
    assert cam.in_image(inside).tolist() == [True] * 4
    assert cam.in_image(outside).tolist() == [False] * 5
    assert cam.in_image([CX, CY]) is True
    unsized = Camera(_K(800, 800))
    assert unsized.in_image(np.array([[-100.0, 5000.0], [1.0, 2.0]])).tolist() == [True, True]


# ---------------------------------------------------------------------------
# kernels inside other njit code
# ---------------------------------------------------------------------------


@numba.njit(cache=False)
def _kernel_user(K, dist, X):
    uv = np.empty(2)
    J = np.empty((2, 3))
    b = np.empty(3)
    out = np.empty((X.shape[0], 2))
    ok = 0
    for i in range(X.shape[0]):
        project_kernel(K, dist, X[i], uv)
        if project_jac_kernel(K, dist, X[i], uv, J) and undistort_kernel(K, dist, uv, b):
            ok += 1
        out[i, 0] = uv[0]
        out[i, 1] = uv[1]
    return out, ok


def test_kernels_callable_from_njit_code() -> None:
    cam = Camera(_K(), STRONG_8)
    X = _random_points(np.random.default_rng(9), 20)
    X[0, 2] = -1.0
    uv, ok = _kernel_user(cam.K, cam.dist, X)
    assert ok == 19
    np.testing.assert_allclose(uv, cam.project(X), rtol=0, atol=1e-12)


# ---------------------------------------------------------------------------
# parameters and validation
# ---------------------------------------------------------------------------


def test_parameters_storage_and_to_dict() -> None:
    cam = Camera(_K(700, 710).tolist(), [-0.1, 0.01, 0.0, 0.001, 0.002], [W, H])
    assert cam.K.dtype == np.float64 and cam.K.flags.c_contiguous
    assert cam.dist.shape == (8,) and cam.dist.flags.c_contiguous
    assert cam.n_dist == 5 and cam.size == (W, H)
    d = cam.to_dict()
    assert d == {"K": _K(700, 710).tolist(), "dist": [-0.1, 0.01, 0.0, 0.001, 0.002], "size": [W, H]}
    again = Camera(**d)
    np.testing.assert_array_equal(again.K, cam.K)
    np.testing.assert_array_equal(again.dist, cam.dist)
    assert "size" not in Camera(_K()).to_dict()
    assert Camera(_K()).to_dict()["dist"] == []
    assert Camera(_K(), np.zeros((1, 4))).n_dist == 4  # OpenCV-shaped (1, n)
    assert "Camera(" in repr(cam) and "fx=700" in repr(cam)


def test_camera_is_immutable() -> None:
    cam = Camera(_K(), [0.1, 0, 0, 0])
    with pytest.raises(AttributeError):
        cam.K = np.eye(3)  # type: ignore[misc]
    with pytest.raises(ValueError):
        cam.K[0, 0] = 1.0
    with pytest.raises(ValueError):
        cam.dist[0] = 1.0


@pytest.mark.parametrize(
    "kwargs",
    [
        {"K": np.eye(2)},
        {"K": "not a matrix"},
        {"K": _K(fx=0.0)},
        {"K": _K(fy=-800.0)},
        {"K": np.where(np.eye(3) == 1, np.nan, _K())},
        {"K": _K() + np.array([[0, 0, 0], [0, 0, 0], [0.1, 0, 0]])},
        {"K": _K() * 2.0},  # bottom row [0, 0, 2]
        {"K": _K() + np.array([[0, 0, 0], [1.0, 0, 0], [0, 0, 0]])},
        {"K": _K(), "dist": [0.1, 0.2]},
        {"K": _K(), "dist": [0.1] * 6},
        {"K": _K(), "dist": [0.1, 0.0, np.inf, 0.0]},
        {"K": _K(), "dist": np.zeros((2, 4))},
        {"K": _K(), "dist": ["a", 0, 0, 0]},
        {"K": _K(), "size": (640,)},
        {"K": _K(), "size": (640, 0)},
        {"K": _K(), "size": (640.5, 480)},
        {"K": _K(), "size": (True, 480)},
        {"K": _K(), "size": 640},
    ],
)
def test_bad_parameters_raise_rig_error(kwargs) -> None:
    with pytest.raises(RigError):
        Camera(**kwargs)


@pytest.mark.parametrize("method", ["pixels_to_bearings", "project", "bearings_to_pixels", "project_jacobian"])
def test_nan_and_bad_shapes_raise_input_error(method: str) -> None:
    cam = Camera(_K(), STRONG_8, (W, H))
    dim = 2 if method == "pixels_to_bearings" else 3
    with pytest.raises(InputError):
        getattr(cam, method)(np.full((4, dim), np.nan))
    with pytest.raises(InputError):
        getattr(cam, method)(np.zeros((4, dim + 1)))
    with pytest.raises(InputError):
        getattr(cam, method)(np.zeros((2, 2, dim)))


_CAM = Camera(_K(), STRONG_8, (W, H))
_METHODS = ["pixels_to_bearings", "project", "project_jacobian", "bearings_to_pixels", "in_image"]

_elements = st.floats(allow_nan=True, allow_infinity=True, width=64) | st.sampled_from([0.0, 1.0, -1.0, 1e308])
_arrays = hnp.arrays(
    np.float64,
    hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=4),
    elements=_elements,
)
_junk = st.one_of(
    st.none(),
    st.text(max_size=5),
    st.lists(st.one_of(st.floats(), st.text(max_size=2), st.lists(st.floats(), max_size=3)), max_size=4),
    st.dictionaries(st.text(max_size=2), st.floats(), max_size=2),
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(method=st.sampled_from(_METHODS), data=_arrays | _junk)
def test_fuzzed_inputs_raise_only_mutloc_errors(method: str, data) -> None:
    try:
        out = getattr(_CAM, method)(data)
    except MutlocError as exc:
        assert isinstance(exc, InputError)
        return
    arr = np.asarray(data, dtype=np.float64)
    n = 1 if arr.ndim == 1 else arr.shape[0]
    if method == "pixels_to_bearings":
        b = np.asarray(out).reshape(n, 3)
        np.testing.assert_allclose(np.linalg.norm(b, axis=1), 1.0, atol=1e-12)
        assert np.all(b[:, 2] > 0)
    elif method == "project_jacobian":
        uv, J = out
        assert np.asarray(uv).reshape(n, 2).shape == (n, 2)
        assert np.asarray(J).reshape(n, 2, 3).shape == (n, 2, 3)
    elif method == "in_image":
        assert np.asarray(out).dtype == bool and np.asarray(out).size == n
    else:
        assert np.asarray(out).reshape(n, 2).shape == (n, 2)
