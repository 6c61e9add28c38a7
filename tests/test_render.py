"""The built-in renderer against ground truth that does not come from it.

Every expected pixel is computed here with ``cv2.projectPoints`` from the
pose the world was *built* with (not from the renderer's own helpers), and
every expected silhouette from the exact geometry of a sphere's tangent cone.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

from mutloc.core.geometry import so3_exp
from mutloc.core.pose import Pose
from mutloc.core.rig import Marker, Rig, Robot
from mutloc.errors import InputError, ObservationError, RigError
from mutloc.sim.render import (
    linear_to_srgb,
    moving_world,
    project_markers,
    relative_pose,
    render,
    srgb_to_linear,
    two_robot_world,
)
from mutloc.sim.synthetic import facing_pose
from mutloc.sim.world import Light, Sensor, light_is_on, standard_rig

RADIUS = 0.03  # the standard rig's balls


def project(cam, X: np.ndarray) -> np.ndarray:
    """Independent projection: OpenCV's."""
    uv, _ = cv2.projectPoints(np.asarray(X, float).reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K,
                              cam.dist[: max(cam.n_dist, 5)])
    return uv.reshape(-1, 2)


def flat(world):
    """Unshaded (ambient only), no bloom: a pixel's linear value is coverage x albedo."""
    world.light = Light(intensity=0.0, ambient=1.0)
    world.sensor = Sensor(bloom_strength=0.0)
    return world


def sphere_silhouette(C: np.ndarray, r: float, cam, n: int = 4000) -> tuple[np.ndarray, float]:
    """Area centroid and area (px^2) of the exact image of a sphere: the tangent
    cone's contact circle projected with cv2.projectPoints (distortion included),
    shoelace formulas."""
    d = np.linalg.norm(C)
    a = C / d
    e1 = np.cross(a, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    centre = a * (d - r * r / d)
    rho = r * np.sqrt(d * d - r * r) / d
    ph = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    uv = project(cam, centre + rho * (np.cos(ph)[:, None] * e1 + np.sin(ph)[:, None] * e2))
    x, y = uv[:, 0], uv[:, 1]
    x1, y1 = np.roll(x, -1), np.roll(y, -1)
    cr = x * y1 - x1 * y
    area = cr.sum() / 2
    return np.array([((x + x1) * cr).sum(), ((y + y1) * cr).sum()]) / (6 * area), float(abs(area))


def ellipse_centre_pinhole(C: np.ndarray, r: float, K: np.ndarray) -> np.ndarray:
    """Analytic centre of a sphere's image under an undistorted pinhole with fx = fy:
    radially at f * (tan(theta + alpha) + tan(theta - alpha)) / 2, sin(alpha) = r / |C|."""
    theta = np.arccos(C[2] / np.linalg.norm(C))
    alpha = np.arcsin(r / np.linalg.norm(C))
    rho = 0.5 * (np.tan(theta + alpha) + np.tan(theta - alpha))
    direction = C[:2] / np.linalg.norm(C[:2])
    return K[:2, 2] + K[0, 0] * rho * direction


def coverage_centroid(img: np.ndarray, rgb: tuple[int, int, int], uv: np.ndarray, half: float) -> tuple[np.ndarray, float]:
    """Centroid of a ball's coverage in a flat render on black: alpha = linear(pixel) / linear(colour)
    in the colour's strongest channel, over a window around ``uv``."""
    bgr = np.array(rgb[::-1], float)
    ch = int(np.argmax(bgr))
    u0, u1 = int(uv[0] - half), int(uv[0] + half) + 1
    v0, v1 = int(uv[1] - half), int(uv[1] + half) + 1
    patch = img[v0:v1, u0:u1, ch] / 255.0
    alpha = srgb_to_linear(patch) / srgb_to_linear(bgr[ch] / 255.0)
    vv, uu = np.mgrid[v0:v1, u0:u1]
    return np.array([(alpha * uu).sum(), (alpha * vv).sum()]) / alpha.sum(), float(alpha.sum())


POSES = {
    "1m": facing_pose(1.0, yaw_p=np.radians(15), yaw_q=np.radians(20), lateral=0.2, tilt=np.radians([3, 0, 2])),
    "2m": facing_pose(2.0, yaw_p=np.radians(-10), yaw_q=np.radians(-12), lateral=-0.3, tilt=np.radians([-2, 1, 0])),
    "3m": facing_pose(3.0, yaw_p=np.radians(5), yaw_q=np.radians(8), lateral=0.5, tilt=np.radians([0, 0, 4])),
}


# ---------------------------------------------------------------------------
# geometry: projections and poses
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("k1", [0.0, -0.3])
@pytest.mark.parametrize("pose", list(POSES))
def test_project_markers_equals_opencv(k1: float, pose: str) -> None:
    rig = standard_rig("balls", k1=k1)
    T_qp = POSES[pose]
    world = two_robot_world(rig, T_qp)
    for observer, other, T in (("q", "p", T_qp), ("p", "q", T_qp.inverse())):
        got = project_markers(world, observer)
        names = list(rig.robot(other).markers)
        want = project(rig.robot(observer).camera, T.apply(rig.robot(other).marker_positions(names)))
        assert sorted(got) == sorted(names)
        for name, uv in zip(names, want):
            np.testing.assert_allclose(got[name], uv, atol=1e-6)


def test_relative_pose_is_the_pose_the_world_was_built_with() -> None:
    rig = standard_rig("balls")
    T_qp = POSES["2m"]
    world = two_robot_world(rig, T_qp)
    est = relative_pose(world, "p", "q")
    np.testing.assert_allclose(est.R, T_qp.R, atol=1e-12)
    np.testing.assert_allclose(est.t, T_qp.t, atol=1e-12)
    inv = relative_pose(world, "q", "p")
    np.testing.assert_allclose((inv @ est).as_matrix(), np.eye(4), atol=1e-12)


def test_moving_world_follows_its_path() -> None:
    rig = standard_rig("balls")

    def path(t: float) -> Pose:
        return facing_pose(1.5 + 0.5 * t, yaw_p=0.2 * t, lateral=0.1 * t)

    world = moving_world(rig, path, room=False)
    for t in (0.0, 0.4, 1.3):
        T = relative_pose(world, "p", "q", t)
        np.testing.assert_allclose(T.as_matrix(), path(t).as_matrix(), atol=1e-12)
        got = project_markers(world, "q", t)
        want = project(rig.robot("q").camera, path(t).apply(rig.robot("p").marker_positions(["M3", "M4"])))
        np.testing.assert_allclose([got["M3"], got["M4"]], want, atol=1e-6)
    # The default path keeps p in q's view and q in p's, and it moves.
    world = moving_world(rig)
    poses = [relative_pose(world, "p", "q", t) for t in np.linspace(0, 8, 17)]
    assert all(len(project_markers(world, r, t)) == 2 for t in np.linspace(0, 8, 17) for r in ("p", "q"))
    assert max(np.linalg.norm(a.t - poses[0].t) for a in poses) > 0.3


def test_varied_world_draws_motion_and_blinks_per_seed() -> None:
    from mutloc.sim.tracking import varied_world

    base = standard_rig("lights")
    times = np.linspace(0.0, 3.0, 31)
    # Without vary only the room changes: the motion is moving_world's.
    _, fixed = varied_world(base, 5, vary=False)
    plain = moving_world(base, seed=5)
    for t in times[::10]:
        np.testing.assert_allclose(relative_pose(fixed, "p", "q", t).as_matrix(),
                                   relative_pose(plain, "p", "q", t).as_matrix(), atol=1e-12)
    runs = {s: varied_world(base, s, distance=2.0) for s in (0, 1, 2)}
    again = varied_world(base, 1, distance=2.0)[1]
    for t in times[::10]:  # reproducible
        np.testing.assert_allclose(relative_pose(again, "p", "q", t).as_matrix(),
                                   relative_pose(runs[1][1], "p", "q", t).as_matrix(), atol=1e-12)
    tracks, blinks = [], []
    for rig, world in runs.values():
        xyz = np.array([relative_pose(world, "p", "q", t).t for t in times])
        # p stays within its path's envelope: sway <= 0.4 d, in-and-out 15 %, at camera height.
        assert np.all(np.abs(xyz[:, 0]) <= 0.4 * 2.0 + 1e-9) and np.allclose(xyz[:, 1], 0.0, atol=1e-9)
        assert np.all((xyz[:, 2] >= 0.85 * 2.0 - 1e-9) & (xyz[:, 2] <= 1.15 * 2.0 + 1e-9))
        tracks.append(xyz)
        m = rig.marker("M1")
        on = [light_is_on(m, t) for t in times]
        ph = m.extra["phase"]
        assert on == [((m.blink_hz * t + ph) % 1.0) < 0.5 for t in times]
        blinks.append(on)
    # Different seeds: different motion and different blink phases.
    for a in range(3):
        for b in range(a + 1, 3):
            assert np.max(np.linalg.norm(tracks[a] - tracks[b], axis=1)) > 0.1
    assert len({tuple(b) for b in blinks}) > 1


def test_project_markers_skips_points_folded_back_by_distortion() -> None:
    """With k1 = -0.3 a point 63 degrees off-axis lands *inside* the image by
    OpenCV's formula (the distortion folds over), but no camera would see it there."""
    rig = standard_rig("balls", k1=-0.3)
    cam = rig.robot("q").camera
    X_q = np.array([2.0, 0.0, 1.0])  # normalized radius 2: r_d = 2 (1 - 0.3 * 4) < 0
    uv = project(cam, X_q)[0]
    assert cam.in_image(uv)  # the trap is real
    # Place p so that its marker M3 is at X_q in q's frame.
    T_qp = Pose(so3_exp([0, np.pi, 0]), X_q - so3_exp([0, np.pi, 0]) @ rig.robot("p").markers["M3"].position)
    world = two_robot_world(rig, T_qp, room=False)
    assert "M3" not in project_markers(world, "q")


def test_occlusion_check_hides_a_tag_seen_from_behind() -> None:
    rig = standard_rig("tags")
    front = facing_pose(1.5)
    world = two_robot_world(rig, front)
    assert sorted(project_markers(world, "q", check_occlusion=True)) == ["M3", "M4"]
    # Turn p around: its tags now face away from q (q sees the back of the cards).
    back = Pose(np.eye(3), [0.0, 0.0, 1.5])
    world = two_robot_world(rig, back)
    assert sorted(project_markers(world, "q")) == ["M3", "M4"]
    assert project_markers(world, "q", check_occlusion=True) == {}


# ---------------------------------------------------------------------------
# pixels: silhouettes, tags, lights, cylinders
# ---------------------------------------------------------------------------


def test_sphere_image_centre_reference_is_right() -> None:
    """The test's own ground truth: the shoelace centroid of the projected
    contact circle equals the analytic ellipse centre for a pinhole camera."""
    cam = standard_rig("balls").robot("q").camera
    for C in ([0.4, -0.2, 1.0], [-0.9, 0.5, 2.0], [0.1, 0.05, 3.0]):
        C = np.array(C)
        np.testing.assert_allclose(sphere_silhouette(C, RADIUS, cam)[0],
                                   ellipse_centre_pinhole(C, RADIUS, cam.K), atol=2e-3)


@pytest.mark.parametrize("k1", [0.0, -0.3])
@pytest.mark.parametrize("pose", list(POSES))
def test_ball_silhouette_centroid_is_subpixel_accurate(k1: float, pose: str) -> None:
    rig = standard_rig("balls", k1=k1)
    T_qp = POSES[pose]
    world = flat(two_robot_world(rig, T_qp, room=False, body=False))
    for observer, other, T in (("q", "p", T_qp), ("p", "q", T_qp.inverse())):
        img = render(world, observer)
        cam = rig.robot(observer).camera
        for m in rig.robot(other).markers.values():
            C = T.apply(m.position)
            true_uv = project(cam, C)[0]
            silhouette, sil_area = sphere_silhouette(C, RADIUS, cam)
            bias = np.linalg.norm(silhouette - true_uv)  # sphere-to-ellipse bias, exact
            assert bias < 0.3, (observer, m.name, bias)
            half = cam.K[0, 0] * RADIUS / np.linalg.norm(C) * 1.6 + 4
            got, area = coverage_centroid(img, m.color, true_uv, half)
            # The silhouette's area is right (to 0.5 %), and its centroid to 0.05 px.
            assert area == pytest.approx(sil_area, rel=0.005)
            assert np.linalg.norm(got - silhouette) < 0.05, (observer, m.name, got, silhouette)
            assert np.linalg.norm(got - true_uv) < bias + 0.05


def test_shaded_ball_in_the_room_is_where_it_should_be() -> None:
    """Default lighting, textured room, sensor noise: thresholding the ball's
    hue still puts its centre within a pixel of the true projection."""
    rig = standard_rig("balls")
    T_qp = POSES["2m"]
    world = two_robot_world(rig, T_qp)
    img = render(world, "q", noise_sigma=2.0, seed=3)
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    cam = rig.robot("q").camera
    for m, hue in (("M3", 0), ("M4", 60)):  # red, green (OpenCV hue is degrees / 2)
        true_uv = project(cam, T_qp.apply(rig.robot("p").markers[m].position))[0]
        dh = np.minimum(np.abs(hsv[..., 0].astype(int) - hue), 180 - np.abs(hsv[..., 0].astype(int) - hue))
        mask = (dh < 8) & (hsv[..., 1] > 150) & (hsv[..., 2] > 40)
        vv, uu = np.mgrid[0:img.shape[0], 0:img.shape[1]]
        near = mask & ((uu - true_uv[0]) ** 2 + (vv - true_uv[1]) ** 2 < 20 ** 2)
        assert near.sum() > 0.8 * np.pi * 12 ** 2 * 0.8
        centre = np.array([uu[near].mean(), vv[near].mean()])
        assert np.linalg.norm(centre - true_uv) < 1.0


@pytest.mark.parametrize("k1", [0.0, -0.3])
def test_tag_found_by_opencv_at_the_projected_corners(k1: float) -> None:
    rig = standard_rig("tags", k1=k1)
    T_qp = facing_pose(1.2, yaw_p=np.radians(20), yaw_q=np.radians(-10), lateral=0.1, tilt=np.radians([5, 0, 3]))
    world = two_robot_world(rig, T_qp)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11), params)
    for observer, other, T in (("q", "p", T_qp), ("p", "q", T_qp.inverse())):
        img = render(world, observer)
        corners, ids, _ = detector.detectMarkers(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
        found = {int(i): c.reshape(4, 2) for i, c in zip(ids.ravel(), corners)}
        cam = rig.robot(observer).camera
        for m in rig.robot(other).markers.values():
            # Tag frame of mutloc.detect.tags: x right, y down as printed, z into the tag.
            h = m.tag["size"] / 2
            local = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]])
            want = project(cam, T.apply(m.position + local @ so3_exp(m.tag["rotation"]).T))
            got = found[m.tag["id"]]
            err = got - want
            # OpenCV's sub-pixel corners lean a few tenths of a pixel into the
            # tag (a bias of the detector); the tag itself must not be displaced.
            assert np.abs(err).max() < 0.6, (observer, m.name, err)
            assert np.linalg.norm(err.mean(axis=0)) < 0.15, (observer, m.name, err)


def test_tag_edges_sit_exactly_on_the_projected_square() -> None:
    """Detector-free check of the tag texture mapping: across a vertical edge of
    the black square, the white fraction of each pixel (linear light, flat
    lighting) adds up to the edge's sub-pixel position."""
    rig = standard_rig("tags")
    cam = rig.robot("q").camera
    black, white = srgb_to_linear(20 / 255), srgb_to_linear(235 / 255)  # the printed albedos
    for dx in (0.0, 0.0007, 0.0013):
        T_qp = Pose(so3_exp([0, np.pi, 0]), [0.01 + dx, 0.003, 1.3])  # p square on to q
        world = flat(two_robot_world(rig, T_qp, room=False, body=False))
        lin = srgb_to_linear(render(world, "q")[..., 1] / 255.0)
        m = rig.robot("p").markers["M3"]
        h = m.tag["size"] / 2
        local = np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]])
        uv = project(cam, T_qp.apply(m.position + local @ so3_exp(m.tag["rotation"]).T))
        edges = {"left": uv[:, 0].min(), "right": uv[:, 0].max()}
        v_mid = int(round(uv[:, 1].mean()))
        for side, u_edge in edges.items():
            est = []
            for row in range(v_mid - 3, v_mid + 4):
                u0 = int(np.floor(u_edge)) - 3
                frac_white = (lin[row, u0:u0 + 7] - black) / (white - black)
                if side == "left":  # white margin, then black border
                    est.append(u0 - 0.5 + frac_white.sum())
                else:  # black border, then white margin
                    est.append(u0 - 0.5 + (1 - frac_white).sum())
            assert abs(np.mean(est) - u_edge) < 0.05, (dx, side, np.mean(est), u_edge)


def test_lights_blink_as_a_square_wave() -> None:
    rig = standard_rig("lights")
    # Give one light a phase, to check it is honoured.
    q = rig.robot("q")
    m1 = q.markers["M1"]
    shifted = Marker("M1", "q", m1.position, color=m1.color, blink_hz=m1.blink_hz, extra={**m1.extra, "phase": 0.25})
    rig = Rig({"p": rig.robot("p"), "q": Robot("q", q.camera, {"M1": shifted, "M2": q.markers["M2"]})})
    T_qp = POSES["2m"]
    world = two_robot_world(rig, T_qp)
    for t in (0.03, 0.11, 0.2, 0.26, 0.37, 0.52, 0.61):
        for observer, other in (("q", "p"), ("p", "q")):
            img = render(world, observer, t)
            cam = rig.robot(observer).camera
            T = relative_pose(world, other, observer, t)
            for m in rig.robot(other).markers.values():
                on = ((m.blink_hz * t + m.extra.get("phase", 0.0)) % 1.0) < 0.5  # independent square wave
                assert light_is_on(m, t) == on
                u, v = np.round(project(cam, T.apply(m.position))[0]).astype(int)
                peak = int(img[v - 1:v + 2, u - 1:u + 2].max())
                if on:
                    assert peak == 255, (t, m.name)  # saturated LED
                else:
                    assert peak < 150, (t, m.name, peak)
    # Switching instants: frame times k / fps that land on an edge are stable.
    m = rig.robot("p").markers["M4"]  # 7.5 Hz
    assert [light_is_on(m, k / 30) for k in range(8)] == [True, True, False, False] * 2


def test_cylinder_bands_follow_the_code() -> None:
    rig = standard_rig("cylinders")
    T_qp = facing_pose(1.2, yaw_p=np.radians(30), lateral=0.05)
    world = two_robot_world(rig, T_qp)
    img = cv2.cvtColor(render(world, "q"), cv2.COLOR_BGR2GRAY)
    cam = rig.robot("q").camera
    for m in rig.robot("p").markers.values():
        spec = m.extra["cylinder"]
        r, height, code = spec["radius"], spec["height"], spec["code"]
        c_q = T_qp.apply(m.position)
        up_q = T_qp.R @ np.array([0.0, -1.0, 0.0])  # the robot's -y
        toward = -c_q - (-c_q @ up_q) * up_q  # horizontal direction to q's camera
        toward /= np.linalg.norm(toward)
        for i, bit in enumerate(code):
            s = height / 2 - (i + 0.5) * height / len(code)  # code[0] is the top band
            u, v = np.round(project(cam, c_q + s * up_q + r * toward)[0]).astype(int)
            val = int(img[v, u])
            assert (val < 60) if bit else (val > 90), (m.name, i, bit, val)


# ---------------------------------------------------------------------------
# sensor model, determinism, options, errors
# ---------------------------------------------------------------------------


def test_render_is_deterministic_and_the_noise_is_right() -> None:
    rig = standard_rig("balls")
    world = two_robot_world(rig, POSES["2m"], seed=5)
    a = render(world, "q", noise_sigma=2.0, seed=11)
    b = render(two_robot_world(rig, POSES["2m"], seed=5), "q", noise_sigma=2.0, seed=11)
    assert a.dtype == np.uint8 and a.shape == (540, 960, 3)
    np.testing.assert_array_equal(a, b)
    c = render(world, "q", noise_sigma=2.0, seed=12)
    assert np.any(a != c)
    clean = render(world, "q")
    np.testing.assert_array_equal(clean, render(world, "q"))
    diff = a.astype(float) - clean
    ok = (clean > 10) & (clean < 245)  # away from clipping
    assert abs(diff[ok].mean()) < 0.05
    assert diff[ok].std() == pytest.approx(2.0, rel=0.05)
    # Another room seed gives another room.
    assert np.mean(render(two_robot_world(rig, POSES["2m"], seed=6), "q") != clean) > 0.3


def test_jpeg_and_motion_blur() -> None:
    rig = standard_rig("balls")
    world = flat(two_robot_world(rig, POSES["2m"], room=False, body=False))
    clean = render(world, "q")
    jpg = render(world, "q", jpeg_quality=80)
    assert np.any(jpg != clean)
    mse = np.mean((jpg.astype(float) - clean) ** 2)
    assert 10 * np.log10(255 ** 2 / mse) > 30
    # A symmetric linear blur spreads the ball along u but keeps its centroid.
    blurred = render(world, "q", blur_px=6.0)
    cam = rig.robot("q").camera
    m = rig.robot("p").markers["M3"]
    uv = project(cam, POSES["2m"].apply(m.position))[0]
    c0, _ = coverage_centroid(clean, m.color, uv, 20)
    c1, _ = coverage_centroid(blurred, m.color, uv, 20)
    assert np.linalg.norm(c1 - c0) < 0.05
    width0 = np.sum(clean[int(round(uv[1])), :, 2] > 20)
    width1 = np.sum(blurred[int(round(uv[1])), :, 2] > 20)
    assert width1 >= width0 + 4


def test_exposure_and_gain_scale_linear_light() -> None:
    rig = standard_rig("balls")
    world = flat(two_robot_world(rig, POSES["2m"], room=False, body=False))
    base = render(world, "q").astype(float)
    world.sensor = Sensor(bloom_strength=0.0, exposure=0.5)
    half = render(world, "q").astype(float)
    sel = base > 60
    np.testing.assert_allclose(linear_to_srgb(0.5 * srgb_to_linear(base[sel] / 255)) * 255, half[sel], atol=1.01)


def test_bad_input_raises_typed_errors() -> None:
    rig = standard_rig("balls")
    world = two_robot_world(rig, POSES["2m"], room=False)
    with pytest.raises(ObservationError):
        render(world, "nobody")
    with pytest.raises(InputError):
        render(world, "q", noise_sigma=-1)
    with pytest.raises(InputError):
        render(world, "q", jpeg_quality=0)
    with pytest.raises(InputError):
        render(world, "q", t=float("nan"))
    bad = Rig({"p": Robot("p", rig.robot("p").camera, {"X": Marker("X", "p", np.zeros(3),
                                                                      extra={"cylinder": {"radius": 0.03}})}),
               "q": rig.robot("q")})
    with pytest.raises(RigError, match="cylinder"):
        render(two_robot_world(bad, POSES["2m"], room=False), "q")
    with pytest.raises(InputError, match="marker kind"):
        standard_rig("nonsense")


def test_render_time() -> None:
    """Reports the time of a 960x540 frame in the textured room (no assertion)."""
    rig = standard_rig("balls")
    world = two_robot_world(rig, POSES["2m"])
    render(world, "q")  # JIT, bearings, textures
    times = []
    for _ in range(5):
        t0 = time.process_time()
        render(world, "q")
        times.append(time.process_time() - t0)
    print(f"\nrender 960x540 (room, 2 robots, balls): best {min(times) * 1e3:.0f} ms, "
          f"median {np.median(times) * 1e3:.0f} ms CPU")
