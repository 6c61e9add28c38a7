"""Tags on camera-like renders: sRGB-encoded, optically blurred, noisy, some JPEG.

Images come from mutloc's ray caster (linear light -> Gaussian PSF -> sRGB ->
noise -> JPEG), the truth from the scene geometry.  The peer is the AprilTag 3
library as the ``pupil-apriltags`` wheel exposes it (``Detector.detect`` on the
grey image, its defaults), compared on the same images.
"""

from __future__ import annotations

import dataclasses
import functools

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mutloc
from mutloc.core.geometry import rotation_error_deg
from mutloc.core.rig import Marker, Rig, Robot
from mutloc.detect.apriltag_lib import peer_detector
from mutloc.detect.base import DetectionResult
from mutloc.detect.tag_edges import linearize
from mutloc.detect.tags import aruco_dictionary, canonical_family, detect_tags, expand_tag_corners, tag_observations
from mutloc.errors import InputError, RigError
from mutloc.sim.render import render, srgb_to_linear, two_robot_world
from mutloc.sim.synthetic import facing_pose
from mutloc.sim.tag_scenes import tag_scene
from mutloc.sim.world import DEFAULT_TAG_ROTATION, standard_rig

TAG_SIZE = 0.12
PSF_SIGMA_PX = 0.8


def tag_rig(family: str = "tag36h11", tilt_p_deg: float = 0.0) -> Rig:
    """Two robots, each with one 12 cm tag 12 cm below its camera, facing forward (p's turned by
    ``tilt_p_deg`` about its vertical axis: a slanted mount, seen that far off its normal by q)."""
    base = standard_rig("balls")
    robots = {}
    for rn, rob in base.robots.items():
        tn = "T" + rn.upper()
        rot = np.array(DEFAULT_TAG_ROTATION, dtype=float)
        if rn == "p":
            rot[1] += np.deg2rad(tilt_p_deg)
        tag = {"family": family, "id": {"p": 11, "q": 10}[rn], "size": TAG_SIZE, "rotation": rot.tolist()}
        robots[rn] = Robot(rn, rob.camera, {tn: Marker(tn, rn, np.array([0.0, 0.12, 0.0]), tag=tag)})
    return Rig(robots)


def pair_scene(seed: int, distance: float, family: str = "tag36h11", jpeg: int | None = None,
               psf_sigma_px: float = PSF_SIGMA_PX, tilt_p_deg: float = 0.0):
    """(rig, T_qp, {observer: image}) of p and q facing each other ``distance`` apart, jittered by ``seed``
    (p's tag turned by ``tilt_p_deg``: :func:`tag_rig`)."""
    rig = tag_rig(family, tilt_p_deg)
    rng = np.random.default_rng(seed)
    T = facing_pose(distance, yaw_p=rng.uniform(-0.25, 0.25), yaw_q=rng.uniform(-0.25, 0.25),
                    lateral=rng.uniform(-0.2, 0.2) * distance / 3, tilt=rng.normal(0, 0.04, 3))
    world = two_robot_world(rig, T, seed=seed)
    world = dataclasses.replace(world, sensor=dataclasses.replace(world.sensor, psf_sigma_px=psf_sigma_px))
    images = {o: render(world, o, seed=seed, noise_sigma=2.0, jpeg_quality=jpeg) for o in ("p", "q")}
    return rig, T, images


@functools.cache
def pose_scenes():
    """Eight pairs from 1.2 to 3.5 m; every other one through JPEG at quality 90."""
    return [pair_scene(seed, 1.2 + 2.3 * seed / 7, jpeg=90 if seed % 2 else None) for seed in range(8)]


def solve(rig: Rig, images: dict, **detect_kw) -> mutloc.Estimate:
    ex = expand_tag_corners(rig)
    obs = {}
    for o, other in (("p", "q"), ("q", "p")):
        res = detect_tags(images[o], rig.robot(other).markers, **detect_kw)
        obs[o] = tag_observations(res, ex)
        assert len(obs[o]) == 5  # centre and four corners
    # confidence=1: the estimate itself is measured here, not the consistency test.
    return mutloc.localize(ex, obs, source="p", target="q", confidence=1)


def pose_errors(**detect_kw) -> np.ndarray:
    """Per scene: translation error (cm), rotation error (deg), signed range error (cm)."""
    out = []
    for rig, T, images in pose_scenes():
        est = solve(rig, images, **detect_kw)
        out.append([100 * np.linalg.norm(est.t - T.t), rotation_error_deg(est.R, T.R),
                    100 * (np.linalg.norm(est.t) - np.linalg.norm(T.t))])
    return np.array(out)


@pytest.mark.slow
def test_tags_alone_pose_without_range_bias() -> None:
    err = pose_errors()
    print("\n[tags alone, sRGB + blur] t cm / rot deg / range cm per scene:\n", err.round(3))
    assert np.median(err[:, 0]) <= 0.3
    assert np.median(err[:, 1]) <= 0.1
    assert abs(np.median(err[:, 2])) <= 0.1  # no range bias
    assert err[:, 0].max() <= 0.6


@pytest.mark.slow
def test_linearisation_removes_the_gamma_range_bias() -> None:
    """The same images read as if linear (edges of gamma-encoded, blurred steps
    sit towards the dark side: the tag shrinks, the range grows), and the
    AprilTag library's own corners, are biased; the linearised edge fit is not."""
    ours = pose_errors()
    as_linear = pose_errors(gamma="linear")
    library = pose_errors(refine="none")
    print(f"\nmedian range error cm: linearised {np.median(ours[:, 2]):.3f}, read as linear "
          f"{np.median(as_linear[:, 2]):.3f}, AprilTag library corners {np.median(library[:, 2]):.3f}")
    assert np.all(as_linear[:, 2] > 1.0) and np.all(library[:, 2] > 1.0)  # too far, every scene
    assert np.median(as_linear[:, 2]) > 20 * abs(np.median(ours[:, 2]))
    assert np.median(library[:, 0]) > 10 * np.median(ours[:, 0])


@pytest.mark.slow
def test_heavy_blur_and_jpeg_keep_most_of_the_gain() -> None:
    """1.5 px optical blur (half a cell of a 27 px tag at 3.5 m) and JPEG at 80:
    the edge fit's profiles no longer reach flat plateaus on the smallest tags,
    so a range bias returns there (measured 2.2 cm at 3.5 m), but it stays a
    small fraction of the library's own corners' and of the gamma-read fit's."""
    rows = []
    for seed, distance in ((0, 1.2), (3, 2.2), (5, 2.9), (7, 3.5)):
        rig, T, images = pair_scene(seed, distance, jpeg=80, psf_sigma_px=1.5)
        rng_true = np.linalg.norm(T.t)
        rows.append([100 * (np.linalg.norm(solve(rig, images, **kw).t) - rng_true)
                     for kw in ({}, {"gamma": "linear"}, {"refine": "none"})])
    rows = np.array(rows)
    print("\n[1.5 px blur, JPEG 80] range error cm (ours, read as linear, library corners):\n", rows.round(3))
    assert np.all(np.abs(rows[:2, 0]) < 0.1)  # up to 2.2 m: still no bias
    assert np.all(np.abs(rows[:, 0]) < 0.3 * rows[:, 1]) and np.all(np.abs(rows[:, 0]) < 0.3 * rows[:, 2])


# ---------------------------------------------------------------------------
# many tags, partial views: recall against the AprilTag 3 library
# ---------------------------------------------------------------------------


def _library_ids(image: np.ndarray, family: str) -> set[int]:
    peer = peer_detector(family)
    return {d.tag_id for d in peer.detect(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY))}


@pytest.mark.slow
@pytest.mark.parametrize("family, seeds", [("tag36h11", (0, 1, 2, 3)), ("tagStandard41h12", (4, 5))])
def test_recall_at_least_the_librarys_on_many_tags_and_partial_views(family: str, seeds: tuple) -> None:
    found = library = total = 0
    errors = []
    for seed in seeds:
        sc = tag_scene(seed, n_tags=14, family=family, psf_sigma_px=PSF_SIGMA_PX, jpeg_quality=90 if seed % 2 else None)
        res = detect_tags(sc.image, sc.markers)
        lib_ids = _library_ids(sc.image, family)
        ids = {m.tag["id"]: n for n, m in sc.markers.items()}
        assert lib_ids <= set(ids)  # the peer reports nothing that is not there
        ours = {sc.markers[n].tag["id"] for n in res.detections}
        assert lib_ids <= ours, f"seed {seed}: the library found {sorted(lib_ids - ours)}, we did not"
        assert set(res.missing) == set(sc.markers) - set(res.detections)
        assert all(res.missing_reasons[n] == "not_found" for n in res.missing)
        found += len(ours)
        library += len(lib_ids)
        total += len(sc.markers)
        for n, d in res.detections.items():
            e = np.linalg.norm(d.corners - sc.corners[n], axis=1)
            assert e.max() < 1.5, (seed, n, e)  # partial views too: never a wrong corner
            if sc.in_frame[n] and not sc.occluded[n]:
                errors.append(e)
    errors = np.concatenate(errors)
    print(f"\n[{family}] found {found}, AprilTag library {library}, placed {total}; corner error px "
          f"median {np.median(errors):.3f}, p90 {np.percentile(errors, 90):.3f}")
    assert np.median(errors) <= 0.1


def test_new_families_end_to_end() -> None:
    """tagStandard41h12 and tagStandard52h13 (reversed border: the corners are
    those of the inner edge of the black ring) found and localized from renders."""
    for family in ("tagStandard41h12", "tagStandard52h13"):
        rig, T, images = pair_scene(3, 2.0, family=family)
        est = solve(rig, images)
        t_err = 100 * np.linalg.norm(est.t - T.t)
        r_err = rotation_error_deg(est.R, T.R)
        print(f"\n[{family}] pose error {t_err:.3f} cm, {r_err:.3f} deg")
        assert t_err < 0.3 and r_err < 0.1
        res = detect_tags(images["q"], rig.robot("p").markers)
        d = res.detections["TP"]
        assert d.info["library"] == "apriltag" and d.info["refine"] == "edges" and d.info["family"] == family


# ---------------------------------------------------------------------------
# quality, reasons, options, bad input
# ---------------------------------------------------------------------------


def test_quality_figures_and_missing_reasons() -> None:
    rig, T, images = pose_scenes()[0]
    markers = dict(rig.robot("p").markers)
    markers["absent"] = Marker("absent", "p", np.zeros(3), tag={"family": "tag36h11", "id": 99, "size": 0.1})
    res = detect_tags(images["q"], markers)
    d = res.detections["TP"]
    assert 0 < d.score <= 1 and d.score == min(1.0, d.info["decision_margin"] / 100)
    assert d.info["hamming"] == 0 and 0 < d.info["edge_rms_px"] < 0.5
    assert res.missing == ["absent"] and res.missing_reasons == {"absent": "not_found"}
    assert res.to_dict()["missing_reasons"] == {"absent": "not_found"}
    # The OpenCV path has no decision margin: full score, same reasons.
    ocv = detect_tags(images["q"], markers, backend="opencv")
    assert ocv.detections["TP"].score == 1.0 and ocv.missing_reasons == {"absent": "not_found"}
    np.testing.assert_allclose(ocv.detections["TP"].corners, d.corners, atol=0.05)  # same corner order
    # Merging: a marker found elsewhere loses its reason.
    other = DetectionResult(detections={"absent": d}, missing=[])
    res.merge(other)
    assert res.missing == [] and res.missing_reasons == {}


def test_linearize_matches_the_srgb_curve() -> None:
    v = np.arange(256, dtype=np.uint8).reshape(16, 16)
    np.testing.assert_allclose(linearize(v), 255 * srgb_to_linear(v / 255.0), rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(linearize(v, "linear"), v.astype(np.float32))
    np.testing.assert_allclose(linearize(v, 2.2), 255 * (v / 255.0) ** 2.2, rtol=1e-5, atol=1e-4)


def test_family_names_and_bad_input() -> None:
    assert canonical_family("tagstandard41h12") == "tagStandard41h12"
    assert canonical_family("Standard52h13") == "tagStandard52h13"
    assert canonical_family("apriltag_circle21h7") == "tagCircle21h7"
    with pytest.raises(RigError, match="no tagStandard41h12 dictionary"):
        aruco_dictionary("tagStandard41h12")
    image = np.zeros((60, 80, 3), np.uint8)
    big = Marker("B", "p", np.zeros(3), tag={"family": "tagStandard41h12", "id": 2115, "size": 0.1})
    with pytest.raises(RigError, match="ids 0..2114"):
        detect_tags(image, {"B": big})
    m41 = {"A": Marker("A", "p", np.zeros(3), tag={"family": "tagStandard41h12", "id": 1, "size": 0.1})}
    with pytest.raises(InputError, match="AprilTag library only"):
        detect_tags(image, m41, refine="subpix")
    with pytest.raises(InputError, match="backend"):
        detect_tags(image, m41, backend="magic")
    with pytest.raises(InputError, match="not decode"):
        detect_tags(image, {"C": Marker("C", "p", np.zeros(3), tag={"family": "4x4_50", "id": 1, "size": 0.1})},
                    backend="apriltag")
    with pytest.raises(InputError, match="neither an AprilTag detector setting"):
        detect_tags(image, m41, params={"magic": 1})
    with pytest.raises(InputError, match="quad_decimate"):
        detect_tags(image, m41, params={"quad_decimate": -1})
    with pytest.raises(InputError, match="gamma"):
        detect_tags(image, m41, gamma="sRGB-ish")
    assert detect_tags(image, m41).missing_reasons == {"A": "not_found"}


# ---------------------------------------------------------------------------
# the edge-fit stage on drawn quadrilaterals (independent of the renderer)
# ---------------------------------------------------------------------------


def _encoded_square(corners: np.ndarray, blur: float, shape=(110, 150), ss: int = 16) -> np.ndarray:
    """A dark quadrilateral (albedo 0.03) on white (0.8): area coverage by
    supersampling (edges quantised to 1/ss px), Gaussian blur in linear light,
    then sRGB-encoded to uint8."""
    # Sub-sample centres in image pixels (pixel centres at integers), tested
    # against each side of the convex quadrilateral (cv2.fillPoly would add
    # its right and bottom boundary rows).
    v, u = np.mgrid[0:shape[0] * ss, 0:shape[1] * ss].astype(np.float32)
    u, v = (u + 0.5) / ss - 0.5, (v + 0.5) / ss - 0.5
    inside = np.ones(u.shape, bool)
    for k in range(4):
        a, b = corners[k], corners[(k + 1) % 4]
        inside &= (b[0] - a[0]) * (v - a[1]) - (b[1] - a[1]) * (u - a[0]) >= 0  # clockwise in image axes
    cover = cv2.resize(inside.astype(np.float32), (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    lin = 0.8 - 0.77 * cover
    if blur > 0:
        lin = cv2.GaussianBlur(lin, (0, 0), blur)
    srgb = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * np.clip(lin, 0, 1) ** (1 / 2.4) - 0.055)
    return np.clip(np.round(255 * srgb), 0, 255).astype(np.uint8)


@settings(max_examples=8, deadline=None)
@given(st.floats(50, 100), st.floats(45, 65), st.floats(40, 60), st.floats(-0.6, 0.6), st.floats(0.5, 1.3),
       st.integers(0, 2**31 - 1))
def test_edge_fit_on_srgb_blurred_squares(cx: float, cy: float, side: float, angle: float, blur: float,
                                          seed: int) -> None:
    """Linearised, the fit recovers the corners of a blurred sRGB square; read as
    linear, the same edges move towards the dark side (the square shrinks)."""
    from mutloc.detect.tag_edges import refine_edges

    rng = np.random.default_rng(seed)
    c, s = np.cos(angle), np.sin(angle)
    local = 0.5 * side * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float)
    truth = np.array([cx, cy]) + local @ np.array([[c, s], [-s, c]])
    img = _encoded_square(truth, blur)
    start = truth + rng.uniform(-0.7, 0.7, truth.shape)  # a detector's rough corners
    fit = refine_edges(linearize(img, "srgb"), start, 8, None)
    assert fit is not None
    assert np.abs(fit[0] - truth).max() < 0.06  # the drawing's own quantisation is 1/32 px
    naive = refine_edges(linearize(img, "linear"), start, 8, None)
    assert naive is not None
    centre = truth.mean(axis=0)
    inward = np.linalg.norm(truth - centre, axis=1) - np.linalg.norm(naive[0] - centre, axis=1)
    assert inward.mean() > 0.1 * blur  # the gamma-encoded edges sit inside the true square
