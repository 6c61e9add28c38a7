"""One image per camera of robots with several cameras and any lens (issue 36 items 3-4):
`localize_images` / `mutloc localize-images` keyed by camera, and the second looks through the mount.

Ground truth is independent of the detector and of its rectified views: each camera's image is ray-traced
from its lens model and its mount -- for every raw pixel (4x4 sub-pixels) the ray of ``pixels_to_bearings``
is intersected with each tag's plane (cells of ``cv2.aruco.generateImageMarker``, a white quiet zone),
the tag placed by the robots' true poses and the camera's pose on its robot -- and the truth pose is the
one the scene was built from.

Two robots with back-to-back fisheyes (195 degrees, 800x500 images, ~150 px/rad): facing away from each
other (only the back cameras see the other robot, tags ~10-20 degrees off their axes) and side by side
(every tag seen 79-92 degrees off a camera's axis, two cameras of each robot seeing).
"""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from mutloc.cli.main import main
from mutloc.core.camera import Camera
from mutloc.core.geometry import so3_exp, so3_log
from mutloc.core.lenses import FisheyeCamera
from mutloc.core.pose import Pose
from mutloc.core.rig import Marker, Mount, Rig, Robot
from mutloc.detect.base import DetectionResult
from mutloc.errors import ObservationError
from mutloc.sim.bodies import OPTICAL_IN_BASE
from mutloc.sim.render import linear_to_srgb, srgb_to_linear
from mutloc.track.frames import localize_images
from mutloc.track.second_look import ball_centres
from mutloc.track.tag_look import find_missing_tags

SS = 4  # sub-pixels per pixel side
W, H = 800, 500
TAG = 0.2  # black square's side (m)
_K4 = np.array([0.012, -0.004, 0.0006, -0.0001])
_THETA = math.radians(97.5)
_F = 0.5 * H / (_THETA * (1 + _K4[0] * _THETA**2 + _K4[1] * _THETA**4 + _K4[2] * _THETA**6 + _K4[3] * _THETA**8))
FISHEYE = FisheyeCamera([[_F, 0, (W - 1) / 2], [0, _F, (H - 1) / 2], [0, 0, 1]], _K4, (W, H))

# Tag frames in the body (x forward, y left, z up): columns x (right as printed), y (down), z into the tag.
FACING_BACK = np.column_stack([[0, -1, 0], [0, 0, -1], [1, 0, 0]]).astype(float)   # seen from behind
FACING_LEFT = np.column_stack([[-1, 0, 0], [0, 0, -1], [0, -1, 0]]).astype(float)  # seen from the left
FACING_RIGHT = np.column_stack([[1, 0, 0], [0, 0, -1], [0, 1, 0]]).astype(float)  # seen from the right

#: Worst tolerated pose error.  Measured (printed with -s) over noise seeds 0-40: 0.28-0.35 mm and
#: 0.014-0.017 degrees facing away (24 corners), 0.40-0.54 mm and 0.013-0.015 degrees side by side (20
#: corners) -- mostly the same every seed (the corners' sub-pixel bias through the rectified views, ~0.1-0.2
#: px, tests/test_detect_lenses.py), so about 4x to spare; a corner misplaced by a pixel or a mount's pose
#: or lens ignored is far outside.
TOL_M, TOL_DEG = 0.002, 0.06


def _yaw(a: float) -> np.ndarray:
    return so3_exp(np.array([0.0, 0.0, a]))


def _body(name: str, tags: dict[str, tuple[list[float], np.ndarray, int]]) -> Robot:
    cams = {c: Mount(c, FISHEYE, Pose(_yaw(a) @ OPTICAL_IN_BASE, _yaw(a) @ np.array([0.15, 0.0, 0.0]) + [0, 0, 0.3]))
            for c, a in (("front", 0.0), ("back", math.pi))}
    markers = {n: Marker(n, name, np.asarray(pos, float),
                         tag={"family": "tag36h11", "id": tid, "size": TAG, "rotation": so3_log(R).tolist()})
               for n, (pos, R, tid) in tags.items()}
    return Robot(name, None, markers, cameras=cams)


def facing_away():
    """q turned back to p, p turned away from q: each robot's back camera sees the other's back tags."""
    spots = ([-0.22, 0.18, 0.42], [-0.22, -0.18, 0.42], [-0.22, 0.0, 0.7])
    rig = Rig({r: _body(r, {f"{r.upper()}{i + 1}": (pos, FACING_BACK, first + i) for i, pos in enumerate(spots)})
               for r, first in (("p", 0), ("q", 3))})
    return rig, {"q": Pose(_yaw(math.pi), [0, 0, 0]), "p": Pose(_yaw(0.12), [1.3, 0.15, 0.0])}


def side_by_side():
    """p 1.3 m to q's left, both facing forward: every tag seen 79-92 degrees off a fisheye's axis."""
    rig = Rig({"p": _body("p", {"P1": ([0.3, -0.2, 0.45], FACING_RIGHT, 0), "P2": ([-0.3, -0.2, 0.45], FACING_RIGHT, 1),
                                "P3": ([0.1, -0.2, 0.72], FACING_RIGHT, 2)}),
               "q": _body("q", {"Q1": ([0.3, 0.2, 0.45], FACING_LEFT, 3), "Q2": ([-0.3, 0.2, 0.45], FACING_LEFT, 4),
                                "Q3": ([-0.1, 0.2, 0.72], FACING_LEFT, 5)})})
    return rig, {"q": Pose(np.eye(3), [0, 0, 0]), "p": Pose(_yaw(0.05), [0.0, 1.3, 0.0])}


def _background(seed: int, size: tuple[int, int]) -> np.ndarray:
    """Smooth grey clutter (float, sRGB levels)."""
    w, h = size
    rng = np.random.default_rng(seed)
    small = rng.uniform(0, 255, (h // 16 + 2, w // 16 + 2)).astype(np.float32)
    return np.clip(0.35 * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC) + 80, 0, 255).astype(float)


def _draw_tag(img: np.ndarray, camera, C: np.ndarray, R: np.ndarray, tid: int) -> bool:
    """Ray-trace a tag36h11 tag (side TAG, one white cell of quiet zone) centred at ``C`` with frame ``R`` (camera
    frame) into ``img`` (grey, float, sRGB levels); False when the lens does not image all of it."""
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    cells = d.markerSize + 2
    bits = cv2.aruco.generateImageMarker(d, tid, cells, borderBits=1)
    cell, h = TAG / cells, TAG / 2
    q = h + cell
    s = np.linspace(-q, q, 33)
    outline = C + np.r_[np.c_[s, -q + 0 * s, 0 * s], np.c_[s, q + 0 * s, 0 * s], np.c_[-q + 0 * s, s, 0 * s],
                        np.c_[q + 0 * s, s, 0 * s]] @ R.T
    uv = camera.project(outline)
    # A 195-degree lens images nothing beyond 97.5 degrees off its axis (its model would go on).
    if not (np.all(np.isfinite(uv)) and np.all(camera.in_image(uv))
            and np.all(outline[:, 2] > math.cos(_THETA) * np.linalg.norm(outline, axis=1))):
        return False
    u0, v0 = np.maximum(np.floor(uv.min(axis=0)).astype(int) - 4, 0)
    u1, v1 = np.minimum(np.ceil(uv.max(axis=0)).astype(int) + 4, [camera.size[0] - 1, camera.size[1] - 1])
    offs = (np.arange(SS) + 0.5) / SS - 0.5
    us = (np.arange(u0, u1 + 1)[:, None] + offs[None, :]).ravel()
    vs = (np.arange(v0, v1 + 1)[:, None] + offs[None, :]).ravel()
    U, V = np.meshgrid(us, vs)
    rays = camera.pixels_to_bearings(np.c_[U.ravel(), V.ravel()])
    n = R[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (n @ C) / (rays @ n)
    P = rays * t[:, None] - C
    x, y = P @ R[:, 0], P @ R[:, 1]
    hit = np.isfinite(t) & (t > 0) & (np.abs(x) < q) & (np.abs(y) < q)
    val = np.full(len(rays), np.nan)
    val[hit] = 225.0
    inner = hit & (np.abs(x) < h) & (np.abs(y) < h)
    ci = np.clip(((x[inner] + h) / cell).astype(int), 0, cells - 1)
    ri = np.clip(((y[inner] + h) / cell).astype(int), 0, cells - 1)
    val[inner] = np.where(bits[ri, ci] > 127, 225.0, 25.0)
    rows, cols = v1 - v0 + 1, u1 - u0 + 1
    patch = img[v0:v1 + 1, u0:u1 + 1]
    sub = np.repeat(np.repeat(patch, SS, axis=0), SS, axis=1).ravel()
    sub = np.where(np.isnan(val), sub, val).reshape(rows * SS, cols * SS)
    mixed = srgb_to_linear(sub / 255.0).reshape(rows, SS, cols, SS).mean(axis=(1, 3))
    img[v0:v1 + 1, u0:u1 + 1] = 255.0 * linear_to_srgb(mixed)
    return True


def render(rig: Rig, poses: dict[str, Pose], keys=None, seed: int = 0, noise: float = 1.5) -> dict[str, np.ndarray]:
    """Every camera's BGR image (``{ROBOT/CAMERA: image}``) of the other robot's tags under ``poses`` (world)."""
    out = {}
    for k, key in enumerate(keys or rig.observer_keys()):
        robot, _ = rig.observer(key)
        mount = rig.mount(key)
        T_cw = (poses[robot] @ mount.pose).inverse()
        img = _background(seed + 10 * k, mount.camera.size)
        for other, orobot in rig.robots.items():
            if other == robot:
                continue
            for m in orobot.markers.values():
                if m.tag is not None and "tag_of" not in m.extra:
                    R = T_cw.R @ poses[other].R @ so3_exp(np.asarray(m.tag["rotation"], float))
                    _draw_tag(img, mount.camera, T_cw.apply(poses[other].apply(m.position)), R, m.tag["id"])
        img = img + np.random.default_rng(seed + 10 * k + 1).normal(0, noise, img.shape)
        out[key] = cv2.cvtColor(np.clip(img + 0.5, 0, 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    return out


def _errors(est, T: Pose) -> tuple[float, float]:
    return float(np.linalg.norm(est.t - T.t)), float(np.degrees(np.linalg.norm(so3_log(est.R @ T.R.T))))


@pytest.mark.parametrize("scene, seeing", [(facing_away, {"p/back", "q/back"}),
                                           (side_by_side, {"p/front", "p/back", "q/front", "q/back"})])
def test_localize_images_through_fisheyes(scene, seeing):
    rig, poses = scene()
    T = poses["q"].inverse() @ poses["p"]
    images = render(rig, poses)
    res = localize_images(rig, images, "p", "q")
    assert set(res.detections) == set(images)
    seen = {k for k, d in res.detections.items() if d.detections}
    assert seen == seeing
    # Detected through each camera's lens: the pixels are the raw image's, where the mount puts the corners.
    for key in seeing:
        robot, _ = rig.observer(key)
        other = "q" if robot == "p" else "p"
        mount = rig.mount(key)
        T_co = (poses[robot] @ mount.pose).inverse() @ poses[other]
        for name, d in res.detections[key].detections.items():
            truth = mount.camera.project(T_co.apply(_corner(rig, name)))
            assert np.linalg.norm(d.uv - truth) < 0.5, (key, name)
    dt, dr = _errors(res.estimate, T)
    print(f"{scene.__name__}: {len(res.estimate.markers_used)} corners, error {1000 * dt:.2f} mm, {dr:.3f} deg")
    assert res.estimate.status == "solved"
    assert dt < TOL_M and dr < TOL_DEG


def _corner(rig: Rig, name: str) -> np.ndarray:
    from mutloc.track.frames import expanded_rig

    return expanded_rig(rig).marker(name).position


#: A pinhole camera, for a robot given with ``camera:`` and for a posed pinhole camera on a body.
PINHOLE = Camera([[400, 0, 319.5], [0, 400, 199.5], [0, 0, 1]], size=(640, 400))
# A tag in an optical frame (x right, y down, z forward) seen from the camera's front: x left, z backwards.
FACING_OPTICAL = np.column_stack([[-1, 0, 0], [0, 1, 0], [0, 0, -1]]).astype(float)


def mixed():
    """p: one pinhole camera (``camera:``, its frame the optical one) looking at q; q: back-to-back fisheyes,
    turned away from p (its back camera sees p)."""
    tags = {"P1": ([-0.2, 0.1, 0.0], 0), "P2": ([0.2, 0.1, 0.0], 1), "P3": ([0.0, -0.15, 0.0], 2)}
    p = Robot("p", PINHOLE, {n: Marker(n, "p", np.asarray(pos, float), tag={
        "family": "tag36h11", "id": tid, "size": TAG, "rotation": so3_log(FACING_OPTICAL).tolist()})
        for n, (pos, tid) in tags.items()})
    q = _body("q", {"Q1": ([-0.22, 0.18, 0.42], FACING_BACK, 3), "Q2": ([-0.22, -0.18, 0.42], FACING_BACK, 4),
                    "Q3": ([-0.22, 0.0, 0.7], FACING_BACK, 5)})
    # p's optical frame 0.4 m up at x = 1.4, looking back along -x (at q).
    R_p = _yaw(math.pi + 0.1) @ OPTICAL_IN_BASE
    return Rig({"p": p, "q": q}), {"q": Pose(_yaw(math.pi), [0, 0, 0]), "p": Pose(R_p, [1.4, 0.1, 0.4])}


def test_cli_images_keyed_by_camera(tmp_path, capsys):
    """`mutloc localize-images --image p=... --image q/back=... --image q/front=...`: a robot given with
    `camera:` keeps ROBOT=, a body's cameras are ROBOT/CAMERA=; --detections-out is keyed so."""
    from mutloc.io import save_rig

    rig, poses = mixed()
    T = poses["q"].inverse() @ poses["p"]
    save_rig(rig, tmp_path / "rig.yaml")
    args = ["localize-images", "--rig", str(tmp_path / "rig.yaml"), "--detections-out", str(tmp_path / "d.json")]
    for key, img in render(rig, poses, keys=["p", "q/back", "q/front"], seed=3).items():
        path = tmp_path / f"{key.replace('/', '_')}.png"
        cv2.imwrite(str(path), img)
        args += ["--image", f"{key}={path}"]
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert (out["from"], out["to"]) == ("p", "q")
    dt = float(np.linalg.norm(np.asarray(out["t"]) - T.t))
    dr = float(np.degrees(np.linalg.norm(so3_log(np.asarray(out["R"]) @ T.R.T))))
    print(f"cli, mixed pinhole + fisheye: {len(out['markers_used'])} corners, error {1000 * dt:.2f} mm, {dr:.3f} deg")
    assert dt < TOL_M and dr < TOL_DEG
    dets = json.loads((tmp_path / "d.json").read_text())
    assert set(dets) == {"p", "q/back", "q/front"}
    assert {f"Q{i}#{k}" for i in (1, 2, 3) for k in range(4)} <= set(json.dumps(dets["p"]).replace('"', " ").split())
    assert "P1#0" in json.dumps(dets["q/back"]) and "P1#0" not in json.dumps(dets["q/front"])


@pytest.mark.parametrize("images, message", [
    ({"p": 0, "q/back": 0}, r"image 'p': robot 'p' has cameras front, back: give one image per camera"),
    ({"p/side": 0, "q/back": 0}, r"image 'p/side': unknown camera 'side' \(robot 'p' has cameras front, back\)"),
    ({"r/back": 0, "q/back": 0}, r"image 'r/back': unknown robot 'r'"),
    ({"p/back": 0, "q/back": 0, "q/../back": 0}, r"image 'q/../back': unknown robot 'q/..'"),
    ({"p/back": 0}, r"no image for robot 'q'"),
])
def test_bad_image_keys(images, message):
    rig, _ = facing_away()
    blank = np.zeros((H, W, 3), np.uint8)
    with pytest.raises(ObservationError, match=message):
        localize_images(rig, {k: blank for k in images}, "p", "q")


def test_bad_image_keys_mixed_rig():
    rig, _ = mixed()
    blank = np.zeros((H, W, 3), np.uint8)
    with pytest.raises(ObservationError, match=r"image 'p/cam': unknown camera 'cam' \(robot 'p' has one camera: "
                                               r"name it 'p' alone\)"):
        localize_images(rig, {"p/cam": blank, "q/back": blank})


def test_cli_bad_key_is_one_line(tmp_path, capsys):
    from mutloc.io import save_rig

    rig, _ = facing_away()
    save_rig(rig, tmp_path / "rig.yaml")
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((H, W, 3), np.uint8))
    for key in ("p", "p/side"):
        code = main(["localize-images", "--rig", str(tmp_path / "rig.yaml"), "--image", f"{key}={tmp_path / 'a.png'}",
                     "--image", f"q/back={tmp_path / 'a.png'}"])
        err = capsys.readouterr().err.strip()
        assert code != 0 and len(err.splitlines()) == 1 and f"'{key}'" in err and "Traceback" not in err, err


def _corners_truth(rig: Rig, poses: dict[str, Pose], key: str, name: str) -> np.ndarray:
    from mutloc.detect.tags import tag_corner_points

    robot, _ = rig.observer(key)
    other = "q" if robot == "p" else "p"
    T = (poses[robot] @ rig.mount(key).pose).inverse() @ poses[other]
    return rig.mount(key).camera.project(T.apply(tag_corner_points(rig.marker(name))))


@pytest.mark.parametrize("scene, key, name", [(side_by_side, "p/front", "Q1"), (side_by_side, "q/front", "P1"),
                                              (facing_away, "p/back", "Q3")])
def test_tag_looked_for_through_the_fisheye_where_the_mount_puts_it(scene, key, name):
    """The second look for a tag the first look missed: predicted through the camera's mount (its pose on the
    robot, its lens) from the robots' pose, found in a rectified view around the prediction, its corners
    back in the raw image where the ray-tracer put them (85 and 82 degrees off the axis side by side)."""
    rig, poses = scene()
    robot, _ = rig.observer(key)
    other = "q" if robot == "p" else "p"
    img = render(rig, poses, keys=[key])[key]
    T_ro = poses[robot].inverse() @ poses[other]  # the tag's robot -> the observing robot (body frames)
    more = find_missing_tags(rig, key, img, DetectionResult(), {other: [T_ro]})
    assert more is not None and f"{name}#0" in more.detections
    found = np.array([more.detections[f"{name}#{k}"].uv for k in range(4)])
    err = np.linalg.norm(found - _corners_truth(rig, poses, key, name), axis=1)
    print(f"{key} {name} looked for again: corner error max {err.max():.3f} px")
    assert err.max() < 0.3


def test_tag_looked_for_in_a_posed_pinhole_camera():
    """A body's pinhole camera posed on it (not at the robot's origin): the tag is predicted through the pose."""
    rig, poses = facing_away()
    q = rig.robot("q")
    back = q.cameras["back"]
    pinhole = Mount("back", PINHOLE, back.pose)
    rig = Rig({"p": rig.robot("p"), "q": Robot("q", None, q.markers, cameras={"front": q.cameras["front"],
                                                                              "back": pinhole})})
    img = render(rig, poses, keys=["q/back"])["q/back"]
    T_qp = poses["q"].inverse() @ poses["p"]
    more = find_missing_tags(rig, "q/back", img, DetectionResult(), {"p": [T_qp]})
    assert more is not None
    inside = [n for n in ("P1", "P2", "P3") if np.all(PINHOLE.in_image(_corners_truth(rig, poses, "q/back", n)))]
    assert len(inside) >= 2
    for name in inside:
        found = np.array([more.detections[f"{name}#{k}"].uv for k in range(4)])
        assert np.linalg.norm(found - _corners_truth(rig, poses, "q/back", name), axis=1).max() < 0.3


def test_ball_centres_through_the_mount():
    """The second look's ball centres are in the observing camera's frame (its pose on the robot)."""
    rig, poses = facing_away()
    ball = Marker("B", "p", np.array([-0.2, 0.0, 0.3]), color=(255, 40, 40), extra={"radius": 0.05})
    rig = Rig({"p": Robot("p", None, {**rig.robot("p").markers, "B": ball}, cameras=rig.robot("p").cameras),
               "q": rig.robot("q")})
    T_qp = poses["q"].inverse() @ poses["p"]
    got = ball_centres(rig, T_qp, "p", "q", ["q/back", "q/front"])
    for key in ("q/back", "q/front"):
        truth = (poses["q"] @ rig.mount(key).pose).inverse().apply(poses["p"].apply(ball.position))
        assert np.allclose(got[key]["B"], truth, atol=1e-12)
