"""The window test of rig disagreement (issue 38, mutloc.track.rig_check):
on synthetic chi-square streams against the chi-square distribution, and
through the team tracker (a pair's track and a team's) on simulated logs
whose rig is right or has every marker 1-2 cm off (the simulator's truth
says which)."""

import math

import numpy as np
import pytest
from scipy.stats import chi2 as chi2_dist

from mutloc.api import load_rig
from mutloc.cli.main import main
from mutloc.io.logs import write_observation_log
from mutloc.sim.calibration import perturb_rig
from mutloc.sim.render import default_path
from mutloc.sim.team import random_team, team_sequence
from mutloc.sim.tracking import observation_sequence
from mutloc.sim.world import standard_rig
from mutloc.track.frames import expanded_rig
from mutloc.track.rig_check import FALSE_ALARM, RIG_HINT, WINDOW, RigCheck
from mutloc.track.team import track_team_log
from mutloc.track.tracker import track_log


def _feed(check, values, dof):
    return [check.add(c, dof) for c in values]


def test_window_sum_and_threshold_are_the_chi_square_quantile():
    """Thirty records of chi2 1.5 over 2 dof: the window sums 45 over 60 dof,
    judged against chi-square(60)'s 1 - 1e-6 quantile; not before it is full."""
    check = RigCheck()
    tests = _feed(check, [1.5] * WINDOW, 2)
    assert all(not t.full and not t.disagrees for t in tests[:-1])
    last = tests[-1]
    assert last.full and last.records == WINDOW and last.dof == 2 * WINDOW
    assert last.chi2 == pytest.approx(1.5 * WINDOW)
    assert last.threshold == pytest.approx(chi2_dist.ppf(1 - FALSE_ALARM, 2 * WINDOW), rel=1e-9)
    assert not check.disagrees and check.hint() is None
    # a sliding window: the 31st record replaces the first
    t = check.add(9.0, 2)
    assert t.records == WINDOW and t.chi2 == pytest.approx(1.5 * (WINDOW - 1) + 9.0)


def test_records_without_degrees_of_freedom_are_not_counted():
    check = RigCheck()
    assert check.add(5.0, 0) is None and check.add(math.nan, 4) is None
    t = check.add(2.0, 4)
    assert t.records == 1 and t.dof == 4
    assert check.add(math.nan, 0) is t


def test_level_on_honest_chi_square_streams():
    """Records drawn from chi-square (2 to 6 dof, as pairs of 4-6 observations
    give): at a 1 % level the share of windows that disagree is the level
    (the cap only lowers it), and at the default level none of 20,000 does."""
    rng = np.random.default_rng(0)
    dof = rng.integers(1, 4, size=20000) * 2
    values = rng.chisquare(dof)
    loose = RigCheck(false_alarm=0.01)
    default = RigCheck()
    for c, d in zip(values, dof):
        loose.add(c, d)
        default.add(c, d)
    share = loose.flagged / (loose.records - WINDOW + 1)
    assert 0.004 < share < 0.014, share
    assert default.flagged == 0


def test_excess_is_flagged_within_a_window():
    """Noise 1.7x the stated (every chi-square three times its share) or a
    rig that bends every record: flagged as soon as the window is full."""
    rng = np.random.default_rng(1)
    check = RigCheck()
    tests = _feed(check, 3.0 * rng.chisquare(2, size=60), 2)
    first = next(k for k, t in enumerate(tests) if t.disagrees)
    assert first == WINDOW - 1
    assert check.hint() == RIG_HINT and RIG_HINT in check.summary()
    assert "calibrate-markers" in tests[-1].words()


def test_one_stray_detection_is_not_the_rig():
    """One record a thousand sigmas off among honest ones counts as one bad
    record (capped at its own 0.99 quantile), not as the rig."""
    rng = np.random.default_rng(2)
    values = rng.chisquare(2, size=90)
    values[40] = 1e6
    check = RigCheck()
    assert not any(t.disagrees for t in _feed(check, values, 2))


def _sequence(seed, seconds=5.0):
    rig = standard_rig("balls")
    seq = observation_sequence(rig, default_path(2.0, 12.0, 0.3), duration=seconds, fps=30.0, pixel_sigma=1.0,
                               seed=seed)
    return rig, seq


@pytest.mark.parametrize("seed", [0, 1])
def test_pair_tracker_flags_a_rig_with_markers_off_and_not_the_right_one(seed):
    """Honest 1 px noise, 2 % stray detections, markers dropped and cameras
    blind at times: with the true rig no row is flagged and no hint; with every
    marker 1-2 cm off the track says so (rows and the hint) within two windows."""
    rig, seq = _sequence(seed)
    records = list(zip(seq.times, seq.frames))
    good = track_log(rig, records, progress=False)
    assert good.notes == []
    assert not any(RIG_HINT in r.reason for r in good.rows)
    wrong = expanded_rig(load_rig(perturb_rig(rig.to_dict(), np.random.default_rng([seed, 38]))))
    bad = track_log(wrong, records, progress=False)
    flagged = [k for k, r in enumerate(bad.rows) if RIG_HINT in r.reason]
    assert flagged and flagged[0] < 3 * WINDOW, flagged[:3]
    assert len(flagged) > 0.5 * len(bad.rows)
    assert len(bad.notes) == 1 and bad.notes[0].startswith(RIG_HINT)


def test_cli_track_prints_the_hint(tmp_path, capsys):
    rig, seq = _sequence(0, seconds=3.0)
    from mutloc.io import save_rig

    save_rig(perturb_rig(rig.to_dict(), np.random.default_rng([0, 38])), tmp_path / "rig.yaml")
    write_observation_log(tmp_path / "log.jsonl", seq.frames)
    assert main(["track", "--rig", str(tmp_path / "rig.yaml"), "--observations", str(tmp_path / "log.jsonl"),
                 "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert any(line.startswith(RIG_HINT) for line in out), out


def _team(seed, seconds=2.5):
    """Three robots (some pairs seen one way), every camera at once at 30 fps, honest 1 px noise; the
    rig as measured (true) and one with every marker 1-2 cm off."""
    scene = random_team(3, np.random.default_rng(seed), one_way=0.3)
    seq = team_sequence(scene, int(30 * seconds), 30.0, sigma=1.0, seed=seed)
    wrong = perturb_rig(scene.rig.to_dict(), np.random.default_rng([seed, 38]))
    return scene.rig, wrong, [(t, o) for t, _, o in seq]


def _flagged(traj):
    """The records (indices) whose rows say the rig disagrees."""
    n = len(next(iter(traj.tracks.values())).rows)
    return [k for k in range(n) if any(RIG_HINT in tr.rows[k].reason for tr in traj.tracks.values())]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_team_tracker_flags_a_rig_with_markers_off_and_not_the_right_one(seed):
    """The team path (``track`` with more than two robots): the true rig is
    never flagged; with every marker 1-2 cm off, the rows say so from the
    first full window on (or soon after) and the track's note is the hint."""
    rig, wrong, records = _team(seed)
    good = track_team_log(rig, records, progress=False)
    assert good.notes == [] and _flagged(good) == []
    bad = track_team_log(wrong, records, progress=False)
    flagged = _flagged(bad)
    assert flagged and flagged[0] < 2 * WINDOW, flagged[:3]
    assert len(flagged) > 0.5 * (len(records) - flagged[0])
    assert len(bad.notes) == 1 and bad.notes[0].startswith(RIG_HINT)
    assert all(RIG_HINT in bad.tracks[r].rows[flagged[0]].reason for r in bad.robots)  # every robot's row


def test_cli_team_track_prints_the_hint_and_the_rows_say_it(tmp_path, capsys):
    """``mutloc track`` on a team's log: with the rig 1-2 cm off one hint line
    and the reason column of the robots' files names it; with the true rig neither."""
    from mutloc.io import save_rig
    from mutloc.io.trajectory import read_trajectory_csv

    rig, wrong, records = _team(0)
    write_observation_log(tmp_path / "log.jsonl", [o for _, o in records])
    for name, spec in (("true", rig), ("wrong", wrong)):
        save_rig(spec, tmp_path / f"{name}.yaml")
        assert main(["track", "--rig", str(tmp_path / f"{name}.yaml"), "--observations", str(tmp_path / "log.jsonl"),
                     "--out", str(tmp_path / name), "--no-progress"]) == 0
        out = capsys.readouterr().out.splitlines()
        hints = [line for line in out if line.startswith(RIG_HINT)]
        rows = read_trajectory_csv(tmp_path / name / "trajectory_r1.csv")
        said = [RIG_HINT in r["reason"] for r in rows]
        if name == "true":
            assert hints == [] and not any(said), out
        else:
            assert len(hints) == 1 and sum(said) > len(said) / 3, out


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_team_update_reports_its_observations_fitted_on_their_own(seed):
    """``TeamUpdate.own``, accepted (the true rig) or rejected by the gate
    (every marker 1-2 cm off, the filter tight about the true poses): the
    chi-square and degrees of freedom of the same observations fitted on
    their own by the joint solver (nonlinear least squares, nothing left out)."""
    from mutloc.core.team_filter import TeamFilter
    from mutloc.team import localize_team, team_problem

    rng = np.random.default_rng(seed)
    scene = random_team(3, rng, one_way=0.0)
    names, truth = scene.names, scene.truth(scene.names[0])
    obs = scene.observations(0.5, rng)  # (as stated: the chi-square is over pixel_sigma squared)
    wrong = load_rig(perturb_rig(scene.rig.to_dict(), np.random.default_rng([seed, 38])))
    for rig, accepted in ((scene.rig, True), (wrong, False)):
        f = TeamFilter(names, names[0], pixel_sigma=0.5)
        f.time = 0.0
        for r in names[1:]:
            f.add(r, truth[r], np.diag([0.01] * 3 + [0.02] * 3) ** 2)
        upd = f.update(team_problem(rig, obs)[0])
        fit = localize_team(rig, obs, names[0], pixel_sigma=0.5, confidence=1.0, reject_outliers=False).consistency
        assert upd.accepted is accepted and len(upd.dropped) == (0 if accepted else len(obs))
        assert upd.own[1] == fit.dof == 2 * len(obs) - 12
        assert upd.own[0] == pytest.approx(fit.chi2, rel=0.01)
