"""Observation logs (SPEC "Observation logs"): written by track, read back,
tracked from, and bad lines named."""

import json

import numpy as np
import pytest

from mutloc.cli.main import main
from mutloc.core.observations import ObservationSet
from mutloc.errors import FileFormatError, ObservationError
from mutloc.io import save_rig
from mutloc.io.logs import read_observation_log, write_observation_log
from mutloc.io.trajectory import read_trajectory_csv, read_tum
from mutloc.sim.render import moving_world, relative_pose, render
from mutloc.sim.world import standard_rig


def test_round_trip(tmp_path):
    frames = [ObservationSet.from_dict({"p": {"M1": [1.5, 2.0]}, "q": [[3.0, 4.0]]}, time=0.1 * i) for i in range(3)]
    write_observation_log(tmp_path / "log.jsonl", frames)
    back = list(read_observation_log(tmp_path / "log.jsonl"))
    assert back == frames
    lines = (tmp_path / "log.jsonl").read_text().splitlines()
    assert json.loads(lines[1]) == {"time": 0.1, "observations": {"p": {"M1": [1.5, 2.0]}, "q": [[3.0, 4.0]]}}


@pytest.mark.parametrize("line,words", [
    ("not json", ["log.jsonl:2", "not JSON"]),
    ('{"time": "x", "observations": {}}', ["log.jsonl:2", "time"]),
    ('{"time": 0.0, "observations": {}}', ["log.jsonl:2", "goes back"]),
    ('{"time": 2.0, "obs": {}}', ["log.jsonl:2"]),
    ('{"time": 2.0, "observations": {"p": {"M1": [1, "a"]}}}', ["log.jsonl:2", "'M1'"]),
])
def test_bad_lines_name_file_and_line(tmp_path, line, words):
    f = tmp_path / "log.jsonl"
    f.write_text('{"time": 1.0, "observations": {"p": {"M1": [1, 2]}}}\n' + line + "\n")
    with pytest.raises((FileFormatError, ObservationError)) as info:
        list(read_observation_log(f))
    for w in words:
        assert w in str(info.value)


@pytest.mark.parametrize("text", ["", "\n\n  \n"])
def test_a_log_without_frames_is_refused(tmp_path, capsys, text):
    """An empty trajectory would look like a track that saw nothing."""
    f = tmp_path / "log.jsonl"
    f.write_text(text)
    with pytest.raises(FileFormatError, match="log.jsonl: no frames"):
        list(read_observation_log(f))
    save_rig(standard_rig("balls"), tmp_path / "rig.yaml")
    code = main(["track", "--rig", str(tmp_path / "rig.yaml"), "--observations", str(f),
                 "--out", str(tmp_path / "out"), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code != 0 and "no frames" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_track_writes_a_log_and_tracks_from_it(tmp_path, capsys):
    import cv2

    rig = standard_rig("balls")
    world = moving_world(rig, distance=2.0, seed=4)
    fps = 10.0
    for r in ("p", "q"):
        (tmp_path / r).mkdir()
    for i in range(5):
        for r in ("p", "q"):
            cv2.imwrite(str(tmp_path / r / f"{i:06d}.png"), render(world, r, i / fps, seed=i, noise_sigma=1.0))
    save_rig(rig, tmp_path / "rig.yaml")
    log = tmp_path / "out" / "log.jsonl"
    assert main(["track", "--rig", str(tmp_path / "rig.yaml"), "--stream", f"p={tmp_path / 'p'}",
                 "--stream", f"q={tmp_path / 'q'}", "--fps", str(fps), "--out", str(tmp_path / "a"),
                 "--observations-out", str(log), "--no-progress"]) == 0
    frames = list(read_observation_log(log))
    assert len(frames) == 5 and all(len(f) == 4 for f in frames)
    assert main(["track", "--rig", str(tmp_path / "rig.yaml"), "--observations", str(log),
                 "--out", str(tmp_path / "b"), "--no-progress"]) == 0
    a = read_trajectory_csv(tmp_path / "a" / "trajectory.csv")
    b = read_trajectory_csv(tmp_path / "b" / "trajectory.csv")
    assert [r["status"] for r in b] == [r["status"] for r in a] == ["solved"] * 5
    for ra, rb, i in zip(a, b, range(5)):
        assert rb["pose"].translation_error(ra["pose"]) < 1e-9
        T = relative_pose(world, "p", "q", i / fps)
        assert rb["pose"].translation_error(T) < 0.01
        assert np.all(rb["sigma"] > 0)
    times, poses = read_tum(tmp_path / "b" / "trajectory.tum")
    np.testing.assert_allclose(times, np.arange(5) / fps, atol=1e-9)
    assert "5 frames: 5 solved" in capsys.readouterr().out


@pytest.mark.parametrize("bad", ['{"time": oops}\n', '{"time": 0.0, "observations": {}}\n'],
                         ids=["not JSON", "time goes back"])
@pytest.mark.parametrize("team", [False, True], ids=["pair", "team"])
def test_a_bad_line_ends_the_log_there_and_keeps_the_records_before_it(tmp_path, capsys, bad, team):
    """A bad line in the middle of a log: the records before it are tracked
    and written -- the same rows as a track of a log that ends there -- and
    the error names the file and line (one line, exit 2)."""
    from mutloc.sim.team import random_team, team_sequence
    from mutloc.sim.tracking import camera_records

    n = 20
    if team:
        scene = random_team(3, np.random.default_rng(4), one_way=0.0)
        rig, records = scene.rig, [(t, obs) for t, _, obs in team_sequence(scene, 30, 20.0, sigma=1.0, seed=4)]
        names = [f"trajectory_{r}.csv" for r in scene.names[1:]]
    else:
        rig = standard_rig()
        recs = camera_records(rig, duration=1.0, offsets={"q": 1 / 60}, seed=3)
        records = [(float(f.times[0]) + 1.0, f) for f in recs.frames]
        names = ["trajectory.csv"]
    save_rig(rig, tmp_path / "rig.yaml")
    write_observation_log(tmp_path / "good.jsonl", [obs.with_time(t) for t, obs in records[:n]])
    write_observation_log(tmp_path / "all.jsonl", [obs.with_time(t) for t, obs in records])
    lines = (tmp_path / "all.jsonl").read_text().splitlines(keepends=True)
    (tmp_path / "bad.jsonl").write_text("".join(lines[:n] + [bad] + lines[n:]))
    args = ["track", "--rig", str(tmp_path / "rig.yaml"), "--no-progress"]
    assert main(args + ["--observations", str(tmp_path / "good.jsonl"), "--out", str(tmp_path / "ref")]) == 0
    capsys.readouterr()
    assert main(args + ["--observations", str(tmp_path / "bad.jsonl"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"mutloc: error: {tmp_path / 'bad.jsonl'}:{n + 1}: "), err
    assert f"the {n} records before it were tracked" in err and "trajectory" in err, err
    for name in names:
        assert (tmp_path / "out" / name).read_bytes() == (tmp_path / "ref" / name).read_bytes()
        assert len(read_trajectory_csv(tmp_path / "out" / name)) == n
