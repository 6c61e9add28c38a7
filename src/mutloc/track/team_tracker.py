"""The team tracker: one joint filter of the whole team, a row per robot
per record (the behaviour: :mod:`mutloc.track.team`'s docstring).

Its parts: each track's state and rules (:mod:`.lifecycle`), the three ways
a track starts (:mod:`.starts`), hindsight -- confirmation reported back and
undo (:mod:`.hindsight`), the record and its rows (:mod:`.records`).  Here:
a record in (:meth:`TeamTracker.step`), the joint filter's update and each
track's confirmation or rejection (:meth:`TeamTracker._filtered`), the
smoothed rows out (:meth:`TeamTracker.finalize`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import replace
from typing import Any, Mapping

import numpy as np

from ..api import Estimate, rejected_text
from ..core.consistency import DEFAULT_CONFIDENCE
from ..core.observations import ObservationSet
from ..core.pose import Pose
from ..core.rays import set_aside_past_rim
from ..core.rig import Rig
from ..core.team import MIN_TIES, TeamProblem, residual_norms
from ..core.filter import STATE_DIM
from ..core.team_filter import TeamFilter
from ..core.team_smoother import TeamSmoother
from ..errors import (InconsistentObservationsError, InputError, MutlocError, ObservationError, OdometryError,
                      positive_number)
from ..team import TeamEstimate, in_rays, localize_team, team_problem
from . import lifecycle
from .lifecycle import PoseCov, Track, TrackState, UndoRequest, ties_to_one
from .filtering import FilterOptions, lost_reason
from .status import FrameStatus
from .rows import TrackRow
from .hindsight import Hindsight
from .records import Record, Rows, Tentative, join
from .rig_check import RigCheck
from .starts import Starts

__all__ = ["TeamTracker"]


class TeamTracker(Starts, Hindsight, Rows):
    """Turns each record of team observations into one row per robot (see the module docstring)."""

    def __init__(self, rig: Rig, reference: str | None = None, *, pixel_sigma: float = 1.0,
                 confidence: float = DEFAULT_CONFIDENCE, options: FilterOptions | None = None) -> None:
        names = list(rig.robots)
        if len(names) < 2:
            raise ObservationError(f"a team tracker needs two or more robots; the rig has {len(names)}")
        if reference is None:
            reference = names[0]
        if not isinstance(reference, str) or reference not in rig.robots:
            raise ObservationError(f"unknown reference robot {reference!r} (rig has {sorted(rig.robots)})")
        self.rig, self.reference = rig, reference
        self.robots = [n for n in names if n != reference]
        self.pixel_sigma = positive_number(pixel_sigma, "pixel_sigma")
        self.confidence = confidence
        self.options = options if options is not None else FilterOptions()
        self.filter = TeamFilter(names, reference, self.options.noise, pixel_sigma, confidence,
                                 measure_noise=self.options.measure_noise)
        for name, odo in self.options.odometry.items():
            if name not in rig.robots:
                raise OdometryError(f"odometry of {name!r}: no robot {name!r} in the rig "
                                    f"(robots: {', '.join(names)})")
            self.filter.set_odometry(name, odo, self.options.clock_offsets.get(name, 0.0))
        #: With ``smooth_lag``: the joint filter's states of the records not yet
        #: final and their rows (see :meth:`finalize`).
        self.smoother = TeamSmoother(self.options.smooth_lag) if self.options.smooth_lag and self.filtering else None
        self._unfinal: list[Record] = []
        #: Confirmations of tentative tracks whose records may still be reported
        #: again: (time, the records, the one that started it, its record number, robot).
        self._confirmations: list[tuple[float, list[Tentative], Tentative | None, int, str]] = []
        self._k = 0  #: the number of the record being filtered
        self._replaying = False
        self.tracks: dict[str, Track] = {}
        #: The records of the last ``start_window`` seconds (a start may bridge them).
        self._recent: deque[tuple[float, ObservationSet]] = deque()
        self.last_time: float | None = None
        self.joint_solves = 0  #: records solved on their own to start (or restart) a robot
        #: Do the records keep disagreeing with the rig? (a window test, see .rig_check): fed each
        #: record's observations fitted on their own (see _rig_test); while its window disagrees,
        #: the records' rows say so.
        self.rig_check = RigCheck()
        self._own = [0.0, 0]  # the record's (chi2, dof) so far: its filter updates'
        #: The record's update's rows when they fit any rig on their own, and the velocities and tracked robots
        #: before it.
        self._alone: tuple[TeamProblem, tuple[np.ndarray, np.ndarray]] | None = None
        self._names = names  # (rig order: a TeamProblem's robot indices)
        self._own_solve: Any = None  # the record's joint solve's test (covers all of it: preferred)
        self._solve_test: Any = None

    @property
    def filtering(self) -> bool:
        return self.options.kind == "cv"

    # -- one record -----------------------------------------------------------

    def step(self, t: float, observations: ObservationSet | None, times: Mapping[str, float | None] | None = None,
             problems: Mapping[str, tuple[FrameStatus, str]] | None = None,
             rows: dict[str, TrackRow] | None = None) -> dict[str, TrackRow]:
        """One row per robot (not the reference) for the record at ``t``: its
        observations (any cameras', taken at ``t``) fused at ``t``.

        ``times``: each robot's own frame time in the record (``t_source``;
        the reference's is ``t_target``; None: the record holds no frame of
        that camera); ``problems``: per robot an input status (``unpaired``,
        ``corrupt``) and reason for its own frame.  ``observations`` None: no
        frame at all.  ``rows``: the row objects to fill (default new ones);
        with smoothing a row may still change until :meth:`finalize` makes it final."""
        if self.last_time is not None and t < self.last_time:
            raise InputError(f"frame at {t} s comes before the previous one ({self.last_time} s)")
        if rows is None:
            rows = {r: TrackRow(t, t if times is None else times.get(r),
                                t if times is None else times.get(self.reference), FrameStatus.SOLVED,
                                observations=observations) for r in self.robots}
        rec = Record(float(t), observations, times, problems, rows)
        if not self.filtering:
            self.last_time = rec.t
            self._own, self._own_solve, self._alone = [0.0, 0], None, None
            self._per_record(observations, rows)
            self._rig_test(rows)
            self._input_problems(rec)
            return rows
        undo = self._filter_record(rec)
        if undo is not None:
            self._roll_back(undo)
            again = self._filter_record(rec)  # the undone records no longer hold the track: this cannot undo any
            assert again is None
        return rows

    def _filter_record(self, rec: Record, exclude: str | None = None) -> UndoRequest | None:
        """Filter one record and keep it (with smoothing) until final
        (``exclude``: a robot whose observations in it are left out); or,
        when it contradicts records a track took unverified, the request to
        undo them (the record then is neither kept nor final)."""
        sm = self.smoother
        # an undo can only go back to a record a track took unsupported: save the state before such records
        rec.saved = self._save() if sm is not None and not self._replaying and any(
            tr.confirmed and not tr.supported for tr in self.tracks.values()) else None
        self.last_time = rec.t
        self._k = len(sm) if sm is not None else 0
        self.filter.predict(rec.t)
        prior = self.filter.snapshot() if sm is not None else None
        obs = rec.obs
        if exclude is not None and obs is not None:
            obs = obs.take(np.array([i for i, (o, m) in enumerate(zip(obs.observer, obs.marker))
                                     if self._observer(o) != exclude and (m is None or self._owner(m) != exclude)],
                                    dtype=np.int64))
        undo = self._filtered(rec.t, obs, rec.rows)
        if undo is not None:
            return undo
        if obs is not None and len(obs):
            self._recent.append((rec.t, obs))
        while self._recent and rec.t - self._recent[0][0] > self.options.start_window:
            self._recent.popleft()
        if sm is not None:
            sm.add(prior, self.filter.snapshot())
            self._unfinal.append(rec)
        self._input_problems(rec)
        return None

    def _owner(self, marker: str) -> str | None:
        try:
            return self.rig.owner(marker)
        except MutlocError:
            return None

    def _observer(self, key: str) -> str | None:
        """The robot of an observation key (``ROBOT`` or ``ROBOT/CAMERA``), None for an unknown one."""
        try:
            return self.rig.observer(key)[0]
        except MutlocError:
            return None

    @property
    def history(self) -> TeamSmoother | None:
        """The smoother's records (None without smoothing: every row is final at once)."""
        return self.smoother

    def finalize(self, end: bool = False, *, most: int | None = None, smooth: bool = True) -> int:
        """Make final the rows of the records that nothing to come can
        change, in input order, and return how many records are final (all
        of them without smoothing).  ``most``: at most this many records
        made final by this call (the others wait for the next); ``smooth``
        False: those records' rows are made final as the causal filter gave
        them, not smoothed (the live localizer when it cannot keep up).

        With ``smooth_lag``: each robot's pose, covariance and velocity in a
        record's rows become the fixed-lag smoothed ones of the joint state
        (the record and the ``smooth_lag`` records after it; see
        :mod:`mutloc.core.team_smoother`) -- what a fixed-lag smoother reports
        ``smooth_lag`` records late.  A record is final once ``smooth_lag +
        1`` records came after it and no confirmation of a tentative track may
        still report it again; ``end``: the input ended, every record is."""
        sm = self.smoother
        if sm is None:
            return 0
        self._report_tentative(end)
        n = len(sm)
        limit = n if end else max(sm.first, n - sm.lag - 1)
        if not end:
            for c in self._confirmations:
                limit = min(limit, min(p.k for p in c[1]))
            for tr in self.tracks.values():
                if tr.undo is not None:
                    limit = min(limit, tr.undo.first - sm.lag)
            limit = max(limit, sm.first)
        if most is not None:
            limit = min(limit, sm.first + max(0, most))
        for k in range(sm.first, limit if smooth else sm.first):
            state = sm.smoothed(k)
            for r, row in self._unfinal[k - sm.first].rows.items():
                e = row.estimate
                x = state.position(self.filter.index(r))
                if e is None or x < 0 or e.extra.get("filter") != "cv" or e.extra.get("smoother") == "backward":
                    continue
                b = slice(STATE_DIM * x, STATE_DIM * x + 6)
                pose = Pose(state.R[x].copy(), state.t[x].copy())
                row.estimate = replace(e, pose=pose, covariance=state.P[b, b].copy(),
                                       candidates=Pose.concatenate([pose]),
                                       extra=dict(e.extra, smooth_lag=sm.lag, velocity=state.vel[x].tolist()))
        del self._unfinal[:limit - sm.first]
        sm.forget(limit)
        return limit

    def relative(self, a: str, b: str) -> Estimate | None:
        """``T_ba`` (robot ``a`` in ``b``'s frame; either may be the
        reference) now, with its covariance from the joint filter (their
        correlation included; the causal filter's, not smoothed); None
        unless both are tracked."""
        if a == b or any(r != self.reference and r not in self.tracks for r in (a, b)):
            return None
        pose, cov = self.filter.relative(a, b)
        return Estimate(source=a, target=b, pose=pose, covariance=cov, pixel_sigma=self.pixel_sigma,
                        reprojection_rms_px=0.0, markers_used=[], candidates=Pose.concatenate([pose]),
                        consistency=None, extra={"filter": "cv", "team_reference": self.reference})

    def predicted(self, t: float) -> dict[str, Pose]:
        """Where the filter expects each robot of a confirmed track at ``t`` (``{robot: T_ref_robot}``, the
        reference's identity included; the filter itself is not moved), e.g. to look for a marker the
        record's first look missed (:func:`mutloc.track.tag_look.look_where_tracked`).  Empty without the
        filter, before any robot is confirmed, or for a ``t`` before the filter's time."""
        if not self.filtering or self.filter.time is None or t < self.filter.time:
            return {}
        confirmed = [r for r, tr in self.tracks.items() if tr.confirmed and self.filter.is_tracked(r)]
        if not confirmed:
            return {}
        f = self.filter.copy()
        f.predict(t)
        return {self.reference: Pose.identity(), **{r: f.pose(r) for r in confirmed}}

    def _solve(self, obs: ObservationSet, reference: str, confidence: float | None = None
               ) -> tuple[TeamEstimate | None, FrameStatus, str]:
        """The record's joint estimate in ``reference``'s frame, or None with a status and reason.
        ``_solve_test``: its chi-square test (a rejected one's best attempt's; None: nothing fitted)."""
        self._solve_test = None
        try:
            team = localize_team(self.rig, obs, reference, pixel_sigma=self.pixel_sigma,
                                 confidence=self.confidence if confidence is None else confidence)
            self._solve_test = team.consistency
            return team, FrameStatus.SOLVED, ""
        except InconsistentObservationsError as exc:
            self._solve_test = getattr(exc.estimate, "consistency", None)
            return None, FrameStatus.REJECTED, " ".join(str(exc).split())
        except ObservationError as exc:
            status = FrameStatus.TOO_FEW if "three or more" in str(exc) else FrameStatus.FAILED
            return None, status, " ".join(str(exc).split())
        except MutlocError as exc:
            return None, FrameStatus.FAILED, " ".join(str(exc).split())

    # -- the joint filter -------------------------------------------------------

    def _filtered(self, t: float, obs: ObservationSet | None, rows: dict[str, TrackRow]) -> UndoRequest | None:
        f = self.filter
        self._own, self._own_solve, self._alone = [0.0, 0], None, None
        if obs is None or len(obs) == 0:
            self._coast(rows, set())
            for r, row in rows.items():
                self._unobserved(r, row, "no frame" if obs is None else "no markers seen")
            return None
        for tr in self.tracks.values():
            if tr.undo is not None and self._k - tr.undo.first > self.options.smooth_lag:
                tr.undo = None  # beyond the lag its reports are out: taken as they stand
        if obs.has_alternatives and self.tracks:
            obs = self._nearest_candidates(obs)
        aside: list[dict[str, Any]] = []
        try:
            try:
                problem, names, markers = team_problem(self.rig, obs)
            except ObservationError:
                # a pixel noise pushed a little past a lens's rim: set aside (named in the rows' reasons)
                obs, aside = set_aside_past_rim(self.rig, obs, self.pixel_sigma)
                if not aside:
                    raise
                problem, names, markers = team_problem(self.rig, obs)
        except MutlocError as exc:
            why = " ".join(str(exc).split())
            self._coast(rows, set())
            for r, row in rows.items():
                if r in self.tracks:
                    self._unobserved(r, row, why)
                else:
                    row.status, row.reason = FrameStatus.FAILED, why
            return None
        index = {n: i for i, n in enumerate(names)}
        touch = {r: (problem.cam == index[r]) | (problem.own == index[r]) for r in self.robots}
        used = np.zeros(len(problem.cam), dtype=bool)
        notes: dict[str, list[str]] = {r: [] for r in self.robots}
        for a in aside:
            for r in {self.rig.observer(a["observer"])[0], self.rig.owner(a["marker"])} & set(notes):
                notes[r].append("set aside " + rejected_text([a]))
        # Where a tentative track predicts each of its observations (before the update): a record confirms
        # a track started on three only through observations it predicted sharply (see _confirms).
        spread = {j: self._spread_px(problem, j) for r, tr in self.tracks.items() if tr.strict
                  for j in np.flatnonzero(touch[r]).tolist()}
        prior = {r: (f.pose(r), f.covariance(r)) for r, tr in self.tracks.items() if tr.strict}
        # 1. the tracked robots: one update with every observation among them and the reference
        rejected, test, why_rejected, dropped = self._update_tracked(problem, touch, used)
        for r in self.robots:
            for j in dropped.tolist():
                if touch[r][j]:
                    notes[r].append(f"dropped {names[problem.cam[j]]} saw {markers[j]} (inconsistent with the track)")
        restart: dict[str, str] = {}
        for r in rejected:
            tr = self.tracks[r]
            tr.supported = False
            if (tr.undo is not None and not self._replaying and ties_to_one(problem, index[r]) > MIN_TIES
                    and self._undoable(tr.undo)):
                # a record that holds on its own contradicts a track made by records of three nothing confirmed
                team, _, _ = self._solve(obs, self.reference)
                if team is not None and team.status == "solved" and r in team.poses and r not in team.unverified:
                    return UndoRequest(r, t)
            lifecycle.count_rejection(tr, {names[c] for c in problem.cam[touch[r]].tolist()})
            why, note = lifecycle.restart_reason(tr, self.options.reinit_after)
            if why is not None:
                restart[r] = why
            elif note is not None:
                notes[r].append(note)
        for r in self.tracks:
            if r not in rejected and used[touch[r]].any():
                lifecycle.count_accepted(self.tracks[r], {names[c] for c in problem.cam[touch[r] & used].tolist()})
        # tentative tracks this record confirms; one started on three that a record of four or more
        # observations does not confirm restarts from it (or goes, if the record does not place it)
        confirmed: dict[str, str] = {}
        for r, tr in self.tracks.items():
            mine = used & touch[r]
            if tr.confirmed or r in rejected or r in restart or not mine.any():
                continue
            ok, note = self._confirms(tr, problem, names, markers, mine,
                                      spread, bool(touch[r][dropped].any()) if len(dropped) else False)
            if ok:
                confirmed[r] = note
            elif (why := lifecycle.restart_on_four(tr, ties_to_one(problem, self.filter.index(r)))) is not None:
                restart[r] = why
                used[touch[r]] = False
        C = np.zeros((problem.n_robots, problem.n_robots), dtype=np.int64)  # used observations, camera -> robot
        np.add.at(C, (problem.cam[used], problem.own[used]), 1)
        C = C + C.T
        for r, tr in self.tracks.items():
            if r in rejected or r in restart or not (used & touch[r]).any():
                continue
            if r in confirmed:
                tr.supported = int(C[index[r]].max()) > MIN_TIES
            elif tr.confirmed:
                lifecycle.judge_support(tr, int(C[index[r]].max()), self._k,
                                        self.smoother is not None and not self._replaying)
        for r in confirmed:
            self.tracks[r].state = TrackState.CONFIRMED
        # 2. robots not tracked (or to restart) that the record places on its own (see .starts)
        started, failed = self._start_all(t, obs, problem, names, markers, touch, used, restart, rejected, notes)
        self._coast(rows, {r for r in self.tracks if used[touch[r]].any()})
        # 3. every robot's row (see .records)
        self._fill_rows(t, rows, problem, names, markers, touch, used, notes, started, rejected, why_rejected,
                        confirmed, failed, test, prior)
        self._rig_test(rows)
        return None

    def _took(self, upd: Any) -> None:
        """Count an update's observations fitted on their own (``TeamUpdate.own``, accepted or not) in the
        record's (each observation once: the caller leaves out an update of observations counted before)."""
        if upd is not None and upd.own[1] > 0:
            self._own[0] += upd.own[0]
            self._own[1] += upd.own[1]

    def _rig_test(self, rows: dict[str, TrackRow]) -> None:
        """The record's observations fitted on their own into the rig check
        (its joint solve's chi-square when it had one, else the sum of its
        filter updates'); while the window disagrees (the last test stands
        through records that fit any rig), every row says so (and names the hint)."""
        c = self._own_solve
        chi2, dof = (float(c.chi2), int(c.dof)) if c is not None and c.dof > 0 else self._own
        if dof <= 0 and self._alone is not None and self.filtering and not self.filter.odometry:
            # (one camera's few observations: fitted with the next such records, see RigCheck.pooled; moved by
            # the constant-velocity state, so not where odometry moves the robots instead)
            f, (rows_alone, before) = self.filter, self._alone
            chi2, dof = self.rig_check.pooled(self.last_time, in_rays(self.rig, self._names, rows_alone), before,
                                              f.R, f.t, f.index(self.reference), self.pixel_sigma)
        test = self.rig_check.add(chi2, dof)
        if test is not None and test.disagrees:
            for row in rows.values():
                row.reason = join(row.reason, test.words())

    def _nearest_candidates(self, obs: ObservationSet) -> ObservationSet:
        """Where a detector handed over several candidates for a marker, the
        one nearest where the filter predicts it (the track decides, not the
        score) when both its observer and the marker's robot are tracked (or
        the reference); else the best scored."""
        f = self.filter
        known = {self.reference, *self.tracks}
        best: dict[tuple, tuple[float, int]] = {}
        for i, (o, m) in enumerate(zip(obs.observer, obs.marker)):
            key = (o, m if m is not None else f"#{i}")
            err = -float(obs.score[i])
            owner = self._owner(m) if m is not None else None
            robot = self._observer(o)
            if owner is not None and robot in known and owner in known and robot != owner:
                try:
                    one, _, _ = team_problem(self.rig, obs.take(np.array([i])))
                    err = float(residual_norms(one, f.R, f.t)[0])
                except MutlocError:
                    pass
            if key not in best or err < best[key][0]:
                best[key] = (err, i)
        return obs.take(np.array(sorted(i for _, i in best.values()), dtype=np.int64))

    def _update_tracked(self, problem: TeamProblem, touch: Mapping[str, np.ndarray], used: np.ndarray
                        ) -> tuple[set[str], Any, str, np.ndarray]:
        """Update the filter with the record's observations among tracked
        robots and the reference; when they fail the gate, without each
        involved robot in turn (the one whose observations contradict the
        track).  Marks the rows used; returns the robots whose observations
        were rejected, the accepted test, the rejection's reason and the
        single observation the gate dropped (if any)."""
        f = self.filter
        known = np.ones(len(problem.cam), dtype=bool)
        for r in self.robots:
            if r not in self.tracks:
                known &= ~touch[r]
        rows = np.flatnonzero(known)
        involved = [r for r in self.tracks if touch[r][rows].any()]
        none = np.empty(0, dtype=np.int64)
        if len(rows) == 0:
            return set(), None, "", none
        before = (f.vel.copy(), np.asarray(sorted(f.tracked), dtype=np.int64))  # (the rig check's, see _rig_test)
        upd = f.update(problem.take(rows))
        self._took(upd)
        if upd is not None and upd.own[1] <= 0:
            self._alone = (problem.take(rows), before)  # fits any rig on its own: pooled with the next such
        if upd.accepted:
            used[rows[upd.used]] = True
            return set(), upd.test, "", rows[upd.dropped]
        reason = upd.reason
        if len(involved) > 1:
            # blame one robot: the record without its observations passes
            share = {r: float(np.sum(upd.residuals_px[touch[r][rows[upd.dropped]]] ** 2)) for r in involved} \
                if len(upd.residuals_px) == len(upd.dropped) else {r: 0.0 for r in involved}
            for r in sorted(involved, key=lambda x: -share[x]):
                keep = rows[~touch[r][rows]]
                if len(keep) == 0:
                    continue
                alt = f.update(problem.take(keep))  # (its observations are upd's: counted once, there)
                if alt.accepted:
                    used[keep[alt.used]] = True
                    return {r}, alt.test, reason, keep[alt.dropped]
        # one robot in every observation (a single camera's view of the others) is the one at odds
        common = [r for r in involved if touch[r][rows].all()]
        if len(common) == 1:
            return {common[0]}, None, reason, none
        return set(involved), None, reason, none

    def _coast(self, rows: dict[str, TrackRow], observed: set[str]) -> None:
        """Drop the tracks that the record did not update and whose
        predicted sigma is beyond the options' limits (coasted too long)."""
        for r in list(self.tracks):
            if r in observed:
                continue
            why = lost_reason(PoseCov(self.filter.covariance(r)), self.options)
            if why:
                self._drop(r)
                rows[r].reason = join(rows[r].reason, f"track lost: {why}")

    def _drop(self, r: str) -> None:
        if self.filter.is_tracked(r):
            self.filter.drop(r)
        self.tracks.pop(r, None)
