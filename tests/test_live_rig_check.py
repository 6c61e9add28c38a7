"""The live localizer's word on a rig that keeps disagreeing with the
observations (issue 38; the window test of mutloc.track.rig_check, fed by
the team tracker the localizer runs): WARN in ``/diagnostics`` with the
test's values and the ``calibrate-markers`` hint, the hint said once -- and
nothing of it with the rig the simulator drew the observations with.

Without DDS: :class:`~mutloc.live.localizer.Localizer` fed the messages
three simulated robots' nodes would publish (each camera at 30 fps at its
own phase, 1 px noise), and its diagnostics builder asked.
"""

import numpy as np
import pytest

from mutloc.io import save_rig
from mutloc.live import messages as M
from mutloc.live.localizer import NOTICE_HOLD, Localizer
from mutloc.sim.calibration import perturb_rig
from mutloc.sim.team import random_team, team_camera_records
from mutloc.track.rig_check import RIG_HINT

pytest.importorskip("cyclonedds", reason="the live extra (cyclonedds) is part of make test's install")

T0 = 1_800_000_000.0  # the robots' wall clock at the records' time 0
LATENCY = 0.008


def _run(tmp_path, seed, wrong, again=None):
    """The localizer on a team's messages (rig file true, or every marker 1-2 cm off); its lines said.
    ``again``: the same records once more, that many seconds later."""
    scene = random_team(3, np.random.default_rng(seed), one_way=0.3)
    spec = perturb_rig(scene.rig.to_dict(), np.random.default_rng([seed, 38])) if wrong else scene.rig
    path = tmp_path / f"rig_{seed}_{wrong}.yaml"
    save_rig(spec, path)
    rid = M.rig_id(path)
    said: list[str] = []
    loc = Localizer(path, notify=said.append)
    loc.published = []  # (the poses returned for publishing, kept for the tests)
    recs = team_camera_records(scene, 2.5, sigma=1.0, seed=seed)
    if again is not None:
        recs = recs + [(t + again, a, w, obs) for t, a, w, obs in recs]
    for k, (t, a, _, obs) in enumerate(recs):
        now = T0 + t + LATENCY
        while loc.next_due() is not None and loc.next_due() <= now:
            loc.published += loc.poll(loc.next_due())
        loc.published += loc.feed(M.observations_message(a, rid, k, T0 + t, obs), now, a)
    end = T0 + recs[-1][0] + LATENCY
    loc.published += loc.poll(end + 0.05)
    return loc, said, end


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_diagnostics_warn_with_the_hint_when_the_rig_is_off(tmp_path, seed):
    loc, said, end = _run(tmp_path, seed, wrong=True)
    assert loc.rig_flag is not None, "the window test never fired"
    at, test = loc.rig_flag
    assert test.disagrees and test.chi2 > test.threshold
    diag = loc.diagnostics(end + 0.1)
    assert [s.robot for s in diag] == loc.names
    assert loc.rig_withheld is not None  # (2.5 s of a wrong rig: withheld from the first window on, to the end)
    for s in diag:
        assert RIG_HINT in s.message, (s.robot, s.message)
        if s.robot == loc.reference:
            assert s.level == M.WARN, (s.robot, s.message)
        else:  # its poses are withheld: an error, and said so
            assert s.level == M.ERROR and s.message.startswith("not published since"), (s.robot, s.message)
            assert s.values["rig_withheld"] == loc.counts[s.robot].rig_withheld > 0
        # the values are the window's latest test (the one that fired or a later one)
        last = loc.engine.tracker.rig_check.last
        assert float(s.values["rig_chi2"]) == pytest.approx(last.chi2, abs=0.06)
        assert s.values["rig_dof"] == last.dof
        assert float(s.values["rig_threshold"]) == pytest.approx(last.threshold, abs=0.06)
    assert sum(RIG_HINT in line for line in said) == 1, said  # said once
    # held for NOTICE_HOLD s after the last record whose window disagreed, then not said
    assert all(RIG_HINT not in s.message for s in loc.diagnostics(at + NOTICE_HOLD + 0.1))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_no_pose_is_published_while_the_rig_disagrees(tmp_path, seed):
    """From the first record whose window disagrees on, while withheld, no
    pose of any robot is returned for publishing; before it they were."""
    loc, _, _ = _run(tmp_path, seed, wrong=True)
    assert loc.rig_withheld is not None
    before = [p for p in loc.published if p.t < loc.rig_withheld]
    after = [p for p in loc.published if p.t > loc.rig_withheld]
    assert before and not after, (len(before), [(p.robot, p.t - loc.rig_withheld) for p in after[:5]])
    assert sum(c.rig_withheld for c in loc.counts.values()) > 0


def test_the_hint_is_said_once_in_a_run(tmp_path):
    """The rig disagrees again 12 s later (beyond the 10 s after which other
    notices are said again): still one line."""
    loc, said, end = _run(tmp_path, 1, wrong=True, again=12.0)
    assert loc.rig_flag is not None and loc.rig_flag[0] > T0 + 12.0  # it disagreed in the second part too
    assert sum(RIG_HINT in line for line in said) == 1, said


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_true_rig_is_not_flagged(tmp_path, seed):
    loc, said, end = _run(tmp_path, seed, wrong=False)
    assert loc.rig_flag is None and not any(RIG_HINT in line for line in said)
    assert loc.rig_withheld is None and loc.published and all(c.rig_withheld == 0 for c in loc.counts.values())
    diag = loc.diagnostics(end + 0.1)
    for s in diag:
        assert s.level == M.OK and RIG_HINT not in s.message, (s.robot, s.message)
        assert float(s.values["rig_chi2"]) <= float(s.values["rig_threshold"])
        assert s.values["rig_dof"] > 0
