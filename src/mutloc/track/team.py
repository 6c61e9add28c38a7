"""Team tracking: one trajectory per robot, in the reference robot's frame
(SPEC "Filtered tracking": with more than two robots one
``trajectory_NAME.csv`` / ``trajectory_NAME.tum`` per robot).

One joint filter of the whole team (:class:`mutloc.core.team_filter.
TeamFilter`: every tracked robot's pose and velocity relative to the
reference, with their correlations) takes every record at its own time:
the frames of the cameras within ``tolerance`` of each other make one
record, any other frame is a record of its own camera (cameras need not be
synchronized); a log's record may hold any subset of the robots' cameras.
Per record and robot (not the reference):

- a robot not tracked starts when the record's joint solve
  (:func:`mutloc.localize_team`, in the reference's frame or in that of a
  tracked robot the record observes) places it with four or more
  observations and passes its chi-square test: it enters the filter with a
  wide prior about that pose and the record's observations of it update
  the filter (its covariance and correlations are theirs); ``solved``.
  Placed by exactly three (which fit any one bad detection exactly), or
  started from several records solved together (see below), its track
  starts tentatively: its rows are ``unverified`` (``partial`` with fewer
  than three observations) until a later record confirms it -- three or
  more observations, every one accepted by the gate, at least one of them
  not among those that started it and predicted sharply (within
  ``CONFIRM_SPREAD`` pixel sigmas: where a wrong start could have missed
  it); a record tying it to one robot by four or more that does not
  confirm it restarts it from that record's joint solve.  Every new track is
  tentative until a later record's observations of it are accepted: a
  record that contradicts it first drops it (and may start it again).
  While tentative (started on three, or bridged) a row reports what its
  record shows on its own: ``unverified`` with three or more observations;
  with fewer, nothing after a start on three (``too_few``), the filter's
  ``partial``/``predicted`` after a bridged start.  With smoothing, once
  confirmed, the tentative records within the lag before the confirming one
  are reported as the confirmed track reports them ("confirmed in
  hindsight"), going back from it while each record of three or more is
  verified by a filter run backward in time over the records after it
  (independent of it: it must predict every observation sharply, agree with
  them and with the forward prediction); the record that started the track
  is checked the same way, and unless it is verified the others report the
  backward filter's pose.
- a tracked robot whose observations the filter accepts is ``solved`` when
  the record's observations tie it to the reference on their own (a chain
  of robots each pair tied by three or more), else ``partial``;
  ``predicted`` without observations (until its predicted sigma passes the
  options' ``lost_sigma_t``/``lost_sigma_r_deg``: the track is lost);
  ``rejected`` when its observations fail the gate (the row carries the
  filter's pose, the update made without them: when a record's
  observations fail the gate, the robot whose observations left out let the
  rest pass is the one rejected; a single camera's view that nothing
  separates, its observer).  Rejections are counted per camera: after
  ``reinit_after`` records of one camera in a row inconsistent with the
  track, a record whose joint solve places the robot restarts it; after
  twice that many the track is dropped -- unless another camera's record
  solved the robot (placed it on its own, consistent with the track) since
  that camera's first rejection: then that camera is the one at odds, and
  its records of the robot keep being rejected.

With the options' ``smooth_lag`` (default as for a pair) each row's pose,
covariance and velocity are then replaced by the fixed-lag smoothed ones of
the joint state (:mod:`mutloc.core.team_smoother`) once the ``smooth_lag``
records after it have come (:meth:`TeamTracker.finalize`); statuses and
reasons are the causal filter's.

``filter="none"``: every record's joint estimate on its own.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping

import numpy as np
from tqdm import tqdm

from ..api import Estimate, load_rig, localize, rejected_text
from ..core.consistency import DEFAULT_CONFIDENCE, same_pose
from ..core.observations import ObservationSet
from ..core.pose import Pose
from ..core.rays import set_aside_past_rim
from ..core.rig import Rig
from ..core.team import MIN_TIES, TeamProblem, residual_norms, team_residuals_any
from ..core.filter import STATE_DIM, fit_moving_pose
from ..core.team_filter import TeamFilter
from ..core.team_smoother import TeamSmoother
from ..errors import InconsistentObservationsError, InputError, MutlocError, ObservationError, positive_number
from ..io.logs import ObservationLogWriter
from ..team import TeamEstimate, localize_team, team_problem
from .filtering import MIN_START_DOF, FilterOptions, lost_reason, pair_problem
from .solving import CONFIRM_SPREAD
from .frames import DEFAULT_FPS, ObserverDetector, expanded_rig, frame_rate, image_keys, observations_of
from .sources import Frame
from .status import FrameStatus
from .tag_look import look_where_tracked
from .rows import TrackRow
from .trajectory import Trajectory

__all__ = ["TeamTrajectory", "TeamTracker", "track_team", "track_team_log", "sync_streams", "team_file_names",
           "require_streams", "unused_cameras", "camera_sizes", "RowEmitter"]


def team_file_names(robot: str) -> tuple[str, str]:
    """The SPEC's per-robot file names: ``trajectory_NAME.csv``, ``trajectory_NAME.tum``."""
    return f"trajectory_{robot}.csv", f"trajectory_{robot}.tum"


@dataclass
class TeamTrajectory:
    """Every robot's track (a :class:`~mutloc.track.tracker.Trajectory` of
    ``T_ref_r``, one row per input frame) in the frame of ``reference``."""

    reference: str
    tracks: dict[str, Trajectory]
    fps: float | None = None

    @property
    def robots(self) -> list[str]:
        return list(self.tracks)

    def summary(self) -> str:
        """One line per robot: ``r1: 60 frames: 58 solved, 2 partial``."""
        return "; ".join(f"{r}: {tr.summary()}" for r, tr in self.tracks.items())

    def write(self, out: str | Path) -> list[Path]:
        """``trajectory_NAME.csv`` and ``trajectory_NAME.tum`` per robot into folder ``out``."""
        out = Path(out).expanduser()
        written = []
        for r, tr in self.tracks.items():
            csv_name, tum_name = team_file_names(r)
            tr.write_csv(out / csv_name)
            tr.write_tum(out / tum_name)
            written += [out / csv_name, out / tum_name]
        return written

    def in_base_frames(self, rig: Any) -> "TeamTrajectory":
        """Every track between the robots' base frames (``base_from_camera``
        of each robot and of the reference; see
        :meth:`~mutloc.track.tracker.Trajectory.in_base_frames`); still keyed
        by robot name (files ``trajectory_NAME.*``)."""
        return TeamTrajectory(self.reference, {r: tr.in_base_frames(rig) for r, tr in self.tracks.items()}, self.fps)

    def write_rerun(self, path: str | Path) -> None:
        """A Rerun recording (``.rrd``) of every robot's track in the
        reference's frame (see :mod:`mutloc.io.rrd`; poses, covariance
        ellipsoids, trajectories and statuses; no images)."""
        from ..io.rrd import RerunWriter

        with RerunWriter(path, None, self.reference) as viz:
            for r, tr in self.tracks.items():
                for row in tr.rows:
                    e = row.estimate
                    viz.frame(row.t, str(row.status), row.reason, None if e is None else e.pose,
                              None if e is None else e.covariance, robot=r)

    def write_ros(self, bag: str | Path | None = None, mcap: str | Path | None = None) -> None:
        """Every robot's poses as ROS 2 messages, one pose topic per robot
        (``/mutloc/NAME_in_REFERENCE``) and ``/tf`` with one child frame per robot."""
        from ..io.ros import write_mcap, write_ros2_bag

        tracks = [(tr.times, tr.poses, tr.covariances, tr.source, tr.target) for tr in self.tracks.values()]
        if bag is not None:
            write_ros2_bag(bag, tracks=tracks)
        if mcap is not None:
            write_mcap(mcap, tracks=tracks)


def _robot_estimate(team: TeamEstimate, r: str, pose: Pose, cov: np.ndarray, extra: dict | None = None) -> Estimate:
    markers = sorted({m for pair, ms in team.markers_between.items() if r in pair for m in ms})
    return Estimate(source=r, target=team.reference, pose=pose, covariance=np.array(cov, float),
                    pixel_sigma=team.pixel_sigma, reprojection_rms_px=team.reprojection_rms_px, markers_used=markers,
                    candidates=Pose.concatenate([pose]), consistency=team.consistency, extra=dict(extra or {}))


#: A robot entering the joint filter does so with this wide prior (1-sigma:
#: radians, metres) about its pose from the record's joint solve, then the
#: record's observations of it update the filter: its covariance and its
#: correlations with the robots already tracked come from those
#: observations (the prior adds about 1e-3 of their information).
#: Its velocity starts at zero with the motion noise's ``initial_angular`` /
#: ``initial_linear`` sigmas (:class:`~mutloc.core.filter.MotionNoise`): one
#: record says nothing of it; its next records measure it.
START_SIGMA_R, START_SIGMA_T = 0.3, 0.5


@dataclass
class _Track:
    """A robot's track in the joint filter: tentative until a later record
    confirms it (``start``: the observations that started it; ``three``: it
    started from exactly three), and its rejections per camera."""

    start: frozenset
    three: bool = False
    confirmed: bool = False
    bridged: bool = False
    #: per camera: its records of the robot rejected in a row, and whether
    #: since the first of them another camera's record solved the robot
    #: (placed it on its own, consistent with the track).
    contradicted: dict = field(default_factory=dict)
    held_by_others: dict = field(default_factory=dict)
    #: While tentative: its records as a confirmed track would report them (see ``_Tentative``).
    frames: list = field(default_factory=list)
    #: Whether the robot's last update tied it to one robot by four or more
    #: (or started it): a track that can verify a record of three.
    supported: bool = True
    #: Records of three the confirmed track took without being able to verify them (see ``_Undo``).
    undo: "_Undo | None" = None

    def copy(self) -> "_Track":
        return replace(self, contradicted=dict(self.contradicted), held_by_others=dict(self.held_by_others),
                       frames=list(self.frames),
                       undo=None if self.undo is None else replace(self.undo, records=set(self.undo.records)))


@dataclass
class _Undo:
    """Records of exactly three observations tying a robot to one other that
    its confirmed track took while the record before did not support it:
    the first one's number and all of them (see ``TeamTracker._roll_back``)."""

    first: int
    records: set = field(default_factory=set)


class _Unconfirmed(Exception):
    """Internal: a record solved on its own contradicts records of three that
    robot ``robot``'s track took unverified."""

    def __init__(self, robot: str, t: float) -> None:
        super().__init__(robot)
        self.robot, self.t = robot, t


@dataclass
class _Tentative:
    """A record of a tentative track as a confirmed track would report it:
    its number and row, status, estimate and reason, and the robot's pose
    and covariance the filter predicted before it (``start``: it started the track)."""

    k: int
    row: TrackRow
    status: FrameStatus
    estimate: Estimate | None
    reason: str
    prior: tuple
    start: bool = False


@dataclass
class _Record:
    """One input record and its rows, kept until final (a confirmation may
    report them again, :meth:`TeamTracker._report_tentative`)."""

    t: float
    obs: ObservationSet | None
    times: Mapping[str, float | None] | None
    problems: Mapping[str, tuple[FrameStatus, str]] | None
    rows: dict[str, TrackRow]
    #: The tracker's state before it, where an undo may go back to it (see ``_save``).
    saved: tuple | None = None


class TeamTracker:
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
        #: With ``smooth_lag``: the joint filter's states of the records not yet
        #: final and their rows (see :meth:`finalize`).
        self.smoother = TeamSmoother(self.options.smooth_lag) if self.options.smooth_lag and self.filtering else None
        self._unfinal: list[_Record] = []
        #: Confirmations of tentative tracks whose records may still be reported
        #: again: (time, the records, the one that started it, its record number, robot).
        self._confirmations: list[tuple[float, list[_Tentative], _Tentative | None, int, str]] = []
        self._k = 0  #: the number of the record being filtered
        self._replaying = False
        self.tracks: dict[str, _Track] = {}
        #: The records of the last ``start_window`` seconds (a start may bridge them).
        self._recent: deque[tuple[float, ObservationSet]] = deque()
        self.last_time: float | None = None
        self.joint_solves = 0  #: records solved on their own to start (or restart) a robot

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
        rec = _Record(float(t), observations, times, problems, rows)
        if not self.filtering:
            self.last_time = rec.t
            self._per_record(observations, rows)
            self._input_problems(rec)
            return rows
        try:
            self._filter_record(rec)
        except _Unconfirmed as u:
            self._roll_back(u)
            self._filter_record(rec)  # the undone records no longer hold the track: this cannot undo any
        return rows

    def _filter_record(self, rec: _Record, exclude: str | None = None) -> None:
        """Filter one record and keep it (with smoothing) until final
        (``exclude``: a robot whose observations in it are left out)."""
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
        self._filtered(rec.t, obs, rec.rows)
        if obs is not None and len(obs):
            self._recent.append((rec.t, obs))
        while self._recent and rec.t - self._recent[0][0] > self.options.start_window:
            self._recent.popleft()
        if sm is not None:
            sm.add(prior, self.filter.snapshot())
            self._unfinal.append(rec)
        self._input_problems(rec)

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

    @staticmethod
    def _input_problems(rec: _Record) -> None:
        for r, row in rec.rows.items():
            if rec.problems and r in rec.problems:
                status, note = rec.problems[r]
                if row.estimate is None:
                    row.status = status
                    row.reason = _join(note, row.reason)
                else:
                    row.reason = _join(row.reason, f"{note} (localized from the others' views)")

    # -- taking back records of three that a record solved on its own contradicts

    def _save(self) -> tuple:
        """The tracker's state (the filter and the tracks) as an undo restores it."""
        return (self.filter.copy(), {r: tr.copy() for r, tr in self.tracks.items()}, tuple(self._recent),
                self.last_time)

    def _undoable(self, undo: _Undo) -> bool:
        """Whether the state before the undo's first record is still kept."""
        sm = self.smoother
        k = undo.first - (sm.first if sm is not None else 0)
        return sm is not None and 0 <= k < len(self._unfinal) and self._unfinal[k].saved is not None

    def _roll_back(self, u: _Unconfirmed) -> None:
        """Undo robot ``u.robot``'s track since its first unverified record of
        three (a record solved on its own contradicts it): those records
        report it ``rejected`` (with the track's prediction without them),
        every record since is filtered again; the current record then goes again."""
        sm = self.smoother
        undo = self.tracks[u.robot].undo
        assert sm is not None and undo is not None
        redo = self._unfinal[undo.first - sm.first:]
        filt, tracks, recent, last = redo[0].saved
        self.filter, self.tracks, self._recent, self.last_time = filt, tracks, deque(recent), last
        sm.truncate(undo.first)
        del self._unfinal[undo.first - sm.first:]
        self._confirmations = [c for c in self._confirmations if c[3] < undo.first]
        note = (f"not confirmed: the record at {u.t:.3f} s, solved on its own, contradicts the track this record of "
                "three observations made")
        self._replaying = True  # records filtered again make nothing to undo
        try:
            for i, rec in enumerate(redo):
                for row in rec.rows.values():
                    row.status, row.reason, row.estimate = FrameStatus.SOLVED, "", None
                if undo.first + i in undo.records:
                    self._filter_record(rec, exclude=u.robot)
                    row = rec.rows[u.robot]
                    row.status, row.reason = FrameStatus.REJECTED, note
                    row.estimate = self._estimate(u.robot, None, [], None, None, None) \
                        if u.robot in self.tracks else None
                else:
                    self._filter_record(rec)
        finally:
            self._replaying = False

    def _judge_support(self, tr: _Track, n: int) -> None:
        """After an accepted update of a confirmed track: four or more
        observations tying it to one robot support it (and clear the records
        it took unverified); exactly three while the record before did not
        support it are taken but remembered, so that a record solved on its
        own within the smoother's lag that contradicts the track can undo
        them (:meth:`_roll_back`).  Without smoothing nothing is undone.
        ``n``: the record's used observations tying it to one robot, at most."""
        if n > MIN_TIES:
            tr.undo, tr.supported = None, True
            return
        if n == MIN_TIES and not tr.supported and self.smoother is not None and not self._replaying:
            if tr.undo is None:
                tr.undo = _Undo(self._k)
            tr.undo.records.add(self._k)
        tr.supported = False

    # -- a tentative track's records, reported again once it is confirmed ------

    def _report_tentative(self, end: bool) -> None:
        """Report the records of each confirmed tentative track within the
        lag before the confirming record as the confirmed track does, going
        back from it while every record that ties the robot by three or more
        is verified by the records after it (:meth:`_backward`).  The record
        that started the track is checked the same way: unless verified, the
        records verified on their own report the backward track's pose."""
        sm = self.smoother
        n = len(sm)
        ripe = [c for c in self._confirmations if end or c[3] < n - sm.lag]
        self._confirmations = [c for c in self._confirmations if c not in ripe]
        for t, frames, start, _, r in ripe:
            rooted = start is not None and self._backward(r, start) is not None
            for p in reversed(frames):
                back = None
                if p.status == FrameStatus.SOLVED and not (rooted and p is start):
                    back = self._backward(r, p)
                    if back is None:
                        break
                elif not rooted:
                    continue
                note = f"confirmed in hindsight by the record at t = {t:.3f} s and the records after it"
                p.row.status, p.row.estimate = p.status, p.estimate
                p.row.reason = _join(note, p.reason)
                if back is not None and not rooted:
                    p.row.estimate = back

    def _backward(self, r: str, p: _Tentative) -> Estimate | None:
        """Robot ``r``'s estimate at record ``p`` from a filter run backward
        in time over the ``lag`` records after it (independent of ``p`` and
        of the records before), updated with ``p``'s observations of ``r`` --
        if it predicted every one of them within ``CONFIRM_SPREAD`` pixel
        sigmas and agrees with all of them, and predicts the pose the forward
        track predicted within their joint uncertainty; else None.  It starts
        from the last of those records whose joint solve places ``r``."""
        sm = self.smoother
        later = self._unfinal[p.k + 1 - sm.first:p.k + 1 + sm.lag - sm.first]
        f = TeamFilter(self.filter.robots, self.reference, self.options.noise, self.pixel_sigma, self.confidence,
                       measure_noise=self.options.measure_noise)
        started = False
        for rec in reversed(later):
            if rec.obs is None or len(rec.obs) == 0:
                continue
            try:
                problem, _, _ = team_problem(self.rig, rec.obs)
            except MutlocError:
                continue
            if not started:
                if _ties_to_one(problem, f.index(r)) < MIN_TIES:
                    continue
                team, _, _ = self._solve(rec.obs, self.reference)
                if team is None or r not in team.poses:
                    continue
                f.reset(-rec.t, {x: team.poses[x] for x in team.robots}, team.joint_covariance)
                started = True
                continue
            f.predict(-rec.t)
            if lost_reason(_Cov(f.covariance(r)), self.options):
                return None
            rows = self._rows_among(problem, f)
            if len(rows):
                f.update(problem.take(rows))
        if not started or p.row.observations is None:
            return None
        try:
            problem, names, markers = team_problem(self.rig, p.row.observations)
        except MutlocError:
            return None
        f.predict(-p.row.t)
        i = f.index(r)
        mine = np.flatnonzero((problem.cam == i) | (problem.own == i))
        rows = self._rows_among(problem, f)
        if len(mine) == 0 or not np.isin(mine, rows).all():
            return None
        if max(self._spread_px(problem, j, f) for j in mine.tolist()) > CONFIRM_SPREAD * self.pixel_sigma:
            return None
        if not same_pose(f.pose(r), f.covariance(r), p.prior[0], p.prior[1], self.confidence):
            return None
        upd = f.update(problem.take(mine))
        if not (upd.accepted and len(upd.used) == len(mine)):
            return None
        pose, cov = f.pose(r), f.covariance(r)
        rms = float(np.sqrt(np.mean(upd.residuals_px ** 2))) if len(upd.residuals_px) else 0.0
        return Estimate(source=r, target=self.reference, pose=pose, covariance=cov, pixel_sigma=self.pixel_sigma,
                        reprojection_rms_px=rms, markers_used=sorted({markers[j] for j in mine.tolist()}),
                        candidates=Pose.concatenate([pose]), consistency=upd.test,
                        extra={"velocity": (-f.velocity(r)).tolist(), "filter": "cv", "smooth_lag": sm.lag,
                               "smoother": "backward"})

    def _rows_among(self, problem: TeamProblem, f: TeamFilter) -> np.ndarray:
        """The observations between robots ``f`` tracks (or its reference)."""
        ok = np.zeros(problem.n_robots, dtype=bool)
        ok[f.tracked] = True
        ok[f.index(self.reference)] = True
        return np.flatnonzero(ok[problem.cam] & ok[problem.own])

    @property
    def history(self) -> TeamSmoother | None:
        """The smoother's records (None without smoothing: every row is final at once)."""
        return self.smoother

    def finalize(self, end: bool = False) -> int:
        """Make final the rows of the records that nothing to come can
        change, in input order, and return how many records are final (all
        of them without smoothing).

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
        for k in range(sm.first, limit):
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

    # -- without the filter: every record on its own ---------------------------

    def _per_record(self, obs: ObservationSet | None, rows: dict[str, TrackRow]) -> None:
        if obs is None:
            for row in rows.values():
                row.status, row.reason = FrameStatus.UNPAIRED, "no frame"
            return
        team, status, reason = self._solve(obs, self.reference)
        for r, row in rows.items():
            if team is not None and r in team.poses:
                row.estimate = _robot_estimate(team, r, team.poses[r], team.covariance(r))
                row.status = FrameStatus.UNVERIFIED if r in team.unverified else FrameStatus.SOLVED
                row.reason = _dropped(team)
            else:
                row.status, row.reason = self._not_localized(r, team, status, reason, obs)

    def _solve(self, obs: ObservationSet, reference: str, confidence: float | None = None
               ) -> tuple[TeamEstimate | None, FrameStatus, str]:
        """The record's joint estimate in ``reference``'s frame, or None with a status and reason."""
        try:
            return (localize_team(self.rig, obs, reference, pixel_sigma=self.pixel_sigma,
                                  confidence=self.confidence if confidence is None else confidence),
                    FrameStatus.SOLVED, "")
        except InconsistentObservationsError as exc:
            return None, FrameStatus.REJECTED, " ".join(str(exc).split())
        except ObservationError as exc:
            status = FrameStatus.TOO_FEW if "three or more" in str(exc) else FrameStatus.FAILED
            return None, status, " ".join(str(exc).split())
        except MutlocError as exc:
            return None, FrameStatus.FAILED, " ".join(str(exc).split())

    def _not_localized(self, r: str, team: TeamEstimate | None, status: FrameStatus, reason: str,
                       obs: ObservationSet | None) -> tuple[FrameStatus, str]:
        """Status and reason of a robot without a joint pose this record."""
        n = 0
        if obs is not None:
            owner, observer = self.rig.owner, self.rig.observer
            try:
                n = sum(1 for o, m in zip(obs.observer, obs.marker)
                        if m is not None and (observer(o)[0] == r or owner(m) == r))
            except MutlocError:
                n = -1
        if n == 0:
            return FrameStatus.TOO_FEW, "no markers seen"
        if team is None:
            return (FrameStatus.FAILED if status == FrameStatus.SOLVED else status), reason
        if n < MIN_TIES:
            return FrameStatus.TOO_FEW, (f"{n} observation{'s' if n != 1 else ''} involve it: too few to tie it to "
                                         f"{self.reference!r} (three are needed)")
        return FrameStatus.TOO_FEW, f"its {n} observations do not tie it to {self.reference!r}"

    # -- the joint filter -------------------------------------------------------

    def _filtered(self, t: float, obs: ObservationSet | None, rows: dict[str, TrackRow]) -> None:
        f = self.filter
        if obs is None or len(obs) == 0:
            self._coast(rows, set())
            for r, row in rows.items():
                self._unobserved(r, row, "no frame" if obs is None else "no markers seen")
            return
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
            return
        index = {n: i for i, n in enumerate(names)}
        touch = {r: (problem.cam == index[r]) | (problem.own == index[r]) for r in self.robots}
        used = np.zeros(len(problem.cam), dtype=bool)
        notes: dict[str, list[str]] = {r: [] for r in self.robots}
        for a in aside:
            for r in {self.rig.observer(a["observer"])[0], self.rig.owner(a["marker"])} & set(notes):
                notes[r].append("set aside " + rejected_text([a]))
        # Where a tentative track predicts each of its observations (before the update): a record confirms
        # a track started on three only through observations it predicted sharply (see _confirms).
        spread = {j: self._spread_px(problem, j) for r, tr in self.tracks.items() if tr.three and not tr.confirmed
                  for j in np.flatnonzero(touch[r]).tolist()}
        prior = {r: (f.pose(r), f.covariance(r)) for r, tr in self.tracks.items() if tr.three and not tr.confirmed}
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
            if (tr.undo is not None and not self._replaying and _ties_to_one(problem, index[r]) > MIN_TIES
                    and self._undoable(tr.undo)):
                # a record that holds on its own contradicts a track made by records of three nothing confirmed
                team, _, _ = self._solve(obs, self.reference)
                if team is not None and team.status == "solved" and r in team.poses and r not in team.unverified:
                    raise _Unconfirmed(r, t)
            cams = {names[c] for c in problem.cam[touch[r]].tolist()}
            for c in cams:
                tr.contradicted[c] = tr.contradicted.get(c, 0) + 1
                if tr.contradicted[c] == 1:
                    tr.held_by_others[c] = False
            cam, streak = _worst(tr)
            if not tr.confirmed:
                restart[r] = "a record contradicted the tentative track"
            elif streak >= self.options.reinit_after:
                restart[r] = f"{cam}'s last {streak} records inconsistent with the track"
            elif tr.contradicted and max(tr.contradicted.values()) >= self.options.reinit_after:
                c = max(tr.contradicted, key=tr.contradicted.get)
                notes[r].append(f"{c}'s last {tr.contradicted[c]} records of it inconsistent with the track that "
                                "the other cameras' records hold")
        for r in self.tracks:
            if r not in rejected and used[touch[r]].any():
                for c in {names[c] for c in problem.cam[touch[r] & used].tolist()}:
                    self.tracks[r].contradicted[c] = 0
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
            elif tr.three and _ties_to_one(problem, self.filter.index(r)) > MIN_TIES:
                restart[r] = "a record of four or more observations does not confirm the tentative track"
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
                self._judge_support(tr, int(C[index[r]].max()))
        for r in confirmed:
            self.tracks[r].confirmed = True
        # 2. robots not tracked (or to restart) that the record places on its own
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
            cam, streak = _worst(tr)
            if not tr.confirmed or streak >= 2 * self.options.reinit_after:
                self._drop(r)
                notes[r].append(f"track dropped: {why}" if tr.confirmed else
                                "tentative track dropped: a record contradicted it")
        self._coast(rows, {r for r in self.tracks if used[touch[r]].any()})
        # 3. every robot's row
        held = self._held(problem, used)
        res = _reprojection(problem.take(np.flatnonzero(used)), self.filter) if used.any() else None
        if res is not None:
            full = np.zeros(len(used))
            full[used] = res
            res = full
        cams = {names[c] for c in problem.cam[used].tolist()}
        for r in held & set(self.tracks):
            tr = self.tracks[r]
            for c in tr.held_by_others:
                if c not in cams:
                    tr.held_by_others[c] = True
        for r, row in rows.items():
            if notes[r]:
                row.reason = _join(row.reason, "; ".join(notes[r]))
            mine = touch[r]
            if r in started:
                tr = self.tracks[r]
                row.status = (FrameStatus.SOLVED if not tr.three else
                              FrameStatus.UNVERIFIED if int((used & mine).sum()) >= MIN_TIES else FrameStatus.PARTIAL)
                row.reason = _join(row.reason, started[r])
                row.estimate = self._estimate(r, problem, markers, used, mine, test, res)
                if tr.three and self.smoother is not None:
                    n = int((used & mine).sum())
                    on = ", ".join(sorted({markers[j] for j in np.flatnonzero(used & mine).tolist()}))
                    tr.frames.append(_Tentative(self._k, row, FrameStatus.SOLVED if n >= MIN_TIES else
                                                FrameStatus.PARTIAL, row.estimate, f"started the track on {on}",
                                                (f.pose(r), f.covariance(r)), start=True))
            elif r in self.tracks and r in rejected:
                row.status = FrameStatus.REJECTED
                row.reason = _join(row.reason, why_rejected)
                row.estimate = self._estimate(r, problem, markers, np.zeros_like(used), mine, None)
            elif r in self.tracks and (used & mine).any():
                n = int((used & mine).sum())
                tr = self.tracks[r]
                if r in confirmed:
                    row.reason = _join(row.reason, confirmed[r])
                    self._confirmed(t, r, tr)
                if r in held:
                    status, why = FrameStatus.SOLVED, ""
                else:
                    status, why = FrameStatus.PARTIAL, f"{n} observation(s) tie it to the team: updated through the filter"
                row.estimate = self._estimate(r, problem, markers, used, mine, test, res)
                if tr.three and not tr.confirmed:
                    # a tentative track reports nothing of its own yet (see _tentative)
                    self._tentative(r, tr, row, status, _join(row.reason, why), prior.get(r), n)
                else:
                    row.status, row.reason = status, _join(row.reason, why)
            elif r in self.tracks:
                self._unobserved(r, row, "no markers seen" if not mine.any() else "observations not used")
            elif r in rejected:  # (its track dropped)
                row.status = FrameStatus.REJECTED
                row.reason = _join(row.reason, why_rejected)
            elif r in failed:
                row.status, why = failed[r]
                row.reason = _join(row.reason, why)
            else:
                n = int(mine.sum())
                row.status = FrameStatus.TOO_FEW
                row.reason = _join(row.reason, "no markers seen" if n == 0 else
                                   f"{n} observation{'s' if n != 1 else ''} involve it: too few to start its track "
                                   "(three are needed)")

    def _tentative(self, r: str, tr: _Track, row: TrackRow, status: FrameStatus, reason: str,
                   prior: tuple | None, n: int) -> None:
        """A record of a tentative track (not yet confirmed) reports what the
        record shows on its own: ``unverified`` with three or more
        observations of the robot; with fewer, a track bridged over records
        reports ``partial`` (``predicted``), one started on three nothing
        (``too_few``).  What a confirmed track would have reported is kept:
        once confirmed, the records within the lag may report it (see
        :meth:`_report_tentative`)."""
        f = self.filter
        if self.smoother is not None:
            tr.frames.append(_Tentative(self._k, row, status, row.estimate, reason,
                                        prior if prior is not None else (f.pose(r), f.covariance(r))))
        note = "tentative track not yet confirmed " + ("(started from records solved together)" if tr.bridged
                                                        else "(started on three observations)")
        if n >= MIN_TIES:
            row.status = FrameStatus.UNVERIFIED
        elif tr.bridged:
            row.status = status
        else:
            row.status, row.estimate = FrameStatus.TOO_FEW, None
        row.reason = _join(row.reason if n else _join(row.reason, reason), note)

    def _confirmed(self, t: float, r: str, tr: _Track) -> None:
        """Robot ``r``'s tentative track is confirmed now: its records within
        the lag may be reported again once the lag records after this one came."""
        if self.smoother is None:
            return
        near = [p for p in tr.frames if self._k - p.k <= self.options.smooth_lag and p.estimate is not None]
        start = next((p for p in tr.frames if p.start), None)
        if near:
            self._confirmations.append((t, near, start, self._k, r))
        tr.frames = []

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
        upd = f.update(problem.take(rows))
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
                alt = f.update(problem.take(keep))
                if alt.accepted:
                    used[keep[alt.used]] = True
                    return {r}, alt.test, reason, keep[alt.dropped]
        # one robot in every observation (a single camera's view of the others) is the one at odds
        common = [r for r in involved if touch[r][rows].all()]
        if len(common) == 1:
            return {common[0]}, None, reason, none
        return set(involved), None, reason, none

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
            f.add(r, pose, np.diag([START_SIGMA_R**2] * 3 + [START_SIGMA_T**2] * 3),
                  velocity_covariance=np.diag([self.options.noise.initial_angular**2] * 3
                                              + [self.options.noise.initial_linear**2] * 3))
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
        started = {}
        if upd is not None and upd.accepted:
            used[rows[upd.used]] = True
            for r, (pose, three) in guesses.items():
                mine = touch[r][rows[upd.used]]
                keys = frozenset((names[problem.cam[j]], markers[j]) for j in rows[upd.used][mine].tolist())
                # a start on three, or bridged over records (no test of its own), is confirmed the strict way
                self.tracks[r] = _Track(keys, three=three or bridged is not None or len(keys) <= MIN_TIES,
                                        bridged=bridged is not None)
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
        self.tracks[r] = _Track(frozenset(latest), confirmed=True)
        span = 1000.0 * (times[-1] - times[0])
        return (f"track started from {len(times)} records over {span:.0f} ms ({n} observations of {len(latest)} "
                "markers; pose and velocity fitted at each record's time)")

    def _confirms(self, tr: _Track, problem: TeamProblem, names: list[str], markers: list[str], rows: np.ndarray,
                  spread: Mapping[int, float], dropped: bool) -> tuple[bool, str]:
        """Whether a later record's accepted observations of a tentative track
        confirm it, and the row's note.  Three or more; after a start on
        exactly three (which fit any one bad detection exactly, so its pose
        may be wrong) only where every observation of the robot in the record
        agrees (none dropped by the gate) and the observations not among
        those that started it -- at least one -- were predicted sharply
        (``CONFIRM_SPREAD`` x sigma): where the track's prediction could have
        missed them, a wrong start is exposed."""
        n = int(rows.sum())
        if not tr.three:
            return n >= MIN_TIES, f"track confirmed by {n} observations"
        if n < MIN_TIES or dropped:
            return False, ""
        idx = np.flatnonzero(rows).tolist()
        new = [j for j in idx if (names[problem.cam[j]], markers[j]) not in tr.start]
        if not new:
            return False, ""
        worst = max(spread.get(j, math.inf) for j in new)
        if worst > CONFIRM_SPREAD * self.pixel_sigma:
            return False, ""
        seen = ", ".join(sorted({markers[j] for j in idx}))
        start = ", ".join(sorted({m for _, m in tr.start}))
        return True, (f"track confirmed: {seen} agree with the track started on {start} "
                      f"(new observations predicted within {worst:.1f} px)")

    def _spread_px(self, problem: TeamProblem, j: int, f: TeamFilter | None = None) -> float:
        """1-sigma (px, largest axis) of where the filter predicts observation
        ``j`` (its observer's and the marker owner's pose covariance, with
        their correlation, through the projection's Jacobians; ``f``: another filter)."""
        f = self.filter if f is None else f
        one = problem.take(np.array([j]))
        res = np.empty(2)
        Ja, Jb = np.empty((1, 2, 6)), np.empty((1, 2, 6))
        if not team_residuals_any(one.cam, one.own, one.points, one.uv, one.wt, one.K, one.dist, one.fr, f.R, f.t, res,
                                  Ja, Jb, True):
            return math.inf
        terms = [(f.robots[int(one.cam[0])], Ja[0]), (f.robots[int(one.own[0])], Jb[0])]
        if any(name != self.reference and not f.is_tracked(name) for name, _ in terms):
            return math.inf
        S = f.pose_sandwich(terms)
        return float(math.sqrt(max(np.linalg.eigvalsh(S).max(), 0.0)))

    def _held(self, problem: TeamProblem, used: np.ndarray) -> set[str]:
        """Robots the record's used observations tie to the reference on
        their own: a chain of robots each pair tied by three or more."""
        n = problem.n_robots
        C = np.zeros((n, n), dtype=np.int64)
        np.add.at(C, (problem.cam[used], problem.own[used]), 1)
        C = C + C.T
        ref = self.filter.index(self.reference)
        seen, todo = {ref}, [ref]
        while todo:
            a = todo.pop()
            for b in np.flatnonzero(C[a] >= MIN_TIES).tolist():
                if b not in seen:
                    seen.add(b)
                    todo.append(b)
        return {self.filter.robots[i] for i in seen} - {self.reference}

    def _coast(self, rows: dict[str, TrackRow], observed: set[str]) -> None:
        """Drop the tracks that the record did not update and whose
        predicted sigma is beyond the options' limits (coasted too long)."""
        for r in list(self.tracks):
            if r in observed:
                continue
            why = lost_reason(_Cov(self.filter.covariance(r)), self.options)
            if why:
                self._drop(r)
                rows[r].reason = _join(rows[r].reason, f"track lost: {why}")

    def _drop(self, r: str) -> None:
        if self.filter.is_tracked(r):
            self.filter.drop(r)
        self.tracks.pop(r, None)

    def _unobserved(self, r: str, row: TrackRow, why: str) -> None:
        """A row without observations of ``r``: the prediction of a robot tracked, else nothing."""
        tr = self.tracks.get(r)
        if tr is None:
            row.status = FrameStatus.TOO_FEW
            row.reason = _join(row.reason, why)
            return
        tr.supported = False
        row.estimate = self._estimate(r, None, [], None, None, None)
        if tr.three and not tr.confirmed:
            self._tentative(r, tr, row, FrameStatus.PREDICTED, why, None, 0)
            return
        row.status = FrameStatus.PREDICTED
        row.reason = _join(row.reason, why)

    def _estimate(self, r: str, problem: TeamProblem | None, markers: list[str], used: np.ndarray | None,
                  mine: np.ndarray | None, test: Any, res: np.ndarray | None = None) -> Estimate:
        """Robot ``r``'s row estimate now (``res``: every observation's
        reprojection error at the filter's poses, when already computed)."""
        f = self.filter
        pose, vel = f.pose(r), f.velocity(r)
        names, rms = [], 0.0
        if problem is not None and used is not None and mine is not None and (used & mine).any():
            rows = np.flatnonzero(used & mine)
            names = sorted({markers[j] for j in rows.tolist()})
            err = res[rows] if res is not None else _reprojection(problem.take(rows), f)
            rms = float(np.sqrt(np.mean(err ** 2)))
        return Estimate(source=r, target=self.reference, pose=pose, covariance=f.covariance(r),
                        pixel_sigma=self.pixel_sigma, reprojection_rms_px=rms, markers_used=names,
                        candidates=Pose.concatenate([pose]), consistency=test,
                        extra={"velocity": vel.tolist(), "filter": "cv"})


def _worst(tr: _Track) -> tuple[str, int]:
    """The camera whose records of the robot the track keeps rejecting
    while no other camera's record solved the robot since (those can
    expose a wrong track: then the camera is the one at odds), and its
    streak; ("", 0) if none."""
    open_ = {c: n for c, n in tr.contradicted.items() if n and not tr.held_by_others.get(c, False)}
    if not open_:
        return "", 0
    c = max(open_, key=open_.get)
    return c, open_[c]


def _ties_to_one(problem: TeamProblem, i: int) -> int:
    """The most observations between robot ``i`` and any one other robot
    (either way): four or more place it on their own, as a pair's frame does."""
    C = problem.counts()
    ties = C[i] + C[:, i]
    ties[i] = 0
    return int(ties.max()) if len(ties) else 0


@dataclass
class _Cov:
    """What :func:`~mutloc.track.solving.lost_reason` reads of a state."""

    pose_covariance: np.ndarray


def _reprojection(problem: TeamProblem, f: TeamFilter) -> np.ndarray:
    """Each observation's reprojection error (px) at the filter's poses."""
    return residual_norms(problem, f.R, f.t)


def _dropped(team: TeamEstimate) -> str:
    if not team.rejected:
        return ""
    return "joint estimate dropped " + rejected_text(team.rejected)


def _join(a: str, b: str) -> str:
    return f"{a}; {b}" if a and b else (a or b)


def close_all(*outputs: Any) -> None:
    """Close every output of a track that was asked for (None: it was not)."""
    for out in outputs:
        if out is not None:
            out.close()


class RowEmitter:
    """Hands each item (a record's rows, or a pair's row) to ``sink(item,
    payload)`` in input order once final (see :meth:`TeamTracker.finalize`):
    outputs written as the track runs.  ``filtered``: the item is one of the
    tracker's records (items that are not -- an unreadable frame -- go out
    in their turn)."""

    def __init__(self, tracker: "TeamTracker", sink: Callable[[Any, Any], None]) -> None:
        self.tracker, self.sink = tracker, sink
        self.queue: deque[tuple[Any, bool, Any]] = deque()
        self.done = 0  # filtered items handed on

    def add(self, item: Any, filtered: bool, payload: Any = None) -> None:
        self.queue.append((item, filtered, payload))

    def emit(self, end: bool = False) -> None:
        final = math.inf if self.tracker.history is None else self.tracker.finalize(end)
        while self.queue:
            item, filtered, payload = self.queue[0]
            if filtered and self.done >= final:
                break
            self.queue.popleft()
            self.done += filtered
            self.sink(item, payload)


# -- inputs -------------------------------------------------------------------


def sync_streams(streams: Mapping[str, Iterable[Frame]], tolerance: float) -> Iterator[dict[str, Frame]]:
    """Group time-ordered streams into frames of the team: each group holds,
    per robot, its next frame if it lies within ``tolerance`` seconds of the
    earliest pending frame (robots without one are left out of the group)."""
    its = {r: iter(s) for r, s in streams.items()}
    heads = {r: next(it, None) for r, it in its.items()}
    while any(f is not None for f in heads.values()):
        t0 = min(f.t for f in heads.values() if f is not None)
        group = {r: f for r, f in heads.items() if f is not None and f.t - t0 <= tolerance}
        for r in group:
            heads[r] = next(its[r], None)
        yield group


def _team_setup(rig: Any, reference: str | None, names: Iterable[str], what: str) -> tuple[Rig, str]:
    rig = expanded_rig(load_rig(rig))
    image_keys(rig, {n: None for n in names}, what)  # ROBOT or ROBOT/CAMERA, each a camera of the rig
    if reference is not None and (not isinstance(reference, str) or reference not in rig.robots):
        raise ObservationError(f"unknown reference robot {reference!r} (rig has {sorted(rig.robots)})")
    return rig, reference if reference is not None else next(iter(rig.robots))


def require_streams(rig: Rig, names: Iterable[str]) -> list[str]:
    """ObservationError unless every name is a camera of the rig (``ROBOT``, or ``ROBOT/CAMERA`` for a robot
    with several cameras: :func:`~mutloc.track.frames.image_keys`) and every robot has a stream.  Returns the
    cameras of robots with several that have none (unused: a robot needs one camera's stream at least)."""
    keys = image_keys(rig, {n: None for n in names}, "stream")
    missing = [r for r in rig.robots if r not in keys.values()]
    if missing:
        raise ObservationError(f"no stream for robot{'s' if len(missing) > 1 else ''} {', '.join(map(repr, missing))} "
                               "(a team track needs one stream per robot of the rig)")
    return unused_cameras(rig, keys)


def unused_cameras(rig: Rig, keys: Iterable[str]) -> list[str]:
    """The cameras (``ROBOT/CAMERA``) of the robots of ``keys`` that no key names."""
    given = {rig.observer(k) for k in keys}
    robots = {r for r, _ in given}
    return [k for k in rig.observer_keys() if rig.observer(k)[0] in robots and rig.observer(k) not in given]


def track_team_log(rig: Any, frames: Iterable[tuple[float, ObservationSet]], reference: str | None = None, *,
                   pixel_sigma: float = 1.0, confidence: float = DEFAULT_CONFIDENCE, progress: bool = True,
                   total: int | None = None, filter: str | FilterOptions = "cv",
                   sink: Callable[[TrackRow, str], None] | None = None) -> TeamTrajectory:
    """Track a team over an observation log (``(time, ObservationSet)`` per
    frame, as :func:`mutloc.io.logs.iter_observation_log` yields them);
    ``sink(row, robot)`` gets every robot's row, in input order, as soon as
    it is final (after the smoother's lag; see :meth:`TeamTracker.finalize`).
    On Ctrl-C (``KeyboardInterrupt``) every record finished so far is
    reported, as if the input ended there, before the exception goes on."""
    rig, reference = _team_setup(rig, reference, (), "log")
    tracker = TeamTracker(rig, reference, pixel_sigma=pixel_sigma, confidence=confidence, options=_options(filter))
    rows: dict[str, list[TrackRow]] = {r: [] for r in tracker.robots}

    def final(record: dict[str, TrackRow], _: Any) -> None:
        if sink is not None:
            for r, row in record.items():
                sink(row, r)

    emitter = RowEmitter(tracker, final)
    try:
        for t, obs in tqdm(frames, total=total, unit="frame", disable=not progress, desc="track team"):
            record = tracker.step(float(t), obs)
            for r, row in record.items():
                rows[r].append(row)
            emitter.add(record, True)
            emitter.emit()
        emitter.emit(end=True)
    except KeyboardInterrupt:
        emitter.emit(end=True)  # every record finished so far, reported as if the input ended here
        raise
    return TeamTrajectory(reference, {r: Trajectory(r, reference, rows[r]) for r in tracker.robots})


def track_team(rig: Any, streams: Mapping[str, Iterable[Frame]], reference: str | None = None, *,
               tolerance: float = 0.005, pixel_sigma: float = 1.0, confidence: float = DEFAULT_CONFIDENCE,
               fps: float | None = None, observations_out: str | Path | None = None, progress: bool = True,
               total: int | None = None, filter: str | FilterOptions = "cv", annotate: str | Path | None = None,
               sink: Callable[[TrackRow, str], None] | None = None) -> TeamTrajectory:
    """Track a team from one image stream per camera (``{key: frames}``, keyed as observations are: ``ROBOT``
    for a robot with one camera, ``ROBOT/CAMERA`` for each camera of a robot with several; every robot of
    the rig needs one stream at least, a camera without one is not used).  Frames are grouped by timestamp
    (:func:`sync_streams`); each robot's image is searched for every other
    robot's markers and the group localized jointly (see the module
    docstring).  ``sink`` and Ctrl-C as :func:`track_team_log`.
    ``annotate``: an mp4 of every record as it becomes final, every robot's
    camera tiled (its latest image; the detections of those in the record)
    with one status line per robot (:func:`mutloc.track.annotate.draw_team`)."""
    rig, reference = _team_setup(rig, reference, streams, "stream")
    require_streams(rig, streams)
    tracker = TeamTracker(rig, reference, pixel_sigma=pixel_sigma, confidence=confidence, options=_options(filter))
    rate = frame_rate(streams, fps)
    robot_of = image_keys(rig, streams, "stream")  # each camera's robot
    dets = {k: ObserverDetector(rig, k, [o for o in rig.robots if o != r], rate or DEFAULT_FPS)
            for k, r in robot_of.items()}
    log = ObservationLogWriter(observations_out) if observations_out else None
    writer = None
    if annotate:
        from .annotate import Annotator

        writer = Annotator(annotate, fps=rate or DEFAULT_FPS)
    sizes: dict[str, tuple[int, int]] = {}
    last: dict[str, tuple[np.ndarray | None, float | None]] = {}  # each camera's latest image and its time

    def final(record: dict[str, TrackRow], images: dict) -> None:
        if writer is not None:
            writer.write_team(images, record, reference, camera_sizes(rig, images, sizes, list(streams)))
        if sink is not None:
            for r, row in record.items():
                sink(row, r)

    emitter = RowEmitter(tracker, final)
    rows: dict[str, list[TrackRow]] = {r: [] for r in tracker.robots}
    bar = tqdm(sync_streams(streams, tolerance), total=total, unit="frame", disable=not progress, desc="track team")
    try:
        for group in bar:
            for r, fr in group.items():
                dets[r].feed(fr)
            t = float(np.mean([f.t for f in group.values()]))
            problems: dict[str, tuple[FrameStatus, str]] = {}
            detections = {}
            for k in streams:
                fr = group.get(k)
                if fr is None:
                    continue  # a record of the other cameras: fused at its own time
                elif fr.image is None:
                    problems[robot_of[k]] = (FrameStatus.CORRUPT, _join(problems.get(robot_of[k], (None, ""))[1],
                                                                        fr.status))
                else:
                    detections[k] = dets[k].detect(fr)
                    if writer is not None:
                        last[k] = (fr.image, fr.t)
            # Tags missed looked for where the track expects them (see .tag_look).
            detections, looked = look_where_tracked(rig, {r: group[r].image for r in detections}, detections,
                                                    lambda: tracker.predicted(t))
            # What the log (and a live node's message) holds: pixels, each weighed alike, so that a
            # track from its log, or a live run, gives the same poses.
            obs = observations_of(detections, t).with_sigma_scale(None) if detections else None
            if log is not None and obs is not None:
                log.write(t, obs)
            times: dict[str, float] = {}  # each robot's frame time (the mean of its cameras' in the record)
            for r in dict.fromkeys(robot_of[k] for k in group):
                times[r] = float(np.mean([f.t for k, f in group.items() if robot_of[k] == r]))
            out = tracker.step(t, obs, times, {r: p for r, p in problems.items() if r != reference})
            if reference in problems:
                for row in out.values():
                    row.reason = _join(row.reason, f"reference {problems[reference][1]}")
            for r, row in out.items():
                if r not in times:
                    row.reason = _join(row.reason, f"no {r} frame in this record")
                for robot, text in looked:
                    if robot == r:
                        row.reason = _join(row.reason, text)
                row.detections = {o: d for o, d in detections.items()}
                rows[r].append(row)
            emitter.add(out, True, dict(last) if writer is not None else None)
            emitter.emit()
        emitter.emit(end=True)
    except KeyboardInterrupt:
        emitter.emit(end=True)  # every record finished so far, reported as if the input ended here
        raise
    finally:
        close_all(bar, writer, log)
    return TeamTrajectory(reference, {r: Trajectory(r, reference, rows[r], rate) for r in tracker.robots}, rate)


def camera_sizes(rig: Rig, images: Mapping[str, tuple[Any, Any]], sizes: dict[str, tuple[int, int]],
                  cameras: list[str] | None = None) -> dict[str, tuple[int, int]]:
    """Each camera's tile ``(width, height)`` in the annotated video, fixed
    with its first frame: the rig's camera size, else its first image's,
    else (no image yet) the largest known.  ``sizes`` is filled in place.
    ``cameras``: the streams' keys (default the robots, one camera each)."""
    keys = cameras if cameras is not None else list(rig.robots)
    if len(sizes) < len(keys):
        for r in keys:
            if r in sizes:
                continue
            size = rig.mount(r).camera.size
            img = images.get(r, (None, None))[0]
            if size is None and img is not None:
                size = (int(img.shape[1]), int(img.shape[0]))
            if size is not None:
                sizes[r] = (int(size[0]), int(size[1]))
        known = list(sizes.values()) or [(640, 480)]
        fill = (max(s[0] for s in known), max(s[1] for s in known))
        for r in keys:
            sizes.setdefault(r, fill)
    return {r: sizes[r] for r in keys}


def _options(filter: str | FilterOptions) -> FilterOptions:
    return filter if isinstance(filter, FilterOptions) else FilterOptions(kind=filter)
