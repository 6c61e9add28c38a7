"""Printed-tag markers: detection accuracy against rendered ground truth, tag
geometry in the rig, and mutual localization from two tags.

Ground truth is independent of the code under test: the tag image comes from
``cv2.aruco.generateImageMarker``, its true corners from ``cv2.projectPoints``
of a known 3-D pose, and the image from warping the tag (with a white quiet
zone) into a textured background with the homography those corners define,
rendered at 4x resolution and box-filtered down (``INTER_AREA``) so edges are
anti-aliased like a real sensor's.  Pixel convention throughout: (0, 0) is
the centre of the top-left pixel, as in cv2.warpPerspective/remap.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import pytest

import mutloc
from mutloc.core.camera import Camera
from mutloc.core.geometry import rotation_error_deg
from mutloc.core.rig import Marker
from mutloc.detect.base import Detection, DetectionResult
from mutloc.detect.tags import (
    aruco_dictionary,
    canonical_family,
    corner_marker_names,
    detect_tags,
    diagonal_centre,
    expand_tag_corners,
    tag_corner_points,
    tag_observations,
)
from mutloc.errors import InputError, RigError

W, H = 960, 540
K = np.array([[800.0, 0.0, 479.5], [0.0, 800.0, 269.5], [0.0, 0.0, 1.0]])
SS = 4  # supersampling factor of the renderer
DICT_NAMES = {"tag36h11": "DICT_APRILTAG_36h11", "4x4_50": "DICT_4X4_50"}


# ---------------------------------------------------------------------------
# renderer (independent ground truth)
# ---------------------------------------------------------------------------


def _dictionary(family: str) -> Any:
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, DICT_NAMES[family]))


def _background(rng: np.random.Generator) -> np.ndarray:
    """Smooth random texture (supersampled, float32 grey) so the detector sees clutter."""
    small = rng.uniform(0, 255, (H // 8 + 2, W // 8 + 2)).astype(np.float32)
    bg = cv2.resize(small, (W * SS, H * SS), interpolation=cv2.INTER_CUBIC)
    return np.clip(0.5 * bg + 64, 0, 255).astype(np.float32)


def _tag_texture(family: str, tid: int, cell_px: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """High-resolution tag image with a one-cell white quiet zone, and its
    black-square corners (TL, TR, BR, BL) in that image's pixel coordinates."""
    d = _dictionary(family)
    cells = d.markerSize + 2
    side = cells * cell_px
    img = cv2.aruco.generateImageMarker(d, tid, side, borderBits=1)
    pad = cell_px
    img = cv2.copyMakeBorder(img, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)
    a, b = pad - 0.5, pad + side - 0.5  # pixel edges of the black square
    return img.astype(np.float32), np.array([[a, a], [b, a], [b, b], [a, b]])


def _object_corners(size: float) -> np.ndarray:
    h = size / 2
    return np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], float)  # x right, y down


def _to_hi(uv: np.ndarray) -> np.ndarray:
    """Low-resolution pixel coordinates -> supersampled ones (pixel-centre origin in both)."""
    return SS * (uv + 0.5) - 0.5


def render(tags: list[tuple[str, int, np.ndarray, np.ndarray, float]], rng: np.random.Generator, *,
           dist: np.ndarray | None = None, noise: float = 2.0, blur: float = 0.0,
           gamma: float | str = "srgb") -> tuple[np.ndarray, list[np.ndarray]]:
    """BGR image of tags ``(family, id, rvec, tvec, size)`` and each tag's true corners (4, 2).

    Without ``dist`` the tag is placed with cv2.warpPerspective; with lens
    distortion the homography holds only in undistorted coordinates, so every
    (supersampled) pixel near the tag is undistorted and looked up in the tag
    image with cv2.remap.  ``blur`` (Gaussian sigma, px) acts on linear light
    and ``gamma`` then encodes it, as in a camera: ``"srgb"`` (the default,
    what cameras and files deliver, and what the detector assumes unless
    told otherwise), ``"linear"`` or a power-law exponent.
    """
    img = _background(rng)
    truths = []
    for family, tid, rvec, tvec, size in tags:
        tex, src = _tag_texture(family, tid)
        obj = _object_corners(size)
        uv, _ = cv2.projectPoints(obj, rvec, tvec, K, dist)
        uv = uv.reshape(4, 2)
        truths.append(uv)
        mask_tex = np.ones_like(tex)
        if dist is None:
            Hm = cv2.getPerspectiveTransform(src.astype(np.float32), _to_hi(uv).astype(np.float32))
            warped = cv2.warpPerspective(tex, Hm, (W * SS, H * SS), flags=cv2.INTER_LINEAR)
            mask = cv2.warpPerspective(mask_tex, Hm, (W * SS, H * SS), flags=cv2.INTER_LINEAR)
        else:
            # Tag-image coordinates of normalized (undistorted) image points.
            xy, _ = cv2.projectPoints(obj, rvec, tvec, np.eye(3), None)
            Hn = np.linalg.inv(cv2.getPerspectiveTransform(src.astype(np.float32), xy.reshape(4, 2).astype(np.float32)))
            # Only the pixels around the tag (quiet zone included) need the slow lookup.
            big, _ = cv2.projectPoints(obj * 1.4, rvec, tvec, K, dist)
            lo = np.floor(_to_hi(big.reshape(4, 2).min(axis=0) - 2)).astype(int).clip(0)
            hi = np.ceil(_to_hi(big.reshape(4, 2).max(axis=0) + 2)).astype(int).clip(None, [W * SS - 1, H * SS - 1])
            us, vs = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1))
            pix = np.stack([(us + 0.5) / SS - 0.5, (vs + 0.5) / SS - 0.5], axis=-1).reshape(-1, 1, 2)
            und = cv2.undistortPoints(pix.astype(np.float64), K, dist,
                                      criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-15))
            back, _ = cv2.projectPoints(np.c_[und.reshape(-1, 2), np.ones(len(pix))], np.zeros(3), np.zeros(3), K, dist)
            assert np.abs(back.reshape(-1, 2) - pix.reshape(-1, 2)).max() < 1e-4  # the renderer itself is exact
            t = np.c_[und.reshape(-1, 2), np.ones(len(pix))] @ Hn.T
            mx = (t[:, 0] / t[:, 2]).reshape(us.shape).astype(np.float32)
            my = (t[:, 1] / t[:, 2]).reshape(us.shape).astype(np.float32)
            warped = np.zeros_like(img)
            mask = np.zeros_like(img)
            roi = np.s_[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1]
            warped[roi] = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            mask[roi] = cv2.remap(mask_tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        img = img * (1 - mask) + warped * mask
    out = cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA) / 255.0
    if blur > 0:
        out = cv2.GaussianBlur(out, (0, 0), blur)
    out = np.clip(out, 0, 1)
    if gamma == "srgb":  # IEC 61966-2-1
        out = np.where(out <= 0.0031308, 12.92 * out, 1.055 * out ** (1 / 2.4) - 0.055)
    elif gamma != "linear":
        out = out ** (1.0 / gamma)
    out = out * 255.0 + rng.normal(0, noise, out.shape)
    grey = np.clip(out + 0.5, 0, 255).astype(np.uint8)
    return cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR), truths


def random_pose(rng: np.random.Generator, dist: tuple[float, float] = (1.0, 3.5),
                tilt_deg: float = 60.0) -> tuple[np.ndarray, np.ndarray]:
    """A tag pose in the camera frame: in view, 1-3.5 m away, tilted up to 60 degrees."""
    z = rng.uniform(*dist)
    t = np.array([rng.uniform(-0.3, 0.3) * z, rng.uniform(-0.2, 0.2) * z, z])
    axis = rng.normal(size=3)
    return axis / np.linalg.norm(axis) * np.deg2rad(rng.uniform(0, tilt_deg)), t


def tag_marker(name: str, family: str = "tag36h11", tid: int = 3, size: float = 0.15, **extra: Any) -> Marker:
    return Marker(name, "q", np.zeros(3), tag={"family": family, "id": tid, "size": size, **extra})


def opencv_corners(image: np.ndarray, family: str, tid: int, method: int | None = None) -> np.ndarray | None:
    """cv2.aruco.ArucoDetector used directly (OpenCV defaults unless ``method``)."""
    p = cv2.aruco.DetectorParameters()
    if method is not None:
        p.cornerRefinementMethod = method
    corners, ids, _ = cv2.aruco.ArucoDetector(_dictionary(family), p).detectMarkers(image)
    if ids is None or tid not in ids.ravel():
        return None
    return corners[list(ids.ravel()).index(tid)].reshape(4, 2).astype(float)


def _line_intersection(p1, p2, p3, p4) -> np.ndarray:
    """Intersection of lines p1-p2 and p3-p4 (Cramer's rule), for an independent check."""
    d1, d2, r = p2 - p1, p4 - p3, p3 - p1
    den = d1[0] * d2[1] - d1[1] * d2[0]
    s = (r[0] * d2[1] - r[1] * d2[0]) / den
    return p1 + s * d1


# ---------------------------------------------------------------------------
# corner accuracy
# ---------------------------------------------------------------------------


def _corner_errors(n: int, seed: int, **render_kw: Any) -> tuple[dict[str, np.ndarray], dict[str, int]]:
    """Corner errors of ours and OpenCV's on the tags every detector found, and how many each found."""
    from mutloc.detect.apriltag_lib import peer_detector

    rng = np.random.default_rng(seed)
    markers = {"T": tag_marker("T")}
    errs: dict[str, list[np.ndarray]] = {"ours": [], "opencv_default": [], "opencv_subpix": []}
    found = {"ours": 0, "opencv": 0, "apriltag_lib": 0}
    peer = peer_detector("tag36h11")
    gamma = render_kw.get("gamma", "srgb")
    for _ in range(n):
        rvec, tvec = random_pose(rng)
        image, (truth,) = render([("tag36h11", 3, rvec, tvec, 0.15)], rng, **render_kw)
        res = detect_tags(image, markers, gamma=gamma)
        ocv_def = opencv_corners(image, "tag36h11", 3)
        ocv_sub = opencv_corners(image, "tag36h11", 3, cv2.aruco.CORNER_REFINE_SUBPIX)
        found["ours"] += "T" in res.detections
        found["opencv"] += ocv_def is not None
        found["apriltag_lib"] += any(d.tag_id == 3 for d in peer.detect(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)))
        if "T" not in res.detections or ocv_def is None or ocv_sub is None:
            continue
        errs["ours"].append(np.linalg.norm(res.detections["T"].corners - truth, axis=1))
        errs["opencv_default"].append(np.linalg.norm(ocv_def - truth, axis=1))
        errs["opencv_subpix"].append(np.linalg.norm(ocv_sub - truth, axis=1))
    return {k: np.concatenate(v) for k, v in errs.items()}, found


@pytest.mark.parametrize(
    "condition, render_kw",
    [
        ("clean", {}),
        # A camera-like image: defocus blur, sRGB-like gamma (the detector is told), more noise.
        ("blur+gamma", {"blur": 1.0, "gamma": 2.2, "noise": 3.0}),
    ],
)
def test_corner_accuracy_against_opencv(condition: str, render_kw: dict[str, Any]) -> None:
    errs, found = _corner_errors(20, seed=11, **render_kw)
    med = {k: float(np.median(v)) for k, v in errs.items()}
    print(f"\n[{condition}] found of 20: {found}; corner error px (median / p90 / max): " + "; ".join(
        f"{k} {np.median(v):.3f} / {np.percentile(v, 90):.3f} / {v.max():.3f}" for k, v in errs.items()))
    # The AprilTag library decides what is found (it misses a 46 px tag tilted
    # ~60 deg under blur that OpenCV finds: 19 of 20 in the blurred case).
    assert found["ours"] >= found["apriltag_lib"] and found["ours"] >= 19
    assert med["ours"] <= min(med["opencv_default"], med["opencv_subpix"]) + 0.05
    assert errs["ours"].max() <= 0.5


def test_opencv_refinements_keep_their_accuracy_in_our_convention() -> None:
    """refine='subpix' is OpenCV's detector unchanged (same pixel convention);
    refine='apriltag' undoes that method's half-pixel corner-origin offset."""
    rng = np.random.default_rng(5)
    markers = {"T": tag_marker("T")}
    raw_shift, ours_shift = [], []
    for _ in range(6):
        rvec, tvec = random_pose(rng)
        image, (truth,) = render([("tag36h11", 3, rvec, tvec, 0.15)], rng)
        sub = detect_tags(image, markers, refine="subpix").detections["T"]
        np.testing.assert_allclose(sub.corners, opencv_corners(image, "tag36h11", 3, cv2.aruco.CORNER_REFINE_SUBPIX))
        assert sub.info["refine"] == "subpix"
        raw = opencv_corners(image, "tag36h11", 3, cv2.aruco.CORNER_REFINE_APRILTAG)
        ours = detect_tags(image, markers, refine="apriltag").detections["T"].corners
        # The mean over the 4 corners cancels any inward/outward bias and leaves the shift.
        raw_shift.append((raw - truth).mean(axis=0))
        ours_shift.append((ours - truth).mean(axis=0))
    assert np.all(np.abs(np.mean(raw_shift, axis=0) - 0.5) < 0.15)  # OpenCV's apriltag refine: +0.5 px
    assert np.all(np.abs(np.mean(ours_shift, axis=0)) < 0.1)


def test_centre_is_diagonal_intersection() -> None:
    rng = np.random.default_rng(3)
    # Strongly tilted and close: the corner mean is visibly not the centre.
    rvec = np.array([0.0, np.deg2rad(60), 0.0])
    tvec = np.array([0.1, 0.0, 0.9])
    image, _ = render([("tag36h11", 3, rvec, tvec, 0.15)], rng)
    det = detect_tags(image, {"T": tag_marker("T")}).detections["T"]
    c = det.corners
    np.testing.assert_allclose(det.uv, _line_intersection(c[0], c[2], c[1], c[3]), atol=1e-9)
    true_centre = cv2.projectPoints(np.zeros((1, 3)), rvec, tvec, K, None)[0].ravel()
    assert np.linalg.norm(det.uv - true_centre) < 0.05
    assert np.linalg.norm(c.mean(axis=0) - true_centre) > 1.0
    assert det.info["family"] == "tag36h11" and det.info["id"] == 3 and det.info["refine"] == "edges"


def test_lens_distortion_with_camera() -> None:
    """Sides are straight only after undistortion: given the camera, the edge
    fit and the centre account for it."""
    dist = np.array([-0.3, 0.12, 0.001, -0.001, 0.0])
    cam = Camera(K, dist, (W, H))
    # (Some noise draws make OpenCV's candidate search miss this tag altogether --
    # e.g. seed 8 -- which is not what is tested here.)
    rng = np.random.default_rng(0)
    rvec = np.array([0.2, -0.5, 0.1])
    tvec = np.array([-0.55, -0.3, 1.3])  # towards the top-left corner, where distortion is strong
    image, (truth,) = render([("tag36h11", 3, rvec, tvec, 0.15)], rng, dist=dist)
    with_cam = detect_tags(image, {"T": tag_marker("T")}, camera=cam).detections["T"]
    without = detect_tags(image, {"T": tag_marker("T")}).detections["T"]
    err_cam = np.linalg.norm(with_cam.corners - truth, axis=1)
    err_plain = np.linalg.norm(without.corners - truth, axis=1)
    true_centre = cv2.projectPoints(np.zeros((1, 3)), rvec, tvec, K, dist)[0].ravel()
    print(f"\n[distortion] corner error px: with camera {err_cam.round(3)}, without {err_plain.round(3)}; "
          f"centre error with camera {np.linalg.norm(with_cam.uv - true_centre):.3f}")
    assert err_cam.max() < 0.1
    assert np.linalg.norm(with_cam.uv - true_centre) < 0.1


# ---------------------------------------------------------------------------
# identities, families, errors
# ---------------------------------------------------------------------------


def test_ids_families_and_missing() -> None:
    rng = np.random.default_rng(21)
    tags = [
        ("tag36h11", 3, np.array([0.2, 0.3, 0.0]), np.array([-0.35, 0.0, 2.0]), 0.15),
        ("4x4_50", 7, np.array([-0.3, 0.1, 0.1]), np.array([0.35, 0.05, 2.0]), 0.15),
        ("tag36h11", 4, np.array([0.0, 0.0, 0.2]), np.array([0.0, -0.25, 2.2]), 0.15),  # not ours
    ]
    image, truths = render(tags, rng)
    markers = {
        "A": tag_marker("A", "tag36h11", 3),
        "B": tag_marker("B", "aruco_4x4_50", 7),
        "C": tag_marker("C", "apriltag_36h11", 5),  # not in the image
        "D": tag_marker("D", "DICT_4X4_50", 8),  # not in the image
        "ball": Marker("ball", "q", np.array([0.3, 0.0, 0.0]), color=(255, 0, 0)),  # no tag: ignored
    }
    res = detect_tags(image, markers)
    assert set(res.detections) == {"A", "B"}
    assert sorted(res.missing) == ["C", "D"]
    assert res.detections["A"].info["id"] == 3 and res.detections["B"].info == {
        **res.detections["B"].info, "family": "4x4_50", "id": 7}
    for name, truth in (("A", truths[0]), ("B", truths[1])):
        assert np.linalg.norm(res.detections[name].corners - truth, axis=1).max() < 0.3
    # The JSON form carries the corners.
    assert len(res.to_dict()["detections"]["A"]["corners"]) == 4


def test_family_names() -> None:
    for spelling in ("tag36h11", "TAG36H11", "apriltag_36h11", "DICT_APRILTAG_36h11", "36h11", "tag-36h11"):
        assert canonical_family(spelling) == "tag36h11"
    assert canonical_family("tag25h9") == "tag25h9" and canonical_family("tag16h5") == "tag16h5"
    assert canonical_family("5x5_100") == "5x5_100" and canonical_family("aruco_6x6_250") == "6x6_250"
    assert canonical_family("ARUCO_ORIGINAL") == "aruco_original"
    assert aruco_dictionary("6x6_250").markerSize == 6
    assert aruco_dictionary("tag16h5").markerSize == 4
    for bad in ("tag36h12", "3x3_50", "", "qr"):
        with pytest.raises(RigError):
            canonical_family(bad)


def test_bad_input() -> None:
    image = np.full((100, 100, 3), 255, np.uint8)
    with pytest.raises(RigError, match="unknown tag family"):
        detect_tags(image, {"T": tag_marker("T", family="tag99h1")})
    with pytest.raises(RigError, match="does not exist"):
        detect_tags(image, {"T": tag_marker("T", family="4x4_50", tid=50)})
    with pytest.raises(RigError, match="cannot be told apart"):
        detect_tags(image, {"T": tag_marker("T"), "U": tag_marker("U", family="apriltag_36h11")})
    with pytest.raises(InputError, match="refine"):
        detect_tags(image, {"T": tag_marker("T")}, refine="magic")
    with pytest.raises(InputError, match="gamma"):
        detect_tags(image, {"T": tag_marker("T")}, gamma=0)
    with pytest.raises(InputError, match="DetectorParameters"):
        detect_tags(image, {"T": tag_marker("T")}, params={"noSuchThing": 1})
    res = detect_tags(image, {"T": tag_marker("T")}, params={"minMarkerPerimeterRate": 0.01})
    assert res.missing == ["T"] and res.detections == {}
    # No tag markers at all: nothing to do, nothing missing.
    assert detect_tags(image, {}).to_dict() == {"detections": {}, "missing": []}


# ---------------------------------------------------------------------------
# tag geometry in the rig
# ---------------------------------------------------------------------------


def test_tag_corner_points() -> None:
    pos = np.array([0.2, -0.05, 0.01])
    m = Marker("T", "p", pos, tag={"family": "tag36h11", "id": 3, "size": 0.1, "rotation": [0.0, 0.0, 0.0]})
    np.testing.assert_allclose(tag_corner_points(m), pos + [[-0.05, -0.05, 0], [0.05, -0.05, 0],
                                                            [0.05, 0.05, 0], [-0.05, 0.05, 0]])
    rvec = np.array([0.3, -2.0, 0.4])
    m = Marker("T", "p", pos, tag={"family": "tag36h11", "id": 3, "size": 0.1, "rotation": rvec.tolist()})
    R = cv2.Rodrigues(rvec)[0]
    np.testing.assert_allclose(tag_corner_points(m), pos + _object_corners(0.1) @ R.T, atol=1e-12)
    assert tag_corner_points(Marker("T", "p", pos, tag={"family": "tag36h11", "id": 3, "size": 0.1})) is None
    assert tag_corner_points(Marker("B", "p", pos, color=(1, 2, 3))) is None
    with pytest.raises(RigError, match="rotation"):
        tag_corner_points(Marker("T", "p", pos, tag={"family": "tag36h11", "id": 3, "size": 0.1, "rotation": [1, 2]}))


def _two_robot_rig(rot_p: Any = (0.0, np.pi, 0.0), rot_q: Any = (0.0, np.pi, 0.0)) -> dict[str, Any]:
    cam = {"K": K.tolist(), "size": [W, H]}

    def tag(tid: int, rot: Any) -> dict[str, Any]:
        t: dict[str, Any] = {"family": "tag36h11", "id": tid, "size": 0.15}
        if rot is not None:
            t["rotation"] = list(rot)
        return t

    return {"robots": {
        "p": {"camera": cam, "markers": {"P": {"position": [0.16, 0.0, 0.0], "tag": tag(1, rot_p)}}},
        "q": {"camera": cam, "markers": {"Q": {"position": [-0.16, 0.02, 0.0], "tag": tag(2, rot_q)}}},
    }}


def test_expand_tag_corners_and_observations() -> None:
    rig = mutloc.load_rig(_two_robot_rig(rot_q=None))  # q's tag has no orientation
    ex = expand_tag_corners(rig)
    assert list(ex.robot("p").markers) == ["P", *corner_marker_names("P")]
    assert list(ex.robot("q").markers) == ["Q"]
    np.testing.assert_allclose(ex.robot("p").marker_positions(corner_marker_names("P")),
                               tag_corner_points(rig.marker("P")))
    assert ex.marker("P#2").extra == {"tag_of": "P", "tag_corner": 2}
    assert list(expand_tag_corners(ex).robot("p").markers) == list(ex.robot("p").markers)  # idempotent
    # The rig file form round-trips (rotation kept, corners are plain markers).
    assert mutloc.load_rig(ex.to_dict()).marker("P#1").position.tolist() == ex.marker("P#1").position.tolist()

    corners = np.array([[10.0, 20.0], [30.0, 20.0], [30.0, 40.0], [10.0, 40.0]])
    res = DetectionResult(detections={
        "P": Detection("P", np.array([20.0, 30.0]), corners=corners),
        "Q": Detection("Q", np.array([5.0, 6.0]), corners=corners + 100),
    })
    obs = tag_observations(res)
    assert obs["P"] == (20.0, 30.0) and obs["P#3"] == (10.0, 40.0) and obs["Q#0"] == (110.0, 120.0)
    assert len(obs) == 10
    assert set(tag_observations(res, ex)) == {"P", "P#0", "P#1", "P#2", "P#3", "Q"}  # Q has no corners in ex
    assert set(tag_observations(res, ex, centre=False)) == {"P#0", "P#1", "P#2", "P#3"}
    assert np.allclose(diagonal_centre(corners), [20.0, 30.0])


def test_expand_rejects_name_clash() -> None:
    spec = _two_robot_rig()
    spec["robots"]["p"]["markers"]["P#0"] = {"position": [1.0, 1.0, 1.0]}
    with pytest.raises(RigError, match="P#0"):
        expand_tag_corners(mutloc.load_rig(spec))


# ---------------------------------------------------------------------------
# end to end: two robots, each sees the other's tag
# ---------------------------------------------------------------------------


def _look_at(forward: np.ndarray, roll: float) -> np.ndarray:
    """Rotation whose columns are a camera's x, y, z axes with z along ``forward``."""
    z = forward / np.linalg.norm(forward)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.c_[x, y, z]
    c, s = np.cos(roll), np.sin(roll)
    return R @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


@pytest.mark.parametrize("seed, D", [(0, 1.5), (1, 2.25), (2, 3.0)])
def test_mutual_localization_from_two_tags(seed: int, D: float) -> None:
    rng = np.random.default_rng(100 + seed)
    # Each tag beside its robot's camera, facing forward (seen upright from the
    # front: tag x = -camera x, tag z = -camera z, i.e. a half turn about y),
    # tilted by a random few degrees.
    def tag_rotation() -> np.ndarray:
        tilt = cv2.Rodrigues(rng.normal(0, np.deg2rad(8), 3))[0]
        return cv2.Rodrigues(tilt @ np.diag([-1.0, 1.0, -1.0]))[0].ravel()

    rig = mutloc.load_rig(_two_robot_rig(tag_rotation(), tag_rotation()))
    # q stands D in front of p, looking back at it (a few degrees off).
    c_q = D * np.array([rng.uniform(-0.15, 0.15), rng.uniform(-0.08, 0.08), 1.0])
    c_q *= D / np.linalg.norm(c_q)
    aim = -c_q + rng.normal(0, 0.05 * D, 3)
    R_pq = _look_at(aim, rng.uniform(-0.3, 0.3))  # q's axes in p's frame
    R_true, t_true = R_pq.T, -R_pq.T @ c_q  # T_qp: x_q = R x_p + t

    def tag_pose_in(R_obs_from: np.ndarray, t_obs_from: np.ndarray, marker: str) -> tuple:
        m = rig.marker(marker)
        R_tag = cv2.Rodrigues(np.asarray(m.tag["rotation"], float))[0]
        rvec = cv2.Rodrigues(R_obs_from @ R_tag)[0].ravel()
        return ("tag36h11", m.tag["id"], rvec, R_obs_from @ m.position + t_obs_from, m.tag["size"])

    # A camera-like image: slight defocus and sensor noise.
    image_p, _ = render([tag_pose_in(R_pq, c_q, "Q")], rng, blur=0.8, noise=2.0)  # p sees q's tag
    image_q, _ = render([tag_pose_in(R_true, t_true, "P")], rng, blur=0.8, noise=2.0)  # q sees p's tag
    ex = expand_tag_corners(rig)

    def solve(refine: str) -> tuple[Any, float, float]:
        res_p = detect_tags(image_p, rig.robot("q").markers, refine=refine)
        res_q = detect_tags(image_q, rig.robot("p").markers, refine=refine)
        assert set(res_p.detections) == {"Q"} and set(res_q.detections) == {"P"}
        obs = {"p": tag_observations(res_p, ex), "q": tag_observations(res_q, ex)}
        assert len(obs["p"]) == len(obs["q"]) == 5
        est = mutloc.localize(ex, obs, source="p", target="q")
        return est, float(np.linalg.norm(est.t - t_true)), rotation_error_deg(est.R, R_true)

    est, t_err, r_err = solve("edges")
    _, t_sub, r_sub = solve("subpix")  # for the record: OpenCV's own corners
    print(f"\n[mutual D={D:.2f} m] translation error {1000 * t_err:.2f} mm, rotation error {r_err:.3f} deg, "
          f"reprojection rms {est.reprojection_rms_px:.3f} px (OpenCV subpix corners: {1000 * t_sub:.2f} mm, "
          f"{r_sub:.3f} deg)")
    # Measured (D = 1.5, 2.25, 3 m): 0.55, 1.28, 1.49 mm; 0.004, 0.009, 0.007 deg; rms 0.011, 0.011, 0.016 px.
    assert t_err < 0.002 * D
    assert r_err < 0.03
    assert est.reprojection_rms_px < 0.05
