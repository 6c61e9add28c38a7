"""Rig files for robots with several cameras, any lens (SPEC "Robots with
several cameras, any lens"): ``cameras:`` (inline, camera files, poses),
lens models in ``camera:`` and in calibration files, Kalibr camera chains,
save/load round trips and the one-line errors.  Truths are built here, by
hand (rotations from axis and angle, chains from known poses)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from mutloc.core.camera import Camera
from mutloc.core.lenses import FisheyeCamera, OmniCamera
from mutloc.errors import FileFormatError, RigError
from mutloc.io import load_camera_file, load_rig, save_rig
from mutloc.io.kalibr import load_kalibr_camchain

K_PIN = [[800.0, 0.0, 479.5], [0.0, 800.0, 269.5], [0.0, 0.0, 1.0]]
K_FISH = [[290.0, 0.0, 639.5], [0.0, 290.0, 399.5], [0.0, 0.0, 1.0]]
D_FISH = [0.012, -0.004, 0.0006, -0.0001]
# camera optical frame (x right, y down, z forward) in a base_link (x forward, y left, z up)
R_OPTICAL_IN_BASE = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def rot(axis, deg) -> np.ndarray:
    """Rodrigues' formula, written out here (not the library's)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    th = math.radians(deg)
    A = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(th) * A + (1 - math.cos(th)) * A @ A


def hom(R, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def body_rig(cameras, markers=None) -> dict:
    return {"robots": {
        "p": {"cameras": cameras,
              "markers": markers or {"M1": {"position": [0.0, 0.10, 0.45]}, "M2": {"position": [0.0, -0.10, 0.45]}}},
        "q": {"camera": {"K": K_PIN}, "markers": {"M3": {"position": [0.1, 0, 0]}, "M4": {"position": [-0.1, 0, 0]}}},
    }}


def write(path: Path, data) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data, sort_keys=False))
    return path


def assert_one_line(exc_info, *words):
    msg = str(exc_info.value)
    assert "\n" not in msg, msg
    for w in words:
        assert w in msg, (w, msg)


# ---------------------------------------------------------------------------
# cameras: inline, poses
# ---------------------------------------------------------------------------


def test_inline_cameras_with_lens_models_and_poses(tmp_path):
    front = {"model": "fisheye", "K": K_FISH, "dist": D_FISH, "size": [1280, 800],
             "pose": {"t": [0.12, 0.0, 0.30], "quaternion_xyzw": [-0.5, 0.5, -0.5, 0.5]}}
    R_back = rot([0, 0, 1], 180) @ R_OPTICAL_IN_BASE  # looking backwards
    back = {"K": K_PIN, "dist": [0.1, -0.02, 0.001, 0.0], "pose": {"R": R_back.tolist(), "t": [-0.1, 0, 0.3]}}
    side = {"model": "omni", "K": K_PIN, "dist": [0.01, 0.0, 0.0, 0.0], "xi": 0.9,
            "pose": {"rotation": [0.0, 0.0, math.pi / 2], "t": [0, 0.2, 0.3]}}
    top = {"K": K_PIN}
    rig = load_rig(write(tmp_path / "rig.yaml", body_rig({"front": front, "back": back, "side": side, "top": top})))
    p = rig.robots["p"]
    assert p.is_body and p.camera is None and list(p.cameras) == ["front", "back", "side", "top"]

    m = rig.mount("p/front")
    assert isinstance(m.camera, FisheyeCamera) and m.camera.model == "fisheye"
    np.testing.assert_array_equal(m.camera.K, K_FISH)
    np.testing.assert_array_equal(m.camera.dist, D_FISH)
    assert m.camera.size == (1280, 800)
    # the SPEC's quaternion is the optical frame in a base_link: camera z (forward) is the robot's x
    np.testing.assert_allclose(m.pose.R, R_OPTICAL_IN_BASE, atol=1e-12)
    np.testing.assert_allclose(m.pose.apply([0, 0, 1.0]), [1.12, 0.0, 0.30], atol=1e-12)

    m = rig.mount("p/back")
    assert type(m.camera) is Camera and m.camera.model == "pinhole"
    np.testing.assert_allclose(m.pose.apply([0, 0, 1.0]), [-1.1, 0.0, 0.3], atol=1e-12)

    m = rig.mount("p/side")
    assert isinstance(m.camera, OmniCamera) and m.camera.xi == 0.9
    np.testing.assert_allclose(m.pose.R, rot([0, 0, 1], 90), atol=1e-12)
    np.testing.assert_allclose(m.pose.t, [0, 0.2, 0.3])

    m = rig.mount("p/top")
    np.testing.assert_array_equal(m.pose.R, np.eye(3))
    np.testing.assert_array_equal(m.pose.t, np.zeros(3))
    assert rig.observer_keys() == ["p/front", "p/back", "p/side", "p/top", "q"]
    # markers of a body are in its robot frame, as given
    np.testing.assert_array_equal(p.markers["M1"].position, [0.0, 0.10, 0.45])


def test_pose_rounding_tolerated_and_made_exact(tmp_path):
    q = np.array([-0.5, 0.5, -0.5, 0.5]) * (1 + 4e-7)
    R = np.round(rot([1, 2, 3], 40), 7)  # 7 decimals, as a file may hold
    rig = load_rig(write(tmp_path / "rig.yaml", body_rig({
        "a": {"K": K_PIN, "pose": {"t": [0, 0, 0], "quaternion_xyzw": q.tolist()}},
        "b": {"K": K_PIN, "pose": {"t": [0, 0, 0], "R": R.tolist()}}})))
    for c, truth in (("a", R_OPTICAL_IN_BASE), ("b", rot([1, 2, 3], 40))):
        Rl = rig.robots["p"].cameras[c].pose.R
        np.testing.assert_allclose(Rl @ Rl.T, np.eye(3), atol=1e-14)
        np.testing.assert_allclose(Rl, truth, atol=1e-6)


def test_fisheye_given_with_camera_keeps_the_camera_frame(tmp_path):
    d = body_rig({"x": {"K": K_PIN}})
    d["robots"]["p"] = {"camera": {"model": "fisheye", "K": K_FISH, "dist": D_FISH},
                        "markers": {"M1": {"position": [0.0, 0.1, 0.0]}, "M2": {"position": [0.0, -0.1, 0.0]}}}
    rig = load_rig(write(tmp_path / "rig.yaml", d))
    p = rig.robots["p"]
    assert not p.is_body and isinstance(p.camera, FisheyeCamera) and not p.central_pinhole
    assert rig.observer("p") == ("p", "")
    assert p.mounts[""].is_identity


# ---------------------------------------------------------------------------
# camera files under cameras:
# ---------------------------------------------------------------------------


ROS_EQUIDISTANT = """\
image_width: 1280
image_height: 800
camera_name: back
camera_matrix: {rows: 3, cols: 3, data: [290, 0, 639.5, 0, 291, 399.5, 0, 0, 1]}
distortion_model: equidistant
distortion_coefficients: {rows: 1, cols: 4, data: [0.012, -0.004, 0.0006, -0.0001]}
rectification_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}
projection_matrix: {rows: 3, cols: 4, data: [290, 0, 639.5, 0, 0, 291, 399.5, 0, 0, 0, 1, 0]}
"""


def test_camera_info_equidistant_is_fisheye(tmp_path):
    cam = load_camera_file(write(tmp_path / "back.yaml", ROS_EQUIDISTANT))
    assert isinstance(cam, FisheyeCamera)
    np.testing.assert_array_equal(cam.K, [[290, 0, 639.5], [0, 291, 399.5], [0, 0, 1]])
    np.testing.assert_array_equal(cam.dist, D_FISH)
    assert cam.size == (1280, 800)
    # plumb_bob stays pinhole
    cam = load_camera_file(write(tmp_path / "pb.yaml", ROS_EQUIDISTANT.replace("equidistant", "plumb_bob")))
    assert type(cam) is Camera


def test_camera_files_pose_inside_beside_or_identity(tmp_path, monkeypatch):
    T_in = {"t": [-0.1, 0.0, 0.3], "R": (rot([0, 0, 1], 180) @ R_OPTICAL_IN_BASE).tolist()}
    write(tmp_path / "calib" / "back.yaml", ROS_EQUIDISTANT + yaml.safe_dump({"pose": T_in}))
    write(tmp_path / "calib" / "left.yaml", ROS_EQUIDISTANT)
    write(tmp_path / "calib" / "plain.yaml", {"K": K_PIN, "dist": [0.1, 0, 0, 0]})
    beside = {"t": [0.0, 0.2, 0.3], "quaternion_xyzw": [0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)]}
    rig_path = write(tmp_path / "rig.yaml", body_rig({
        "back": "calib/back.yaml", "left": {"file": "calib/left.yaml", "pose": beside}, "plain": "calib/plain.yaml"}))
    monkeypatch.chdir(tmp_path / "calib")  # paths are the rig file's folder's, not the working directory's
    rig = load_rig(rig_path)
    cams = rig.robots["p"].cameras
    assert isinstance(cams["back"].camera, FisheyeCamera) and isinstance(cams["left"].camera, FisheyeCamera)
    np.testing.assert_allclose(cams["back"].pose.apply([0, 0, 1.0]), [-1.1, 0, 0.3], atol=1e-12)
    np.testing.assert_allclose(cams["left"].pose.R, rot([0, 0, 1], 90), atol=1e-12)
    np.testing.assert_allclose(cams["left"].pose.t, [0, 0.2, 0.3])
    assert type(cams["plain"].camera) is Camera and cams["plain"].is_identity


def test_opencv_filestorage_fisheye_and_omnidir(tmp_path):
    K = np.array(K_FISH)
    f = tmp_path / "fish.yml"
    fs = cv2.FileStorage(str(f), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", np.array([D_FISH]))
    fs.write("image_width", 1280)
    fs.write("image_height", 800)
    fs.write("fisheye_model", 1)  # OpenCV's calibration sample
    fs.release()
    cam = load_camera_file(f)
    assert isinstance(cam, FisheyeCamera)
    np.testing.assert_array_equal(cam.dist, D_FISH)

    f = tmp_path / "omni.xml"
    fs = cv2.FileStorage(str(f), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", K)
    fs.write("D", np.array([[0.01, -0.002, 0.0003, 0.0001]]))
    fs.write("xi", np.array([[1.2]]))  # as OpenCV's omnidir calibration writes it
    fs.release()
    cam = load_camera_file(f)
    assert isinstance(cam, OmniCamera) and cam.xi == 1.2
    np.testing.assert_array_equal(cam.dist, [0.01, -0.002, 0.0003, 0.0001])

    # an OpenCV file with model: said in words
    f = tmp_path / "m.yml"
    fs = cv2.FileStorage(str(f), cv2.FILE_STORAGE_WRITE)
    fs.write("model", "fisheye")
    fs.write("K", K)
    fs.write("D", np.array(D_FISH))
    fs.release()
    assert isinstance(load_camera_file(f), FisheyeCamera)


# ---------------------------------------------------------------------------
# Kalibr camera chains
# ---------------------------------------------------------------------------

# Known poses T_robot_camN of three cameras, non-trivial rotations.
KNOWN = [
    hom(rot([0.2, -0.3, 1.0], 25) @ R_OPTICAL_IN_BASE, [0.15, 0.02, 0.40]),
    hom(rot([0.0, 0.1, 1.0], 130) @ R_OPTICAL_IN_BASE, [-0.10, 0.12, 0.38]),
    hom(rot([1.0, 1.0, 0.2], -70) @ R_OPTICAL_IN_BASE, [0.02, -0.20, 0.55]),
]


def camchain(known=KNOWN, topics=("/front/image_raw", "/left/image_raw", "/up/image_raw")) -> dict:
    """A Kalibr chain of cameras at ``known`` poses: ``x_cn = T_cn_cnm1 @ x_cnm1``."""
    lenses = [
        {"camera_model": "pinhole", "distortion_model": "radtan", "intrinsics": [458.6, 457.3, 367.2, 248.4],
         "distortion_coeffs": [-0.28, 0.07, 0.0002, 1.8e-05], "resolution": [752, 480]},
        {"camera_model": "pinhole", "distortion_model": "equidistant", "intrinsics": [290.0, 291.0, 639.5, 399.5],
         "distortion_coeffs": D_FISH, "resolution": [1280, 800]},
        {"camera_model": "omni", "distortion_model": "radtan", "intrinsics": [0.9, 700.0, 701.0, 640.0, 400.0],
         "distortion_coeffs": [0.01, -0.002, 0.0003, 0.0001], "resolution": [1280, 800]},
    ]
    out = {}
    for i, (T, lens) in enumerate(zip(known, lenses)):
        cam = dict(lens, cam_overlaps=[j for j in range(len(known)) if j != i])
        if topics:
            cam["rostopic"] = topics[i]
        if i:
            cam["T_cn_cnm1"] = (np.linalg.inv(T) @ known[i - 1]).tolist()  # cam n-1 -> cam n
        out[f"cam{i}"] = cam
    return out


def test_kalibr_chain_poses_from_known_poses(tmp_path):
    f = write(tmp_path / "camchain.yaml", camchain())
    # robot frame = cam0's: each camera's pose is then inv(T_robot_cam0) @ T_robot_camN
    mounts = load_kalibr_camchain(f)
    assert list(mounts) == ["front", "left", "up"]
    for m, T in zip(mounts.values(), KNOWN):
        np.testing.assert_allclose(m.pose.as_matrix(), np.linalg.inv(KNOWN[0]) @ T, atol=1e-12)
    # cam0's pose given: the known poses themselves
    from mutloc.core.pose import Pose

    mounts = load_kalibr_camchain(f, pose=Pose(KNOWN[0][:3, :3], KNOWN[0][:3, 3]))
    for m, T in zip(mounts.values(), KNOWN):
        np.testing.assert_allclose(m.pose.as_matrix(), T, atol=1e-12)


def test_kalibr_lens_models_and_intrinsics(tmp_path):
    mounts = load_kalibr_camchain(write(tmp_path / "camchain.yaml", camchain()))
    front, left, up = mounts.values()
    assert type(front.camera) is Camera
    np.testing.assert_array_equal(front.camera.K, [[458.6, 0, 367.2], [0, 457.3, 248.4], [0, 0, 1]])
    np.testing.assert_array_equal(front.camera.dist[:4], [-0.28, 0.07, 0.0002, 1.8e-05])
    np.testing.assert_array_equal(front.camera.dist[4:], 0.0)
    assert front.camera.size == (752, 480)
    assert isinstance(left.camera, FisheyeCamera)
    np.testing.assert_array_equal(left.camera.dist, D_FISH)
    np.testing.assert_array_equal(left.camera.K, [[290, 0, 639.5], [0, 291, 399.5], [0, 0, 1]])
    assert isinstance(up.camera, OmniCamera) and up.camera.xi == 0.9
    np.testing.assert_array_equal(up.camera.K, [[700, 0, 640], [0, 701, 400], [0, 0, 1]])
    np.testing.assert_array_equal(up.camera.dist, [0.01, -0.002, 0.0003, 0.0001])


def test_kalibr_names_fall_back_to_keys(tmp_path):
    assert list(load_kalibr_camchain(write(tmp_path / "a.yaml", camchain(topics=None)))) == ["cam0", "cam1", "cam2"]
    same = ("/a/image_raw", "/b/image_raw", "/a/image_raw")
    assert list(load_kalibr_camchain(write(tmp_path / "b.yaml", camchain(topics=same)))) == ["cam0", "cam1", "cam2"]
    flat = ("/front/image_raw", "/image_raw", "/up/image_raw")
    assert list(load_kalibr_camchain(write(tmp_path / "c.yaml", camchain(topics=flat)))) == ["cam0", "cam1", "cam2"]


def test_kalibr_chain_in_a_rig(tmp_path):
    write(tmp_path / "calib" / "camchain.yaml", camchain())
    T0 = KNOWN[0]
    quat = {"t": T0[:3, 3].tolist(), "R": T0[:3, :3].tolist()}
    rig = load_rig(write(tmp_path / "rig.yaml", body_rig({"kalibr": "calib/camchain.yaml", "pose": quat})))
    assert rig.observer_keys()[:3] == ["p/front", "p/left", "p/up"]
    for key, T in zip(("p/front", "p/left", "p/up"), KNOWN):
        np.testing.assert_allclose(rig.mount(key).pose.as_matrix(), T, atol=1e-12)
    rig = load_rig(write(tmp_path / "rig2.yaml", body_rig({"kalibr": "calib/camchain.yaml"})))
    assert rig.mount("p/front").is_identity


def _chain_with(mutate) -> dict:
    d = camchain()
    mutate(d)
    return d


BAD_KALIBR = [
    ("missing intrinsics", lambda d: d["cam1"].pop("intrinsics"), "'cam1'", ["intrinsics"]),
    ("intrinsics count", lambda d: d["cam2"].update(intrinsics=[700.0, 701.0, 640.0, 400.0]), "'cam2'",
     ["intrinsics", "5", "xi"]),
    ("distortion count", lambda d: d["cam0"].update(distortion_coeffs=[0.1, 0.2, 0.3]), "'cam0'",
     ["distortion_coeffs", "4"]),
    ("unknown camera model", lambda d: d["cam1"].update(camera_model="ds"), "'cam1'", ["'ds'", "pinhole-equidistant"]),
    ("unknown combination", lambda d: d["cam2"].update(distortion_model="equidistant"), "'cam2'",
     ["omni-equidistant"]),
    ("T not rigid", lambda d: d["cam2"]["T_cn_cnm1"][0].__setitem__(0, 1.5), "'cam2'", ["T_cn_cnm1", "rigid"]),
    ("T missing", lambda d: d["cam1"].pop("T_cn_cnm1"), "'cam1'", ["T_cn_cnm1"]),
    ("gap", lambda d: d.pop("cam1"), "cam1", ["missing"]),
    ("not a camera", lambda d: d.update(imu0={}), "'imu0'", ["cam0"]),
]


@pytest.mark.parametrize("label,mutate,camera,words", BAD_KALIBR, ids=[b[0] for b in BAD_KALIBR])
def test_kalibr_bad_input_is_one_line(tmp_path, label, mutate, camera, words):
    f = write(tmp_path / "chain.yaml", _chain_with(mutate))
    with pytest.raises(RigError) as info:
        load_kalibr_camchain(f)
    assert_one_line(info, "chain.yaml", camera, *words)
    # and from a rig: the rig file and the robot too
    write(tmp_path / "calib" / "chain.yaml", _chain_with(mutate))
    rig_path = write(tmp_path / "rig.yaml", body_rig({"kalibr": "calib/chain.yaml"}))
    with pytest.raises(RigError) as info:
        load_rig(rig_path)
    assert_one_line(info, "rig.yaml", "robot 'p'", "chain.yaml", camera, *words)


def test_kalibr_unreadable_file(tmp_path):
    with pytest.raises(FileFormatError) as info:
        load_kalibr_camchain(tmp_path / "nope.yaml")
    assert_one_line(info, "nope.yaml")


# ---------------------------------------------------------------------------
# save / load round trip
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_body_rig_round_trip(tmp_path, suffix):
    write(tmp_path / "calib" / "camchain.yaml", camchain())
    src = body_rig({"kalibr": "calib/camchain.yaml", "pose": {"t": KNOWN[0][:3, 3].tolist(),
                                                              "R": KNOWN[0][:3, :3].tolist()}},
                   markers={"T1": {"position": [0.0, 0.10, 0.45], "tag": {"family": "tag36h11", "id": 1, "size": 0.12,
                                                                         "rotation": [0.1, 0.2, 0.3]}},
                            "M2": {"position": [0.0, -0.10, 0.45], "color": [255, 0, 0]}})
    rig = load_rig(write(tmp_path / "rig.yaml", src))
    out = tmp_path / f"saved{suffix}"
    save_rig(rig, out)
    saved = json.loads(out.read_text()) if suffix == ".json" else yaml.safe_load(out.read_text())
    assert set(saved["robots"]["p"]) == {"cameras", "markers"}
    back = load_rig(out)
    for name, m in rig.robots["p"].cameras.items():
        b = back.robots["p"].cameras[name]
        assert type(b.camera) is type(m.camera)
        np.testing.assert_array_equal(b.camera.K, m.camera.K)
        np.testing.assert_array_equal(b.camera.dist, m.camera.dist)
        assert b.camera.size == m.camera.size and getattr(b.camera, "xi", None) == getattr(m.camera, "xi", None)
        np.testing.assert_allclose(b.pose.as_matrix(), m.pose.as_matrix(), atol=1e-15)
    for name, mk in rig.robots["p"].markers.items():
        np.testing.assert_array_equal(back.robots["p"].markers[name].position, mk.position)
        assert back.robots["p"].markers[name].to_dict() == mk.to_dict()
    assert back.observer_keys() == rig.observer_keys()
    np.testing.assert_allclose(back.mount("p/up").pose.as_matrix(), KNOWN[2], atol=1e-12)


def test_one_camera_fisheye_round_trip(tmp_path):
    d = body_rig({})
    d["robots"]["p"] = {"camera": {"model": "omni", "K": K_PIN, "dist": [0.01, 0, 0, 0], "xi": 0.8, "size": [960, 540]},
                        "markers": {"M1": {"position": [0.0, 0.1, 0.0]}, "M2": {"position": [0.0, -0.1, 0.0]}}}
    rig = load_rig(d)
    save_rig(rig, tmp_path / "r.yaml")
    back = load_rig(tmp_path / "r.yaml").robots["p"]
    assert not back.is_body and isinstance(back.camera, OmniCamera) and back.camera.xi == 0.8
    assert back.camera.size == (960, 540)


# ---------------------------------------------------------------------------
# markers of a body, keys
# ---------------------------------------------------------------------------


def test_body_markers_frame(tmp_path):
    markers = {"M1": {"position": [0.0, 0.1, 0.45], "frame": "base"}, "M2": {"position": [0.0, -0.1, 0.45]}}
    rig = load_rig(body_rig({"a": {"K": K_PIN, "pose": {"t": [0.5, 0, 0], "R": R_OPTICAL_IN_BASE.tolist()}}},
                            markers))
    # no conversion: 'base' is the robot frame of a body
    np.testing.assert_array_equal(rig.robots["p"].markers["M1"].position, [0.0, 0.1, 0.45])
    markers["M1"]["frame"] = "camera"
    with pytest.raises(RigError) as info:
        load_rig(body_rig({"a": {"K": K_PIN}}, markers))
    assert_one_line(info, "robot 'p'", "marker 'M1'", "frame 'camera'")


def test_camera_keeps_its_meaning():
    d = body_rig({})
    d["robots"]["p"] = {"camera": {"K": K_PIN},
                        "base_from_camera": {"t": [0, 0, 0.3], "R": R_OPTICAL_IN_BASE.tolist()},
                        "markers": {"M1": {"position": [0.0, 0.1, 0.45], "frame": "base"},
                                    "M2": {"position": [0.0, -0.1, 0.45]}}}
    p = load_rig(d).robots["p"]
    assert not p.is_body and type(p.camera) is Camera
    # frame base is converted into the camera frame: x_cam = R.T @ (x_base - t)
    np.testing.assert_allclose(p.markers["M1"].position, R_OPTICAL_IN_BASE.T @ np.array([0.0, 0.1, 0.15]), atol=1e-12)
    np.testing.assert_array_equal(p.markers["M2"].position, [0.0, -0.1, 0.45])


def _rig_error(tmp_path, cameras=None, robot=None, files=None):
    for name, text in (files or {}).items():
        write(tmp_path / name, text)
    d = body_rig(cameras or {})
    if robot is not None:
        d["robots"]["p"] = robot
    path = write(tmp_path / "rig.yaml", d)
    with pytest.raises(RigError) as info:
        load_rig(path)
    return info


M = {"M1": {"position": [0.0, 0.1, 0.45]}}
BAD_RIGS = [
    ("unknown camera key", dict(cameras={"front": {"K": K_PIN, "posee": {}}}), ["'front'", "'posee'", "'pose'"]),
    ("wrong coefficient count", dict(cameras={"front": {"model": "fisheye", "K": K_FISH, "dist": [0.1, 0.2, 0.3, 0.4, 0]}}),
     ["'front'", "4 coefficients"]),
    ("pose not a rotation", dict(cameras={"front": {"K": K_PIN, "pose": {"t": [0, 0, 0], "R": [[1, 0, 0], [0, 1, 0], [0, 0, 2]]}}}),
     ["'front'", "pose", "not a rotation"]),
    ("reflection", dict(cameras={"front": {"K": K_PIN, "pose": {"t": [0, 0, 0], "R": [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]}}}),
     ["'front'", "not a rotation"]),
    ("quaternion not unit", dict(cameras={"front": {"K": K_PIN, "pose": {"t": [0, 0, 0], "quaternion_xyzw": [0, 0, 0, 2]}}}),
     ["'front'", "quaternion_xyzw", "unit"]),
    ("misspelt model", dict(cameras={"front": {"model": "fishey", "K": K_FISH, "dist": D_FISH}}),
     ["'front'", "'fishey'", "did you mean 'fisheye'"]),
    ("omni without xi", dict(cameras={"front": {"model": "omni", "K": K_FISH, "dist": D_FISH}}), ["'front'", "xi"]),
    ("slash in name", dict(cameras={"front/left": {"K": K_PIN}}), ["'front/left'", "'/'"]),
    ("camera and cameras", dict(robot={"camera": {"K": K_PIN}, "cameras": {"a": {"K": K_PIN}}, "markers": M}),
     ["robot 'p'", "not both"]),
    ("neither", dict(robot={"markers": M}), ["robot 'p'", "'camera'", "'cameras'"]),
    ("empty cameras", dict(robot={"cameras": {}, "markers": M}), ["robot 'p'", "cameras"]),
    ("base_from_camera on a body", dict(robot={"cameras": {"a": {"K": K_PIN}}, "markers": M,
                                               "base_from_camera": {"t": [0, 0, 0], "R": np.eye(3).tolist()}}),
     ["robot 'p'", "base_from_camera"]),
    ("pose in and beside the file", dict(cameras={"back": {"file": "back.yaml", "pose": {"t": [0, 0, 0], "R": np.eye(3).tolist()}}},
                                         files={"back.yaml": {"K": K_PIN, "pose": {"t": [0, 0, 1], "R": np.eye(3).tolist()}}}),
     ["'back'", "both"]),
    ("bad pose in a file", dict(cameras={"back": "back.yaml"},
                                files={"back.yaml": {"K": K_PIN, "pose": {"t": [0, 0, 1], "quaternion_xyzw": [1, 1, 0, 0]}}}),
     ["'back'", "back.yaml", "unit"]),
    ("misspelt distortion_model in a file", dict(cameras={"back": "back.yaml"},
                                                 files={"back.yaml": ROS_EQUIDISTANT.replace("equidistant", "equidistnat")}),
     ["'back'", "back.yaml", "'equidistnat'", "did you mean 'equidistant'"]),
    ("missing camera file", dict(cameras={"back": "nope.yaml"}), ["'back'", "nope.yaml"]),
    ("kalibr with another key", dict(cameras={"kalibr": "c.yaml", "front": {"K": K_PIN}}), ["'front'", "kalibr"]),
]


@pytest.mark.parametrize("label,kw,words", BAD_RIGS, ids=[b[0] for b in BAD_RIGS])
def test_bad_body_rig_is_one_line(tmp_path, label, kw, words):
    if label == "missing camera file":
        with pytest.raises(FileFormatError) as info:
            load_rig(write(tmp_path / "rig.yaml", body_rig(kw["cameras"])))
    else:
        info = _rig_error(tmp_path, **kw)
    assert_one_line(info, "rig.yaml", "robot 'p'", *words)


def test_pose_under_camera_is_refused(tmp_path):
    info = _rig_error(tmp_path, robot={"camera": {"K": K_PIN, "pose": {"t": [0, 0, 0], "R": np.eye(3).tolist()}},
                                       "markers": M})
    assert_one_line(info, "rig.yaml", "robot 'p'", "pose")
