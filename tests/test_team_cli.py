"""``mutloc localize`` / ``localize-images`` in team mode and ``mutloc simulate --robots N``."""

import json

import numpy as np

import mutloc
from mutloc.cli.main import main
from mutloc.io import save_rig, write_json
from mutloc.sim.team import random_team


def _files(tmp_path, scene, obs):
    rig = tmp_path / "rig.yaml"
    save_rig(scene.rig, rig)
    path = tmp_path / "obs.json"
    write_json(obs.to_dict(), path)
    return str(rig), str(path)


def _run(argv, capsys):
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


def test_localize_team_json(tmp_path, capsys):
    rng = np.random.default_rng(0)
    scene = random_team(4, rng)
    rig, obs = _files(tmp_path, scene, scene.observations(0.5, rng))
    rc, out, err = _run(["localize", "--rig", rig, "--observations", obs], capsys)
    assert rc == 0, err
    d = json.loads(out)
    assert d["reference"] == "r0" and set(d["robots"]) == {"r1", "r2", "r3"}
    truth = scene.truth()
    for r, entry in d["robots"].items():
        assert np.linalg.norm(np.array(entry["t"]) - truth[r].t) < 0.05
    rc, out, err = _run(["localize", "--rig", rig, "--observations", obs, "--reference", "r2"], capsys)
    assert rc == 0, err
    d = json.loads(out)
    truth = scene.truth("r2")
    assert d["reference"] == "r2" and set(d["robots"]) == {"r0", "r1", "r3"}
    for r, entry in d["robots"].items():
        assert np.linalg.norm(np.array(entry["t"]) - truth[r].t) < 0.05
    # a pair of a team rig still works as before
    rc, out, err = _run(["localize", "--rig", rig, "--observations", obs, "--source", "r1", "--target", "r0"], capsys)
    assert rc == 0, err
    d = json.loads(out)
    assert (d["from"], d["to"]) == ("r1", "r0")


def test_localize_team_bad_input_is_one_line(tmp_path, capsys):
    rng = np.random.default_rng(1)
    scene = random_team(3, rng)
    obs = scene.observations().to_dict()
    obs["r1"]["r1_m0"] = (10.0, 10.0)
    rig, path = _files(tmp_path, scene, mutloc.ObservationSet.from_dict(obs))
    rc, out, err = _run(["localize", "--rig", rig, "--observations", path], capsys)
    assert rc == 2 and "own marker" in err and len(err.strip().splitlines()) == 1
    rig, path = _files(tmp_path, scene, scene.observations())
    rc, out, err = _run(["localize", "--rig", rig, "--observations", path, "--reference", "nobody"], capsys)
    assert rc == 2 and "nobody" in err
    rc, out, err = _run(["localize", "--rig", rig, "--observations", path, "--reference", "r0", "--source", "r1"],
                        capsys)
    assert rc == 2 and "exclude" in err


def test_simulate_team_then_localize(tmp_path, capsys):
    out = tmp_path / "team"
    rc, stdout, err = _run(["simulate", "--robots", "4", "--out", str(out), "--no-images", "--seed", "3"], capsys)
    assert rc == 0, err
    assert "rendering" not in err  # nothing is rendered: no rendering bar
    assert {p.name for p in out.iterdir()} == {"rig.yaml", "observations.json", "truth.json"}
    truth = json.loads((out / "truth.json").read_text())
    assert truth["reference"] == "r0" and set(truth["robots"]) == {"r1", "r2", "r3"}
    rc, stdout, err = _run(["localize", "--rig", str(out / "rig.yaml"), "--observations",
                            str(out / "observations.json")], capsys)
    assert rc == 0, err
    d = json.loads(stdout)
    # exact pixels: every robot the simulation ties to r0 is found exactly
    assert d["robots"], d
    for r, entry in d["robots"].items():
        np.testing.assert_allclose(entry["t"], truth["robots"][r]["t"], atol=1e-6)
        np.testing.assert_allclose(entry["R"], truth["robots"][r]["R"], atol=1e-6)
    assert len(d["robots"]) + len(d["unlocalized"]) == 3


def test_experiment_team_tiny(tmp_path):
    from mutloc.experiments.team import run_team

    res = run_team(tmp_path, seed=1, progress=False, sizes=(4,), teams=3)
    d = json.loads((tmp_path / "team" / "results.json").read_text())
    assert d["experiment"] == "team" and set(d["methods"]) == {"joint", "chained", "crlb"}
    assert (tmp_path / "team" / "report.md").exists() and (tmp_path / "team" / "team.png").exists()
    # the joint estimate is near its bound: no robot off by more than 10 sigma of the CRB on average
    assert d["methods"]["joint"]["rmse_translation_m"] < 3 * d["methods"]["crlb"]["rmse_translation_m"]
    assert res["by_team_size"]["4"]["robots"] > 0
