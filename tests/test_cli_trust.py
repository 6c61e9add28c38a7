"""The command line never prints a pose it cannot stand behind, and its
shared options are declared once."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np

from mutloc.cli.main import build_parser
from test_cli import run_error, run_ok, scene_observations, write_scene


def test_three_markers_need_allow_unverified(tmp_path, capsys):
    obs = scene_observations()
    obs["p"].pop(sorted(obs["p"])[0])
    while sum(len(v) for v in obs.values()) > 3:
        obs["q"].pop(sorted(obs["q"])[0])
    rig, o = write_scene(tmp_path, obs=obs)
    msg = run_error(["localize", "--rig", rig, "--observations", o], capsys)
    assert "--allow-unverified" in msg and "3 marker observations" in msg
    res = run_ok(["localize", "--rig", rig, "--observations", o, "--allow-unverified"], capsys)
    assert res["status"] == "unverified" and res["consistency"]["dof"] == 0


def test_one_wrong_pixel_among_four_is_an_error_not_a_pose(tmp_path, capsys):
    obs = scene_observations()
    name = sorted(obs["p"])[0]
    obs["p"][name] = [obs["p"][name][0] + 60.0, obs["p"][name][1]]
    rig, o = write_scene(tmp_path, obs=obs)
    msg = run_error(["localize", "--rig", rig, "--observations", o], capsys)
    assert "do not fit one pose" in msg
    # with a noise the user states as 100 px, it fits (and the covariance says so)
    res = run_ok(["localize", "--rig", rig, "--observations", o, "--pixel-sigma", "100"], capsys)
    assert res["status"] == "solved" and res["consistency"]["passed"] is True


def test_clean_result_reports_its_test(tmp_path, capsys):
    rig, o = write_scene(tmp_path)
    res = run_ok(["localize", "--rig", rig, "--observations", o], capsys)
    c = res["consistency"]
    assert res["status"] == "solved" and c["passed"] is True and c["dof"] == 2 * len(res["markers_used"]) - 6
    assert c["chi2"] < 1e-6 and c["threshold"] > 0


def _option_helps(parser):
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    out = {}
    for name, p in sub.choices.items():
        for a in p._actions:
            for s in a.option_strings:
                out.setdefault(s, {})[name] = a.help
    return out


def test_shared_options_are_declared_once():
    helps = _option_helps(build_parser())
    for opt in ("--rig", "--source", "--target", "--pixel-sigma", "--confidence", "--no-progress"):
        texts = set(helps[opt].values())
        assert len(helps[opt]) >= 2 and len(texts) == 1, (opt, helps[opt])


def test_help_imports_no_heavy_library():
    code = ("import sys\nfrom mutloc.cli.main import main\n"
            "for argv in (['--help'], ['localize', '--help'], ['track', '--help']):\n"
            "    try:\n        main(argv)\n    except SystemExit:\n        pass\n"
            "print(sorted(m for m in ('numba', 'scipy', 'cv2', 'matplotlib') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "[]", out


def test_same_stream_for_two_robots_is_refused(tmp_path, capsys):
    import cv2

    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(3):
        cv2.imwrite(str(folder / f"{i:06d}.png"), np.zeros((540, 960, 3), np.uint8))
    rig, _ = write_scene(tmp_path)
    msg = run_error(["track", "--rig", rig, "--stream", f"p={folder}", "--stream", f"q={folder}", "--fps", "10",
                     "--out", str(tmp_path / "out"), "--no-progress"], capsys)
    assert "same stream" in msg and "'p'" in msg and "'q'" in msg


def test_stream_frame_rates(tmp_path):
    import cv2

    from mutloc.track.sources import open_source

    video = tmp_path / "v.mp4"
    vw = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 10.0, (64, 48))
    for i in range(5):
        vw.write(np.full((48, 64, 3), 20 * i, np.uint8))
    vw.release()
    assert abs(open_source(video).fps - 10.0) < 1e-6
    folder = tmp_path / "f"
    folder.mkdir()
    for i in range(4):
        cv2.imwrite(str(folder / f"{i:03d}.png"), np.zeros((8, 8, 3), np.uint8))
    (folder / "frames.csv").write_text("frame,timestamp\n" + "".join(f"{i},{5 + i / 15:.9f}\n" for i in range(4)))
    s = open_source(folder)
    assert abs(s.fps - 15.0) < 1e-6
    np.testing.assert_allclose([f.t for f in s], [5 + i / 15 for i in range(4)], atol=1e-9)
    assert open_source(folder, fps=7.0).fps == 7.0
    json.dumps({"fps": s.fps})
