"""Blinking-light tracker against synthetic video with exact ground truth.

The sequences are drawn here, with NumPy/OpenCV only (not with the project's
renderer): a textured static background seen through a shaking camera (a
global sub-pixel translation), robots (dark bodies) moving along smooth paths
with two Gaussian-profile lights each, a static bright lamp, a lamp flickering
at 7 Hz and Gaussian sensor noise.  Lights are integrated over the exposure, so
frames in which a light switches show it partly lit.  Pixel ``(0, 0)`` is the
centre of the top-left pixel (SPEC): a light at ``(u, v)`` has its peak at
column ``u``, row ``v``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mutloc.core.rig import Marker
from mutloc.detect.blink import BlinkParams, BlinkTracker, GlobalMotion
from mutloc.errors import InputError

W, H, FPS = 960, 540, 30.0
EXPOSURE_S = 1.0 / 60.0
NOISE_SIGMA = 3.0


# ---------------------------------------------------------------------------
# synthetic scene
# ---------------------------------------------------------------------------


@dataclass
class Light:
    """A Gaussian light; ``hz == 0`` means always on."""

    name: str
    path: Callable[[float], np.ndarray]  # t -> (u, v) before camera shake
    hz: float = 0.0
    phase: float = 0.0  # fraction of a period
    amp: float = 230.0
    sigma: float = 1.6
    bgr: tuple[float, float, float] = (1.0, 1.0, 1.0)
    until: float = math.inf  # removed (switched off for good) from this time

    def on_fraction(self, t: float) -> float:
        """Fraction of the exposure [t, t + EXPOSURE_S] during which the light is on."""
        if t >= self.until:
            return 0.0
        if self.hz == 0:
            return 1.0
        ts = t + (np.arange(32) + 0.5) / 32 * EXPOSURE_S
        return float(np.mean(np.mod(self.hz * ts + self.phase, 1.0) < 0.5))


@dataclass
class Robot:
    centre: Callable[[float], np.ndarray]
    half_size: tuple[float, float] = (60.0, 30.0)
    angle: Callable[[float], float] = lambda t: 0.0
    lights: dict[str, tuple[np.ndarray, float, float, tuple[float, float, float], float]] = field(
        default_factory=dict)  # name -> (offset in body frame, hz, phase, bgr, until)

    def point(self, offset: np.ndarray, t: float) -> np.ndarray:
        a = self.angle(t)
        rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        return self.centre(t) + rot @ offset

    def polygon(self, t: float) -> np.ndarray:
        hx, hy = self.half_size
        corners = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
        return np.array([self.point(c, t) for c in corners])


def make_background(rng: np.random.Generator, margin: int) -> np.ndarray:
    """Textured float32 BGR background, larger than the frame by ``margin`` all round."""
    h, w = H + 2 * margin, W + 2 * margin
    bg = np.zeros((h, w), np.float32)
    for scale, weight in ((64, 40.0), (16, 25.0), (4, 12.0)):
        small = rng.normal(size=(h // scale + 2, w // scale + 2)).astype(np.float32)
        bg += weight * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)[:h, :w]
    bg += 95.0
    img = np.repeat(bg[:, :, None], 3, axis=2)
    img *= np.array([0.9, 1.0, 1.1], np.float32)  # a little colour
    # High-contrast edges: what camera shake turns into differential.
    for _ in range(40):
        x, y = int(rng.integers(0, w - 80)), int(rng.integers(0, h - 60))
        c = float(rng.uniform(20, 200))
        cv2.rectangle(img, (x, y), (x + int(rng.integers(10, 80)), y + int(rng.integers(5, 60))),
                      (c, c, c), -1)
    return np.clip(img, 0, 200)


def shake(t: float) -> np.ndarray:
    """Camera shake: a smooth global translation of up to ~2 px."""
    return np.array([1.1 * math.sin(2 * math.pi * 1.3 * t) + 0.6 * math.sin(2 * math.pi * 3.1 * t + 0.5),
                     0.9 * math.sin(2 * math.pi * 1.7 * t + 1.0) + 0.5 * math.sin(2 * math.pi * 2.9 * t)])


def draw_spot(img: np.ndarray, uv: np.ndarray, amp: float, sigma: float,
              bgr: tuple[float, float, float]) -> None:
    """Add a Gaussian spot centred at sub-pixel (u, v) (pixel centres at integers)."""
    r = math.ceil(4 * sigma)
    cx, cy = round(uv[0]), round(uv[1])
    x0, x1, y0, y1 = max(cx - r, 0), min(cx + r + 1, W), max(cy - r, 0), min(cy + r + 1, H)
    if x0 >= x1 or y0 >= y1:
        return
    xs = np.arange(x0, x1) - uv[0]
    ys = np.arange(y0, y1) - uv[1]
    g = np.exp(-(ys[:, None] ** 2 + xs[None, :] ** 2) / (2 * sigma**2)).astype(np.float32) * amp
    img[y0:y1, x0:x1] += g[:, :, None] * np.asarray(bgr, np.float32)


@dataclass
class Scene:
    robots: list[Robot]
    lights: list[Light]  # scene lights not on a robot (clutter)
    seed: int = 0
    camera: Callable[[float], np.ndarray] = shake  # global image translation at time t
    margin: int = 16  # background border the camera motion never exposes

    def __post_init__(self) -> None:
        rng = np.random.default_rng(self.seed)
        self.background = make_background(rng, self.margin)
        self.noise = [rng.normal(0, NOISE_SIGMA, (H, W, 3)).astype(np.float32) for _ in range(5)]

    def all_lights(self) -> list[Light]:
        out = list(self.lights)
        for rb in self.robots:
            for name, (off, hz, phase, bgr, until) in rb.lights.items():
                out.append(Light(name, (lambda t, rb=rb, off=off: rb.point(off, t)), hz, phase,
                                 bgr=bgr, until=until))
        return out

    def frame(self, k: int) -> tuple[np.ndarray, dict[str, tuple[np.ndarray, float]]]:
        """Frame k and, per light, its true image position and on-fraction."""
        t = k / FPS
        s = self.camera(t)
        m = np.array([[1.0, 0.0, self.margin - s[0]], [0.0, 1.0, self.margin - s[1]]])
        img = cv2.warpAffine(self.background, m, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
        for rb in self.robots:
            poly = rb.polygon(t) + s
            cv2.fillPoly(img, [np.round(poly * 16).astype(np.int32)], (55.0, 50.0, 60.0),
                         lineType=cv2.LINE_AA, shift=4)
        truth = {}
        for light in self.all_lights():
            uv = light.path(t) + s
            frac = light.on_fraction(t)
            truth[light.name] = (uv, frac)
            if frac > 0:
                draw_spot(img, uv, light.amp * frac, light.sigma, light.bgr)
        img += self.noise[k % len(self.noise)]
        return np.clip(img + 0.5, 0, 255).astype(np.uint8), truth


def marker(name: str, hz: float | None, robot: str = "q") -> Marker:
    return Marker(name, robot, np.array([0.1, 0.0, 0.0]), blink_hz=hz)


def main_scene() -> Scene:
    """Robot q (2 and 3 Hz), robot r (4 and 5 Hz; the 5 Hz light dies at 5 s)."""
    q = Robot(centre=lambda t: np.array([330 + 140 * math.sin(2 * math.pi * 0.15 * t),
                                         250 + 70 * math.sin(2 * math.pi * 0.23 * t + 1.0)]),
              angle=lambda t: 0.15 * math.sin(2 * math.pi * 0.2 * t),
              lights={"M1": (np.array([-45.0, -12.0]), 2.0, 0.10, (0.4, 0.5, 1.0), math.inf),
                      "M2": (np.array([45.0, -12.0]), 3.0, 0.37, (0.5, 1.0, 0.5), math.inf)})
    r = Robot(centre=lambda t: np.array([650 - 110 * math.sin(2 * math.pi * 0.12 * t + 0.3),
                                         330 + 60 * math.cos(2 * math.pi * 0.19 * t)]),
              half_size=(50.0, 25.0),
              lights={"M5": (np.array([-35.0, -8.0]), 4.0, 0.62, (1.0, 1.0, 1.0), math.inf),
                      "M6": (np.array([35.0, -8.0]), 5.0, 0.81, (1.0, 0.6, 0.3), 5.0)})
    clutter = [
        Light("lamp", lambda t: np.array([820.3, 90.7]), amp=255.0, sigma=4.0),
        Light("flicker7", lambda t: np.array([120.6, 470.2]), hz=7.0, phase=0.2, amp=220.0, sigma=2.0),
    ]
    return Scene([q, r], clutter, seed=3)


def pan_scene() -> Scene:
    """The observing robot turns back and forth: the whole image sweeps by up
    to ~6 px per frame (plus shake) while robot q stands still and robot r
    drives slowly."""
    q = Robot(centre=lambda t: np.array([300.4, 240.7]),
              lights={"M1": (np.array([-40.0, -10.0]), 2.0, 0.55, (0.4, 0.5, 1.0), math.inf),
                      "M2": (np.array([40.0, -10.0]), 3.0, 0.05, (0.5, 1.0, 0.5), math.inf)})
    r = Robot(centre=lambda t: np.array([600 + 30 * t, 350 - 10 * t]), half_size=(50.0, 25.0),
              lights={"M5": (np.array([-35.0, -8.0]), 4.0, 0.3, (1.0, 1.0, 1.0), math.inf),
                      "M6": (np.array([35.0, -8.0]), 5.0, 0.9, (1.0, 0.6, 0.3), math.inf)})
    clutter = [
        Light("lamp", lambda t: np.array([820.3, 90.7]), amp=255.0, sigma=4.0),
        Light("flicker7", lambda t: np.array([120.6, 470.2]), hz=7.0, phase=0.6, amp=220.0, sigma=2.0),
    ]
    return Scene([q, r], clutter, seed=5, margin=80,
                 camera=lambda t: shake(t) + np.array([60 * math.sin(2 * math.pi * 0.5 * t),
                                                       20 * math.sin(2 * math.pi * 0.35 * t)]))


# ---------------------------------------------------------------------------
# the main sequence, run once
# ---------------------------------------------------------------------------

N_FRAMES = 240  # 8 s
M6_GONE_S = 5.0
MARKERS_ALL = {m.name: m for m in (marker("M1", 2.0), marker("M2", 3.0), marker("M5", 4.0, "r"),
                                   marker("M6", 5.0, "r"), marker("M8", 8.0, "r"))}
MARKERS_Q = {m.name: m for m in (marker("M1", 2.0), marker("M2", 3.0), marker("tagged", None))}


@dataclass
class Run:
    truth: list[dict[str, tuple[np.ndarray, float]]]
    results_all: list
    results_q: list
    seconds: float  # time spent in BlinkTracker.update (the all-markers tracker)


@pytest.fixture(scope="module")
def run() -> Run:
    scene = main_scene()
    tr_all = BlinkTracker(MARKERS_ALL, FPS)
    tr_q = BlinkTracker(MARKERS_Q, FPS)
    truth, res_all, res_q = [], [], []
    spent = 0.0
    for k in range(N_FRAMES):
        img, gt = scene.frame(k)
        t0 = time.perf_counter()
        res_all.append(tr_all.update(img))
        spent += time.perf_counter() - t0
        res_q.append(tr_q.update(img))
        truth.append(gt)
    return Run(truth, res_all, res_q, spent)


def identity_rates(truth: list, results: list, names: list[str], present: dict[str, float] | None = None,
                   tol_px: float = 5.0) -> dict[str, float]:
    """Per marker, the fraction of frames after the first second (while its
    light is there: up to ``present[name]`` seconds) in which it is reported at
    its own light: within ``tol_px`` and closer to it than to any other light."""
    present = present or {}
    rates = {}
    for name in names:
        frames = [k for k in range(int(FPS), len(truth)) if k / FPS < present.get(name, math.inf)]
        good = 0
        for k in frames:
            det = results[k].detections.get(name)
            if det is not None:
                d = {other: float(np.linalg.norm(det.uv - uv)) for other, (uv, _) in truth[k].items()}
                good += d[name] <= tol_px and min(d, key=d.get) == name
        rates[name] = good / len(frames)
    return rates


def test_identity_after_first_second(run: Run) -> None:
    rates = identity_rates(run.truth, run.results_all, ["M1", "M2", "M5", "M6"], {"M6": M6_GONE_S})
    print("identity rates (all markers):", rates)
    assert all(r >= 0.99 for r in rates.values()), rates
    # Robot r's lights (4 and 5 Hz) are foreign to this tracker.
    rates_q = identity_rates(run.truth, run.results_q, ["M1", "M2"])
    print("identity rates (robot q only):", rates_q)
    assert all(r >= 0.99 for r in rates_q.values()), rates_q


def test_clutter_never_labelled(run: Run) -> None:
    """Neither the static lamp, the 7 Hz flicker nor (for the q-only tracker)
    robot r's lights at 4 and 5 Hz is ever reported as a marker."""
    for results, foreign in ((run.results_all, ["lamp", "flicker7"]),
                             (run.results_q, ["lamp", "flicker7", "M5", "M6"])):
        for k, res in enumerate(results):
            for name, det in res.detections.items():
                for f in foreign:
                    uv, _ = run.truth[k][f]
                    assert np.linalg.norm(det.uv - uv) > 15.0, (k, name, f)


def test_position_error_when_on(run: Run) -> None:
    """Sub-pixel centres in frames where the light is fully on (the centroid
    of this frame); off frames report the last centroid predicted forward."""
    errs: dict[str, list[float]] = {}
    off_errs: list[float] = []
    for k in range(N_FRAMES):
        for name, det in run.results_all[k].detections.items():
            uv, frac = run.truth[k][name]
            e = float(np.linalg.norm(det.uv - uv))
            if frac == 1.0:
                errs.setdefault(name, []).append(e)
                assert det.info["on"]
            elif frac == 0.0:
                off_errs.append(e)
    medians = {n: float(np.median(e)) for n, e in errs.items()}
    overall = float(np.median(np.concatenate([np.array(e) for e in errs.values()])))
    print("median position error when on (px):", medians, f"overall {overall:.3f}")
    print(f"predicted position error when off (px): median {np.median(off_errs):.2f}, "
          f"95% {np.percentile(off_errs, 95):.2f}, max {np.max(off_errs):.2f}")
    assert set(medians) == {"M1", "M2", "M5", "M6"}
    assert all(m <= 0.3 for m in medians.values()), medians
    assert overall <= 0.3
    assert np.percentile(off_errs, 95) <= 3.0


def test_missing_markers(run: Run) -> None:
    # Never present: always missing.
    assert all("M8" in res.missing and "M8" not in res.detections for res in run.results_all)
    # Removed at 5 s: missing within a second, and from then on.
    gone = math.ceil((M6_GONE_S + 1.0) * FPS)
    assert all("M6" in res.missing for res in run.results_all[gone:])
    # While there, reported (identity test) and not missing, after the first second.
    present = [res for res in run.results_all[int(FPS):int(M6_GONE_S * FPS)]]
    assert np.mean(["M6" in res.missing for res in present]) <= 0.01
    # The first frame has no differential yet: everything missing.
    assert sorted(run.results_all[0].missing) == sorted(MARKERS_ALL)
    # Markers without blink_hz are not the tracker's business.
    assert all("tagged" not in res.missing for res in run.results_q)
    # Every result accounts for every blinking marker exactly once.
    for res in run.results_all:
        assert sorted(list(res.detections) + res.missing) == sorted(MARKERS_ALL)


@pytest.fixture(scope="module")
def pan_run() -> Run:
    scene = pan_scene()
    tracker = BlinkTracker(MARKERS_ALL, FPS)
    truth, results = [], []
    spent = 0.0
    for k in range(N_PAN):
        img, gt = scene.frame(k)
        t0 = time.perf_counter()
        results.append(tracker.update(img))
        spent += time.perf_counter() - t0
        truth.append(gt)
    return Run(truth, results, [], spent)


N_PAN = 150  # 5 s


def test_camera_panning(pan_run: Run) -> None:
    """The whole image sweeping by up to ~6 px per frame: the camera motion is
    compensated, so the static lamp and textured background stay silent and
    every light keeps its identity."""
    rates = identity_rates(pan_run.truth, pan_run.results_all, ["M1", "M2", "M5", "M6"])
    print("identity rates (panning camera):", rates)
    assert all(r >= 0.99 for r in rates.values()), rates
    errs = [float(np.linalg.norm(det.uv - pan_run.truth[k][name][0]))
            for k, res in enumerate(pan_run.results_all) for name, det in res.detections.items()
            if pan_run.truth[k][name][1] == 1.0]
    print(f"panning: median position error when on {np.median(errs):.3f} px")
    assert np.median(errs) <= 0.3
    for k, res in enumerate(pan_run.results_all):
        assert "M8" not in res.detections
        for det in res.detections.values():
            for f in ("lamp", "flicker7"):
                assert np.linalg.norm(det.uv - pan_run.truth[k][f][0]) > 15.0


def test_global_motion_estimate() -> None:
    """Known translations of the textured background, small and large."""
    bg = make_background(np.random.default_rng(1), 40)
    gm = GlobalMotion()
    offsets = [np.zeros(2), np.array([0.3, -0.2]), np.array([1.7, 0.9]), np.array([-8.4, 5.2]),
               np.array([-9.0, 6.1]), np.array([3.3, 12.0])]
    for k, o in enumerate(offsets):
        m = np.array([[1.0, 0.0, 40 - o[0]], [0.0, 1.0, 40 - o[1]]])
        img = cv2.warpAffine(bg, m, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
        d = gm.update(np.clip(img, 0, 255).astype(np.uint8).max(axis=2))
        if k:
            assert np.linalg.norm(d - (o - offsets[k - 1])) < 0.15, (k, d, o - offsets[k - 1])
    # No texture, only a light switching on: not camera motion.
    gm.reset()
    flat = np.full((H, W), 60, np.uint8)
    gm.update(flat)
    lit = flat.copy()
    cv2.circle(lit, (300, 200), 3, 255, -1)
    assert np.all(gm.update(lit) == 0)


# ---------------------------------------------------------------------------
# small cases
# ---------------------------------------------------------------------------


def simple_frames(n: int, hz: float = 2.0, uv: tuple[float, float] = (100.3, 60.6),
                  shape: tuple[int, int] = (120, 320)) -> list[np.ndarray]:
    """A 2-D Gaussian light blinking at ``hz`` on a flat grey image."""
    frames = []
    for k in range(n):
        img = np.full(shape, 40, np.float32)
        if math.fmod(hz * k / FPS, 1.0) < 0.5:
            ys, xs = np.mgrid[0:shape[0], 0:shape[1]]
            img += 200 * np.exp(-((xs - uv[0]) ** 2 + (ys - uv[1]) ** 2) / (2 * 1.5**2))
        frames.append(np.clip(img, 0, 255).astype(np.uint8))
    return frames


def test_grayscale_reset_and_explicit_time() -> None:
    tr = BlinkTracker({"A": marker("A", 2.0)}, FPS)
    frames = simple_frames(60)
    for k, f in enumerate(frames):
        res = tr.update(f, t=10.0 + k / FPS)
    assert "A" in res.detections
    assert np.linalg.norm(res.detections["A"].uv - [100.3, 60.6]) < 0.3
    d = res.to_dict()
    assert set(d) == {"detections", "missing"}
    tr.reset()
    assert tr.update(frames[0]).missing == ["A"]
    assert tr.track_states() == []


@settings(max_examples=12, deadline=None)
@given(u=st.floats(20.0, 140.0), v=st.floats(20.0, 100.0), sigma=st.floats(1.0, 2.5),
       amp=st.floats(90.0, 215.0), phase=st.floats(0.0, 1.0))
def test_pixel_convention_any_subpixel_position(u: float, v: float, sigma: float, amp: float,
                                                phase: float) -> None:
    """A light whose intensity peaks at column u, row v is reported at (u, v)."""
    rng = np.random.default_rng(0)
    ys, xs = np.mgrid[0:120, 0:160]
    spot = amp * np.exp(-((xs - u) ** 2 + (ys - v) ** 2) / (2 * sigma**2))
    tr = BlinkTracker({"A": marker("A", 3.0)}, FPS)
    errs = []
    for k in range(45):
        on = math.fmod(3.0 * k / FPS + phase, 1.0) < 0.5
        img = 40.0 + (spot if on else 0.0) + rng.normal(0, 2.0, spot.shape)
        res = tr.update(np.clip(img + 0.5, 0, 255).astype(np.uint8))
        if on and "A" in res.detections:
            errs.append(float(np.linalg.norm(res.detections["A"].uv - [u, v])))
    assert errs, "never detected"
    assert max(errs) < 0.1


def test_gray_brightness_mode_and_float_images() -> None:
    tr = BlinkTracker({"A": marker("A", 3.0)}, FPS, params=BlinkParams(brightness="gray"))
    for f in simple_frames(60, hz=3.0):
        res = tr.update(np.repeat(f[:, :, None], 3, axis=2).astype(np.float32) / 255.0)
    assert "A" in res.detections and res.missing == []


def test_wrong_frequency_not_labelled() -> None:
    tr = BlinkTracker({"A": marker("A", 2.0), "B": marker("B", 5.0)}, FPS)
    for f in simple_frames(90, hz=3.5):
        res = tr.update(f)
    assert res.detections == {} and sorted(res.missing) == ["A", "B"]


def test_input_errors() -> None:
    with pytest.raises(InputError, match="no marker has a blink_hz"):
        BlinkTracker({"T": marker("T", None)}, FPS)
    with pytest.raises(InputError, match="half the frame rate"):
        BlinkTracker({"A": marker("A", 15.0)}, FPS)
    with pytest.raises(InputError, match="fps"):
        BlinkTracker({"A": marker("A", 2.0)}, 0.0)
    with pytest.raises(InputError, match="cannot tell them apart"):
        BlinkTracker({"A": marker("A", 2.0), "B": marker("B", 2.2)}, FPS, params=BlinkParams(window_s=1.0))
    with pytest.raises(InputError, match="cannot tell them apart"):  # two robots, same lights
        BlinkTracker({"A": marker("A", 2.0), "B": marker("B", 3.0), "C": marker("C", 2.0, "r")}, FPS)
    with pytest.raises(InputError, match="min_lit_fraction"):
        BlinkTracker({"A": marker("A", 2.0)}, FPS, params=BlinkParams(min_lit_fraction=1.5))
    # The default window grows to resolve close frequencies.
    assert BlinkTracker({"A": marker("A", 2.0), "B": marker("B", 2.5)}, FPS).window_s == pytest.approx(2.0)
    tr = BlinkTracker({"A": marker("A", 2.0)}, FPS)
    with pytest.raises(InputError, match="image"):
        tr.update(np.zeros((4, 4, 2), np.uint8))
    tr.update(np.zeros((50, 60), np.uint8), t=1.0)
    with pytest.raises(InputError, match="does not increase"):
        tr.update(np.zeros((50, 60), np.uint8), t=1.0)
    with pytest.raises(InputError, match="size changed"):
        tr.update(np.zeros((40, 60), np.uint8), t=2.0)
    with pytest.raises(InputError, match="finite"):
        tr.update(np.zeros((50, 60), np.uint8), t=float("nan"))


# ---------------------------------------------------------------------------
# sequences rendered by mutloc.sim: large, glowing, fast lights
# ---------------------------------------------------------------------------


def rendered_sequence(size: tuple[int, int], f: float, distance: float, n: int):
    """Robot q's camera watching p's two blinking lights (5 and 7.5 Hz) on
    ``moving_world``: the lights are saturated discs with bloom, on bright
    walls, moving fast across the image."""
    from mutloc.sim.render import moving_world, project_markers, render
    from mutloc.sim.world import light_is_on, standard_rig

    rig = standard_rig("lights", size=size, f=f)
    world = moving_world(rig, distance=distance)
    markers = rig.robot("p").markers
    frames, truth, lit = [], [], []
    for k in range(n):
        t = k / FPS
        frames.append(render(world, "q", t, seed=k, noise_sigma=1.0))
        truth.append(project_markers(world, "q", t))
        lit.append({name: light_is_on(m, t) for name, m in markers.items()})
    return markers, frames, truth, lit


@pytest.mark.parametrize(
    "size, f, distance, n, first",
    [((960, 540), 800.0, 1.4, 75, 30),  # light radius ~11 px (+ glow), ~190 px/s
     ((1920, 1080), 1600.0, 1.6, 32, 24)],  # radius ~20 px, ~380 px/s; identified by 0.8 s (then 8 frames)
    ids=["960x540", "1920x1080"],
)
def test_rendered_close_lights(size, f, distance, n, first) -> None:
    """Light sizes, glow and speeds scale with resolution and distance: the
    tracker's pixel limits must follow (the fixed ones never identified these)."""
    markers, frames, truth, lit = rendered_sequence(size, f, distance, n)
    tracker = BlinkTracker(markers, FPS)
    results, spent = [], 0.0
    for k, img in enumerate(frames):
        t0 = time.perf_counter()
        results.append(tracker.update(img, k / FPS))
        spent += time.perf_counter() - t0
    good = total = 0
    errs = []
    for k, res in enumerate(results):
        for name, det in res.detections.items():
            # Never reported anywhere but at its own light (not on the room's
            # bright clutter, not on the other light).
            assert name in truth[k], (k, name)
            d = {o: float(np.linalg.norm(det.uv - np.asarray(uv))) for o, uv in truth[k].items()}
            assert d[name] <= 5.0 and min(d, key=d.get) == name, (k, name, d)
            if lit[k][name] and det.info["on"]:
                errs.append(d[name])
        if k >= first:
            for name in truth[k]:
                total += 1
                good += name in res.detections
    rate = good / total
    print(f"{size[0]}x{size[1]} at {distance} m: identity {rate:.3f} after frame {first}, median error when "
          f"on {np.median(errs):.3f} px ({len(errs)} reports), {n / spent:.0f} frames/s")
    assert rate >= 0.99
    assert np.median(errs) <= 0.3


# ---------------------------------------------------------------------------
# accuracy at 1.2 m against the renderer's exact projection
# ---------------------------------------------------------------------------

DEGRADED = {"clean": {}, "noise+blur+jpeg": {"noise_sigma": 2.0, "blur_px": 0.7, "jpeg_quality": 90}}


LIMITS = {"clean": 0.2, "noise+blur+jpeg": 0.3}


def test_rendered_lights_at_1_2m_accuracy(monkeypatch) -> None:
    """Issue: median error <= 0.2 px clean and <= 0.3 px with noise, blur and
    JPEG, at 1.2 m and 960x540 (the standard rig's lights, 2 cm spheres, are
    ~13 px in radius there, clipped, with bloom).

    Truth is the projection of each light's centre (what the pose solver
    needs), not the centre of its image: a sphere images as an ellipse whose
    centre lies slightly outward of that projection (by about f alpha^2
    tan(theta) / cos^2(theta) for angular radius alpha at theta off axis:
    median 0.04 px, at most 0.14 px here), and that is counted as error.

    The sequence has p's green light beside a poster's edge and dark text for
    a second: the clipped core around a light extends further over the bright
    side, so its centroid was off by 1.1-1.5 px (before the halo fit: median
    0.24 px clean / 0.22 px degraded, 90th percentile 1.31 / 1.25 px; now about
    0.05 / 0.08 and 0.08 / 0.15 px).

    Both conditions watch the same 60 frames, each with its own tracker: a
    frame's ray cast (``render_linear``, deterministic) is done once and both
    conditions' sensor pipelines are applied to copies of it, so every image
    is the one ``render`` draws for that condition on its own."""
    import mutloc.sim.render as render_module
    from mutloc.sim.render import moving_world, project_markers, render
    from mutloc.sim.world import light_is_on, standard_rig

    cast = render_module.render_linear
    last: dict = {}

    def cast_once(world, observer, t):
        key = (id(world), observer, t)
        if key not in last:
            last.clear()
            last[key] = cast(world, observer, t)
        rgb, emit = last[key]
        return rgb.copy(), emit.copy()  # render() adds the bloom into its copy

    monkeypatch.setattr(render_module, "render_linear", cast_once)
    rig = standard_rig("lights")
    world = moving_world(rig, distance=1.2)
    markers = rig.robot("p").markers
    trackers = {cond: BlinkTracker(markers, FPS) for cond in DEGRADED}
    errs = {cond: [] for cond in DEGRADED}
    good = dict.fromkeys(DEGRADED, 0)
    total = 0
    for k in range(60):
        t = k / FPS
        truth = project_markers(world, "q", t)
        if k >= FPS:
            total += len(truth)
        for cond, tracker in trackers.items():
            res = tracker.update(render(world, "q", t, seed=k, **DEGRADED[cond]), t)
            for name, det in res.detections.items():
                assert name in truth, (cond, k, name)
                e = float(np.linalg.norm(det.uv - np.asarray(truth[name])))
                assert e <= 5.0, (cond, k, name, e)
                if light_is_on(markers[name], t) and det.info["on"]:
                    errs[cond].append(e)
            if k >= FPS:
                good[cond] += sum(name in res.detections for name in truth)
    for cond, limit in LIMITS.items():
        e = errs[cond]
        print(f"1.2 m, {cond}: median error when on {np.median(e):.3f} px, 90% {np.percentile(e, 90):.3f} px "
              f"({len(e)} reports), identity {good[cond] / total:.3f}")
        assert good[cond] / total >= 0.99, cond
        assert len(e) >= 25, cond
        assert np.median(e) <= limit, cond
        assert np.percentile(e, 90) <= 0.5, cond


def test_lights_are_tracked_per_colour_and_a_grey_stream_in_one_channel() -> None:
    """A red light at 2 Hz and a green one at 3 Hz on a grey background:
    each is named by its own colour's tracker in a colour stream, both by the
    single brightness channel in a grey stream; a stream cannot switch."""
    from mutloc.detect.blink.channels import colour_groups

    red = Marker("R", "q", np.array([0.1, 0.0, 0.0]), color=(255, 0, 0), blink_hz=2.0)
    green = Marker("G", "q", np.array([-0.1, 0.0, 0.0]), color=(0, 255, 0), blink_hz=3.0)
    white = marker("W", 5.0)
    groups = colour_groups({"R": red, "G": green, "W": white, "T": marker("T", None)})
    assert sorted(sorted(ms) for _, ms in groups) == [["G"], ["R"], ["W"]]
    assert [own.tolist() for own, ms in groups if "R" in ms] == [[False, False, True]]  # BGR: red's own channel
    assert [own for own, ms in groups if "W" in ms] == [None]  # white: the brightness channel

    uv = {"R": (100.3, 60.6), "G": (220.7, 70.2)}
    reds, greens = simple_frames(60, 2.0, uv["R"]), simple_frames(60, 3.0, uv["G"])
    colour = [cv2.merge([np.full_like(r, 40), g, r]) for r, g in zip(reds, greens)]
    grey = [np.maximum(r, g) for r, g in zip(reds, greens)]
    for frames in (colour, grey):
        tr = BlinkTracker({"R": red, "G": green}, FPS)
        for k, img in enumerate(frames):
            res = tr.update(img, k / FPS)
        for name in ("R", "G"):
            assert np.linalg.norm(res.detections[name].uv - np.array(uv[name])) < 0.5, (name, res)
        channels = {tuple(s["channel"]) if s["channel"] else None for s in tr.track_states()}
        assert channels == ({(False, False, True), (False, True, False)} if frames is colour else {None})
    with pytest.raises(InputError, match="colour and grey"):
        tr.update(colour[0], 100.0)
