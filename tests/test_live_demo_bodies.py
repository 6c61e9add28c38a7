"""Live with robots that are bodies (issue 36): ``mutloc demo --live
--cameras back-to-back-fisheye`` renders two robots with two fisheyes each
(``front`` and ``back``) standing back to back, so that only the back
cameras see the other robot, and runs one ``mutloc node`` per robot with
both cameras (``--camera front=DIR --camera back=DIR``) and a ``mutloc
localizer`` as separate processes on loopback DDS.  The poses a subscriber
receives are checked against the rendered truth (the simulator's world, not
anything the localizer computed)."""

import json

import pytest

from mutloc.cli.main import main

pytestmark = pytest.mark.slow

# 4 s: the cameras run in step, so each record holds both back cameras' frames and tests the rig on its own;
# no pose is published before 30 such records (3 s) agreed with the rig (mutloc.live.rig_gate)
SECONDS, FPS = 4.0, 10.0


def test_demo_live_with_back_to_back_fisheyes_poses_robots_facing_away(tmp_path, capsys, dds_domain):
    assert main(["demo", "--live", "--cameras", "back-to-back-fisheye", "--seconds", str(SECONDS), "--fps",
                 str(FPS), "--out", str(tmp_path), "--domain", str(dds_domain), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    summary = json.loads((tmp_path / "live" / "live_summary.json").read_text())
    frames = int(SECONDS * FPS)
    # each node ran both of its robot's cameras, each camera replayed every frame
    assert sorted(summary["cameras"]) == ["p/back", "p/front", "q/back", "q/front"], summary["cameras"]
    for key, c in summary["cameras"].items():
        assert c["captured"] == frames and c["processed"] + c["dropped"] >= frames, (key, c)
    # the localizer received both cameras' messages of both robots (frame_id ROBOT/CAMERA) ...
    keys = set()
    with open(tmp_path / "live" / "localizer" / "log.jsonl", encoding="utf-8") as fh:
        for line in fh:
            keys.update(json.loads(line).get("observations", {}))
    assert {"p/back", "q/back"} <= keys, keys
    # ... and only the back cameras see the other robot: the poses come from them, and they are right
    loc = summary["localizer"]
    assert loc is not None and loc["records_fused"] >= 0.5 * frames, loc
    assert loc["rig_waiting"] > 0 and loc["rig_withheld"] == 0, loc
    assert summary["poses_received"] >= 5 and summary["poses_received"] >= 0.9 * loc["poses_published"], summary
    assert summary["poses_without_a_known_frame"] == 0
    assert summary["translation_error_cm"]["median"] < 2.0, summary["translation_error_cm"]
    assert summary["rotation_error_deg"]["median"] < 1.0, summary["rotation_error_deg"]
    assert "only the back cameras see the other robot" in printed


def test_cameras_is_for_the_live_demo(capsys):
    assert main(["demo", "--cameras", "back-to-back-fisheye", "--out", "/nonexistent-mutloc-out"]) != 0
    err = capsys.readouterr().err.strip()
    assert "--cameras is for the live demo: add --live" in err and len(err.splitlines()) == 1
