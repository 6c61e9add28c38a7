"""The three ways a track starts in the team tracker
(:class:`~mutloc.track.team_tracker.TeamTracker`): from the record's joint
solve (:meth:`Starts._start`), from the last records' observations solved
together (:meth:`Starts._bridge`, then a joint start), and from the last
records at their own times for a robot seen only with the reference
(:meth:`Starts._moving_start`).  The state each starts in:
:func:`mutloc.track.lifecycle.start_state`.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ..api import localize
from ..core.observations import ObservationSet
from ..core.pose import Pose
from ..core.team import MIN_TIES, TeamProblem
from ..core.filter import fit_moving_pose
from ..errors import MutlocError
from . import lifecycle
from .lifecycle import Track, TrackState
from .filtering import MIN_START_DOF, lost_reason, pair_problem
from .status import FrameStatus


#: A robot entering the joint filter does so with this wide prior (1-sigma:
#: radians, metres) about its pose from the record's joint solve, then the
#: record's observations of it update the filter: its covariance and its
#: correlations with the robots already tracked come from those
#: observations (the prior adds about 1e-3 of their information).
#: Its velocity starts at zero with the motion noise's ``initial_angular`` /
#: ``initial_linear`` sigmas (:class:`~mutloc.core.filter.MotionNoise`), the
#: reference's unknown turning swept through its lever arm added
#: (:meth:`~mutloc.core.team_filter.TeamFilter.start_velocity_covariance`): one
#: record says nothing of it; its next records measure it.
START_SIGMA_R, START_SIGMA_T = 0.3, 0.5


class Starts:
    """Track starts of :class:`~mutloc.track.team_tracker.TeamTracker` (a mixin: its state is the tracker's)."""

    def _start_all(self, t: float, obs: ObservationSet, problem: TeamProblem, names: list[str], markers: list[str],
                   touch: Mapping[str, np.ndarray], used: np.ndarray, restart: Mapping[str, str], rejected: set[str],
                   notes: dict[str, list[str]]) -> tuple[dict[str, str], dict[str, tuple[FrameStatus, str]]]:
        """Start the robots not tracked (or to restart) that the record
        places: from its joint solve (:meth:`_start`), from the last records
        at their own times (:meth:`_moving_start`) or solved together
        (:meth:`_bridge`); drop the tracks due to restart that none
        restarted.  Returns the robots started (with the row's note) and the
        others' statuses."""
        candidates = [r for r in self.robots if (r not in self.tracks or r in restart)
                      and int(touch[r].sum()) >= MIN_TIES]
        started: dict[str, str] = {}
        failed: dict[str, tuple[FrameStatus, str]] = {}
        if candidates:
            started, failed = self._start(obs, problem, names, markers, touch, used, candidates, restart,
                                          rejected - set(restart))
        bridge = self._bridge(obs, touch, set(started) | rejected | set(restart))
        if bridge is not None:
            for r in list(bridge[1]):
                note = self._moving_start(t, obs, r)
                if note is None:
                    continue  # tied to other robots too: the joint start below
                bridge[1].remove(r)  # seen only with the reference: the tested start or none (yet)
                if note:  # placed by the records' observations at their own times, tested
                    started[r] = note
                    failed.pop(r, None)
                    used[touch[r]] = True
        if bridge is not None and bridge[1]:
            more, _ = self._start(obs, problem, names, markers, touch, used, bridge[1], {}, rejected, bridge[0])
            started.update(more)
            for r in more:
                failed.pop(r, None)
        for r, why in restart.items():
            if r in started:
                continue
            tr = self.tracks[r]
            if lifecycle.drop_after_restart(tr, self.options.reinit_after):
                self._drop(r)
                notes[r].append(f"track dropped: {why}" if tr.confirmed else
                                "tentative track dropped: a record contradicted it")
        return started, failed

    def _start(self, obs: ObservationSet, problem: TeamProblem, names: list[str], markers: list[str],
               touch: Mapping[str, np.ndarray], used: np.ndarray, candidates: list[str], restart: Mapping[str, str],
               rejected: set[str], bridged: ObservationSet | None = None
               ) -> tuple[dict[str, str], dict[str, tuple[FrameStatus, str]]]:
        """Place ``candidates`` from the record's joint solve (in the
        reference's frame, or in a tracked robot's it observed) and add those
        it places with four or more ties and a passing test (three: a
        tentative track, ``unverified``) to the filter: each enters with a
        wide prior about the solved pose, then the record's observations of
        it update the filter.  Returns the robots started (with the row's
        note) and the others' statuses.  ``bridged``: the observations of
        the last records together (see :meth:`_bridge`), solved as one for
        the poses the filter starts about (no chi-square test: they are not
        simultaneous; the wide prior covers their motion) -- a tentative
        track, the current record's observations its first update."""
        f = self.filter
        self.joint_solves += 1
        solve_on, conf = (obs, None) if bridged is None else (bridged, 1.0)
        team, status, reason = self._solve(solve_on, self.reference, conf)
        if bridged is None:
            self._own_solve = self._solve_test  # the record fitted on its own: the rig check's
        guesses: dict[str, tuple[Pose, bool]] = {}
        outliers = set()  # observations the joint solve dropped: left out of the update too
        if team is not None:
            outliers |= {(d["observer"], d["marker"]) for d in team.rejected}
            for r in candidates:
                if r in team.poses:
                    guesses[r] = (team.poses[r], r in team.unverified or team.status != "solved")
        missing = [r for r in candidates if r not in guesses]
        anchors = sorted((a for a in self.tracks if a not in restart and a not in candidates and a not in rejected
                          and touch[a].any()),
                         key=lambda a: -int(touch[a].sum()))
        if missing and anchors:
            a = anchors[0]
            other, st2, why2 = self._solve(solve_on, a, conf)
            if other is not None:
                outliers |= {(d["observer"], d["marker"]) for d in other.rejected}
                Ta = f.pose(a)
                for r in missing:
                    if r in other.poses:
                        guesses[r] = (Ta @ other.poses[r], r in other.unverified or other.status != "solved")
            elif team is None:
                status, reason = st2, why2
        failed = {}
        for r in candidates:
            if r not in guesses and r not in restart:
                failed[r] = (status if team is None and status != FrameStatus.SOLVED else FrameStatus.TOO_FEW,
                             reason if team is None else f"its observations do not tie it to {self.reference!r}")
        if not guesses:
            return {}, failed
        before = set(self.tracks)
        saved = (f.R.copy(), f.t.copy(), f.vel.copy(), f.P.copy(), None if f.Pg is None else f.Pg.copy(), f.noise_scale,
                 list(f.tracked), f.serial.copy(), dict(self.tracks))
        for r, (pose, three) in guesses.items():
            if r in self.tracks:
                self._drop(r)
            f.add(r, pose, np.diag([START_SIGMA_R**2] * 3 + [START_SIGMA_T**2] * 3))
        new = set(guesses)
        rows = np.flatnonzero(np.any([touch[r] for r in new], axis=0) & ~used)
        known = np.ones(len(problem.cam), dtype=bool)
        for r in self.robots:
            if (r not in self.tracks and r not in new) or r in rejected:
                known &= ~touch[r]
        rows = rows[known[rows]]
        if outliers:
            rows = np.array([j for j in rows.tolist() if (names[problem.cam[j]], markers[j]) not in outliers],
                            dtype=np.int64)
        upd = f.update(problem.take(rows)) if len(rows) else None
        if not set(guesses) & before:
            self._took(upd)  # (a restart's observations were in the tracked robots' update: counted there)
        started = {}
        if upd is not None and upd.accepted:
            used[rows[upd.used]] = True
            for r, (pose, three) in guesses.items():
                mine = touch[r][rows[upd.used]]
                keys = frozenset((names[problem.cam[j]], markers[j]) for j in rows[upd.used][mine].tolist())
                # a start on three, or bridged over records (no test of its own), is confirmed the strict way
                self.tracks[r] = Track(keys, lifecycle.start_state(three, bridged is not None, len(keys)))
                what = "restarted" if r in before else "started"
                note = f"track {what} from the record's joint solve ({len(keys)} observations)" if bridged is None \
                    else f"tentative track started from the last {len(self._recent) + 1} records solved together"
                if r in restart:
                    note = f"{note}: {restart[r]}"
                started[r] = note
            return started, failed
        # the record's observations of them contradict the others' tracks: not started (tracks restarting kept)
        f.R, f.t, f.vel, f.P, f.Pg, f.noise_scale, f.tracked, f.serial, self.tracks = saved
        for r in new:
            if r not in restart:
                failed[r] = (FrameStatus.REJECTED, "its joint solve is inconsistent with the tracked robots" +
                             (f" ({upd.reason})" if upd is not None else ""))
        return {}, failed

    def _bridge(self, obs: ObservationSet, touch: Mapping[str, np.ndarray], skip: set[str]
                ) -> tuple[ObservationSet, list[str]] | None:
        """The observations of the records of the last ``start_window``
        seconds and this one together (each camera's latest view of each
        marker) and the robots not tracked that this record sees or is
        seen by and that four or more of them tie to the team: a start
        bridging records of cameras that alone place nobody (two balls per
        robot, free-running cameras).  None when there is none."""
        if not self._recent or self.options.start_window <= 0:
            return None
        want = [r for r in self.robots if r not in self.tracks and r not in skip and touch[r].any()]
        if not want:
            return None
        latest: dict[tuple[str, str | None], tuple[tuple[float, float], float]] = {}
        for _, o in [*self._recent, (None, obs)]:
            for k in range(len(o)):
                latest[(o.observer[k], o.marker[k])] = (tuple(o.uv[k]), float(o.score[k]), float(o.sigma_scale[k]))
        keys = [k for k in latest if k[1] is not None]
        ties = {r: 0 for r in self.rig.robots}
        for observer, m in keys:
            ties[self.rig.observer(observer)[0]] += 1
            ties[self.rig.owner(m)] += 1
        want = [r for r in want if ties[r] > MIN_TIES]
        if not want or len(keys) <= MIN_TIES:
            return None
        both = ObservationSet.trusted([k[0] for k in keys], [k[1] for k in keys],
                                      np.array([latest[k][0] for k in keys]), score=[latest[k][1] for k in keys],
                                      sigma_scale=[latest[k][2] for k in keys])
        return both, want

    def _moving_start(self, t: float, obs: ObservationSet, r: str) -> str | None:
        """Start robot ``r`` from the records of the last ``start_window``
        seconds and this one when every observation of ``r`` in them is
        between it and the reference (as for a pair): its pose at ``t`` and
        velocity fitted to every observation at its own time
        (:func:`~mutloc.core.filter.fit_moving_pose`), started only where the
        records hold four or more distinct observations, the fit leaves
        ``MIN_START_DOF`` degrees of freedom and passes its chi-square test,
        and its uncertainty is within the track's limits -- then a confirmed
        track.  Returns the row's note, "" (not started: not yet) or None
        (``r`` is seen with other robots too)."""
        ref = self.reference
        problems, times, latest = [], [], {}
        for tk, o in [*self._recent, (t, obs)]:
            mine = []
            for k, (key, m) in enumerate(zip(o.observer, o.marker)):
                a = self._observer(key)  # the observing robot (a key may name one of its cameras)
                owner = self._owner(m) if m is not None else None
                if a != r and owner != r:
                    continue
                if {a, owner} != {r, ref}:
                    return None  # tied to other robots too: the joint start (see _bridge)
                mine.append(k)
            if not mine:
                continue
            try:
                pair = o.take(np.array(mine, dtype=np.int64)).pair(self.rig, r, ref)
            except MutlocError:
                return ""
            if len(pair.rows) == 0:
                continue
            if len(set(pair.side.tolist())) > 1:
                return ""  # a record of both cameras judges itself
            problems.append(pair_problem(pair))
            times.append(tk)
            for k in pair.rows.tolist():
                latest[(pair.parent.observer[k], pair.parent.marker[k])] = (pair.parent.uv[k],
                                                                            pair.parent.sigma_scale[k])
        n = sum(len(p.side) for p in problems)
        if len(latest) <= MIN_TIES or len(times) < 2 or 2 * n - 12 < MIN_START_DOF:
            return ""
        union = ObservationSet([o for o, _ in latest], [m for _, m in latest], np.array([v[0] for v in latest.values()]),
                               t, sigma_scale=[v[1] for v in latest.values()])
        try:
            first = localize(self.rig, union, r, ref, pixel_sigma=self.pixel_sigma, confidence=1.0)
        except MutlocError:
            return ""
        fit = fit_moving_pose(problems, times, t, first.pose, sigma=self.pixel_sigma, confidence=self.confidence,
                              noise=self.options.noise)
        if fit is None or not fit.test.passed or lost_reason(fit.state, self.options):
            return ""
        st = fit.state
        self._drop(r)
        self.filter.add(r, st.pose, st.pose_covariance, velocity=st.velocity, state_covariance=st.covariance)
        self.tracks[r] = Track(frozenset(latest), TrackState.CONFIRMED)
        span = 1000.0 * (times[-1] - times[0])
        return (f"track started from {len(times)} records over {span:.0f} ms ({n} observations of {len(latest)} "
                "markers; pose and velocity fitted at each record's time)")
