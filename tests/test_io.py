"""Tests of mutloc.io: rig files, camera calibration files, observations, JSON output."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from mutloc.core.rig import Rig
from mutloc.errors import FileFormatError, InputError, MutlocError, ObservationError, RigError
from mutloc.io import load_camera_file, load_observations, load_rig, save_rig, write_json
from mutloc.io.results import dumps_json

K_LIST = [[800.0, 0.0, 479.5], [0.0, 800.0, 269.5], [0.0, 0.0, 1.0]]


def simple_rig_dict() -> dict:
    return {
        "robots": {
            "p": {
                "camera": {"K": K_LIST, "dist": [0, 0, 0, 0, 0], "size": [960, 540]},
                "markers": {
                    "M3": {"position": [-0.15, -0.05, -0.03], "color": [255, 0, 0]},
                    "M4": {"position": [0.15, -0.05, -0.03], "color": [0, 255, 0]},
                },
            },
            "q": {
                "camera": {"K": K_LIST},
                "markers": {
                    "M1": {"position": [-0.15, -0.05, -0.03], "color": [0, 0, 255]},
                    "M2": {"position": [0.15, -0.05, -0.03], "color": [255, 255, 0]},
                },
            },
        }
    }


def full_rig_dict() -> dict:
    """Three robots and every optional marker key, plus unknown extra keys."""
    return {
        "robots": {
            "p": {
                "camera": {"K": K_LIST, "dist": [-0.1, 0.02, 0.001, -0.0005, 0.003], "size": [960, 540]},
                "markers": {
                    "led_left": {"position": [-0.15, -0.05, -0.03], "color": [255, 0, 0], "blink_hz": 7.5},
                    "led_right": {"position": [0.15, -0.05, -0.03], "blink_hz": 11},
                },
            },
            "q": {
                "camera": {"K": [[600, 0.5, 320], [0, 610, 240], [0, 0, 1]], "dist": [0.1, 0, 0, 0]},
                "markers": {
                    "T3": {"position": [0.0, 0.1, 0.0], "tag": {"family": "tag36h11", "id": 3, "size": 0.1}},
                    "B1": {"position": [0.1, 0.1, 0.0], "color": [0, 0, 255], "radius": 0.02,
                           "x_note": "blue ball", "x_meta": {"batch": 7, "ok": True}},
                },
            },
            "r": {
                "camera": {"K": K_LIST, "dist": [0.01, -0.02, 0, 0, 0.001, 0.002, 0.0, 0.0], "size": [1920, 1080]},
                "markers": {"R1": {"position": [1e-3, 2.5, -1.0]}},
            },
        }
    }


def cam_params(camera) -> tuple[np.ndarray, np.ndarray, tuple | None]:
    """(K, dist padded to 8, size) from the camera's documented to_dict()."""
    d = camera.to_dict()
    dist = np.zeros(8)
    given = np.asarray(d.get("dist") or [], dtype=float).ravel()
    dist[: given.size] = given
    size = d.get("size")
    return np.asarray(d["K"], dtype=float), dist, (tuple(size) if size is not None else None)


def pad8(d) -> np.ndarray:
    out = np.zeros(8)
    out[: len(d)] = d
    return out


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")
    return path


# ---------------------------------------------------------------------------
# rig: loading and round trips
# ---------------------------------------------------------------------------


def test_load_rig_from_dict():
    rig = load_rig(simple_rig_dict())
    assert isinstance(rig, Rig)
    assert set(rig.robots) == {"p", "q"}
    assert rig.owner("M1") == "q" and rig.owner("M4") == "p"
    m = rig.marker("M3")
    np.testing.assert_array_equal(m.position, [-0.15, -0.05, -0.03])
    assert m.color == (255, 0, 0)
    K, dist, size = cam_params(rig.robots["p"].camera)
    np.testing.assert_array_equal(K, K_LIST)
    np.testing.assert_array_equal(dist, np.zeros(8))
    assert size == (960, 540)
    assert cam_params(rig.robots["q"].camera)[2] is None


def test_load_rig_passes_rig_through():
    rig = load_rig(simple_rig_dict())
    assert load_rig(rig) is rig


@pytest.mark.parametrize("ext", [".yaml", ".yml", ".json"])
def test_save_load_round_trip(tmp_path, ext):
    rig = load_rig(full_rig_dict())
    path = tmp_path / f"rig{ext}"
    save_rig(rig, path)
    text = path.read_text()
    if ext == ".json":
        json.loads(text)  # really JSON
    back = load_rig(path)
    assert back.to_dict() == rig.to_dict()
    # and once more: saving the loaded rig gives the same file
    path2 = tmp_path / f"again{ext}"
    save_rig(back, path2)
    assert path2.read_text() == text


def test_round_trip_keeps_every_marker_field(tmp_path):
    path = tmp_path / "rig.yaml"
    save_rig(load_rig(full_rig_dict()), path)
    rig = load_rig(path)
    left = rig.marker("led_left")
    assert left.color == (255, 0, 0) and left.blink_hz == 7.5
    assert isinstance(rig.marker("led_right").blink_hz, float)
    tag = rig.marker("T3").tag
    assert dict(tag) == {"family": "tag36h11", "id": 3, "size": 0.1}
    b1 = rig.marker("B1")
    assert dict(b1.extra) == {"radius": 0.02, "x_note": "blue ball", "x_meta": {"batch": 7, "ok": True}}
    assert b1.color == (0, 0, 255)
    np.testing.assert_array_equal(rig.marker("R1").position, [1e-3, 2.5, -1.0])
    K, dist, size = cam_params(rig.robots["r"].camera)
    np.testing.assert_array_equal(dist, [0.01, -0.02, 0, 0, 0.001, 0.002, 0.0, 0.0])
    assert size == (1920, 1080)
    K, dist, size = cam_params(rig.robots["q"].camera)
    assert K[0, 1] == 0.5 and size is None
    np.testing.assert_array_equal(dist, pad8([0.1, 0, 0, 0]))


def test_yaml_rig_file_as_in_spec(tmp_path):
    write(tmp_path / "calib" / "q_camera.yaml", "K: [[700, 0, 320], [0, 700, 240], [0, 0, 1]]\nsize: [640, 480]\n")
    path = write(
        tmp_path / "rig.yaml",
        """\
robots:
  p:                               # any robot name; order does not matter
    camera:
      K: [[800, 0, 479.5], [0, 800, 269.5], [0, 0, 1]]
      dist: [0, 0, 0, 0, 0]        # optional
      size: [960, 540]             # optional
    markers:
      M3: {position: [-0.15, -0.05, -0.03], color: [255, 0, 0]}
      M4: {position: [ 0.15, -0.05, -0.03], color: [0, 255, 0]}
  q:
    camera: calib/q_camera.yaml    # or a path
    markers:
      M1: {position: [-0.15, -0.05, -0.03], color: [0, 0, 255]}
      M2: {position: [ 0.15, -0.05, -0.03], color: [255, 255, 0]}
""",
    )
    rig = load_rig(path)
    assert list(rig.robots) == ["p", "q"]
    K, dist, size = cam_params(rig.robots["q"].camera)
    assert K[0, 0] == 700 and size == (640, 480)


def test_yaml_exponent_without_dot_is_a_number(tmp_path):
    # PyYAML alone reads "1e-3" as a string; rig files must not care.
    path = write(
        tmp_path / "rig.yaml",
        "robots:\n  p:\n    camera: {K: [[8e2, 0, 479.5], [0, 8e+2, 269.5], [0, 0, 1]]}\n"
        "    markers: {A: {position: [1e-3, -2E-2, 3e0]}}\n",
    )
    rig = load_rig(path)
    np.testing.assert_array_equal(rig.marker("A").position, [1e-3, -2e-2, 3.0])


def test_integer_names_become_strings():
    d = simple_rig_dict()
    d["robots"][1] = {"camera": {"K": K_LIST}, "markers": {7: {"position": [0, 0, 0]}}}
    rig = load_rig(d)
    assert "1" in rig.robots and rig.owner("7") == "1"


def test_flat_K_and_integral_floats_accepted():
    d = simple_rig_dict()
    d["robots"]["p"]["camera"] = {"K": [800, 0, 479.5, 0, 800, 269.5, 0, 0, 1], "size": [960.0, 540.0]}
    d["robots"]["p"]["markers"]["M3"]["color"] = [255.0, 0, 0]
    rig = load_rig(d)
    K, _, size = cam_params(rig.robots["p"].camera)
    np.testing.assert_array_equal(K, K_LIST)
    assert size == (960, 540)
    assert rig.marker("M3").color == (255, 0, 0)


def test_robot_without_markers_is_allowed():
    d = simple_rig_dict()
    d["robots"]["watcher"] = {"camera": {"K": K_LIST}, "markers": {}}
    assert load_rig(d).robots["watcher"].markers == {}


# ---------------------------------------------------------------------------
# camera calibration files
# ---------------------------------------------------------------------------

ROS1_CAMERA_INFO = """\
image_width: 960
image_height: 540
camera_name: q_cam
camera_matrix:
  rows: 3
  cols: 3
  data: [810.5, 0, 481.25, 0, 805.0, 268.75, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.1, 0.02, 0.001, -0.0005, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [810.5, 0, 481.25, 0, 0, 805.0, 268.75, 0, 0, 0, 1, 0]
"""

ROS1_K = [[810.5, 0, 481.25], [0, 805.0, 268.75], [0, 0, 1]]
ROS1_D = [-0.1, 0.02, 0.001, -0.0005, 0]


def rig_with_camera(camera) -> dict:
    d = simple_rig_dict()
    d["robots"]["q"]["camera"] = camera
    return d


def test_ros_camera_info_yaml(tmp_path):
    write(tmp_path / "q.yaml", ROS1_CAMERA_INFO)
    path = write(tmp_path / "rig.json", json.dumps(rig_with_camera("q.yaml")))
    K, dist, size = cam_params(load_rig(path).robots["q"].camera)
    np.testing.assert_array_equal(K, ROS1_K)
    np.testing.assert_array_equal(dist, pad8(ROS1_D))
    assert size == (960, 540)


def test_ros2_camera_info_flat_form(tmp_path):
    d8 = [0.1, -0.05, 0.001, 0.002, 0.01, 0.05, -0.01, 0.002]
    text = yaml.safe_dump(
        {
            "width": 1280,
            "height": 720,
            "distortion_model": "rational_polynomial",
            "k": [900.0, 0.0, 639.5, 0.0, 901.0, 359.5, 0.0, 0.0, 1.0],
            "d": d8,
            "r": [1, 0, 0, 0, 1, 0, 0, 0, 1],
            "p": [900.0, 0, 639.5, 0, 0, 901.0, 359.5, 0, 0, 0, 1, 0],
        }
    )
    cam = load_camera_file(write(tmp_path / "cam.yaml", text))
    K, dist, size = cam_params(cam)
    np.testing.assert_array_equal(K, [[900, 0, 639.5], [0, 901, 359.5], [0, 0, 1]])
    np.testing.assert_array_equal(dist, d8)
    assert size == (1280, 720)


def test_ros_camera_info_without_distortion(tmp_path):
    text = ROS1_CAMERA_INFO.replace("  rows: 1\n  cols: 5\n  data: [-0.1, 0.02, 0.001, -0.0005, 0]\n",
                                    "  rows: 1\n  cols: 0\n  data: []\n")
    _, dist, _ = cam_params(load_camera_file(write(tmp_path / "cam.yaml", text)))
    np.testing.assert_array_equal(dist, np.zeros(8))


@pytest.mark.parametrize(
    "ext,keys",
    [
        (".yaml", ("camera_matrix", "distortion_coefficients")),
        (".yml", ("cameraMatrix", "distCoeffs")),
        (".xml", ("K", "D")),
        (".xml", ("camera_matrix", "dist_coeffs")),
    ],
)
def test_opencv_filestorage(tmp_path, ext, keys):
    K = np.array([[812.0, 0.0, 470.5], [0.0, 809.0, 275.25], [0.0, 0.0, 1.0]])
    D = np.array([[-0.2, 0.05, 0.0015, -0.001, 0.01]])
    path = tmp_path / f"calib{ext}"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write(keys[0], K)
    fs.write(keys[1], D.T if ext == ".yml" else D)  # (5, 1) as well as (1, 5)
    fs.write("image_width", 960)
    fs.write("image_height", 540)
    fs.write("avg_reprojection_error", 0.31)
    fs.release()
    write(tmp_path / "rig.yaml", yaml.safe_dump(rig_with_camera(path.name)))
    Kl, dist, size = cam_params(load_rig(tmp_path / "rig.yaml").robots["q"].camera)
    np.testing.assert_array_equal(Kl, K)
    np.testing.assert_array_equal(dist, pad8(D.ravel()))
    assert size == (960, 540)


def test_opencv_filestorage_image_size_and_no_distortion(tmp_path):
    path = tmp_path / "calib.yaml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", np.array(K_LIST))
    fs.write("image_size", np.array([[640, 480]], dtype=np.int32))
    fs.release()
    K, dist, size = cam_params(load_camera_file(path))
    np.testing.assert_array_equal(K, K_LIST)
    np.testing.assert_array_equal(dist, np.zeros(8))
    assert size == (640, 480)


def test_opencv_legacy_yaml_header(tmp_path):
    path = write(
        tmp_path / "old.yaml",
        "%YAML:1.0\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
        "   data: [ 800., 0., 479.5, 0., 800., 269.5, 0., 0., 1. ]\n"
        "distortion_coefficients: !!opencv-matrix\n   rows: 5\n   cols: 1\n   dt: d\n"
        "   data: [ 0.1, -0.2, 0., 0., 0.05 ]\nimage_width: 960\nimage_height: 540\n",
    )
    K, dist, size = cam_params(load_camera_file(path))
    np.testing.assert_array_equal(K, K_LIST)
    np.testing.assert_array_equal(dist, pad8([0.1, -0.2, 0, 0, 0.05]))
    assert size == (960, 540)


def test_camera_path_relative_to_rig_folder_not_cwd(tmp_path, monkeypatch):
    rigdir = tmp_path / "configs" / "lab"
    write(rigdir / "calib" / "q.yaml", ROS1_CAMERA_INFO)
    write(rigdir / "rig.yaml", yaml.safe_dump(rig_with_camera("calib/q.yaml")))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    K, _, _ = cam_params(load_rig(rigdir / "rig.yaml").robots["q"].camera)
    np.testing.assert_array_equal(K, ROS1_K)
    # relative rig path too
    monkeypatch.chdir(tmp_path)
    K, _, _ = cam_params(load_rig("configs/lab/rig.yaml").robots["q"].camera)
    np.testing.assert_array_equal(K, ROS1_K)


def test_camera_path_in_dict_is_relative_to_cwd_or_base_dir(tmp_path, monkeypatch):
    write(tmp_path / "calib" / "q.yaml", ROS1_CAMERA_INFO)
    monkeypatch.chdir(tmp_path)
    K, _, _ = cam_params(load_rig(rig_with_camera("calib/q.yaml")).robots["q"].camera)
    np.testing.assert_array_equal(K, ROS1_K)
    monkeypatch.chdir(tmp_path / "calib")
    K, _, _ = cam_params(load_rig(rig_with_camera("calib/q.yaml"), base_dir=tmp_path).robots["q"].camera)
    np.testing.assert_array_equal(K, ROS1_K)
    with pytest.raises(FileFormatError):
        load_rig(rig_with_camera("calib/q.yaml"))


def test_absolute_camera_path(tmp_path):
    cam = write(tmp_path / "a" / "q.yaml", ROS1_CAMERA_INFO)
    write(tmp_path / "b" / "rig.yaml", yaml.safe_dump(rig_with_camera(str(cam))))
    K, _, _ = cam_params(load_rig(tmp_path / "b" / "rig.yaml").robots["q"].camera)
    np.testing.assert_array_equal(K, ROS1_K)


# ---------------------------------------------------------------------------
# rig: bad input -> typed one-line error saying where
# ---------------------------------------------------------------------------


def _mod(path: list, value, delete: bool = False) -> dict:
    d = simple_rig_dict()
    node = d
    for k in path[:-1]:
        node = node[k]
    if delete:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return d


DEL = object()

# (label, modification path, new value or DEL, expected error, words the message must contain)
BAD_RIGS = [
    ("no robots key", None, {"robot": {}}, RigError, ["robots"]),
    ("top level list", None, [1, 2], RigError, ["robots"]),
    ("robots not mapping", ["robots"], [1, 2], RigError, ["robots"]),
    ("robots empty", ["robots"], {}, RigError, ["robots"]),
    ("robot not mapping", ["robots", "q"], "hello", RigError, ["'q'"]),
    ("missing camera", ["robots", "q", "camera"], DEL, RigError, ["'q'", "camera"]),
    ("missing markers", ["robots", "p", "markers"], DEL, RigError, ["'p'", "markers"]),
    ("markers a list", ["robots", "p", "markers"], [1, 2], RigError, ["'p'", "markers"]),
    ("marker not mapping", ["robots", "p", "markers", "M3"], [0, 0, 1], RigError, ["'p'", "'M3'"]),
    ("missing position", ["robots", "p", "markers", "M3", "position"], DEL, RigError, ["'M3'", "position"]),
    ("position 2 numbers", ["robots", "q", "markers", "M2", "position"], [0.1, 0.2], RigError, ["'q'", "'M2'", "position"]),
    ("position string", ["robots", "q", "markers", "M2", "position"], "0 0 1", RigError, ["'M2'", "position"]),
    ("position string element", ["robots", "q", "markers", "M2", "position"], [0, "1", 2], RigError, ["'M2'", "position"]),
    ("position bool element", ["robots", "q", "markers", "M2", "position"], [0, True, 2], RigError, ["'M2'", "position"]),
    ("position nan", ["robots", "q", "markers", "M2", "position"], [0, math.nan, 2], RigError, ["'M2'", "position"]),
    ("position inf", ["robots", "q", "markers", "M1", "position"], [0, 1, math.inf], RigError, ["'M1'", "position"]),
    ("position null", ["robots", "q", "markers", "M1", "position"], None, RigError, ["'M1'", "position"]),
    ("color 2 values", ["robots", "p", "markers", "M4", "color"], [0, 255], RigError, ["'M4'", "color"]),
    ("color 256", ["robots", "p", "markers", "M4", "color"], [0, 256, 0], RigError, ["'M4'", "color"]),
    ("color negative", ["robots", "p", "markers", "M4", "color"], [0, -1, 0], RigError, ["'M4'", "color"]),
    ("color fractional", ["robots", "p", "markers", "M4", "color"], [0, 0.5, 0], RigError, ["'M4'", "color"]),
    ("color name", ["robots", "p", "markers", "M4", "color"], "red", RigError, ["'M4'", "color"]),
    ("blink zero", ["robots", "p", "markers", "M4", "blink_hz"], 0, RigError, ["'M4'", "blink_hz"]),
    ("blink negative", ["robots", "p", "markers", "M4", "blink_hz"], -2.0, RigError, ["'M4'", "blink_hz"]),
    ("blink string", ["robots", "p", "markers", "M4", "blink_hz"], "fast", RigError, ["'M4'", "blink_hz"]),
    ("blink inf", ["robots", "p", "markers", "M4", "blink_hz"], math.inf, RigError, ["'M4'", "blink_hz"]),
    ("tag not mapping", ["robots", "p", "markers", "M4", "tag"], "tag36h11", RigError, ["'M4'", "tag"]),
    ("tag no family", ["robots", "p", "markers", "M4", "tag"], {"id": 3, "size": 0.1}, RigError, ["'M4'", "family"]),
    ("tag no id", ["robots", "p", "markers", "M4", "tag"], {"family": "tag36h11", "size": 0.1}, RigError, ["'M4'", "id"]),
    ("tag id float", ["robots", "p", "markers", "M4", "tag"], {"family": "tag36h11", "id": 1.5, "size": 0.1}, RigError, ["'M4'", "id"]),
    ("tag id string", ["robots", "p", "markers", "M4", "tag"], {"family": "tag36h11", "id": "3", "size": 0.1}, RigError, ["'M4'", "id"]),
    ("tag no size", ["robots", "p", "markers", "M4", "tag"], {"family": "tag36h11", "id": 3}, RigError, ["'M4'", "size"]),
    ("tag size zero", ["robots", "p", "markers", "M4", "tag"], {"family": "tag36h11", "id": 3, "size": 0}, RigError, ["'M4'", "size"]),
    ("tag size negative", ["robots", "p", "markers", "M4", "tag"], {"family": "tag36h11", "id": 3, "size": -0.1}, RigError, ["'M4'", "size"]),
    ("duplicate marker across robots", ["robots", "q", "markers", "M3"], {"position": [0, 0, 0]}, RigError, ["'M3'"]),
    ("camera number", ["robots", "p", "camera"], 42, RigError, ["'p'", "camera"]),
    ("camera missing K", ["robots", "p", "camera"], {"dist": [0, 0, 0, 0]}, RigError, ["'p'", "K"]),
    ("K 2x2", ["robots", "p", "camera", "K"], [[1, 0], [0, 1]], RigError, ["'p'", "K"]),
    ("K string", ["robots", "p", "camera", "K"], "eye(3)", RigError, ["'p'", "K"]),
    ("K nan", ["robots", "p", "camera", "K"], [[800, 0, math.nan], [0, 800, 269.5], [0, 0, 1]], RigError, ["'p'", "K"]),
    ("K negative focal", ["robots", "p", "camera", "K"], [[-800, 0, 479.5], [0, 800, 269.5], [0, 0, 1]], RigError, ["'p'", "camera"]),
    ("dist 3 values", ["robots", "p", "camera", "dist"], [0.1, 0, 0], RigError, ["'p'", "dist"]),
    ("dist inf", ["robots", "p", "camera", "dist"], [0.1, 0, 0, math.inf], RigError, ["'p'", "dist"]),
    ("dist string", ["robots", "p", "camera", "dist"], "none", RigError, ["'p'", "dist"]),
    ("size 3 values", ["robots", "p", "camera", "size"], [960, 540, 3], RigError, ["'p'", "size"]),
    ("size negative", ["robots", "p", "camera", "size"], [960, -540], RigError, ["'p'", "size"]),
    ("size fractional", ["robots", "p", "camera", "size"], [960.5, 540], RigError, ["'p'", "size"]),
    ("coincident markers", ["robots", "p", "markers", "M4", "position"], [-0.15, -0.05, -0.03], RigError, ["'M3'", "'M4'"]),
]


def _bad_rig(path, value):
    if path is None:
        return value
    return _mod(path, None, delete=True) if value is DEL else _mod(path, value)


@pytest.mark.parametrize("label,path,value,exc,words", BAD_RIGS, ids=[b[0] for b in BAD_RIGS])
def test_bad_rig_dict(label, path, value, exc, words):
    with pytest.raises(exc) as info:
        load_rig(_bad_rig(path, value))
    msg = str(info.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg, (w, msg)
    assert isinstance(info.value, InputError) and isinstance(info.value, ValueError)


@pytest.mark.parametrize("label,path,value,exc,words", BAD_RIGS, ids=[b[0] for b in BAD_RIGS])
def test_bad_rig_file_names_the_file(tmp_path, label, path, value, exc, words):
    data = _bad_rig(path, value)
    f = tmp_path / "bad_rig.json"
    f.write_text(json.dumps(data))  # NaN/Infinity are accepted by Python's JSON reader
    with pytest.raises(exc) as info:
        load_rig(f)
    msg = str(info.value)
    assert "\n" not in msg and "bad_rig.json" in msg
    for w in words:
        assert w in msg, (w, msg)


BAD_RIG_FILES = [
    ("missing file", None, FileFormatError, ["nope.yaml"]),
    ("yaml syntax", "robots:\n  p: {camera: [1, 2\n", FileFormatError, ["line"]),
    ("yaml tab indent", "robots:\n\tp: 1\n", FileFormatError, ["YAML"]),
    ("empty file", "", RigError, ["empty"]),
    ("scalar", "just a string\n", RigError, ["robots"]),
    ("yaml nan position",
     "robots:\n  p:\n    camera: {K: [[800, 0, 479.5], [0, 800, 269.5], [0, 0, 1]]}\n"
     "    markers: {A: {position: [0, .nan, 1]}}\n", RigError, ["'A'", "position"]),
    ("yaml duplicate marker in one robot",
     "robots:\n  p:\n    camera: {K: [[800, 0, 479.5], [0, 800, 269.5], [0, 0, 1]]}\n"
     "    markers:\n      A: {position: [0, 0, 1]}\n      A: {position: [0, 1, 1]}\n", RigError, ["'A'", "duplicate"]),
    ("camera file missing",
     "robots:\n  p:\n    camera: calib/none.yaml\n    markers: {}\n", FileFormatError, ["'p'", "calib/none.yaml"]),
]


@pytest.mark.parametrize("label,text,exc,words", BAD_RIG_FILES, ids=[b[0] for b in BAD_RIG_FILES])
def test_bad_rig_yaml_file(tmp_path, label, text, exc, words):
    f = tmp_path / "nope.yaml"
    if text is not None:
        f.write_text(text)
    with pytest.raises(exc) as info:
        load_rig(f)
    msg = str(info.value)
    assert "\n" not in msg and "nope.yaml" in msg
    for w in words:
        assert w in msg, (w, msg)


def test_bad_json_rig_file(tmp_path):
    f = write(tmp_path / "rig.json", '{"robots": {"p": }}')
    with pytest.raises(FileFormatError, match=r"rig\.json.*JSON.*line 1"):
        load_rig(f)
    f = write(tmp_path / "dup.json", '{"robots": {}, "robots": {}}')
    with pytest.raises(RigError, match="duplicate"):
        load_rig(f)


def test_rig_file_is_a_directory(tmp_path):
    with pytest.raises(FileFormatError):
        load_rig(tmp_path)


def test_load_rig_wrong_source_type():
    with pytest.raises(RigError):
        load_rig(42)


BAD_CAMERA_FILES = [
    ("yaml syntax", "cam.yaml", "camera_matrix: [1, 2\n", FileFormatError, ["cam.yaml"]),
    ("no camera matrix", "cam.yaml", "image_width: 960\nimage_height: 540\n", FileFormatError, ["camera matrix"]),
    ("not a mapping", "cam.yaml", "- 1\n- 2\n", FileFormatError, ["cam.yaml"]),
    ("equidistant with 5 coefficients", "cam.yaml", ROS1_CAMERA_INFO.replace("plumb_bob", "equidistant"), RigError,
     ["equidistant", "4 coefficients"]),
    ("misspelt distortion model", "cam.yaml", ROS1_CAMERA_INFO.replace("plumb_bob", "plumbbob"), RigError,
     ["'plumbbob'", "did you mean 'plumb_bob'"]),
    ("rows x cols mismatch", "cam.yaml", ROS1_CAMERA_INFO.replace("data: [810.5, 0, 481.25, ", "data: [0, 481.25, "),
     RigError, ["camera_matrix"]),
    ("width without height", "cam.yaml", ROS1_CAMERA_INFO.replace("image_height: 540\n", ""), RigError, ["image_height"]),
    ("bad opencv yaml", "cam.yaml", "%YAML:1.0\ncamera_matrix: !!opencv-matrix\n   rows: [3\n", FileFormatError, ["cam.yaml"]),
    ("bad opencv xml", "cam.xml", "<?xml version=\"1.0\"?>\n<opencv_storage>\n<K>\n", FileFormatError, ["cam.xml"]),
    ("binary junk", "cam.yaml", None, FileFormatError, ["cam.yaml"]),
]


@pytest.mark.parametrize("label,name,text,exc,words", BAD_CAMERA_FILES, ids=[b[0] for b in BAD_CAMERA_FILES])
def test_bad_camera_file(tmp_path, label, name, text, exc, words):
    f = tmp_path / name
    if text is None:
        f.write_bytes(b"\xff\xfe\x00\x81junk")
    else:
        f.write_text(text)
    write(tmp_path / "rig.yaml", yaml.safe_dump(rig_with_camera(name)))
    with pytest.raises(exc) as info:
        load_rig(tmp_path / "rig.yaml")
    msg = str(info.value)
    assert "\n" not in msg and "rig.yaml" in msg and "'q'" in msg
    for w in words:
        assert w in msg, (w, msg)


# ---------------------------------------------------------------------------
# observations
# ---------------------------------------------------------------------------

SPEC_OBS = {"p": {"M1": [612.3, 281.9], "M2": [701.0, 280.4]}, "q": {"M3": [402.8, 255.1], "M4": [470.2, 254.7]}}


def _check_plain(obs):
    for observer, seen in obs.to_dict().items():
        assert type(observer) is str
        items = seen.items() if isinstance(seen, dict) else enumerate(seen)
        for _, pix in items:
            assert type(pix) is tuple and len(pix) == 2
            assert all(type(x) is float for x in pix)


@pytest.mark.parametrize("ext", [".json", ".yaml"])
def test_observations_file(tmp_path, ext):
    f = tmp_path / f"obs{ext}"
    f.write_text(json.dumps(SPEC_OBS) if ext == ".json" else yaml.safe_dump(SPEC_OBS))
    obs = load_observations(f)
    assert obs == {"p": {"M1": (612.3, 281.9), "M2": (701.0, 280.4)},
                   "q": {"M3": (402.8, 255.1), "M4": (470.2, 254.7)}}
    _check_plain(obs)
    assert load_observations(str(f)) == obs


def test_observations_mapping_with_numpy_and_ints():
    obs = load_observations({"p": {"M1": np.array([612, 281.5])}, "q": {"M3": (np.float32(1.5), np.int64(2))}})
    assert obs == {"p": {"M1": (612.0, 281.5)}, "q": {"M3": (1.5, 2.0)}}
    _check_plain(obs)


def test_observations_unknown_identity_list(tmp_path):
    data = {"p": [[612.3, 281.9], [701.0, 280.4]], "q": {"M3": [402.8, 255.1]}}
    obs = load_observations(data)
    assert obs.to_dict()["p"] == [(612.3, 281.9), (701.0, 280.4)]
    assert obs.to_dict()["q"] == {"M3": (402.8, 255.1)}
    _check_plain(obs)
    f = write(tmp_path / "obs.json", json.dumps(data))
    assert load_observations(f) == obs
    assert load_observations({"p": np.array([[1.0, 2.0], [3, 4]])}) == {"p": [(1.0, 2.0), (3.0, 4.0)]}


def test_observations_empty_entries_are_structurally_fine():
    assert len(load_observations({"p": {}, "q": []})) == 0
    assert len(load_observations({})) == 0


BAD_OBS = [
    ("top level list", [[1, 2]], ObservationError, []),
    ("observer number", {"p": 3}, ObservationError, ["'p'"]),
    ("observer string", {"p": "M1"}, ObservationError, ["'p'"]),
    ("observer null", {"p": None}, ObservationError, ["'p'"]),
    ("pixel 3 numbers", {"p": {"M1": [1, 2, 3]}}, ObservationError, ["'p'", "'M1'"]),
    ("pixel 1 number", {"p": {"M1": [1]}}, ObservationError, ["'p'", "'M1'"]),
    ("pixel scalar", {"p": {"M1": 5}}, ObservationError, ["'p'", "'M1'"]),
    ("pixel strings", {"q": {"M3": ["1", "2"]}}, ObservationError, ["'q'", "'M3'"]),
    ("pixel bool", {"q": {"M3": [True, 2]}}, ObservationError, ["'q'", "'M3'"]),
    ("pixel null", {"q": {"M3": None}}, ObservationError, ["'q'", "'M3'"]),
    ("pixel nan", {"q": {"M4": [math.nan, 2]}}, ObservationError, ["'q'", "'M4'"]),
    ("pixel inf", {"q": {"M4": [1, -math.inf]}}, ObservationError, ["'q'", "'M4'"]),
    ("pixel nested", {"q": {"M4": [[1, 2]]}}, ObservationError, ["'q'", "'M4'"]),
    ("list entry bad", {"p": [[1, 2], [3]]}, ObservationError, ["'p'", "point 1"]),
    ("list entry nan", {"p": [[1, math.nan]]}, ObservationError, ["'p'", "point 0"]),
    ("marker name not a string", {"p": {None: [1, 2]}}, ObservationError, ["'p'"]),
]


@pytest.mark.parametrize("label,data,exc,words", BAD_OBS, ids=[b[0] for b in BAD_OBS])
def test_bad_observations(tmp_path, label, data, exc, words):
    with pytest.raises(exc) as info:
        load_observations(data)
    msg = str(info.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg, (w, msg)
    # the same through a file names the file
    if label != "marker name not a string":
        f = write(tmp_path / "obs_bad.json", json.dumps(data))
        with pytest.raises(exc) as info:
            load_observations(f)
        assert "obs_bad.json" in str(info.value)
        for w in words:
            assert w in str(info.value)


def test_bad_observation_files(tmp_path):
    with pytest.raises(FileFormatError, match="missing.json"):
        load_observations(tmp_path / "missing.json")
    with pytest.raises(FileFormatError, match="JSON"):
        load_observations(write(tmp_path / "o.json", '{"p": {"M1": [1, 2]'))
    with pytest.raises(FileFormatError, match="YAML"):
        load_observations(write(tmp_path / "o.yaml", "p: {M1: [1, 2}\n"))
    with pytest.raises(ObservationError, match="empty"):
        load_observations(write(tmp_path / "empty.yaml", ""))
    with pytest.raises(ObservationError, match="duplicate"):
        load_observations(write(tmp_path / "d.yaml", "p:\n  M1: [1, 2]\n  M1: [3, 4]\n"))
    with pytest.raises(ObservationError):
        load_observations(12)


# ---------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------


def test_write_json_numpy_to_stdout(capsys):
    obj = {"R": np.eye(3), "t": np.array([1.0, 2.0, 3.0]), "n": np.int64(4), "x": np.float32(0.5),
           "ok": np.bool_(True), "names": ("M1", "M2"), "bad": float("nan")}
    write_json(obj, None)
    out = capsys.readouterr().out
    assert out.endswith("\n") and '\n  "R"' in out  # indent 2
    back = json.loads(out)
    assert back == {"R": np.eye(3).tolist(), "t": [1.0, 2.0, 3.0], "n": 4, "x": 0.5, "ok": True,
                    "names": ["M1", "M2"], "bad": None}


def test_write_json_to_file(tmp_path):
    class Result:
        def to_dict(self):
            return {"t": np.zeros(3)}

    f = tmp_path / "out" / "sub" / "r.json"
    write_json(Result(), f)
    assert json.loads(f.read_text()) == {"t": [0.0, 0.0, 0.0]}
    assert dumps_json({"a": 1}) == '{\n  "a": 1\n}\n'


def test_write_json_oserror_propagates(tmp_path):
    with pytest.raises(OSError):
        write_json({"a": 1}, tmp_path)  # a directory


def test_errors_are_mutloc_errors():
    for exc in (FileFormatError, RigError, ObservationError):
        assert issubclass(exc, MutlocError)
