"""Coloured-ball detector against an independent, exact sphere renderer.

The official renderer (``mutloc.sim.render``) is not used on purpose: these
tests need ground truth that owes nothing to the code under test or to the
project's own simulation.  ``render_scene`` below ray-traces spheres through a
pinhole ``K`` with 8x8 rays per pixel (pixel ``(0, 0)`` is the centre of the
top-left pixel, as in the SPEC), shades them with Lambert + ambient light in
linear radiance and encodes sRGB, so the true projection of each sphere centre
is simply ``K @ C / C_z``.
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass, field

import cv2
import numpy as np
import pytest

from mutloc.core.camera import Camera
from mutloc.core.rig import Marker
from mutloc.detect.balls import BallParams, detect_balls
from mutloc.errors import InputError


F = 800.0
W, H = 960, 540
K = np.array([[F, 0.0, (W - 1) / 2], [0.0, F, (H - 1) / 2], [0.0, 0.0, 1.0]])
CAM = Camera(K, size=(W, H))
RADIUS = 0.03
SS = 8  # rays per pixel along each axis

# Nominal sRGB colours (r, g, b) of the test balls; red exercises hue wrap-around.
COLOURS = {
    "red": (255, 0, 0),
    "green": (0, 255, 0),
    "blue": (0, 0, 255),
    "yellow": (255, 255, 0),
    "orange": (255, 128, 0),
    "magenta": (255, 0, 255),
}


# ---------------------------------------------------------------------------
# independent renderer
# ---------------------------------------------------------------------------


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, float)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb8(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.clip(np.round(s * 255.0), 0, 255).astype(np.uint8)


@dataclass
class Ball:
    centre: np.ndarray  # camera frame, metres
    rgb: tuple[int, int, int]  # nominal sRGB
    radius: float = RADIUS

    def truth_uv(self) -> np.ndarray:
        p = K @ self.centre
        return p[:2] / p[2]


@dataclass
class Scene:
    balls: list[Ball]
    light: np.ndarray = field(default_factory=lambda: np.array([-0.4, -0.6, -0.7]))
    ambient: float = 0.3
    exposure: float = 1.0
    # Colour of the light (linear RGB gains), e.g. warm tungsten.
    light_rgb: tuple[float, float, float] = (1.0, 1.0, 1.0)
    # Image-space polygons drawn in front of everything, as (vertices (n, 2), linear RGB).
    occluders: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    # Flat-coloured image-space blobs behind the balls: (signed-distance function, linear RGB).
    clutter: list[tuple[object, np.ndarray]] = field(default_factory=list)
    # OpenCV distortion coefficients of the camera (None: ideal pinhole).
    dist: np.ndarray | None = None

    def truth_uv(self, ball: Ball) -> np.ndarray:
        """The exact image of the ball's centre."""
        if self.dist is None:
            return ball.truth_uv()
        uv, _ = cv2.projectPoints(ball.centre.reshape(1, 1, 3), np.zeros(3), np.zeros(3), K, self.dist)
        return uv.reshape(2)


def background(u: np.ndarray, v: np.ndarray, params: dict) -> np.ndarray:
    """Linear-RGB textured background on the grid ``u`` (nu,) x ``v`` (nv,): (nv, nu, 3).

    A smooth function of continuous (u, v): sums of plane waves, evaluated
    separably (sin(a + b) = sin a cos b + cos a sin b) to keep it cheap.
    """

    def wave(amp, kx, ky, ph):
        a = kx * u
        b = ky * v + ph
        return amp * (np.cos(b)[:, None] * np.sin(a)[None, :] + np.sin(b)[:, None] * np.cos(a)[None, :])

    val = sum(wave(*w) for w in params["waves"])
    out = np.empty((len(v), len(u), 3))
    for c in range(3):
        out[..., c] = np.clip(params["base"][c] * (1.0 + val) + wave(*params["tint"][c]), 0.01, 1.0)
    return out


def bg_params(rng: np.random.Generator) -> dict:
    waves = []
    for _ in range(6):
        period = rng.uniform(14.0, 120.0)
        ang = rng.uniform(0, np.pi)
        k = 2 * np.pi / period
        waves.append((rng.uniform(0.05, 0.22), k * np.cos(ang), k * np.sin(ang), rng.uniform(0, 2 * np.pi)))
    tint = []
    for _ in range(3):
        period = rng.uniform(30.0, 200.0)
        ang = rng.uniform(0, np.pi)
        k = 2 * np.pi / period
        tint.append((rng.uniform(0.0, 0.04), k * np.cos(ang), k * np.sin(ang), rng.uniform(0, 2 * np.pi)))
    grey = rng.uniform(0.08, 0.35)
    return {"base": grey * (1.0 + rng.uniform(-0.15, 0.15, 3)), "waves": waves, "tint": tint}


def _shade_grid(scene: Scene, bgp: dict, u: np.ndarray, v: np.ndarray, objects: bool = True) -> np.ndarray:
    """Linear radiance at the continuous grid ``u`` (nu,) x ``v`` (nv,): (nv, nu, 3).

    ``objects=False`` gives the background alone (what lies outside every
    object's box).
    """
    col = background(u, v, bgp)
    if not objects:
        return col * scene.exposure * np.asarray(scene.light_rgb)
    us, vs = np.meshgrid(u, v)
    for sdf, rgb in scene.clutter:
        col[sdf(us, vs) < 0] = rgb
    # Rays through the pinhole: d = K^-1 [u, v, 1] (after undoing the lens
    # distortion, if any, to machine precision with OpenCV's iterative solver).
    if scene.dist is None:
        dx = (us - K[0, 2]) / K[0, 0]
        dy = (vs - K[1, 2]) / K[1, 1]
    else:
        dx, dy = _undistort(us, vs, scene.dist)
    depth = np.full(us.shape, np.inf)
    light = scene.light / np.linalg.norm(scene.light)
    for ball in scene.balls:
        C = ball.centre
        dd = dx * dx + dy * dy + 1.0
        dc = dx * C[0] + dy * C[1] + C[2]
        disc = dc * dc - dd * (C @ C - ball.radius**2)
        hit = disc >= 0
        t = np.where(hit, (dc - np.sqrt(np.maximum(disc, 0))) / dd, np.inf)
        hit &= t < depth
        if not np.any(hit):
            continue
        th = t[hit]
        P = np.stack([th * dx[hit], th * dy[hit], th], axis=-1)
        n = (P - C) / ball.radius
        lam = np.maximum(0.0, n @ light)
        albedo = 0.72 * srgb_to_linear(np.array(ball.rgb) / 255.0) + 0.04
        col[hit] = albedo * (scene.ambient + (1.0 - scene.ambient) * lam)[:, None]
        depth[hit] = th
    for verts, rgb in scene.occluders:
        col[_inside_polygon(verts, us, vs)] = rgb
    return col * scene.exposure * np.asarray(scene.light_rgb)


def _undistort(u: np.ndarray, v: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised coordinates whose OpenCV (k1, k2, p1, p2, k3) distortion lands on (u, v).

    Newton's method with the analytic Jacobian, to machine precision: the
    renderer must not share the detector's camera code.
    """
    k1, k2, p1, p2, k3 = (list(dist) + [0.0] * 5)[:5]
    xd = (u - K[0, 2]) / K[0, 0]
    yd = (v - K[1, 2]) / K[1, 1]
    x, y = xd.copy(), yd.copy()
    for _ in range(12):  # quadratic convergence: far more than enough
        r2 = x * x + y * y
        rad = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
        drad = k1 + 2 * k2 * r2 + 3 * k3 * r2**2  # d rad / d r2
        fx = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - xd
        fy = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - yd
        a = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
        b = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
        c = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
        d = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
        det = a * d - b * c
        x, y = x - (d * fx - b * fy) / det, y - (a * fy - c * fx) / det
    return x, y


def _inside_polygon(verts: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Convex polygon (counter-clockwise in (u, v)) membership."""
    inside = np.ones(u.shape, bool)
    n = len(verts)
    for i in range(n):
        a, b = verts[i], verts[(i + 1) % n]
        inside &= (b[0] - a[0]) * (v - a[1]) - (b[1] - a[1]) * (u - a[0]) >= 0
    return inside


def render_linear(scene: Scene, seed: int = 0) -> np.ndarray:
    """Exact supersampled render of ``scene``: linear RGB radiance (H, W, 3).

    The background is smooth, so it is evaluated once per pixel away from the
    balls; inside each ball's bounding box (and each clutter or occluder
    shape's) every pixel gets SS x SS rays and the average linear radiance,
    which is what an ideal sensor integrates.
    """
    rng = np.random.default_rng(seed)
    bgp = bg_params(rng)
    img = _shade_grid(scene, bgp, np.arange(W, dtype=float), np.arange(H, dtype=float), objects=False)
    # Regions to supersample: balls, clutter and occluders (their bounding boxes).
    boxes = []
    for ball in scene.balls:
        uv = scene.truth_uv(ball)
        # The image of the sphere is an ellipse stretched by up to ~25 % at
        # the corners of this frame.
        r = F * ball.radius / ball.centre[2] * 1.35 + 3
        boxes.append((uv[0] - r, uv[1] - r, uv[0] + r, uv[1] + r))
    for sdf, _ in scene.clutter:
        boxes.append(sdf.box)  # type: ignore[attr-defined]
    for verts, _ in scene.occluders:
        boxes.append((verts[:, 0].min() - 2, verts[:, 1].min() - 2, verts[:, 0].max() + 2, verts[:, 1].max() + 2))
    offs = (np.arange(SS) + 0.5) / SS - 0.5
    for u0, v0, u1, v1 in boxes:
        j0, j1 = max(0, int(np.floor(u0))), min(W, int(np.ceil(u1)) + 1)
        i0, i1 = max(0, int(np.floor(v0))), min(H, int(np.ceil(v1)) + 1)
        if j0 >= j1 or i0 >= i1:
            continue
        # Pixel (i, j) covers [j - 0.5, j + 0.5] x [i - 0.5, i + 0.5].
        uf = (np.arange(j0, j1)[:, None] + offs[None, :]).ravel()
        vf = (np.arange(i0, i1)[:, None] + offs[None, :]).ravel()
        col = _shade_grid(scene, bgp, uf, vf)
        img[i0:i1, j0:j1] = col.reshape(i1 - i0, SS, j1 - j0, SS, 3).mean(axis=(1, 3))
    return img


def encode(lin: np.ndarray, blur_sigma: float = 0.0) -> np.ndarray:
    """Linear RGB -> sRGB-encoded BGR uint8, after an optional optical blur."""
    if blur_sigma > 0:
        # Optical blur acts on linear radiance.
        lin = cv2.GaussianBlur(lin.astype(np.float32), (0, 0), blur_sigma)
    rgb8 = linear_to_srgb8(lin)
    return np.ascontiguousarray(rgb8[:, :, ::-1])


def render_scene(scene: Scene, seed: int = 0, blur_sigma: float = 0.0) -> np.ndarray:
    """``render_linear`` then ``encode``: a BGR uint8 image."""
    return encode(render_linear(scene, seed), blur_sigma)


def degrade(bgr: np.ndarray, rng: np.random.Generator, noise_sigma: float = 2.0, quality: int = 90) -> np.ndarray:
    """Sensor noise (8-bit units) then a JPEG round trip."""
    noisy = np.clip(bgr.astype(float) + rng.normal(0.0, noise_sigma, bgr.shape), 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", noisy, [cv2.IMWRITE_JPEG_QUALITY, quality])
    assert ok
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)


class Sdf:
    """An image-space shape for clutter: signed distance < 0 inside; ``box`` its bounds."""

    def __init__(self, fn, box):
        self.fn = fn
        self.box = box

    def __call__(self, u, v):
        return self.fn(u, v)


def rect_sdf(cu: float, cv_: float, half_w: float, half_h: float, ang: float) -> Sdf:
    c, s = np.cos(ang), np.sin(ang)

    def fn(u, v):
        x = (u - cu) * c + (v - cv_) * s
        y = -(u - cu) * s + (v - cv_) * c
        return np.maximum(np.abs(x) - half_w, np.abs(y) - half_h)

    r = np.hypot(half_w, half_h) + 2
    return Sdf(fn, (cu - r, cv_ - r, cu + r, cv_ + r))


def disc_sdf(cu: float, cv_: float, r: float) -> Sdf:
    return Sdf(lambda u, v: np.hypot(u - cu, v - cv_) - r, (cu - r - 2, cv_ - r - 2, cu + r + 2, cv_ + r + 2))


def random_ball(rng: np.random.Generator, rgb, margin_px: float = 40.0) -> Ball:
    """A ball at depth 1-3 m whose centre projects to a uniform random pixel
    at least ``margin_px`` inside the frame (so the whole ball is visible)."""
    z = rng.uniform(1.0, 3.0)
    u = rng.uniform(margin_px, W - 1 - margin_px)
    v = rng.uniform(margin_px, H - 1 - margin_px)
    return Ball(np.linalg.solve(K, [u, v, 1.0]) * z, rgb)


def random_light(rng: np.random.Generator) -> np.ndarray:
    """A light in front of the ball (from the camera's side), at a random angle."""
    l = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), -rng.uniform(0.3, 1.2)])
    return l / np.linalg.norm(l)


def marker(name: str, rgb, position=(0.0, 0.0, 0.0), robot: str = "q", **extra) -> Marker:
    return Marker(name=name, robot=robot, position=np.asarray(position, float), color=tuple(rgb), extra=extra)


def hue_shifted(rgb, deg: float) -> np.ndarray:
    """Linear RGB of ``rgb`` with its hue turned by ``deg`` (clutter of a similar hue)."""
    h, s_, v = colorsys.rgb_to_hsv(*(np.array(rgb) / 255.0))
    r, g, b = colorsys.hsv_to_rgb((h + deg / 360.0) % 1.0, s_, v)
    return 0.72 * srgb_to_linear(np.array([r, g, b])) * 0.8 + 0.04


def add_clutter(scene: Scene, rng: np.random.Generator) -> None:
    """A long bar of a similar hue and a small disc of the same colour nearby."""
    ball = scene.balls[0]
    uv = ball.truth_uv()
    r = F * ball.radius / ball.centre[2]
    for kind in ("bar", "disc"):
        for _ in range(100):
            ang = rng.uniform(0, 2 * np.pi)
            dist = rng.uniform(3.0, 5.0) * r + 10
            cu, cv_ = uv[0] + dist * np.cos(ang), uv[1] + dist * np.sin(ang)
            if 30 < cu < W - 30 and 30 < cv_ < H - 30:
                break
        if kind == "bar":
            sdf = rect_sdf(cu, cv_, 2.2 * r, 0.7 * r, rng.uniform(0, np.pi))
            scene.clutter.append((sdf, hue_shifted(ball.rgb, rng.choice([-6.0, 6.0]))))
        else:
            scene.clutter.append((disc_sdf(cu, cv_, max(2.0, 0.35 * r)), hue_shifted(ball.rgb, 0.0)))


def add_occluder(scene: Scene, rng: np.random.Generator, depth: float = 0.45) -> None:
    """A grey box whose edge cuts the ball at ``depth`` radii from its centre (covers ~25 %)."""
    ball = scene.balls[0]
    uv = ball.truth_uv()
    r = F * ball.radius / ball.centre[2]
    ang = rng.uniform(0, 2 * np.pi)
    n = np.array([np.cos(ang), np.sin(ang)])  # towards the box
    t = np.array([-n[1], n[0]])
    p0 = uv + depth * r * n
    # Just big enough to cover the cut-off cap (its far edges stay off the
    # ball), since every pixel of the box is supersampled.
    a, b = r + 4, (1.0 - depth) * r + 5
    verts = np.array([p0 - a * t, p0 + a * t, p0 + a * t + b * n, p0 - a * t + b * n])
    # Counter-clockwise in (u, v) for _inside_polygon.
    e1, e2 = verts[1] - verts[0], verts[2] - verts[1]
    if e1[0] * e2[1] - e1[1] * e2[0] < 0:
        verts = verts[::-1]
    grey = rng.uniform(0.1, 0.5)
    scene.occluders.append((verts, np.array([grey, grey * 0.95, grey * 1.05])))


def detect_one(img: np.ndarray, cname: str, camera: Camera | None = CAM, **kw):
    rgb = COLOURS[cname]
    return detect_balls(img, {cname: marker(cname, rgb)}, camera=camera, params=BallParams(**kw)).detections.get(cname)


def errors_px(cases, make_image, camera: Camera | None = CAM) -> np.ndarray:
    """Detection error of each case (inf where the ball was not found)."""
    out = []
    for cname, scene, lin in cases:
        d = detect_one(make_image(lin), cname, camera)
        out.append(np.inf if d is None else float(np.linalg.norm(d.uv - scene.truth_uv(scene.balls[0]))))
    return np.array(out)


# ---------------------------------------------------------------------------
# accuracy against ground truth
# ---------------------------------------------------------------------------


N_PLACEMENTS = 50


@pytest.fixture(scope="module")
def placements():
    """Random single-ball scenes at 1-3 m (0.03 m radius, f = 800 px, 960x540), rendered once."""
    rng = np.random.default_rng(2024)
    names = list(COLOURS)
    out = []
    for i in range(N_PLACEMENTS):
        cname = names[i % len(names)]
        scene = Scene([random_ball(rng, COLOURS[cname])], light=random_light(rng), ambient=rng.uniform(0.2, 0.45))
        out.append((cname, scene, render_linear(scene, seed=i)))
    return out


def test_renderer_is_self_consistent():
    """The test renderer's own ground truth: distortion inversion and sphere outline."""
    rng = np.random.default_rng(0)
    u, v = rng.uniform(0, W, 500), rng.uniform(0, H, 500)
    dist = np.array([-0.15, 0.05, 0.001, -0.002, 0.0])
    x, y = _undistort(u, v, dist)
    rays = np.stack([x, y, np.ones_like(x)], -1).reshape(-1, 1, 3)
    uv, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, dist)
    assert np.abs(uv.reshape(-1, 2) - np.stack([u, v], -1)).max() < 1e-9
    # A ball on the optical axis is a disc of radius f R / sqrt(Z^2 - R^2):
    # unmixing every pixel between the background and the (unshaded) ball
    # colour must give its area.
    ball = Ball(np.array([0.0, 0.0, 1.0]), (255, 0, 0))
    lin = render_linear(Scene([ball], ambient=1.0))
    bg = render_linear(Scene([]))
    albedo = 0.72 * srgb_to_linear(np.array(ball.rgb) / 255.0) + 0.04
    diff = albedo - bg
    alpha = ((lin - bg) * diff).sum(-1) / (diff * diff).sum(-1)
    r_true = F * RADIUS / np.sqrt(1.0 - RADIUS**2)
    assert abs(alpha.sum() - np.pi * r_true**2) < 1e-3 * np.pi * r_true**2


def test_clean_renders_median_error(placements):
    err = errors_px(placements, encode)
    print(f"\nclean: median {np.median(err):.3f} px, 90% {np.percentile(err, 90):.3f} px, max {err.max():.3f} px")
    assert np.all(np.isfinite(err)), "a ball was not found"
    assert np.median(err) <= 0.2
    assert err.max() < 1.0


def test_noisy_blurred_jpeg_median_error(placements):
    rng = np.random.default_rng(7)
    err = errors_px(placements, lambda lin: degrade(encode(lin, blur_sigma=0.7), rng, noise_sigma=2.0, quality=90))
    print(f"\nnoise+blur+JPEG: median {np.median(err):.3f} px, 90% {np.percentile(err, 90):.3f} px, "
          f"max {err.max():.3f} px")
    assert np.all(np.isfinite(err)), "a ball was not found"
    assert np.median(err) <= 0.3
    assert err.max() < 1.5


@pytest.mark.parametrize(
    "gain", [(0.25, 0.25, 0.25), (1.0, 0.85, 0.7), (0.75, 0.85, 1.0)], ids=["dim", "warm", "cool"]
)
def test_lighting_changes(placements, gain):
    """Dim light (a quarter of the exposure) and tinted light: same accuracy.

    (Light tinted much more strongly turns hues beyond ``hue_tol_deg``.)
    """
    cases = placements[:24]
    err = errors_px(cases, lambda lin: encode(lin * np.asarray(gain)))
    print(f"\nlight {gain}: median {np.median(err):.3f} px, max {err.max():.3f} px")
    assert np.all(np.isfinite(err)), "a ball was not found"
    assert np.median(err) <= 0.2


def test_without_camera_reports_ellipse_centre(placements):
    """No K: the ellipse centre, close to the truth except for the perspective bias."""
    err = errors_px(placements[:24], encode, camera=None)
    assert np.all(np.isfinite(err))
    assert np.median(err) <= 0.3


def test_perspective_bias_is_corrected():
    """Near a corner at 1 m the ellipse centre is ~0.6 px off the sphere centre's image."""
    C = np.linalg.solve(K, [60.0, 60.0, 1.0])
    ball = Ball(C / np.linalg.norm(C), (0, 255, 0))
    scene = Scene([ball], light=np.array([0.3, 0.2, -1.0]))
    img = render_scene(scene, seed=3)
    truth = ball.truth_uv()
    with_k = detect_one(img, "green")
    without_k = detect_one(img, "green", camera=None)
    assert with_k is not None and without_k is not None
    bias = np.linalg.norm(without_k.uv - truth)
    print(f"\nperspective bias {bias:.3f} px, corrected error {np.linalg.norm(with_k.uv - truth):.3f} px")
    assert bias > 0.4
    assert np.linalg.norm(with_k.uv - truth) < 0.15
    # The reported outline is the ellipse, whose centre is the uncorrected one.
    assert np.linalg.norm(np.array(with_k.info["ellipse"]["centre"]) - without_k.uv) < 0.2
    assert abs(with_k.info["distance_m"] - 1.0) < 0.02


def test_lens_distortion():
    rng = np.random.default_rng(11)
    dist = np.array([-0.15, 0.05, 0.0, 0.0, 0.0])
    cam = Camera(K, dist, (W, H))
    names = list(COLOURS)
    err = []
    for i in range(10):
        cname = names[i % len(names)]
        scene = Scene([random_ball(rng, COLOURS[cname], margin_px=60)], light=random_light(rng), dist=dist)
        d = detect_one(render_scene(scene, seed=100 + i), cname, camera=cam)
        assert d is not None
        err.append(np.linalg.norm(d.uv - scene.truth_uv(scene.balls[0])))
    assert np.median(err) <= 0.2


# ---------------------------------------------------------------------------
# robustness
# ---------------------------------------------------------------------------


def test_clutter_of_similar_hue():
    """A long bar turned 6 deg in hue and a small disc of the very same colour nearby."""
    rng = np.random.default_rng(12)
    names = list(COLOURS)
    err = []
    for i in range(24):
        cname = names[i % len(names)]
        scene = Scene([random_ball(rng, COLOURS[cname], margin_px=60)], light=random_light(rng))
        add_clutter(scene, rng)
        d = detect_one(render_scene(scene, seed=200 + i), cname)
        assert d is not None
        err.append(np.linalg.norm(d.uv - scene.truth_uv(scene.balls[0])))
        assert 0.0 < d.score <= 1.0
    err = np.array(err)
    print(f"\nclutter: median {np.median(err):.3f} px, max {err.max():.3f} px")
    assert err.max() < 1.0, "picked the clutter"
    assert np.median(err) <= 0.2


def test_partial_occlusion():
    """A box hides the ball up to 0.45 radii from its centre (about a quarter)."""
    rng = np.random.default_rng(13)
    names = list(COLOURS)
    err, rim = [], []
    for i in range(24):
        cname = names[i % len(names)]
        scene = Scene([random_ball(rng, COLOURS[cname], margin_px=60)], light=random_light(rng))
        add_occluder(scene, rng)
        d = detect_one(render_scene(scene, seed=300 + i), cname)
        assert d is not None
        err.append(np.linalg.norm(d.uv - scene.truth_uv(scene.balls[0])))
        rim.append(d.info["rim_fraction"])
    err = np.array(err)
    print(f"\nocclusion: median {np.median(err):.3f} px, max {err.max():.3f} px, rim {np.median(rim):.2f}")
    assert err.max() < 1.0
    assert np.median(err) <= 0.25
    # The hidden part of the rim is not counted as fitting.
    assert 0.5 < np.median(rim) < 0.9


def test_linear_images(placements):
    """Raw (linear, not sRGB-encoded) images: ``srgb=False``."""
    err = []
    for cname, scene, lin in placements[:12]:
        img = np.clip(np.round(lin * 255.0), 0, 255).astype(np.uint8)[:, :, ::-1]
        d = detect_one(np.ascontiguousarray(img), cname, srgb=False)
        assert d is not None
        err.append(np.linalg.norm(d.uv - scene.truth_uv(scene.balls[0])))
    assert np.median(err) <= 0.2


def test_implausible_size_is_rejected(placements):
    """With a camera, a blob whose size puts the ball outside ``distance_range_m`` is not it."""
    cname, scene, lin = placements[0]
    img = encode(lin)
    assert detect_one(img, cname) is not None
    res = detect_balls(img, {cname: marker(cname, COLOURS[cname])}, camera=CAM, params=BallParams(distance_range_m=(5.0, 50.0)))
    assert res.missing == [cname]
    # The marker's own radius (Marker.extra) sets the distance scale.
    big = detect_balls(img, {cname: marker(cname, COLOURS[cname], radius=0.3)}, camera=CAM)
    # (distance_m is to the ball's centre, not its depth)
    distance = np.linalg.norm(scene.balls[0].centre)
    assert abs(big.detections[cname].info["distance_m"] / distance - 10.0) < 0.1


def test_ball_cut_by_image_border():
    C = np.linalg.solve(K, [8.0, 300.0, 1.0]) * 1.2
    ball = Ball(C, (0, 0, 255))
    scene = Scene([ball], light=np.array([-0.5, 0.0, -1.0]))
    d = detect_one(render_scene(scene, seed=5), "blue")
    assert d is not None
    assert np.linalg.norm(d.uv - ball.truth_uv()) < 0.5


def test_hue_wrap_around():
    """A red whose hue is just below 360 deg, and pure red, are both found."""
    rng = np.random.default_rng(14)
    for rgb in [(255, 0, 40), (255, 0, 0), (255, 30, 0)]:
        ball = random_ball(rng, rgb)
        img = render_scene(Scene([ball], light=random_light(rng)), seed=7)
        res = detect_balls(img, {"M": marker("M", rgb)}, camera=CAM)
        assert "M" in res.detections, rgb
        assert np.linalg.norm(res.detections["M"].uv - ball.truth_uv()) < 0.3


def four_ball_frame(rng: np.random.Generator):
    """Four balls of one robot in one noisy frame, and their markers.

    The markers' positions are the balls' centres in the camera frame (the
    robot's frame taken as the camera's), so the rig check applies.
    """
    names = ["red", "green", "blue", "yellow"]
    balls = []
    for i, cname in enumerate(names):
        uv = [150.0 + 210 * i, 200.0 + 120 * (i % 2), 1.0]
        balls.append(Ball(np.linalg.solve(K, uv) * rng.uniform(1.0, 3.0), COLOURS[cname]))
    scene = Scene(balls, light=random_light(rng))
    img = degrade(encode(render_linear(scene, seed=9), blur_sigma=0.7), rng)
    markers = {n: marker(n, COLOURS[n], position=b.centre) for n, b in zip(names, balls)}
    return names, balls, img, markers


def test_several_markers_missing_and_uncoloured():
    rng = np.random.default_rng(15)
    names, balls, img, markers = four_ball_frame(rng)
    markers["absent"] = marker("absent", COLOURS["magenta"], position=[0.5, 0.0, 2.0])
    markers["tag"] = Marker(name="tag", robot="q", position=np.zeros(3), tag={"family": "tag36h11", "id": 3})
    res = detect_balls(img, markers, camera=CAM)
    assert res.missing == ["absent"]
    assert sorted(res.detections) == sorted(names)
    for n, b in zip(names, balls):
        assert np.linalg.norm(res.detections[n].uv - b.truth_uv()) < 0.5
    assert set(res.pixels()) == set(names)
    res.to_dict()  # JSON-ready


def test_empty_and_degenerate_images_do_not_raise():
    markers = {n: marker(n, COLOURS[n]) for n in COLOURS}
    rng = np.random.default_rng(16)
    images = [
        np.zeros((H, W, 3), np.uint8),
        np.full((H, W, 3), 255, np.uint8),
        np.full((H, W, 3), 128, np.uint8),
        np.zeros((2, 2, 3), np.uint8),
        np.zeros((H, W), np.uint8),
        np.zeros((H, W, 4), np.uint8),
        np.zeros((H, W, 3), np.float32),
    ]
    for img in images:
        res = detect_balls(img, markers, camera=CAM)
        assert res.detections == {}
        assert res.missing == list(COLOURS)
    # Pure colour noise: whatever it finds, it must not fail.
    noise = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    res = detect_balls(noise, markers, camera=CAM)
    assert set(res.missing) | set(res.detections) == set(COLOURS)
    # No coloured marker at all: nothing to report.
    assert detect_balls(noise, {}).missing == []


@pytest.mark.parametrize("rgb", [(255, 255, 255), (128, 128, 128), (0, 0, 0), (200, 190, 185)])
def test_achromatic_colour_is_a_clear_error(rgb):
    with pytest.raises(InputError, match="'W1'.*saturated"):
        detect_balls(np.zeros((H, W, 3), np.uint8), {"W1": marker("W1", rgb)})


def test_bad_arguments():
    img = np.zeros((H, W, 3), np.uint8)
    mk = {"M": marker("M", (255, 0, 0))}
    with pytest.raises(InputError):
        detect_balls("not an image", mk)
    with pytest.raises(InputError):
        detect_balls(img, mk, camera=K)  # a matrix is not a Camera
    with pytest.raises(InputError):
        detect_balls(img, mk, params=BallParams(hue_tol_deg=-1))
    with pytest.raises(InputError):
        detect_balls(img, mk, params=BallParams(downscale=0))
    with pytest.raises(InputError):
        detect_balls(img, [marker("M", (255, 0, 0))])


def test_rig_geometry_picks_the_right_one_of_two_same_coloured_balls():
    """A stray green ball, nearer (so bigger), and the robot's green ball 0.3 m from its red one.

    Alone, the bigger ball wins; told where the balls sit on the robot (and
    given the camera), the detector takes the green ball at the right
    distance from the red one.
    """
    red = Ball(np.linalg.solve(K, [400.0, 300.0, 1.0]) * 2.0, COLOURS["red"])
    green = Ball(red.centre + [0.3, 0.0, 0.0], COLOURS["green"])
    stray = Ball(np.linalg.solve(K, [800.0, 120.0, 1.0]) * 1.2, COLOURS["green"])
    scene = Scene([red, green, stray], light=np.array([-0.3, -0.4, -1.0]))
    img = render_scene(scene, seed=21)
    unrelated = {"R": marker("R", COLOURS["red"], robot="a"), "G": marker("G", COLOURS["green"], robot="b")}
    res = detect_balls(img, unrelated, camera=CAM)
    assert np.linalg.norm(res.detections["G"].uv - stray.truth_uv()) < 0.5
    rig = {"R": marker("R", COLOURS["red"], position=[-0.15, 0, 0]),
           "G": marker("G", COLOURS["green"], position=[0.15, 0, 0])}
    res = detect_balls(img, rig, camera=CAM)
    assert np.linalg.norm(res.detections["G"].uv - green.truth_uv()) < 0.3
    assert np.linalg.norm(res.detections["R"].uv - red.truth_uv()) < 0.3


def test_flat_disc_loses_to_a_shaded_ball():
    """A printed disc of the ball's colour, bigger than the ball: the shading tells them apart."""
    ball = Ball(np.linalg.solve(K, [300.0, 250.0, 1.0]) * 2.0, COLOURS["blue"])
    scene = Scene([ball], light=np.array([-0.5, -0.5, -0.8]))
    disc_rgb = 0.72 * srgb_to_linear(np.array(COLOURS["blue"]) / 255.0) * 0.8 + 0.04
    scene.clutter.append((disc_sdf(650.0, 300.0, 20.0), disc_rgb))
    d = detect_one(render_scene(scene, seed=22), "blue")
    assert d is not None and np.linalg.norm(d.uv - ball.truth_uv()) < 0.3
    assert d.info["shading"] > 0.12
