"""The light tracker's stages, each against a known truth."""

import math
from collections import deque

import numpy as np
import pytest

from mutloc.core.rig import Marker
from mutloc.detect.blink import GlobalMotion
from mutloc.detect.blink.tracker import LightTracker
from mutloc.detect.blink.halo import SRGB_LUT
from mutloc.detect.blink.state import Track

FPS = 30.0


def _texture(shape=(200, 260), seed=0):
    rng = np.random.default_rng(seed)
    import cv2

    img = rng.uniform(0, 255, (shape[0] // 4, shape[1] // 4)).astype(np.float32)
    return cv2.resize(img, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)


@pytest.mark.parametrize("shift", [(3.0, -2.0), (-7.5, 4.25), (12.0, 0.5)])
def test_global_motion_recovers_a_known_shift(shift):
    import cv2

    base = _texture()
    M = np.float32([[1, 0, shift[0]], [0, 1, shift[1]]])
    moved = cv2.warpAffine(base, M, (base.shape[1], base.shape[0]), borderMode=cv2.BORDER_REFLECT)
    gm = GlobalMotion()
    gm.update(np.clip(base, 0, 255).astype(np.uint8))
    d = gm.update(np.clip(moved, 0, 255).astype(np.uint8))
    np.testing.assert_allclose(d, shift, atol=0.25)


def test_track_motion_model_predicts_constant_acceleration():
    tr = Track(id=0, pos=np.zeros(2), conf=1.0, born_frame=0, born_t=0.0, hist=deque(), events=deque(),
               samples=deque(), vel=np.array([10.0, -4.0]), acc=np.array([2.0, 0.0]),
               last_on_pos=np.array([100.0, 50.0]), last_on_t=1.0)
    off = np.array([7.0, 3.0])  # a stabilised model ignores the camera
    np.testing.assert_allclose(tr.predict(1.5, 1.0, off), [100 + 5 + 0.25, 50 - 2])
    np.testing.assert_allclose(tr.predict(9.0, 1.0, off), [100 + 10 + 1.0, 50 - 4])  # never far
    # An image-frame model predicts in the image, returned in stabilised coordinates.
    tr.stabilised, tr.last_on_offset = False, np.array([5.0, 0.0])
    tr.vel_img, tr.acc_img = tr.vel, tr.acc
    np.testing.assert_allclose(tr.predict(1.5, 1.0, off) + off, [105 + 5 + 0.25, 50 - 2])


@pytest.mark.parametrize("camera_follows", [False, True])
def test_motion_model_predicts_in_the_frame_where_the_light_moves_smoothly(camera_follows):
    """A light blinking (4 frames on, 4 off) at constant velocity while the
    camera shakes: over the scene (smooth in stabilised coordinates) or
    followed by the camera (smooth in the image).  After a few off periods
    the model predicts in the smooth frame, exactly."""
    rng = np.random.default_rng(3)
    tr = _tracker()
    offsets = np.cumsum(rng.normal(0.0, 3.0, (41, 2)), axis=0)  # cumulative camera shift, px
    smooth = lambda k: np.array([300.0, 200.0]) + np.array([2.0, -0.7]) * k  # noqa: E731
    track = Track(id=0, pos=np.zeros(2), conf=1.0, born_frame=0, born_t=0.0, hist=deque(), events=deque(),
                  samples=deque())
    for k in range(36):
        if k % 8 < 4:
            tr._offset = offsets[k]
            tr._commit(track, smooth(k) if camera_follows else smooth(k) + offsets[k], 0.0, k / FPS, k)
    assert track.stabilised is not camera_follows
    expect = smooth(40) if camera_follows else smooth(40) + offsets[40]
    np.testing.assert_allclose(track.predict(40 / FPS, 1.0, offsets[40]) + offsets[40], expect, atol=1e-6)


def _tracker(hz=(2.0, 3.0)):
    lights = {f"L{i}": Marker(f"L{i}", "q", np.array([0.1 * i, 0.0, 0.0]), blink_hz=h) for i, h in enumerate(hz)}
    return LightTracker(lights, FPS)


def test_identity_basis_is_orthonormal_and_zero_mean():
    tr = _tracker()
    times = np.arange(40) / FPS
    q = tr._basis(times)
    assert q.shape == (40, 2 * 3 * 2)
    for k in range(0, q.shape[1], 2):  # each probe frequency: an orthonormal cos/sin pair
        block = q[:, k:k + 2]
        np.testing.assert_allclose(block.T @ block, np.eye(2), atol=1e-9)
        # spans the zero-mean cos/sin at its frequency
        f = np.r_[tr.freqs, tr.freqs - tr._delta_hz, tr.freqs + tr._delta_hz][k // 2]
        x = np.cos(2 * np.pi * f * (times - times[-1]))
        x -= x.mean()
        np.testing.assert_allclose(block @ (block.T @ x), x, atol=1e-9)
    np.testing.assert_allclose(q.sum(axis=0), 0.0, atol=1e-9)


@pytest.mark.parametrize("uv", [(60.3, 40.7), (61.0, 39.25), (59.55, 41.5)])
def test_measurement_centroid_of_a_known_spot(uv):
    tr = _tracker()
    ys, xs = np.mgrid[0:80, 0:120]
    img = 200.0 * np.exp(-((xs - uv[0]) ** 2 + (ys - uv[1]) ** 2) / (2 * 1.5 ** 2))
    c, spread = tr._centroid(img.astype(np.float32), round(uv[0]), round(uv[1]), float(img.max()), 5)
    np.testing.assert_allclose(c, uv, atol=0.05)  # sampling bias of a 1.5 px spot, well below the noise
    assert 1.0 < spread < 3.0


def test_identity_by_blink_frequency():
    """Two lights at 2 and 3 Hz, same brightness and colour: told apart by their blink alone."""
    tr = _tracker()
    ys, xs = np.mgrid[0:120, 0:200]
    spots = {"L0": (50.2, 60.4), "L1": (140.6, 58.3)}
    res = None
    for k in range(60):
        img = np.full((120, 200), 40.0)
        for name, (u, v) in spots.items():
            hz = 2.0 if name == "L0" else 3.0
            if math.fmod(hz * k / FPS, 1.0) < 0.5:
                img += 200 * np.exp(-((xs - u) ** 2 + (ys - v) ** 2) / (2 * 1.5 ** 2))
        res = tr.update(np.clip(img + 0.5, 0, 255).astype(np.uint8), t=k / FPS)
    for name, uv in spots.items():
        assert name in res.detections
        assert np.linalg.norm(res.detections[name].uv - uv) < 0.5


def test_srgb_table_is_the_standard_curve():
    x = np.arange(256) / 255.0
    ref = np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)
    np.testing.assert_allclose(SRGB_LUT, ref, atol=1e-6)


def _clipped_disc(uv, radius, shape=(90, 120), n=8):
    """A saturated disc (255, area-sampled n x n per pixel) on a grey background."""
    ys, xs = np.mgrid[0:shape[0] * n, 0:shape[1] * n]
    inside = ((xs + 0.5) / n - 0.5 - uv[0]) ** 2 + ((ys + 0.5) / n - 0.5 - uv[1]) ** 2 <= radius ** 2
    cover = inside.reshape(shape[0], n, shape[1], n).mean(axis=(1, 3))
    return (60.0 + 195.0 * cover).round().astype(np.uint8)


@pytest.mark.parametrize("uv", [(60.3, 44.7), (58.85, 46.2)])
def test_plateau_circle_ignores_bleed_beside_a_clipped_light(uv):
    """Glow over a bright patch beside a light clips too: the plateau's
    centroid moves towards it by pixels, its outline's circle does not."""
    tr = _tracker()
    img = _clipped_disc(uv, 10.0)
    # The bleed: a clipped patch touching the disc's upper right.
    img[int(uv[1]) - 16:int(uv[1]) - 2, int(uv[0]) + 2:int(uv[0]) + 16] = 255
    ys, xs = np.nonzero(img >= 250)
    assert math.hypot(xs.mean() - uv[0], ys.mean() - uv[1]) > 2.0  # the bias exists
    centre, radius = tr._plateau_circle(img, np.array([xs.mean(), ys.mean()]), 25)
    np.testing.assert_allclose(centre, uv, atol=0.3)
    assert abs(radius - 10.0) < 0.6
    # Without the bleed, the same answer.
    centre, _ = tr._plateau_circle(_clipped_disc(uv, 10.0), np.array(uv), 25)
    np.testing.assert_allclose(centre, uv, atol=0.3)


def test_plateau_circle_refuses_what_is_no_disc():
    tr = _tracker()
    img = np.full((90, 120), 60, np.uint8)
    img[30:50, 20:100] = 255  # a clipped strip (a bright window, say)
    assert tr._plateau_circle(img, np.array([60.0, 40.0]), 25) is None
