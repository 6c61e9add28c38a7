"""The Bundler baseline: COLMAP structure from motion (mutloc.baselines.sfm) on
rendered views of a textured room, checked against the rendered truth."""

from __future__ import annotations

import numpy as np
import pycolmap
import pytest

from mutloc.baselines.sfm import ScaleReference, SfmResult, SfmScene, colmap_camera_params
from mutloc.core.camera import Camera
from mutloc.core.geometry import rotation_error_deg
from mutloc.core.pose import Pose
from mutloc.errors import InputError, NoSolutionError
from mutloc.sim.render import surface_distance
from mutloc.sim.walkaround import render_view, walkaround_poses
from mutloc.sim.world import Light, Room, World



W, H, F = 640, 360, 500.0
CAM = Camera(np.array([[F, 0.0, (W - 1) / 2], [0.0, F, (H - 1) / 2], [0.0, 0.0, 1.0]]), [-0.05, 0.01, 0, 0, 0], (W, H))


def _room_scene(n: int = 16, seed: int = 3):
    room = Room(center=(0.0, 0.0), size=(6.0, 6.0), seed=seed, floor_decals=1.5)
    world = World(robots={}, room=room, light=Light(position=(0.5, -0.5, 2.4)))
    poses = walkaround_poses((0.0, 0.0), n, radius=1.6, height=0.9, room=room)
    images = {f"v{j:02d}": render_view(world, CAM, T, seed=j, noise_sigma=2.0) for j, T in enumerate(poses)}
    return world, dict(zip(images, poses)), images


@pytest.fixture(scope="module")
def room_sfm():
    world, truth, images = _room_scene()
    with SfmScene(images, CAM, seed=0, num_threads=2) as scene:
        res = scene.reconstruct(ScaleReference("v00", "v08", float(np.linalg.norm(truth["v00"].t - truth["v08"].t))))
        # The same triangulator from the *true* poses: the points must lie on the room's surface.
        X, err, length, colour = scene.triangulate(truth)
    return world, truth, res, (X, err, length, colour)


def test_colmap_camera_matches_mutloc_projection_half_pixel_shifted():
    """COLMAP's pixel origin is the top-left corner, mutloc's the centre of the top-left pixel."""
    model, params = colmap_camera_params(CAM)
    cam = pycolmap.Camera(model=model, width=W, height=H, params=params)
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(-0.5, 0.5, (50, 2)), rng.uniform(1.0, 3.0, 50)])
    uv_colmap = cam.img_from_cam(X)
    np.testing.assert_allclose(uv_colmap, CAM.project(X) + 0.5, atol=1e-6)


def test_full_opencv_model_when_the_rational_terms_are_used():
    cam = Camera(CAM.K, [0.1, 0.0, 0.0, 0.0, 0.01, 0.02, 0.0, 0.0], (W, H))
    model, params = colmap_camera_params(cam)
    assert model == "FULL_OPENCV" and len(params) == 12 and params[8] == pytest.approx(0.01)


def test_sfm_registers_a_walk_around_and_its_poses_match_the_truth(room_sfm):
    _world, truth, res, _ = room_sfm
    # Measured (seed 0): all 16 views registered.
    assert len(res.poses) >= 15 and res.images == 16
    assert res.mean_reprojection_px < 1.0
    names = sorted(res.poses)
    ref = names[0]
    t_err, r_err = [], []
    for n in names[1:]:
        est = res.relative(n, ref)
        true = truth[ref].inverse() @ truth[n]
        t_err.append(float(np.linalg.norm(est.t - true.t)))
        r_err.append(float(rotation_error_deg(est.R, true.R)))
    # Measured (seed 0): median 0.9 cm / 0.18 deg, largest 2.0 cm / 0.28 deg; bounds with margin.
    assert np.median(t_err) < 0.03 and max(t_err) < 0.06
    assert np.median(r_err) < 0.4 and max(r_err) < 0.8


def test_scaled_result_has_the_reference_distance(room_sfm):
    _world, truth, res, _ = room_sfm
    d = float(np.linalg.norm(res.poses["v00"].t - res.poses["v08"].t))
    assert d == pytest.approx(float(np.linalg.norm(truth["v00"].t - truth["v08"].t)), rel=1e-9)
    half = res.scaled(ScaleReference("v00", "v08", d / 2))
    assert float(np.linalg.norm(half.poses["v00"].t - half.poses["v08"].t)) == pytest.approx(d / 2)
    assert half.scale == pytest.approx(res.scale / 2)


def test_triangulation_from_the_true_poses_lies_on_the_room_surface(room_sfm):
    world, _truth, _res, (X, err, length, colour) = room_sfm
    assert len(X) > 200 and np.all(length >= 2) and colour.shape == (len(X), 3)
    d = surface_distance(world, X)
    # Measured (seed 0): 1346 points, median 4 mm, 98% within 5 cm of the exact surface.
    assert np.median(d) < 0.01
    assert np.mean(d < 0.05) > 0.9


def test_unregistered_image_and_bad_input_are_typed_errors():
    res = SfmResult(poses={"a": Pose.identity()}, images=2, points=0)
    with pytest.raises(NoSolutionError, match="'b' was not registered"):
        res.relative("a", "b")
    with pytest.raises(NoSolutionError):
        res.scaled(ScaleReference("a", "b", 1.0))
    img = np.zeros((H, W, 3), np.uint8)
    with pytest.raises(InputError):
        SfmScene({"a": img}, CAM)
    with pytest.raises(InputError, match="is 320x"):
        SfmScene({"a": img, "b": img[:, :320]}, CAM)
    with pytest.raises(InputError, match="plain file name"):
        SfmScene({"a/b": img, "c": img}, CAM)


def test_images_that_share_nothing_give_no_model():
    rng = np.random.default_rng(0)
    images = {n: rng.integers(0, 256, (H, W, 3), dtype=np.uint8) for n in ("a", "b", "c")}
    with SfmScene(images, CAM, seed=0) as scene:
        with pytest.raises(NoSolutionError):
            scene.reconstruct()


def test_walkaround_views_stay_in_the_room_and_look_at_the_centre():
    room = Room(center=(1.0, -0.5), size=(6.0, 4.0))
    centre = np.array([1.5, -0.5])
    poses = walkaround_poses(centre, 12, radius=2.5, height=0.9, pitch_deg=0.0, room=room, margin=0.4)
    assert len(poses) == 12
    for T in poses:
        assert np.all(np.abs(T.t[:2] - np.array(room.center)) <= np.array(room.size) / 2 - 0.4 + 1e-9)
        assert T.t[2] == pytest.approx(0.9)
        fwd = T.R[:, 2]  # the optical axis in the world points at the centre, level
        to_c = centre - T.t[:2]
        assert fwd[2] == pytest.approx(0.0, abs=1e-12)
        assert np.dot(fwd[:2], to_c / np.linalg.norm(to_c)) == pytest.approx(1.0, abs=1e-9)
    with pytest.raises(InputError):
        walkaround_poses(centre, 0)
