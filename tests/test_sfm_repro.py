"""The Bundler baseline is reproducible (same seed, same registered images and
errors, bit for bit), matches only image pairs that can share a point of the
scene, and reports its run time by stage."""

from __future__ import annotations

import csv
import json
import math
import sqlite3

import numpy as np
import pytest

from mutloc.baselines.sfm import SfmScene, farthest_reference
from mutloc.core.camera import Camera
from mutloc.core.rig import Marker, Robot
from mutloc.errors import InputError, NoSolutionError
from mutloc.experiments._common import StageTimer, timing_lines
from mutloc.experiments.localization import run_localization
from mutloc.sim.walkaround import robot_points, view_overlap
from mutloc.sim.world import Room, camera_to_world_facing

W, H, F = 640, 360, 500.0
CAM = Camera(np.array([[F, 0.0, (W - 1) / 2], [0.0, F, (H - 1) / 2], [0.0, 0.0, 1.0]]), [0.0] * 5, (W, H))
ROOM = Room(center=(0.0, 0.0), size=(6.0, 6.0), height=2.6)


def _bundler_rows(out):
    with open(out / "localization" / "positions.csv", newline="", encoding="utf-8") as f:
        return [(r["bundler_translation_m"], r["bundler_rotation_deg"], r["bundler_failure"])
                for r in csv.DictReader(f)]


def _database(path):
    """Every image's id, keypoints and descriptors, and every verified pair, from a COLMAP database."""
    con = sqlite3.connect(path)
    try:
        return {t: con.execute(f"SELECT * FROM {t} ORDER BY 1").fetchall()
                for t in ("images", "keypoints", "descriptors", "two_view_geometries")}
    finally:
        con.close()


@pytest.mark.slow
def test_same_seed_gives_the_same_sfm_result_twice(tmp_path, monkeypatch):
    """Two runs of the localization experiment on a small grid: the SfM baseline
    registers the same images with bit-identical errors, and those errors are
    small against the rendered truth.  Underneath, with matching on two
    threads, the two runs wrote the same COLMAP database (the same image
    numbering, features and verified matches) and built the same model, pose
    for pose.  Before extraction ran on one thread, COLMAP numbered the images
    in the order their features finished, and the model changed run to run.
    (The experiment's own SfmScene, kept in a folder of the test's to be read.)"""
    import mutloc.baselines.sfm as sfm_module

    scenes = []

    class KeptScene(sfm_module.SfmScene):
        def __init__(self, *args, **kwargs):
            kwargs["workdir"] = tmp_path / f"sfm{len(scenes)}"
            super().__init__(*args, **kwargs)
            self.result = None
            scenes.append(self)

        def reconstruct(self, *args, **kwargs):
            self.result = super().reconstruct(*args, **kwargs)
            return self.result

    monkeypatch.setattr(sfm_module, "SfmScene", KeptScene)
    kw = dict(seed=2, grid_x_ft=(0,), grid_z_ft=(5, 6), walkaround_views=10, progress=False)
    a, b = (run_localization(tmp_path / name, **kw) for name in ("a", "b"))
    ba, bb = a["methods"]["bundler"], b["methods"]["bundler"]
    for key in ("registered_images", "sfm_points", "solved", "matched_pairs", "median_translation_m",
                "median_rotation_deg", "mean_reprojection_px"):
        assert ba[key] == bb[key], key
    assert _bundler_rows(tmp_path / "a") == _bundler_rows(tmp_path / "b")
    # The same database and model, run to run.
    assert len(scenes) == 2 and all(s.result is not None for s in scenes)
    assert _database(scenes[0].database) == _database(scenes[1].database)
    res_a, res_b = scenes[0].result, scenes[1].result
    assert sorted(res_a.poses) == sorted(res_b.poses)
    for n in res_a.poses:
        np.testing.assert_array_equal(res_a.poses[n].as_matrix(), res_b.poses[n].as_matrix())
    assert res_a.points == res_b.points and res_a.mean_reprojection_px == res_b.mean_reprojection_px
    # Independent ground truth: the rendered poses.  Measured (seed 2): 14 of 14 images, both positions.
    assert ba["solved"] == 2 and ba["registered_images"] == ba["images"] == 14
    assert ba["median_translation_m"] < 0.05 and ba["median_rotation_deg"] < 1.0
    # Fewer pairs than all of them: the two robots' frames face each other and share nothing.
    assert ba["matched_pairs"] < ba["all_pairs"] == 14 * 13 // 2
    # The run time by stage reaches results.json and the report.
    timing = json.loads((tmp_path / "a" / "localization" / "results.json").read_text())["timing"]
    for stage in ("render robot frames", "SfM: feature extraction", "SfM: matching and verification",
                  "SfM: incremental mapping"):
        assert timing["stages"][stage]["cpu_s"] > 0 and timing["stages"][stage]["wall_s"] > 0
    assert "| SfM: incremental mapping |" in (tmp_path / "a" / "localization" / "report.md").read_text()


def _facing(pos, yaw_deg):
    return camera_to_world_facing(pos, yaw=math.radians(yaw_deg))


def test_view_overlap_of_facing_and_parallel_cameras():
    """Two cameras 2 m apart facing each other see opposite walls: nothing
    shared; side by side, looking the same way, they share most of the wall."""
    a = _facing((-1.0, 0.0, 0.5), 0.0)  # looking along +x
    b = _facing((1.0, 0.0, 0.5), 180.0)  # looking along -x, at a
    c = _facing((-1.0, 0.3, 0.5), 0.0)  # beside a, the same way
    ov = view_overlap(ROOM, {"a": (CAM, a), "b": (CAM, b), "c": (CAM, c)}, margin=0.0)
    assert ov[("a", "b")] == 0.0 and ov[("b", "a")] == 0.0
    assert ov[("a", "c")] > 0.8 and ov[("c", "a")] > 0.8
    assert set(ov) == {(x, y) for x in "abc" for y in "abc" if x != y}


def test_view_overlap_counts_an_object_only_where_it_exists():
    """b sees a robot standing in front of a; a pair shares it only if the robot is in both views' worlds."""
    a = _facing((-1.0, 0.0, 0.5), 0.0)
    b = _facing((1.0, 0.0, 0.5), 180.0)
    robot = Robot("r", CAM, {"M": Marker("M", "r", np.array([0.0, 0.0, 0.0]))})
    pts = robot_points(robot, _facing((0.0, 0.0, 0.5), 90.0))  # between a and b, seen by both
    views = {"a": (CAM, a), "b": (CAM, b)}
    both = view_overlap(ROOM, views, objects={"a": {"r": pts}, "b": {"r": pts}}, margin=0.0)
    assert both[("a", "b")] > 0.0 and both[("b", "a")] > 0.0
    one = view_overlap(ROOM, views, objects={"b": {"r": pts}}, margin=0.0)
    assert one[("a", "b")] == 0.0 and one[("b", "a")] == 0.0
    # The same key for a different robot position is a different object only if the key says so.
    moved = view_overlap(ROOM, views, objects={"a": {("r", 0): pts}, "b": {("r", 1): pts}}, margin=0.0)
    assert moved[("a", "b")] == 0.0


def test_view_outside_the_room_and_bad_pairs_are_typed_errors():
    with pytest.raises(InputError, match="not inside the room"):
        view_overlap(ROOM, {"a": (CAM, _facing((5.0, 0.0, 0.5), 0.0)), "b": (CAM, _facing((0.0, 0.0, 0.5), 0.0))})
    img = np.zeros((H, W, 3), np.uint8)
    with pytest.raises(InputError, match="image pair"):
        SfmScene({"a": img, "b": img}, CAM, pairs=[("a", "c")])
    with pytest.raises(InputError, match="image pair"):
        SfmScene({"a": img, "b": img}, CAM, pairs=[("a", "a")])
    with pytest.raises(NoSolutionError):
        farthest_reference({"a": (0, 0, 0), "b": (1, 0, 0)}, ["a"])
    ref = farthest_reference({"a": (0, 0, 0), "b": (1, 0, 0), "c": (0, 3, 0), "d": (9, 9, 9)}, ["a", "b", "c"])
    assert {ref.a, ref.b} == {"b", "c"} and ref.distance == pytest.approx(math.sqrt(10))


def test_stage_timer_adds_up_cpu_and_wall_time():
    timer = StageTimer()
    with timer("busy"):
        x = 0.0
        for i in range(200_000):
            x += i ** 0.5
    with timer("busy"):
        pass
    t = timer.as_dict()
    busy = t["stages"]["busy"]
    assert busy["cpu_s"] > 0 and busy["wall_s"] > 0
    assert t["wall_s"] >= busy["wall_s"] - 0.01 and t["cpu_s"] >= busy["cpu_s"] - 0.01
    assert t["stages"]["other"]["wall_s"] == pytest.approx(t["wall_s"] - busy["wall_s"], abs=0.02)
    assert any("| busy |" in ln for ln in timing_lines(t))
