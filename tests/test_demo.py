"""`mutloc demo` end to end: files written, pose close to the known truth."""

import json

import numpy as np

from mutloc.cli.main import main
from mutloc.sim.demo import demo_truth


def test_demo_runs_and_recovers_the_truth(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "translation error" in out
    result = json.loads((tmp_path / "result.json").read_text())
    truth = demo_truth()
    cov = np.array(result["covariance"])
    err_t = np.array(result["t"]) - truth.t
    # Within 4 sigma of the reported covariance, and a few cm in absolute terms.
    assert err_t @ np.linalg.solve(cov[3:, 3:], err_t) < 16 * 3
    assert np.linalg.norm(err_t) < 0.05
    assert (tmp_path / "rig.yaml").exists() and (tmp_path / "observations.json").exists()
