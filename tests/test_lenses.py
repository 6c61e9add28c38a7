"""Wide-angle lens models (core/lenses.py) against independent truth: OpenCV's
fisheye functions, the models' closed forms written out here independently,
the pinhole Camera (omni with xi = 0), and central finite differences."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

import mutloc
from mutloc.core.camera import Camera
from mutloc.core.lenses import FisheyeCamera, Lens, OmniCamera, lens_from_dict, make_camera
from mutloc.errors import InputError, RigError

W, H = 1280, 800
FISH_K = np.array([[290.0, 0.0, 639.5], [0.0, 289.0, 399.5], [0.0, 0.0, 1.0]])
FISH_D = [0.012, -0.004, 0.0006, -0.0001]
# A 200+ degree lens: theta_d keeps increasing well past 100 degrees off the axis.
WIDE_D = [-0.02, 0.003, -0.0002, 0.00001]
OMNI_K = np.array([[420.0, 0.0, 641.0], [0.0, 418.0, 398.0], [0.0, 0.0, 1.0]])
OMNI_D = [-0.05, 0.01, 0.0008, -0.0006]


def _with_skew(K: np.ndarray, skew: float) -> np.ndarray:
    K = K.copy()
    K[0, 1] = skew
    return K


def _directions(rng: np.random.Generator, n: int, min_deg: float, max_deg: float) -> np.ndarray:
    """Points (random distance 0.2..30) at angles off the axis uniform in [min_deg, max_deg]."""
    th = np.radians(rng.uniform(min_deg, max_deg, n))
    ph = rng.uniform(-np.pi, np.pi, n)
    d = np.column_stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
    return d * rng.uniform(0.2, 30.0, n)[:, None]


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (rad) between rows of a and b, accurate for tiny angles."""
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.sum(a * b, axis=1))


# --- independent closed forms -----------------------------------------------------------------


def _ref_fisheye(X: np.ndarray, K: np.ndarray, k) -> np.ndarray:
    x, y, z = X.T
    r = np.hypot(x, y)
    th = np.arctan2(r, z)
    thd = th + k[0] * th**3 + k[1] * th**5 + k[2] * th**7 + k[3] * th**9
    scale = thd / r
    xd, yd = scale * x, scale * y
    return np.column_stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]])


def _ref_omni(X: np.ndarray, K: np.ndarray, d, xi: float) -> np.ndarray:
    Xs = X / np.linalg.norm(X, axis=1, keepdims=True)
    mx = Xs[:, 0] / (Xs[:, 2] + xi)
    my = Xs[:, 1] / (Xs[:, 2] + xi)
    k1, k2, p1, p2 = d
    r2 = mx**2 + my**2
    rad = 1 + k1 * r2 + k2 * r2**2
    xd = mx * rad + 2 * p1 * mx * my + p2 * (r2 + 2 * mx**2)
    yd = my * rad + p1 * (r2 + 2 * my**2) + 2 * p2 * mx * my
    return np.column_stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]])


# --- fisheye ------------------------------------------------------------------------------------


@pytest.mark.parametrize("skew", [0.0, 0.7])
def test_fisheye_projection_matches_opencv(skew):
    rng = np.random.default_rng(1)
    K = _with_skew(FISH_K, skew)
    cam = FisheyeCamera(K, FISH_D, size=(W, H))
    X = _directions(rng, 500, 0.0, 85.0)
    ref, _ = cv2.fisheye.projectPoints(X.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.array(FISH_D),
                                       alpha=skew / K[0, 0])
    uv = cam.project(X)
    assert np.max(np.abs(uv - ref.reshape(-1, 2))) < 1e-9
    # the image of 85 degrees is inside the 1280 x 800 frame only partly: the test covers the corners
    assert np.mean(cam.in_image(uv)) < 1.0


def test_fisheye_unprojection_matches_opencv():
    rng = np.random.default_rng(2)
    cam = FisheyeCamera(FISH_K, FISH_D)
    X = _directions(rng, 500, 0.0, 85.0)
    uv = cam.project(X)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    xy = cv2.fisheye.undistortPoints(uv.reshape(-1, 1, 2), FISH_K, np.array(FISH_D), criteria=crit).reshape(-1, 2)
    cv_rays = np.column_stack([xy, np.ones(len(xy))])
    b = cam.pixels_to_bearings(uv)
    assert np.allclose(np.linalg.norm(b, axis=1), 1.0, atol=1e-14)
    assert np.max(_angle(b, cv_rays)) < 1e-8
    assert np.max(_angle(b, X)) < 1e-12


def test_fisheye_past_90_degrees_closed_form_and_round_trip():
    rng = np.random.default_rng(3)
    K = _with_skew(FISH_K, 0.4)
    cam = FisheyeCamera(K, WIDE_D)
    assert cam.max_angle > math.radians(100.0)
    X = _directions(rng, 400, 90.0, 100.0)
    assert np.all(X[:, 2] <= 0.0)
    uv = cam.project(X)
    assert np.all(np.isfinite(uv))
    assert np.max(np.abs(uv - _ref_fisheye(X, K, WIDE_D))) < 1e-9
    b = cam.pixels_to_bearings(uv)
    assert np.max(_angle(b, X)) < 1e-9
    assert np.all(b[:, 2] <= 0.0)


def test_fisheye_max_angle_is_where_theta_d_stops_increasing():
    cam = FisheyeCamera(FISH_K, FISH_D)
    t = cam.max_angle
    assert math.radians(90.0) < t < math.pi

    def theta_d(th):
        return th * (1 + FISH_D[0] * th**2 + FISH_D[1] * th**4 + FISH_D[2] * th**6 + FISH_D[3] * th**8)

    grid = np.linspace(0.0, t, 2001)
    assert np.all(np.diff(theta_d(grid)) > 0)
    assert theta_d(t + 1e-3) < theta_d(t)  # past it the lens folds back
    # just inside: imaged; just outside: not
    inside = np.array([math.sin(t - 1e-6), 0.0, math.cos(t - 1e-6)])
    outside = np.array([0.0, math.sin(t + 1e-6), math.cos(t + 1e-6)])
    assert np.all(np.isfinite(cam.project(inside)))
    assert np.all(np.isnan(cam.project(outside)))
    assert np.all(np.isnan(cam.project_jacobian(outside)[1]))
    # a pixel beyond the image of max_angle has no bearing
    far = np.array([FISH_K[0, 2] + FISH_K[0, 0] * (theta_d(t) + 0.01), FISH_K[1, 2]])
    assert np.all(np.isnan(cam.pixels_to_bearings(far)))
    # an undistorted lens sees everything but straight back
    ideal = FisheyeCamera(FISH_K)
    assert ideal.max_angle == pytest.approx(math.pi)
    assert np.all(np.isfinite(ideal.project([0.01, 0.0, -1.0])))
    assert np.all(np.isnan(ideal.project([0.0, 0.0, -1.0])))


def test_fisheye_pixel_grid_round_trip():
    """Every pixel of the frame inside the image of max_angle maps to a ray
    and back; the corners beyond it (past the lens's fold) give NaN."""
    K = _with_skew(FISH_K, 0.3)
    cam = FisheyeCamera(K, FISH_D, size=(W, H))
    u, v = np.meshgrid(np.linspace(-0.5, W - 0.5, 65), np.linspace(-0.5, H - 0.5, 41))
    uv = np.column_stack([u.ravel(), v.ravel()])
    b = cam.pixels_to_bearings(uv)
    yd = (uv[:, 1] - K[1, 2]) / K[1, 1]
    rd = np.hypot((uv[:, 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0], yd)
    t = cam.max_angle
    rd_max = t * (1 + FISH_D[0] * t**2 + FISH_D[1] * t**4 + FISH_D[2] * t**6 + FISH_D[3] * t**8)
    ok = np.all(np.isfinite(b), axis=1)
    assert np.array_equal(ok, rd < rd_max) and 0 < np.sum(~ok) < 0.2 * len(ok)
    assert np.max(np.abs(cam.bearings_to_pixels(b[ok]) - uv[ok])) < 1e-8
    assert np.any(b[ok, 2] < -0.5)  # the frame reaches well past 90 degrees


def test_fisheye_principal_point_and_axis():
    cam = FisheyeCamera(_with_skew(FISH_K, 0.5), FISH_D)
    assert np.array_equal(cam.pixels_to_bearings([FISH_K[0, 2], FISH_K[1, 2]]), [0.0, 0.0, 1.0])
    assert np.allclose(cam.project([0.0, 0.0, 3.0]), FISH_K[:2, 2], atol=0)
    assert np.all(np.isnan(cam.project([0.0, 0.0, 0.0])))


# --- omni -----------------------------------------------------------------------------------------


def _omni_points(rng, n, xi, margin_deg=2.0):
    limit = math.degrees(math.acos(-min(xi, 1.0 / xi))) if xi > 0 else 90.0
    return _directions(rng, n, 0.0, limit - margin_deg)


@pytest.mark.parametrize("xi", [0.3, 0.9, 1.0, 1.7])
def test_omni_projection_matches_mei_closed_form(xi):
    rng = np.random.default_rng(4)
    K = _with_skew(OMNI_K, 0.3)
    cam = OmniCamera(K, OMNI_D, xi=xi)
    X = _omni_points(rng, 500, xi, margin_deg=30.0)  # where the radial-tangential polynomial is still sane
    uv = cam.project(X)
    assert np.max(np.abs(uv - _ref_omni(X, K, OMNI_D, xi))) < 1e-9
    b = cam.pixels_to_bearings(uv)
    assert np.max(_angle(b, X)) < 1e-9


def test_omni_stops_where_its_radial_distortion_folds():
    """k1 < 0: r (1 + k1 r^2) stops increasing at r = 1 / sqrt(3 |k1|); past it (2 % inside) a pixel would have
    two directions, so the lens images nothing there -- with xi = 1, r = tan(theta / 2): 136.3 deg for
    k1 = -0.05.  Inside, every direction comes back from its pixel."""
    cam = OmniCamera(OMNI_K, [-0.05, 0.0, 0.0, 0.0], xi=1.0)
    fold = 2 * math.degrees(math.atan(0.98 / math.sqrt(3 * 0.05)))
    assert math.degrees(cam.max_angle) == pytest.approx(fold, abs=1e-6)
    inside = _directions(np.random.default_rng(8), 200, 0.0, fold - 1.0)
    assert np.max(_angle(cam.pixels_to_bearings(cam.project(inside)), inside)) < 1e-9
    assert np.all(np.isnan(cam.project(_directions(np.random.default_rng(9), 50, fold + 0.5, fold + 20.0))))


@pytest.mark.parametrize("xi", [0.0, 0.6, 1.0, 2.0])
def test_omni_valid_region_and_pixel_round_trip(xi):
    cam = OmniCamera(OMNI_K, [0.0, 0.0, 0.0005, -0.0004], xi=xi, size=(W, H))
    limit = math.acos(-min(xi, 1.0 / xi)) if xi > 0 else math.pi / 2
    assert cam.max_angle == pytest.approx(limit)
    inside = [math.sin(limit - 1e-3), 0.0, math.cos(limit - 1e-3)]
    # (for xi = 1 everything but straight back is imaged)
    outside = [0.0, math.sin(limit + 1e-3), math.cos(limit + 1e-3)] if limit < math.pi else [0.0, 0.0, -1.0]
    assert np.all(np.isfinite(cam.project(inside)))
    assert np.all(np.isnan(cam.project(outside)))
    if xi > 1:
        # z_s + xi > 0 there, but the sphere beyond z_s = -1/xi folds onto the part in front of it
        back = np.array([0.3, 0.0, -0.99])
        assert back[2] / np.linalg.norm(back) + xi > 0
        assert np.all(np.isnan(cam.project(back)))
    # pixels -> bearings -> pixels over the image
    u, v = np.meshgrid(np.linspace(-0.5, W - 0.5, 33), np.linspace(-0.5, H - 0.5, 21))
    uv = np.column_stack([u.ravel(), v.ravel()])
    b = cam.pixels_to_bearings(uv)
    ok = np.all(np.isfinite(b), axis=1)
    # the image of the valid region: for xi > 1 a disc of normalized radius 1 / sqrt(xi^2 - 1)
    r = np.hypot((uv[:, 0] - OMNI_K[0, 2]) / OMNI_K[0, 0], (uv[:, 1] - OMNI_K[1, 2]) / OMNI_K[1, 1])
    r_max = 1.0 / math.sqrt(xi**2 - 1.0) if xi > 1 else np.inf
    assert np.all(ok[r < 0.95 * r_max]) and not np.any(ok[r > 1.05 * r_max])
    assert ok.mean() > 0.1
    assert np.allclose(np.linalg.norm(b[ok], axis=1), 1.0, atol=1e-14)
    assert np.max(np.abs(cam.bearings_to_pixels(b[ok]) - uv[ok])) < 1e-8
    assert np.array_equal(OmniCamera(OMNI_K, xi=xi).pixels_to_bearings(OMNI_K[:2, 2]), [0.0, 0.0, 1.0])


@pytest.mark.parametrize("n_dist", [0, 4])
def test_omni_with_xi_zero_is_the_pinhole_camera(n_dist):
    rng = np.random.default_rng(6)
    d = OMNI_D[:n_dist]
    K = _with_skew(OMNI_K, 0.8)
    omni = OmniCamera(K, d, xi=0.0)
    pin = Camera(K, d)
    X = _directions(rng, 300, 0.0, 55.0)
    uv_o, J_o = omni.project_jacobian(X)
    uv_p, J_p = pin.project_jacobian(X)
    assert np.max(np.abs(uv_o - uv_p)) < 1e-9
    assert np.allclose(J_o, J_p, rtol=1e-9, atol=1e-12)
    assert np.max(_angle(omni.pixels_to_bearings(uv_p), pin.pixels_to_bearings(uv_p))) < 1e-12
    back = [0.1, 0.2, -1.0]
    assert np.all(np.isnan(omni.project(back))) and np.all(np.isnan(pin.project(back)))


# --- Jacobians --------------------------------------------------------------------------------


def _cameras():
    return {
        "pinhole": Camera(_with_skew(OMNI_K, 0.6), [-0.1, 0.02, 0.001, -0.002, -0.003]),
        "fisheye": FisheyeCamera(_with_skew(FISH_K, 0.6), WIDE_D),
        "omni_0.8": OmniCamera(_with_skew(OMNI_K, 0.6), OMNI_D, xi=0.8),
        "omni_1.6": OmniCamera(_with_skew(OMNI_K, 0.6), OMNI_D, xi=1.6),
    }


@pytest.mark.parametrize("name", list(_cameras()))
def test_jacobian_matches_central_differences(name):
    cam = _cameras()[name]
    rng = np.random.default_rng(7)
    max_deg = {"pinhole": 50.0, "fisheye": 105.0, "omni_0.8": 100.0, "omni_1.6": 100.0}[name]
    X = _directions(rng, 200, 0.0, max_deg)
    X = np.vstack([X, [[1e-12, -2e-12, 2.0], [0.0, 0.0, 0.7]]])  # on and next to the axis
    uv, J = cam.project_jacobian(X)
    assert np.all(np.isfinite(J))
    assert np.allclose(uv, cam.project(X), rtol=0, atol=1e-9)
    for i, x in enumerate(X):
        h = 1e-6 * np.linalg.norm(x)
        num = np.empty((2, 3))
        for j in range(3):
            e = np.zeros(3)
            e[j] = h
            num[:, j] = (cam.project(x + e) - cam.project(x - e)) / (2 * h)
        scale = np.max(np.abs(J[i]))
        assert np.max(np.abs(J[i] - num)) < 1e-6 * scale + 1e-9, (i, x, J[i], num)
    uv1, J1 = cam.project_jacobian(X[0])
    assert uv1.shape == (2,) and J1.shape == (2, 3)


# --- the interface, rig-file form, errors -------------------------------------------------------


def test_one_interface_and_immutability():
    for name, cam in _cameras().items():
        assert isinstance(cam, Lens), name
        assert cam.model == name.split("_")[0]
        assert 0 < cam.max_angle <= math.pi
        with pytest.raises(AttributeError):
            cam.K = np.eye(3)
        with pytest.raises(ValueError):
            cam.K[0, 0] = 1.0
        with pytest.raises(ValueError):
            cam.dist[0] = 1.0
        assert repr(cam).startswith(type(cam).__name__ + "(fx=")
        assert cam.project(np.zeros((0, 3))).shape == (0, 2)
        with pytest.raises(InputError):
            cam.project([np.nan, 0.0, 1.0])
        with pytest.raises(InputError):
            cam.pixels_to_bearings([[1.0, 2.0, 3.0]])
    assert mutloc.FisheyeCamera is FisheyeCamera and mutloc.OmniCamera is OmniCamera


def test_rig_file_form_round_trips():
    old = Camera(OMNI_K, [-0.1, 0.02, 0.001, -0.002, 0.003], size=(W, H))
    assert "model" not in old.to_dict()  # old rig files stay byte for byte what they were
    back = lens_from_dict(old.to_dict())
    assert isinstance(back, Camera) and back.to_dict() == old.to_dict()
    for cam in [FisheyeCamera(_with_skew(FISH_K, 0.2), FISH_D, size=(W, H)), FisheyeCamera(FISH_K),
                OmniCamera(OMNI_K, OMNI_D, xi=1.2), OmniCamera(OMNI_K, xi=0.5, size=[W, H])]:
        d = cam.to_dict()
        assert d["model"] == cam.model
        again = lens_from_dict(d)
        assert type(again) is type(cam) and again.to_dict() == d
        assert np.array_equal(again.K, cam.K) and np.array_equal(again.dist, cam.dist)
    assert lens_from_dict({"model": "OMNI", "K": OMNI_K, "xi": 0.4}).xi == 0.4
    assert FisheyeCamera(FISH_K).n_dist == 0 and np.array_equal(FisheyeCamera(FISH_K).dist, np.zeros(4))


@pytest.mark.parametrize("spec, needle", [
    ({"model": "fishey", "K": FISH_K, "dist": FISH_D}, "did you mean 'fisheye'"),
    ({"model": "equidistant", "K": FISH_K, "dist": FISH_D}, "'fisheye'"),
    ({"model": "fisheye", "K": FISH_K, "dist": FISH_D + [0.0]}, "4 coefficients"),
    ({"model": "fisheye", "K": FISH_K, "dist": FISH_D[:2]}, "got 2"),
    ({"model": "omni", "K": OMNI_K, "dist": [0.1, 0.0, 0.0, 0.0, 0.0], "xi": 1.0}, "4 coefficients"),
    ({"model": "omni", "K": OMNI_K, "dist": OMNI_D}, "missing key 'xi'"),
    ({"model": "omni", "K": OMNI_K, "xi": float("nan")}, "xi must be finite"),
    ({"model": "omni", "K": OMNI_K, "xi": -0.5}, "xi must be >= 0"),
    ({"model": "omni", "K": OMNI_K, "xi": "big"}, "xi must be a number"),
    ({"model": "pinhole", "K": OMNI_K, "xi": 0.5}, "omni model only"),
    ({"model": "pinhole", "K": OMNI_K, "dist": [0.1, 0.2, 0.3]}, "coefficients"),
    ({"model": "fisheye", "K": [[290, 0, 640], [0, float("nan"), 400], [0, 0, 1]]}, "NaN"),
    ({"model": "fisheye", "K": FISH_K, "dist": [0.1, float("inf"), 0, 0]}, "NaN or inf"),
    ({"model": "fisheye", "K": FISH_K, "dsit": FISH_D}, "did you mean 'dist'"),
    ({"model": "fisheye", "dist": FISH_D}, "missing key 'K'"),
    ({"model": 3, "K": FISH_K}, "model must be a string"),
])
def test_bad_camera_entries_give_one_line_rig_errors(spec, needle):
    with pytest.raises(RigError) as exc:
        lens_from_dict(spec, "rig.yaml: robots.a.camera")
    msg = str(exc.value)
    assert "\n" not in msg
    assert msg.startswith("rig.yaml: robots.a.camera: "), msg
    assert needle in msg, msg


def test_make_camera_and_constructors_raise_typed_errors():
    with pytest.raises(RigError, match="xi is missing"):
        make_camera("omni", OMNI_K, OMNI_D)
    with pytest.raises(RigError, match="^cam0: xi is missing"):
        make_camera("omni", OMNI_K, OMNI_D, where="cam0")
    with pytest.raises(RigError, match="^camera dist must have 4 coefficients"):
        FisheyeCamera(FISH_K, [0.0] * 5)
    with pytest.raises(RigError, match="camera K contains NaN"):
        OmniCamera(np.full((3, 3), np.nan), xi=1.0)
    with pytest.raises(RigError, match="did you mean 'omni'"):
        make_camera("omin", OMNI_K, xi=1.0)
    assert isinstance(make_camera(None, OMNI_K), Camera)
    assert isinstance(make_camera("fisheye", FISH_K, np.array(FISH_D).reshape(1, 4)), FisheyeCamera)
