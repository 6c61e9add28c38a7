"""Detection through any lens (issue 36 item 3): tags and balls in fisheye and
omnidirectional images out to the rim, reported in the raw image's pixels.

Ground truth is independent of the detector and of the rectified views: each
image is ray-traced from the lens model -- for every raw pixel (4x4
sub-pixels) its ray from ``pixels_to_bearings`` is intersected with the tag's
plane (cells of ``cv2.aruco.generateImageMarker``'s image, a white quiet
zone) or the ball's sphere placed in the camera frame -- and the truth pixel
of a tag corner or a ball centre is ``camera.project`` of the 3-D point.
Pixel convention: (0, 0) is the centre of the top-left pixel.
"""

from __future__ import annotations

import math
import sys

import cv2
import numpy as np
import pytest

from mutloc.core.camera import Camera
from mutloc.core.lenses import FisheyeCamera, OmniCamera
from mutloc.core.rig import Marker, MarkerKind
from mutloc.detect import detect_image
from mutloc.detect.balls import detect_balls
from mutloc.detect.tags import detect_tags
from mutloc.detect.views import needs_views, views_for
from mutloc.sim.render import linear_to_srgb, srgb_to_linear

SS = 4  # sub-pixels per pixel side
#: The SPEC's example fisheye (190 degrees and more across the image's width), 1280x800.
FISHEYE = FisheyeCamera([[290, 0, 639.5], [0, 290, 399.5], [0, 0, 1]], [0.012, -0.004, 0.0006, -0.0001],
                        (1280, 800))
#: Mei's model, xi = 1 (a 180-degree-plus mirror lens), 1024x768.
OMNI = OmniCamera([[450, 0, 511.5], [0, 450, 383.5], [0, 0, 1]], [-0.05, 0.01, 0.0005, -0.0003], 1.0,
                  (1024, 768))
TAG_SIZE = 0.12
BALL_RADIUS = 0.05
RED = (255, 40, 40)  # sRGB


def _direction(off_axis_deg: float, azimuth_deg: float = 0.0) -> np.ndarray:
    t, a = math.radians(off_axis_deg), math.radians(azimuth_deg)
    return np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])


def _background(camera, seed: int) -> np.ndarray:
    """Smooth grey clutter (uint8 grey, raw size)."""
    w, h = camera.size
    rng = np.random.default_rng(seed)
    small = rng.uniform(0, 255, (h // 16 + 2, w // 16 + 2)).astype(np.float32)
    return np.clip(0.35 * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC) + 80, 0, 255)


def _subpixel_rays(camera, box: tuple[int, int, int, int]) -> tuple[np.ndarray, tuple[int, int]]:
    """Rays (n, 3) of the 4x4 sub-pixels of every pixel in ``box`` (u0, v0, u1, v1 inclusive)."""
    u0, v0, u1, v1 = box
    offs = (np.arange(SS) + 0.5) / SS - 0.5
    us = (np.arange(u0, u1 + 1)[:, None] + offs[None, :]).ravel()
    vs = (np.arange(v0, v1 + 1)[:, None] + offs[None, :]).ravel()
    U, V = np.meshgrid(us, vs)
    return camera.pixels_to_bearings(np.c_[U.ravel(), V.ravel()]), (v1 - v0 + 1, u1 - u0 + 1)


def _box(camera, pts3: np.ndarray, pad: int = 4) -> tuple[int, int, int, int]:
    uv = camera.project(pts3)
    uv = uv[np.all(np.isfinite(uv), axis=1)]
    w, h = camera.size
    u0, v0 = np.floor(uv.min(axis=0)).astype(int) - pad
    u1, v1 = np.ceil(uv.max(axis=0)).astype(int) + pad
    return max(0, u0), max(0, v0), min(w - 1, u1), min(h - 1, v1)


def _facing(C: np.ndarray, tilt_deg: float) -> np.ndarray:
    """Tag frame (columns x, y, z) at ``C``: z (into the tag) along the line of sight turned ``tilt_deg``
    about the tag's y, y as near the camera's down as can be."""
    z = C / np.linalg.norm(C)
    y = np.array([0.0, 1.0, 0.0]) - z[1] * z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    R = np.stack([x, y, z], axis=1)
    t = math.radians(tilt_deg)
    Ry = np.array([[math.cos(t), 0, math.sin(t)], [0, 1, 0], [-math.sin(t), 0, math.cos(t)]])
    return R @ Ry


def render_tag(camera, C: np.ndarray, R: np.ndarray, tid: int = 3, seed: int = 0,
               noise: float = 1.5) -> tuple[np.ndarray, np.ndarray]:
    """BGR image of a tag36h11 tag (black square side TAG_SIZE, one white cell of quiet zone) centred at
    ``C`` with frame ``R`` (x right, y down, z into the tag), and its true corners (TL, TR, BR, BL)."""
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    cells = d.markerSize + 2
    bits = cv2.aruco.generateImageMarker(d, tid, cells, borderBits=1)  # one pixel per cell
    cell = TAG_SIZE / cells
    h = TAG_SIZE / 2
    q = h + cell  # quiet zone's half side
    corners3 = C + np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]]) @ R.T
    s = np.linspace(-q, q, 33)
    outline = np.r_[np.c_[s, -q + 0 * s], np.c_[s, q + 0 * s], np.c_[-q + 0 * s, s], np.c_[q + 0 * s, s]]
    box = _box(camera, C + np.c_[outline, 0 * s.repeat(4)] @ R.T)
    rays, shape = _subpixel_rays(camera, box)
    n = R[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (n @ C) / (rays @ n)
    P = rays * t[:, None] - C
    x, y = P @ R[:, 0], P @ R[:, 1]
    hit = np.isfinite(t) & (t > 0) & (np.abs(x) < q) & (np.abs(y) < q)
    val = np.full(len(rays), np.nan)
    val[hit] = 225.0  # quiet zone
    inner = hit & (np.abs(x) < h) & (np.abs(y) < h)
    ci = np.clip(((x[inner] + h) / cell).astype(int), 0, cells - 1)
    ri = np.clip(((y[inner] + h) / cell).astype(int), 0, cells - 1)
    val[inner] = np.where(bits[ri, ci] > 127, 225.0, 25.0)
    img = _background(camera, seed)
    u0, v0, u1, v1 = box
    patch = img[v0:v1 + 1, u0:u1 + 1]
    sub = np.repeat(np.repeat(patch, SS, axis=0), SS, axis=1).ravel()
    sub = np.where(np.isnan(val), sub, val).reshape(shape[0] * SS, shape[1] * SS)
    # Light mixes linearly within a pixel: average in linear light, then encode (sRGB) as a camera does.
    mixed = srgb_to_linear(sub / 255.0).reshape(shape[0], SS, shape[1], SS).mean(axis=(1, 3))
    img[v0:v1 + 1, u0:u1 + 1] = 255.0 * linear_to_srgb(mixed)
    img = img + np.random.default_rng(seed + 1).normal(0, noise, img.shape)
    grey = np.clip(img + 0.5, 0, 255).astype(np.uint8)
    return cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR), camera.project(corners3)


def render_ball(camera, S: np.ndarray, seed: int = 0, noise: float = 1.5) -> np.ndarray:
    """BGR image of a shaded RED ball of radius BALL_RADIUS centred at ``S`` (lit from the camera's side)."""
    ring = np.array([[math.cos(a), math.sin(a)] for a in np.linspace(0, 2 * math.pi, 48, endpoint=False)])
    z = S / np.linalg.norm(S)
    e1 = np.cross(z, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(z, e1)
    box = _box(camera, S + 1.2 * BALL_RADIUS * (ring[:, :1] * e1 + ring[:, 1:] * e2))
    rays, shape = _subpixel_rays(camera, box)
    bS = rays @ S
    disc = bS**2 - (S @ S - BALL_RADIUS**2)
    hit = np.isfinite(bS) & (bS > 0) & (disc > 0)
    t = bS - np.sqrt(np.where(hit, disc, 0.0))
    normal = (rays * t[:, None] - S) / BALL_RADIUS
    light = -z + np.array([0.3, -0.5, 0.0])
    light /= np.linalg.norm(light)
    shade = 0.45 + 0.55 * np.clip(normal @ light, 0, 1)
    lin = (np.array(RED[::-1], float) / 255.0) ** 2.2  # BGR, linear
    colour = 255.0 * (shade[:, None] * lin) ** (1 / 2.2)
    grey = _background(camera, seed)
    img = np.repeat(grey[:, :, None], 3, axis=2)
    u0, v0, u1, v1 = box
    patch = img[v0:v1 + 1, u0:u1 + 1]
    sub = np.repeat(np.repeat(patch, SS, axis=0), SS, axis=1).reshape(-1, 3)
    sub = np.where(hit[:, None], colour, sub).reshape(shape[0] * SS, shape[1] * SS, 3)
    mixed = srgb_to_linear(sub / 255.0).reshape(shape[0], SS, shape[1], SS, 3).mean(axis=(1, 3))
    img[v0:v1 + 1, u0:u1 + 1] = 255.0 * linear_to_srgb(mixed)
    img = img + np.random.default_rng(seed + 1).normal(0, noise, img.shape)
    return np.clip(img + 0.5, 0, 255).astype(np.uint8)


def _tag_marker(tid: int = 3) -> dict[str, Marker]:
    return {"T": Marker("T", "q", np.zeros(3), tag={"family": "tag36h11", "id": tid, "size": TAG_SIZE})}


def _ball_marker() -> dict[str, Marker]:
    return {"B": Marker("B", "q", np.zeros(3), color=RED, extra={"radius": BALL_RADIUS})}


# Tags at 1.5-2 m (17-22 px at 290 px/rad: a 0.12 m tag farther is below the detector's size limit
# in any image), turned 20 degrees off facing the camera.
TAG_CASES = [(0.0, 0.0, 1.5), (45.0, 20.0, 2.0), (70.0, 200.0, 2.0), (85.0, 0.0, 2.0), (92.0, 180.0, 2.0),
             (85.0, 0.0, 0.7), (92.0, 180.0, 0.7)]
#: Tolerances (px) on the worst corner: the edge fit's sub-pixel accuracy plus the rectification's
#: bilinear resampling; the measured errors are printed (-s) and recorded in the report.
TAG_TOL_PX = 0.25


def _corner_errors(camera, off, az, dist, tid=3, seed=0, detect=None):
    C = dist * _direction(off, az)
    img, truth = render_tag(camera, C, _facing(C, 20.0), tid=tid, seed=seed)
    res = (detect or (lambda i, m: detect_image(MarkerKind.TAG, i, m, camera)))(img, _tag_marker(tid))
    if "T" not in res.detections:
        return None, truth
    return np.linalg.norm(res.detections["T"].corners - truth, axis=1), truth


@pytest.mark.parametrize("off, az, dist", TAG_CASES)
def test_fisheye_tag_corners_out_to_the_rim(off, az, dist):
    err, truth = _corner_errors(FISHEYE, off, az, dist, seed=int(off))
    assert np.all(FISHEYE.in_image(truth))
    assert err is not None, f"tag {off} degrees off the axis not found"
    print(f"fisheye tag {off:5.1f} deg: corner error median {np.median(err):.3f} px, max {err.max():.3f} px")
    assert err.max() < TAG_TOL_PX


@pytest.mark.parametrize("off, az, dist", [(0.0, 0.0, 1.0), (60.0, 90.0, 1.5), (85.0, 180.0, 1.5), (85.0, 0.0, 0.8)])
def test_omni_tag_corners(off, az, dist):
    err, _ = _corner_errors(OMNI, off, az, dist, seed=int(off) + 7)
    assert err is not None, f"omni: tag {off} degrees off the axis not found"
    print(f"omni tag {off:5.1f} deg: corner error median {np.median(err):.3f} px, max {err.max():.3f} px")
    assert err.max() < TAG_TOL_PX


def test_rim_tags_need_the_views():
    """The mutation: the detector run on the raw fisheye image itself (no views; it cannot take the lens,
    so without a camera) measures the rim tags' corners off, by the sides' curvature: 1.2-1.3 px at
    60 px (0.7 m), against <= 0.2 px through the views.  (Small rim tags, ~20 px, are nearly straight-sided:
    there the raw image's corners are as good.)"""
    for off, az, dist in TAG_CASES[5:]:
        err, _ = _corner_errors(FISHEYE, off, az, dist, seed=int(off),
                                detect=lambda i, m: detect_tags(i, m))
        assert err is None or err.max() > 3 * TAG_TOL_PX, (off, err)


BALL_CASES = [(0.0, 0.0, 2.0), (45.0, 30.0, 1.8), (70.0, 200.0, 1.5), (85.0, 0.0, 1.3), (92.0, 180.0, 1.3)]
BALL_TOL_PX = 0.2


def _ball_error(camera, off, az, dist, seed=0, detect=None):
    S = dist * _direction(off, az)
    img = render_ball(camera, S, seed=seed)
    res = (detect or (lambda i, m: detect_image(MarkerKind.BALL, i, m, camera)))(img, _ball_marker())
    truth = camera.project(S)
    if "B" not in res.detections:
        return None
    return float(np.linalg.norm(res.detections["B"].uv - truth))


@pytest.mark.parametrize("off, az, dist", BALL_CASES)
def test_fisheye_ball_centres_out_to_the_rim(off, az, dist):
    err = _ball_error(FISHEYE, off, az, dist, seed=int(off) + 3)
    assert err is not None, f"ball {off} degrees off the axis not found"
    print(f"fisheye ball {off:5.1f} deg: centre error {err:.3f} px")
    assert err < BALL_TOL_PX


def test_omni_ball_centre():
    err = _ball_error(OMNI, 85.0, 0.0, 1.0, seed=11)
    assert err is not None
    print(f"omni ball 85 deg: centre error {err:.3f} px")
    assert err < BALL_TOL_PX


def test_rim_balls_need_the_views():
    """The mutation: on the raw image without views (no camera: the ellipse centre) a rim ball's centre is
    pixels off (the rim's compression bends its outline), or not found."""
    for off, az, dist in BALL_CASES[3:]:
        err = _ball_error(FISHEYE, off, az, dist, seed=int(off) + 3, detect=lambda i, m: detect_balls(i, m))
        assert err is None or err > 2 * BALL_TOL_PX, (off, err)


def test_views_cover_the_field_and_are_cached():
    vs = views_for(FISHEYE)
    assert views_for(FISHEYE) is vs  # per camera, not per frame
    rng = np.random.default_rng(0)
    d = rng.normal(size=(20000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    uv = FISHEYE.bearings_to_pixels(d)
    inside = np.all(np.isfinite(uv), axis=1) & FISHEYE.in_image(uv)
    d = d[inside]
    best = np.full(len(d), -np.inf)
    for v in vs:
        b = d @ v.R
        with np.errstate(all="ignore"):
            m = np.degrees(np.minimum(math.radians(50) - np.abs(np.arctan2(b[:, 0], b[:, 2])),
                                      math.radians(50) - np.abs(np.arctan2(b[:, 1], b[:, 2]))))
        m[b[:, 2] <= 0] = -90
        # only where the (cropped) view shows it
        pv = b[:, :2] / b[:, 2:3] * v.camera.K[0, 0] + v.camera.K[:2, 2]
        w, h = v.camera.size
        m[~((pv[:, 0] > 0) & (pv[:, 0] < w - 1) & (pv[:, 1] > 0) & (pv[:, 1] < h - 1))] = -90
        best = np.maximum(best, m)
    assert best.min() > 8.0  # every imaged direction well inside some view
    # a view pixel goes back through its ray to the raw pixel the lens images that ray at
    v = vs.views[3]
    p = np.array([[100.0, 120.0]])
    assert np.allclose(FISHEYE.project(v.bearings(p)), v.to_raw(p))


def test_pinhole_path_unchanged():
    """A pinhole camera gets no views: detect_image is the detector itself, call for call."""
    K = np.array([[800.0, 0, 479.5], [0, 800.0, 269.5], [0, 0, 1]])
    cam = Camera(K, [0.05, -0.02, 0, 0, 0], (960, 540))
    assert not needs_views(cam) and not needs_views(None) and needs_views(FISHEYE)
    C = np.array([0.3, -0.1, 2.5])
    img, _ = render_tag(cam, C, _facing(C, 25.0), seed=5)
    a = detect_image(MarkerKind.TAG, img, _tag_marker(), cam)
    b = detect_tags(img, _tag_marker(), camera=cam)
    assert np.array_equal(a.detections["T"].corners, b.detections["T"].corners)
    assert "view" not in a.detections["T"].info


def test_edge_on_side_tag_at_the_rim_and_its_limit(monkeypatch):
    """A 20 cm tag on a robot's side, 1.2 m away, 85 degrees off the axis of the simulator's fisheye
    (1280x800, f = 261 px) and turned 60 degrees off facing it: 16 px across in the raw image (cells of
    2 px).  The views at quad decimation 2 miss it; ``params={"quad_decimate": 1.0}``, passed through to
    every view, finds it, corners within 0.3 px of the truth.  Turned 70 degrees its cells are under 1.5
    raw pixels: not decoded even in a view centred on it at twice the raw density (the raw image's
    resolution is the limit, bench/fisheye_edge_on_tags.py)."""
    from mutloc.detect.views import detection_to_raw, view_towards
    from mutloc.sim.body_scenes import FISHEYE_DIST, FISHEYE_FOCAL, FISHEYE_SIZE

    cam = FisheyeCamera([[FISHEYE_FOCAL, 0, 639.5], [0, FISHEYE_FOCAL, 399.5], [0, 0, 1]], FISHEYE_DIST,
                        FISHEYE_SIZE)
    monkeypatch.setattr(sys.modules[__name__], "TAG_SIZE", 0.20)
    C = 1.2 * _direction(85.0, 183.0)
    img, truth = render_tag(cam, C, _facing(C, 60.0), seed=2)
    assert np.linalg.norm(truth - np.roll(truth, 1, axis=0), axis=1).min() < 17.0
    assert "T" not in detect_image(MarkerKind.TAG, img, _tag_marker(), cam).detections
    res = detect_image(MarkerKind.TAG, img, _tag_marker(), cam, params={"quad_decimate": 1.0})
    err = np.linalg.norm(res.detections["T"].corners - truth, axis=1)
    print(f"85 deg off the axis, turned 60: worst corner {err.max():.3f} px")
    assert err.max() < 0.3
    img, truth = render_tag(cam, C, _facing(C, 70.0), seed=3)
    assert np.linalg.norm(truth - np.roll(truth, 1, axis=0), axis=1).min() / 8 < 1.5
    view = view_towards(cam, C, half_fov_deg=20.0, density=2.0)
    d = detect_tags(view.rectify(img), _tag_marker(), camera=view.camera,
                    params={"quad_decimate": 1.0}).detections.get("T")
    assert d is None or np.linalg.norm(detection_to_raw(d, view).corners - truth, axis=1).max() > 1.0
