"""The live localizer's word on a rig that keeps disagreeing with the
observations (issue 38; the window test of mutloc.track.rig_check, fed by
the team tracker the localizer runs): WARN in ``/diagnostics`` with the
test's values and the ``calibrate-markers`` hint, the hint said once -- and
nothing of it with the rig the simulator drew the observations with.  No
pose is published before the rig check's first full window has agreed
(mutloc.live.rig_gate), unless the rig check gets no test at all.

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
from mutloc.core.consistency import chi2_quantile
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
    loc.batches = []  # (the rig check's last test when poses were returned, how many)
    loc.waiting_diag = {}  # (each robot's diagnostics when a pose of it was first held back waiting for the rig check)

    def took(poses):
        if poses:
            loc.batches.append((loc.engine.tracker.rig_check.last, len(poses)))
        loc.published += poses
    recs = team_camera_records(scene, 2.5, sigma=1.0, seed=seed)
    if again is not None:
        recs = recs + [(t + again, a, w, obs) for t, a, w, obs in recs]
    for k, (t, a, _, obs) in enumerate(recs):
        now = T0 + t + LATENCY
        while loc.next_due() is not None and loc.next_due() <= now:
            took(loc.poll(loc.next_due()))
        took(loc.feed(M.observations_message(a, rid, k, T0 + t, obs), now, a))
        for r, c in loc.counts.items():
            if r not in loc.waiting_diag and c.rig_waiting:
                loc.waiting_diag[r] = {s.robot: s for s in loc.diagnostics(now)}[r]
    end = T0 + recs[-1][0] + LATENCY
    took(loc.poll(end + 0.05))
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
def test_no_pose_is_published_with_the_rig_off(tmp_path, seed):
    """Every marker of the rig file 1-2 cm off: no pose of any robot is
    returned for publishing -- neither before the first window is full
    (waiting for the rig check) nor once it disagrees (withheld) -- and both
    are counted."""
    loc, _, _ = _run(tmp_path, seed, wrong=True)
    assert loc.rig_withheld is not None
    assert not loc.published, [(p.robot, p.t - T0) for p in loc.published[:5]]
    assert sum(c.rig_waiting for c in loc.counts.values()) > 0
    assert sum(c.rig_withheld for c in loc.counts.values()) > 0
    assert loc.rig_gate.state == "disagrees"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_right_rig_is_published_once_a_full_window_agreed(tmp_path, seed):
    """The rig file the simulator drew with: poses are returned only after a
    full window of the rig check has agreed (the test at each return: full,
    chi-square within its threshold; the first within its 0.99 quantile); before, they were held back, counted,
    and ``/diagnostics`` said so (WARN, waiting for the rig check, N of 30
    tests), and the summary counts them."""
    loc, _, _ = _run(tmp_path, seed, wrong=False)
    assert loc.published and loc.rig_gate.state == "agrees"
    for test, n in loc.batches:
        assert test is not None and test.full and test.chi2 <= test.threshold, (test, n)
    held = sum(c.rig_waiting for c in loc.counts.values())
    assert held > 0
    first, _ = loc.batches[0]
    assert first.chi2 <= chi2_quantile(0.99, first.dof)
    assert min(p.t for p in loc.published) >= loc.rig_gate.agreed - loc.tolerance
    assert loc.waiting_diag and loc.reference not in loc.waiting_diag
    for r, s in loc.waiting_diag.items():  # (when its first pose was held back)
        assert s.values["rig_check"] == "waiting", (r, s.values)
        assert s.level == M.WARN and "waiting for the rig check:" in s.message, (r, s.message)
        n, m = map(int, s.message.split("waiting for the rig check: ")[1].split(" tests")[0].split(" of "))
        assert 0 <= n < m == loc.engine.tracker.rig_check.window, s.message
    assert f"poses not published: {held} waiting for the rig check" in loc.summary()


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
    assert loc.rig_gate.state == "agrees"
    diag = loc.diagnostics(end + 0.1)
    for s in diag:
        assert s.level == M.OK and RIG_HINT not in s.message, (s.robot, s.message)
        assert float(s.values["rig_chi2"]) <= float(s.values["rig_threshold"])
        assert s.values["rig_dof"] > 0


def _pair(tmp_path, odometry):
    """Two robots of two balls each, free-running cameras (q half a frame after p): one camera's
    record fits any rig on its own; ``odometry``: p's odometry given (the pooled rig test is then
    skipped: the rig check gets no test).  Returns the localizer, the poses returned, the truth."""
    from mutloc.core.odometry import Odometry
    from mutloc.sim.odometry import drifting_odometry, odometry_times
    from mutloc.sim.render import default_path
    from mutloc.sim.tracking import camera_records
    from mutloc.sim.world import standard_rig
    from mutloc.track.filtering import FilterOptions

    rig = standard_rig("balls")
    path = default_path(2.0, 8.0, 0.3)  # T_qp(t): q stays, p drives in front of it
    recs = camera_records(rig, path, duration=3.5, offsets={"q": 1 / 60}, pixel_sigma=1.0, seed=3)
    file = tmp_path / "rig.yaml"
    save_rig(rig, file)
    rid = M.rig_id(file)
    options = None
    if odometry:
        times = odometry_times(0.0, 3.6, 50.0)
        odo = Odometry(T0 + times, drifting_odometry(path, times, seed=3))
        options = FilterOptions(smooth_lag=0, odometry={"p": odo})
    loc = Localizer(file, filter=options)
    published, k = [], 0
    for t, obs, cams in zip(recs.times, recs.frames, recs.cameras):
        for c in cams:
            k += 1
            now = T0 + t + LATENCY
            while loc.next_due() is not None and loc.next_due() <= now:
                published += loc.poll(loc.next_due())
            published += loc.feed(M.observations_message(c, rid, k, T0 + t, obs), now, c)
    published += loc.finish()
    return loc, published, {round(float(t), 6): T for t, T in zip(recs.times, recs.truth)}


def test_without_a_rig_test_the_wait_ends_after_a_window_of_records(tmp_path):
    """With odometry the one-camera records are not pooled: the rig check gets no test, and
    the wait ends after UNTESTED records held back by it alone (state ``not running``, said
    once); the poses published then are the truth's (each record's own gate tests them).
    The same records without odometry are pooled: the window fills and agrees."""
    from mutloc.live.rig_gate import UNTESTED

    loc, published, truth = _pair(tmp_path, odometry=True)
    gate = loc.rig_gate
    assert loc.engine.tracker.rig_check.records == 0  # (no test at all: the case)
    assert gate.state == "not running" and gate.untested_at is not None
    assert sum(c.rig_waiting for c in loc.counts.values()) == UNTESTED
    assert published and min(p.t for p in published) >= gate.untested_at - loc.tolerance
    errs = [float(np.linalg.norm(p.estimate.t - truth[round(p.t - T0, 6)].t)) for p in published]
    assert np.median(errs) < 0.05, np.median(errs)
    diag = {s.robot: s for s in loc.diagnostics(max(p.t for p in published))}
    assert diag["p"].values["rig_check"] == "not running"
    pooled, published2, _ = _pair(tmp_path, odometry=False)
    assert pooled.rig_gate.state == "agrees" and pooled.engine.tracker.rig_check.last.full and published2
