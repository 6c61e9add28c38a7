"""The Blender spec of robots with several fisheyes and printed tags (no bpy needed: only the spec)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from mutloc.core.lenses import FisheyeCamera
from mutloc.core.pose import Pose
from mutloc.core.rig import Marker, Mount, Robot
from mutloc.errors import InputError
from mutloc.sim.blender import scene_spec
from mutloc.sim.bodies import OPTICAL_IN_BASE, back_to_back_fisheye
from mutloc.sim.world import DEFAULT_TAG_ROTATION, Room, World, WorldRobot, tag_image


def _body(name: str, lens: FisheyeCamera, tag_id: int) -> Robot:
    cams = {"front": Mount("front", lens, Pose(OPTICAL_IN_BASE, np.array([0.1, 0.0, 0.6])))}
    tag = Marker(f"{name}T", name, np.array([0.2, 0.0, 0.3]),
                 tag={"family": "tag36h11", "id": tag_id, "size": 0.14, "rotation": list(DEFAULT_TAG_ROTATION)})
    return Robot(name, None, {tag.name: tag}, cameras=cams)


def test_fisheye_views_and_tags_in_the_spec(tmp_path):
    f = 400 / math.radians(97.5)
    lens = FisheyeCamera([[f, 0, 399.5], [0, f, 399.5], [0, 0, 1]], [0, 0, 0, 0], (800, 800))
    T_p = Pose(np.eye(3), np.array([0.0, 0.0, 0.0]))
    T_q = Pose(np.diag([-1.0, -1.0, 1.0]), np.array([1.5, 0.0, 0.0]))
    w = World({"p": WorldRobot(_body("p", lens, 0), T_p, body=False),
               "q": WorldRobot(_body("q", lens, 1), T_q, body=False)}, room=Room(size=(6.0, 6.0)))
    spec = scene_spec(w, {"p/front": tmp_path / "p.png", "q/front": tmp_path / "q.png"}, texture_dir=tmp_path / "tex")
    views = {v["robot"]: v for v in spec["views"]}
    assert views["p/front"]["lens"] == {"model": "fisheye", "f": pytest.approx(f)}
    # The camera's pose in the world is the body's pose times the mount's.
    assert np.allclose(views["q/front"]["t"], T_q.apply([0.1, 0.0, 0.6]))
    assert np.allclose(views["q/front"]["R"], T_q.R @ OPTICAL_IN_BASE)
    tags = [o for o in spec["objects"] if o.get("interpolation") == "Closest"]
    assert len(tags) == 2
    for o in tags:
        img = cv2.imread(o["texture"], cv2.IMREAD_UNCHANGED)
        assert any(np.array_equal(img, tag_image("tag36h11", i)) for i in (0, 1))
        assert o["uv_scale"] == [1.0, 1.0] and o["half_u"] == pytest.approx(0.5 * 0.14 * 10 / 8)


def test_lenses_blender_cannot_draw_are_refused(tmp_path):
    T = Pose(np.eye(3), np.zeros(3))
    kb = back_to_back_fisheye("p", {"M1": [0.0, 0.1, 0.4]})  # Kannala-Brandt k1..k4 != 0
    w = World({"p": WorldRobot(kb, T, body=False)})
    with pytest.raises(InputError, match="equidistant"):
        scene_spec(w, {"p/front": tmp_path / "p.png"}, texture_dir=tmp_path / "tex")
    with pytest.raises(InputError, match="has cameras front, back: name one"):
        scene_spec(w, {"p": tmp_path / "p.png"}, texture_dir=tmp_path / "tex")
    with pytest.raises(InputError, match="no camera 'side'"):
        scene_spec(w, {"p/side": tmp_path / "p.png"}, texture_dir=tmp_path / "tex")
    off = FisheyeCamera([[235.0, 0, 390.0], [0, 235.0, 399.5], [0, 0, 1]], [0, 0, 0, 0], (800, 800))
    w = World({"p": WorldRobot(_body("p", off, 0), T, body=False)})
    with pytest.raises(InputError, match="principal point"):
        scene_spec(w, {"p/front": tmp_path / "p.png"}, texture_dir=tmp_path / "tex")
