"""``track --stream ... --clock-offsets estimate`` (SPEC "The robots' own motion and clocks"): the offsets
estimated from the streams' detections (a first pass over them) exactly as from the observation log of
those detections, and every frame of a robot then fused at its stamp plus its offset.  A rendered pair
(:func:`mutloc.sim.scenario.write_simulation`, rendered once per run for this test and
tests/test_live_end_to_end.py: tests/_shared_inputs.py) whose p stamps its frames 40 ms behind q (its own
``frames.csv``); the estimate's accuracy against the truth is tests/test_clock_offsets.py's (on logs)."""

import json

import numpy as np
from _shared_inputs import clock_offset_pair

from mutloc.cli.main import main
from mutloc.io.trajectory import read_trajectory_csv


def test_track_stream_estimates_as_from_the_log_and_shifts_the_robots_frames(tmp_path, tmp_path_factory, capsys):
    sim = clock_offset_pair(tmp_path_factory)  # 60 frames at 30 fps, p 40 ms behind (rendered once per run)
    base = ["track", "--rig", str(sim / "rig.yaml"), "--no-progress", "--clock-offsets", "estimate"]
    streams = ["--stream", f"p={sim / 'p'}", "--stream", f"q={sim / 'q'}"]
    log = tmp_path / "log.jsonl"
    assert main(["track", "--rig", str(sim / "rig.yaml"), "--no-progress", *streams, "--observations-out", str(log),
                 "--out", str(tmp_path / "plain")]) == 0
    assert main([*base, *streams, "--out", str(tmp_path / "s")]) == 0
    assert main([*base, "--observations", str(log), "--out", str(tmp_path / "o")]) == 0
    printed = capsys.readouterr().out
    got = json.loads((tmp_path / "s" / "clock_offsets.json").read_text())
    assert got == json.loads((tmp_path / "o" / "clock_offsets.json").read_text())
    off = got["p"]["offset_s"]
    assert off is not None and abs(off) > 0.002, got  # (a shift the stamps below can show)
    assert printed.count(f"clock offset of p: {off * 1000:+.1f} ms") == 2
    # every frame of p fused at its stamp plus the offset (the rows' t_source, 4 decimals), q's as stamped
    p_stamps = np.loadtxt(sim / "p" / "frames.csv", delimiter=",", skiprows=1)[:, 1]
    q_stamps = np.loadtxt(sim / "q" / "frames.csv", delimiter=",", skiprows=1)[:, 1]
    for out, shift in (("s", off), ("plain", 0.0)):
        rows = read_trajectory_csv(tmp_path / out / "trajectory.csv")
        for column, stamps in (("t_source", p_stamps + shift), ("t_target", q_stamps)):
            got = np.sort([float(r[column]) for r in rows if r[column] != ""])
            np.testing.assert_allclose(got, np.sort(stamps), atol=1e-4, err_msg=f"{out} {column}")
