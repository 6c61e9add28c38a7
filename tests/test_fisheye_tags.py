"""Printed tags on the sides of robots with back-to-back fisheyes (issue 36 items 3 and 5):
``mutloc simulate --cameras back-to-back-fisheye --markers tags`` renders them, ``truth.json`` gives their
corners' pixels, ``mutloc localize-images`` localizes from the rendered images.

Truth independent of the code under test: the tags' corners are built here from the faces' geometry (outward
normal, centre, side; upright, read from outside) and projected with a Kannala-Brandt projection written here,
through the true pose ``T_qp`` and the camera's mount; the poses are the simulator's.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from _oracles import kb_project

from mutloc.cli.main import main
from mutloc.core.geometry import rotation_error_deg
from mutloc.core.pose import Pose
from mutloc.io import load_rig
from mutloc.sim import body_scenes as bodies
from mutloc.sim.render import relative_pose, render
from mutloc.track.frames import localize_images

SIZE = (640, 400)
# The faces of the simulated bodies (base_link: x forward, y left, z up): outward normal and tag centre.
FACES = {"front": ((1.0, 0.0, 0.0), (0.21, 0.0, 0.155)), "left": ((0.0, 1.0, 0.0), (0.0, 0.16, 0.155)),
         "back": ((-1.0, 0.0, 0.0), (-0.21, 0.0, 0.155)), "right": ((0.0, -1.0, 0.0), (0.0, -0.16, 0.155))}
NAMES = {"q": ("M1", "M2", "M3", "M4"), "p": ("M5", "M6", "M7", "M8")}


def face_corners(face: str, size: float = 0.20) -> np.ndarray:
    """A tag's corners on a face, as a viewer in front of it reads them: top-left, top-right, bottom-right,
    bottom-left (OpenCV's order)."""
    n, c = (np.array(v) for v in FACES[face])
    up = np.array([0.0, 0.0, 1.0])
    right = np.cross(-n, up)  # looking at the face (along -n), up is +z
    h = 0.5 * size
    return np.array([c - h * right + h * up, c + h * right + h * up, c + h * right - h * up, c - h * right - h * up])


def true_corners(rig, key: str, T_qp: Pose) -> dict[str, np.ndarray]:
    """Corners of the other robot's tags in camera ``key``'s raw pixels (all four faces, seen or not)."""
    rname, cname = key.split("/")
    other = "q" if rname == "p" else "p"
    T_r_other = T_qp if rname == "q" else T_qp.inverse()
    mount = rig.robot(rname).cameras[cname]
    T = mount.pose.inverse() @ T_r_other
    return {name: kb_project(mount.camera.K, np.asarray(mount.camera.dist), T.apply(face_corners(face)))
            for name, face in zip(NAMES[other], FACES)}


def test_simulate_tags_on_fisheye_bodies_truth_and_localize_images(tmp_path: Path, capsys) -> None:
    """Facing each other: the truth's corners are the independent projection; localize-images on the
    rendered images finds the front tags' corners where they are and the pose to a few millimetres."""
    out = tmp_path / "sim"
    assert main(["simulate", "--out", str(out), "--cameras", "back-to-back-fisheye", "--markers", "tags",
                 "--size", f"{SIZE[0]}x{SIZE[1]}", "--distance", "1.2", "--seed", "3", "--no-room"]) == 0
    assert "tags" in capsys.readouterr().out
    rig = load_rig(out / "rig.yaml")
    # a tag on each side of each body, each with its own id, pose and size
    tags = {n: m.tag for r in rig.robots.values() for n, m in r.markers.items()}
    assert sorted(tags) == [f"M{i}" for i in range(1, 9)] and len({t["id"] for t in tags.values()}) == 8
    truth = json.loads((out / "truth.json").read_text())
    frame = truth["frames"][0]
    T = Pose(np.array(frame["T_qp"]["R"]), np.array(frame["T_qp"]["t"]))
    assert set(frame["corners"]) >= {"p/front", "q/front"}
    for key, per_tag in frame["corners"].items():
        expect = true_corners(rig, key, T)
        for name, uv in per_tag.items():
            np.testing.assert_allclose(uv, expect[name], atol=1e-6, err_msg=f"{key} {name}")
    # facing each other, each front camera sees the other's front tag unhidden
    assert "M1" in frame["observations"]["p/front"] and "M1" not in frame["hidden"]["p/front"]
    assert "M5" in frame["observations"]["q/front"] and "M5" not in frame["hidden"]["q/front"]
    images = [a for k in ("p/front", "p/back", "q/front", "q/back")
              for a in ("--image", f"{k}={out / frame['images'][k]}")]
    est_file, det_file = tmp_path / "est.json", tmp_path / "det.json"
    assert main(["localize-images", "--rig", str(out / "rig.yaml"), *images, "--output", str(est_file),
                 "--detections-out", str(det_file)]) == 0
    est = json.loads(est_file.read_text())
    err_t = float(np.linalg.norm(np.array(est["t"]) - T.t))
    err_r = rotation_error_deg(np.array(est["R"]), T.R)
    print(f"facing toward, 1.2 m, {SIZE[0]}x{SIZE[1]}: {1000 * err_t:.2f} mm, {err_r:.3f} deg")
    assert err_t < 0.005 and err_r < 0.3
    det = json.loads(det_file.read_text())
    for key, name in (("p/front", "M1"), ("q/front", "M5")):
        found = det[key]["detections"]
        for k in range(4):
            uv = np.array(found[f"{name}#{k}"]["uv"])
            assert np.linalg.norm(uv - frame["corners"][key][name][k]) < 0.5, (key, name, k)


@pytest.mark.parametrize("seed", [1])
def test_tags_localize_back_to_back_through_the_back_fisheyes(seed: int) -> None:
    """Facing away from each other: only the back cameras see the other robot (its back tag, and a side
    tag steeply), and the pose from the four raw fisheye images is the simulator's."""
    rig = bodies.fisheye_pair_rig("tags", size=SIZE)
    world = bodies.body_pair_world(rig, *bodies.body_pair_pose(1.2, seed, "away"), room=False)
    keys = ("p/front", "p/back", "q/front", "q/back")
    images = {k: render(world, k, seed=seed, noise_sigma=1.0) for k in keys}
    res = localize_images(rig, images, "p", "q")
    truth = relative_pose(world, "p", "q")
    err_t = float(np.linalg.norm(res.estimate.t - truth.t))
    err_r = rotation_error_deg(res.estimate.R, truth.R)
    print(f"facing away, 1.2 m, {SIZE[0]}x{SIZE[1]}: {1000 * err_t:.2f} mm, {err_r:.3f} deg, "
          f"{ {k: sorted(d.detections) for k, d in res.detections.items()} }")
    assert not res.detections["p/front"].detections and not res.detections["q/front"].detections
    assert {"M3#0", "M3#3"} <= set(res.detections["p/back"].detections)
    assert {"M7#0", "M7#3"} <= set(res.detections["q/back"].detections)
    assert err_t < 0.005 and err_r < 0.3
