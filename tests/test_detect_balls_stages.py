"""Each stage of the ball detector on its own, against ground truth built from geometry.

The whole detector is tested on exact sphere renders in
``test_detect_balls.py``; here every stage gets inputs whose answer is known
by construction: supersampled discs (search, rim), 1-D profiles with a known
step (unmixing), cones of bearings of a known sphere (cone fit), points of a
known ellipse (ellipse fit), and hand-made candidates (choice).
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest

from mutloc.core.camera import Camera
from mutloc.core.rig import Marker
from mutloc.detect.balls import BallParams, BallSearch, detect_balls
from mutloc.detect.balls.choose import Candidate, assign, choose_consistent, rig_mates
from mutloc.detect.balls.fit import CameraModel, cone_fit, fit_ellipse, fit_ellipse_irls, fit_rim
from mutloc.detect.balls.params import value_lut
from mutloc.detect.balls.rim import Rim, rim_radii, sample_rim, unmix_edge
from mutloc.detect.balls.search import coarse_blobs, find_blobs, hue_masks, pick_downscale, ransac_circle
from mutloc.errors import InputError

F = 800.0
W, H = 320, 240
K = np.array([[F, 0.0, (W - 1) / 2], [0.0, F, (H - 1) / 2], [0.0, 0.0, 1.0]])

BALL_BGR = np.array([40.0, 40.0, 210.0])  # a red ball (BGR, 0..255 linear values)
BG_BGR = np.array([150.0, 110.0, 60.0])  # a bluish background


def disc_image(cu: float, cv_: float, r: float, ss: int = 16, w: int = W, h: int = H) -> np.ndarray:
    """A disc of BALL_BGR on BG_BGR, each pixel the exact mixture by its area covered (ss x ss samples).

    Pixel ``(j, i)`` covers ``[j - 0.5, j + 0.5] x [i - 0.5, i + 0.5]`` (pixel
    centres at integers, as in the SPEC).
    """
    off = (np.arange(ss) + 0.5) / ss - 0.5
    u = (np.arange(w)[:, None] + off[None, :]).ravel()
    v = (np.arange(h)[:, None] + off[None, :]).ravel()
    inside = ((u[None, :] - cu) ** 2 + (v[:, None] - cv_) ** 2 <= r * r).astype(float)
    cover = inside.reshape(h, ss, w, ss).mean(axis=(1, 3))
    img = cover[..., None] * BALL_BGR + (1.0 - cover[..., None]) * BG_BGR
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def red_search(**kw) -> BallSearch:
    return BallSearch.from_marker("R", Marker("R", "q", np.zeros(3), color=(255, 0, 0)), BallParams(**kw))


# ---------------------------------------------------------------------------
# parameters
# ---------------------------------------------------------------------------


def test_params_are_frozen_and_validated():
    p = BallParams()
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.hue_tol_deg = 20.0  # type: ignore[misc]
    for bad in (
        {"hue_tol_deg": 95.0},
        {"min_radius_px": 0.0},
        {"max_radius_px": 1.0},  # not above min_radius_px
        {"downscale": 0},
        {"max_candidates": 1.5},
        {"distance_range_m": (3.0, 1.0)},
        {"min_score": 2.0},
        {"mix_gamma": -1.0},
    ):
        with pytest.raises(InputError):
            BallParams(**bad)
    with pytest.raises(InputError, match="BallParams"):
        detect_balls(np.zeros((H, W, 3), np.uint8), {}, params={"hue_tol_deg": 10.0})  # type: ignore[arg-type]


def test_value_lut():
    assert value_lut(False, 1.7)[255] == pytest.approx(1.0)
    assert value_lut(False, 1.7)[51] == pytest.approx(0.2)
    assert value_lut(True, 2.0)[51] == pytest.approx(0.04)


# ---------------------------------------------------------------------------
# coarse search
# ---------------------------------------------------------------------------


def test_pick_downscale():
    assert pick_downscale(None, 2.0, 960, 540) == 1  # 2 px balls need full resolution
    assert pick_downscale(None, 3.0, 960, 540) == 2
    assert pick_downscale(None, 6.0, 960, 540) == 4
    assert pick_downscale(None, 6.0, 300, 200) == 1  # 150 x 100 would be too small to search
    assert pick_downscale(8, 2.0, 64, 64) == 4  # never below 16 pixels a side


def test_hue_mask_wraps_around_red():
    """Hues of 350 and 10 deg are both within 12 deg of 0 (red); 30 deg is not."""
    hsv = np.zeros((1, 3, 3), np.uint8)
    hsv[0, :, 0] = np.round(np.array([350.0, 10.0, 30.0]) * 256 / 360) % 256
    hsv[0, :, 1:] = 200
    (mask,) = hue_masks(hsv, [red_search()], 12.0, 20)
    assert list(mask[0] > 0) == [True, True, False]


@pytest.mark.parametrize("k", [1, 2])
def test_coarse_search_finds_a_disc(k):
    cu, cv_, r = 141.3, 97.6, 17.4
    img = disc_image(cu, cv_, r)
    (blobs,) = find_blobs(img, [red_search()], k, 80.0, 12, BallParams())
    assert len(blobs) == 1
    b = blobs[0]
    # Within a (coarse) pixel: the stage only has to seed the rim.
    assert math.hypot(b.u - cu, b.v - cv_) < 0.6 * k
    assert abs(b.radius - r) < 0.8 * k
    assert b.fill > 0.95 and b.quality > 0.8


def test_coarse_search_separates_a_disc_from_a_touching_rectangle():
    """A mask of a disc merged with a rectangle: RANSAC still finds the disc, not the whole blob."""
    mask = np.zeros((H, W), np.uint8)
    cv2.circle(mask, (100, 120), 20, 255, -1)
    cv2.rectangle(mask, (118, 90), (200, 150), 255, -1)
    blobs = coarse_blobs(mask, 1.0, 1.0, 2.0, 80.0)
    best = max(blobs, key=lambda b: b.quality)
    assert math.hypot(best.u - 100, best.v - 120) < 1.0
    assert abs(best.radius - 20.5) < 1.0


def test_ransac_circle_ignores_a_straight_cut():
    """Points of a circle cut by a chord (an occluder's edge): the circle, not the chord, is found."""
    phi = np.linspace(0, 2 * math.pi, 200, endpoint=False)
    c, r = np.array([50.0, 40.0]), 15.0
    pts = c + r * np.column_stack([np.cos(phi), np.sin(phi)])
    keep = pts[:, 0] < 58.0
    chord = np.column_stack([np.full(30, 58.0), np.linspace(40 - 12.7, 40 + 12.7, 30)])
    fit = ransac_circle(np.vstack([pts[keep], chord]), 0.5, 2.0, 100.0)
    assert fit is not None
    # (A least-squares circle through all the points is off by pixels.)
    assert math.hypot(fit[0] - c[0], fit[1] - c[1]) < 0.01 and abs(fit[2] - r) < 0.01


# ---------------------------------------------------------------------------
# sub-pixel rim
# ---------------------------------------------------------------------------


def test_rim_of_an_antialiased_disc_is_sub_pixel():
    cu, cv_, r = 160.37, 118.81, 10.3
    img = disc_image(cu, cv_, r)
    ang = np.arange(64) * (2 * math.pi / 64)
    # Rays from a centre 0.6 px off and a guess 0.8 px too big, as the coarse
    # search may leave them; the truth along each ray is where it meets the circle.
    ox, oy = cu + 0.4, cv_ - 0.45
    rim = sample_rim(img, value_lut(False, 1.7), ox, oy, ang, np.full(64, r + 0.8), 2.5, 0.5)
    dx, dy = ox - cu, oy - cv_
    b = dx * np.cos(ang) + dy * np.sin(ang)
    truth = -b + np.sqrt(b * b - (dx * dx + dy * dy - r * r))
    assert rim.valid.all()
    err = rim.radius - truth
    assert np.median(np.abs(err)) < 0.03 and np.max(np.abs(err)) < 0.1
    # Inner colour is the ball's (values of the linear lut are v / 255).
    assert np.allclose(np.median(rim.inner, axis=0) * 255, BALL_BGR, atol=2.0)
    assert isinstance(rim, Rim) and np.allclose(np.hypot(*(rim.pts - [ox, oy]).T), rim.radius)


def test_rays_leaving_the_image_are_invalid():
    img = disc_image(10.0, 120.0, 15.0)
    ang = np.arange(32) * (2 * math.pi / 32)
    rim = sample_rim(img, value_lut(False, 1.7), 10.0, 120.0, ang, np.full(32, 15.0), 2.5, 0.5)
    left = np.cos(ang) < -0.8
    assert not rim.valid[left].any() and np.isnan(rim.radius[left]).all()
    assert rim.valid[np.cos(ang) > 0.5].all()


@pytest.mark.parametrize("shade, light", [(1.0, 1.0), (0.5, 1.4), (1.3, 0.6)])
def test_unmixing_is_independent_of_shading(shade, light):
    """A box-blurred step at ``x_e``, ball and background scaled by different factors."""
    step, x_e = 0.5, 4.37
    t = np.arange(19) * step  # 0 .. 9
    a = np.clip(x_e - t + 0.5, 0.0, 1.0)  # ball fraction of a 1-px-wide pixel centred at t
    ball, bg = np.array([0.1, 0.1, 0.8]), np.array([0.5, 0.4, 0.2])
    P = a[:, None] * shade * ball + (1 - a[:, None]) * light * bg
    alpha, B = np.empty(len(t)), np.empty(3)
    ok, edge, contrast = unmix_edge(P, 0, len(t) - 1, step, alpha, B)
    assert ok and contrast > 0.1
    assert abs(edge - x_e) < 0.02
    assert np.allclose(B, shade * ball)


def test_a_second_edge_in_the_window_is_refused():
    step = 0.5
    t = np.arange(19) * step
    a = np.clip(4.0 - t + 0.5, 0, 1) + np.clip(t - 6.0 + 0.5, 0, 1) * np.clip(7.0 - t + 0.5, 0, 1)  # ball, gap, ball
    P = a[:, None] * np.array([0.1, 0.1, 0.8]) + (1 - a[:, None]) * np.array([0.5, 0.4, 0.2])
    ok, _, _ = unmix_edge(P, 0, len(t) - 1, step, np.empty(len(t)), np.empty(3))
    assert not ok


# ---------------------------------------------------------------------------
# fit
# ---------------------------------------------------------------------------


def sphere_rim_bearings(C: np.ndarray, R: float, n: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Unit bearings of the rim of a sphere (centre C, radius R) seen from the origin."""
    d = C / np.linalg.norm(C)
    sin_t = R / np.linalg.norm(C)
    cos_t = math.sqrt(1 - sin_t**2)
    e1 = np.cross(d, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    phi = np.arange(n) * (2 * math.pi / n)
    b = cos_t * d + sin_t * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    return b, d, cos_t


def test_cone_fit_recovers_the_sphere_direction_despite_outliers():
    C, R = np.array([0.21, -0.13, 1.4]), 0.03
    b, d_true, cos_true = sphere_rim_bearings(C, R, 60)
    # An arc of six rim points pushed outwards (clutter) by ~3 px at f = 800
    # (the cone's half-angle is 0.021 rad, 17 px).
    bad = np.arange(6)
    b[bad] = b[bad] + 0.18 * (b[bad] - d_true)
    b /= np.linalg.norm(b, axis=1)[:, None]
    fin = np.ones(60, bool)
    d, w = np.empty(3), np.empty(60)
    ok, cos_t, rms = cone_fit(b, fin, fin, F, d, w)
    assert ok
    assert np.linalg.norm(d - d_true) < 1e-9 and abs(cos_t - cos_true) < 1e-12
    assert np.all(w[bad] == 0) and np.all(np.delete(w, bad) > 0.99) and rms < 1e-6


@pytest.mark.parametrize("dist", [None, np.array([-0.25, 0.08, 0.001, -0.0005, 0.0])])
def test_fit_rim_with_camera_recovers_the_sphere_centre(dist):
    """Rim pixels projected by OpenCV (with lens distortion) give back the sphere's direction."""
    cam = Camera(K, dist=dist, size=(W, H))
    C, R = np.array([0.15, 0.09, 0.9]), 0.03
    b, d_true, _ = sphere_rim_bearings(C, R, 48)
    uv, _ = cv2.projectPoints(b.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
    uv = uv.reshape(-1, 2)
    c0 = uv.mean(axis=0) + [0.3, -0.2]  # the rays' origin need not be the centre
    rel = uv - c0
    ang = np.arctan2(rel[:, 1], rel[:, 0])
    rim = Rim(c0[0], c0[1], ang, np.hypot(*rel.T), np.ones(48, bool), np.zeros((48, 3)), np.ones(48))
    fit = fit_rim(rim, np.ones(48, bool), CameraModel(cam), 1.6)
    assert fit is not None and fit.direction is not None
    assert np.linalg.norm(fit.direction - d_true) < 1e-7
    truth_uv, _ = cv2.projectPoints(C.reshape(1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
    assert np.linalg.norm(cam.project(fit.direction) - truth_uv.reshape(2)) < 1e-4
    # The outline passes through the rim points.
    assert np.allclose(rim_radii(fit.outline, c0[0], c0[1], ang), rim.radius, atol=1e-3)
    assert fit.rms < 1e-6 and np.all(fit.weights > 0.99)


def ellipse_points(c, a, b, ang_deg, n=40):
    phi = np.arange(n) * (2 * math.pi / n) + 0.1
    ca, sa = math.cos(math.radians(ang_deg)), math.sin(math.radians(ang_deg))
    x, y = a * np.cos(phi), b * np.sin(phi)
    return np.column_stack([c[0] + ca * x - sa * y, c[1] + sa * x + ca * y])


def test_ellipse_fit_recovers_a_known_ellipse():
    pts = ellipse_points((40.3, 60.7), 12.0, 9.0, 30.0)
    model = fit_ellipse(pts, np.ones(len(pts)), 1.6)
    assert model is not None
    (cu, cv_), axes, ang = model["ellipse"]
    assert math.hypot(cu - 40.3, cv_ - 60.7) < 1e-9
    i = int(np.argmax(axes))
    assert axes[i] == pytest.approx(12.0, abs=1e-9) and axes[1 - i] == pytest.approx(9.0, abs=1e-9)
    major = ang if i == 0 else ang + 90.0
    assert (major - 30.0 + 90.0) % 180.0 - 90.0 == pytest.approx(0.0, abs=1e-6)
    assert np.max(np.abs(model["dist"])) < 1e-9


def test_ellipse_irls_ignores_outliers_and_refuses_elongated_fits():
    """Rim points with the noise of a measured rim (on noise-free points the algebraic fit's
    scatter matrix is singular), four of them pulled 4 px inwards by an occluder."""
    c = np.array([40.3, 60.7])
    pts = ellipse_points(c, 12.0, 10.0, -20.0) + np.random.default_rng(3).normal(0.0, 0.03, (40, 2))
    bad = [3, 4, 5, 6]
    v = pts[bad] - c
    pts[bad] -= 4.0 * v / np.linalg.norm(v, axis=1)[:, None]
    out = fit_ellipse_irls(pts, np.ones(len(pts), bool), 1.6)
    assert out is not None
    outline, w, rms, centre = out
    assert np.linalg.norm(centre - c) < 0.03
    assert np.all(w[bad] == 0) and np.all(np.delete(w, bad) > 0.5) and rms < 0.05
    # The outline is the ellipse: its points are within noise of the true curve.
    assert np.all(np.abs(np.hypot(*((outline - c) @ np.array([[math.cos(-0.349), -math.sin(-0.349)],
                                                          [math.sin(-0.349), math.cos(-0.349)]])).T
                                  / np.array([[12.0], [10.0]])) - 1.0) < 0.01)
    # Twice as long as wide is not the image of a sphere.
    long = ellipse_points((40.3, 60.7), 20.0, 10.0, 0.0)
    assert fit_ellipse(long, np.ones(len(long)), 1.6) is None
    assert fit_ellipse(long, np.ones(len(long)), 2.5) is not None


# ---------------------------------------------------------------------------
# choice
# ---------------------------------------------------------------------------


def search(name: str, pos, robot: str = "q") -> BallSearch:
    return BallSearch(name, (255, 0, 0), 0.0, 1.0, 1.0, 0.03, robot, np.asarray(pos, float))


def candidate(s: BallSearch, xyz, score: float) -> Candidate:
    """A candidate of a ball at ``xyz`` (camera frame), as the fit would report it."""
    xyz = np.asarray(xyz, float)
    uv = K @ xyz
    uv = uv[:2] / uv[2]
    dist = float(np.linalg.norm(xyz))
    r_px = F * 0.03 / dist
    return Candidate(s, uv, uv.copy(), r_px, score, {"distance_m": dist}, xyz)


def test_rig_mates_needs_two_balls_at_distinct_places():
    a, b = search("A", [0, 0, 0]), search("B", [0.3, 0, 0])
    assert rig_mates([a, b]) == {"q": [a, b]}
    assert rig_mates([a, search("C", [0, 0, 0])]) == {}
    assert rig_mates([a, search("D", [0.3, 0, 0], robot="p")]) == {}


def test_choice_prefers_the_blob_consistent_with_the_rig():
    """B's best-scoring blob is 1 m from A; the rig says 0.3 m: the other blob is chosen."""
    a, b = search("A", [0, 0, 0]), search("B", [0.3, 0, 0])
    ca = candidate(a, [0.0, 0.0, 2.0], 0.97)
    stray = candidate(b, [1.0, 0.0, 2.0], 0.95)
    right = candidate(b, [0.3, 0.0, 2.0], 0.6)
    picked, clean = choose_consistent([a, b], {"A": [ca], "B": [stray, right]}, BallParams())
    assert clean and picked == [ca, right]
    # Without the right blob the weaker of the two inconsistent balls is
    # left out, and the choice is not clean (the caller then refines the blobs it passed over).
    picked, clean = choose_consistent([a, b], {"A": [ca], "B": [stray]}, BallParams())
    assert picked == [ca] and not clean


def test_choice_never_reports_one_blob_for_two_markers():
    a, b = search("A", [0, 0, 0], robot=None), search("B", [0.3, 0, 0], robot=None)
    blob_a = candidate(a, [0.0, 0.0, 2.0], 0.9)
    blob_b_same = candidate(b, [0.0, 0.0, 2.0], 0.8)  # B's colour matched A's ball too
    blob_b = candidate(b, [0.3, 0.0, 2.0], 0.5)
    dup_a = candidate(a, [0.0, 0.001, 2.0], 0.85)  # the same ball found twice for A
    taken = assign([], [blob_a, blob_b_same, blob_b, dup_a])
    assert taken == [blob_a, blob_b]
    # A rig-checked choice goes first even with a lower score.
    taken = assign([blob_b_same], [blob_a])
    assert taken == [blob_b_same]
