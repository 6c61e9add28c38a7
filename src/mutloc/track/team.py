"""Team tracking: one trajectory per robot, in the reference robot's frame
(SPEC "Filtered tracking": with more than two robots one
``trajectory_NAME.csv`` / ``trajectory_NAME.tum`` per robot).

Each frame's observations of the whole team are localized **jointly**
(:func:`mutloc.localize_team`, warm-started from the filters' predictions),
then every robot's pose ``T_ref_r`` is filtered on its own:

- one constant-velocity filter per robot (:class:`mutloc.core.filter.
  ConstantVelocityFilter`, the pair tracker's), whose measurement is the
  joint estimate's pose of that robot with its 6x6 covariance block
  (:meth:`~mutloc.core.filter.ConstantVelocityFilter.update_pose`, gated
  with 6 degrees of freedom).  The correlations between robots in the joint
  covariance are not carried from frame to frame: each robot's filter is
  independent (the simplest honest generalisation; the per-frame joint
  estimate keeps them).
- a robot the joint problem cannot place this frame (one or two
  observations tie it) but whose track runs is updated on its **pixels**
  through the pair filter: for each localized robot ``s`` it shares
  observations with, the state is moved into ``s``'s frame (``T_s_ref``
  from the joint estimate, taken as exact), updated by the observations
  between ``r`` and ``s`` as a pair track would be, and moved back: status
  ``partial``.
- no observations: ``predicted``; a joint pose inconsistent with the track:
  ``rejected`` (the row carries the prediction).

A track starts from a frame in which the joint estimate of the robot is
``solved`` (four or more observations tie it and the team passes its
chi-square test), as a pair track does.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping

import numpy as np
from tqdm import tqdm

from ..api import Estimate, load_rig
from ..core.consistency import DEFAULT_CONFIDENCE
from ..core.filter import ConstantVelocityFilter, FilterState
from ..core.observations import ObservationSet
from ..core.pose import Pose
from ..core.rig import Rig
from ..core.team import MIN_TIES
from ..errors import InconsistentObservationsError, InputError, MutlocError, ObservationError, positive_number
from ..io.logs import ObservationLogWriter
from ..team import TeamEstimate, localize_team
from .filtering import FilterOptions, lost_reason, pair_problem
from .frames import expanded_rig, observations_of
from .sources import Frame
from .status import FrameStatus
from .tracker import DEFAULT_FPS, ObserverDetector, TrackRow, Trajectory, frame_rate

__all__ = ["TeamTrajectory", "TeamTracker", "track_team", "track_team_log", "sync_streams", "team_file_names",
           "require_streams"]


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


class TeamTracker:
    """Turns each frame of team observations into one row per robot (see the module docstring)."""

    def __init__(self, rig: Rig, reference: str | None = None, *, pixel_sigma: float = 1.0,
                 confidence: float = DEFAULT_CONFIDENCE, options: FilterOptions | None = None) -> None:
        names = list(rig.robots)
        if len(names) < 3:
            raise ObservationError(f"a team tracker needs three or more robots; the rig has {len(names)} "
                                   "(track a pair with --source/--target)")
        if reference is None:
            reference = names[0]
        if not isinstance(reference, str) or reference not in rig.robots:
            raise ObservationError(f"unknown reference robot {reference!r} (rig has {sorted(rig.robots)})")
        self.rig, self.reference = rig, reference
        self.robots = [n for n in names if n != reference]
        self.pixel_sigma = positive_number(pixel_sigma, "pixel_sigma")
        self.confidence = confidence
        self.options = options if options is not None else FilterOptions(smooth_lag=0)
        if self.options.smooth_lag:
            raise InputError("smoothing (--smooth-lag) is not available for teams yet: "
                             "teams report the causal filter (smooth_lag=0)")
        self.filters = {r: ConstantVelocityFilter(self.options.noise, pixel_sigma, confidence) for r in self.robots}
        self.rejections = {r: 0 for r in self.robots}
        self.last_time: float | None = None
        self.warm_starts = 0

    @property
    def filtering(self) -> bool:
        return self.options.kind == "cv"

    # -- one frame ----------------------------------------------------------

    def step(self, t: float, observations: ObservationSet | None, times: Mapping[str, float | None] | None = None,
             problems: Mapping[str, tuple[FrameStatus, str]] | None = None) -> dict[str, TrackRow]:
        """One row per robot (not the reference) for the frame at ``t``.

        ``times``: each robot's own frame time (``t_source``; the
        reference's is ``t_target``); ``problems``: per robot an input
        status (``unpaired``, ``corrupt``) and reason for its own frame.
        ``observations`` None: no frame at all (every row takes ``problems``
        or ``unpaired``)."""
        if self.last_time is not None and t < self.last_time:
            raise InputError(f"frame at {t} s comes before the previous one ({self.last_time} s)")
        self.last_time = t
        problems = problems or {}
        rows = {r: TrackRow(t, t if times is None else times.get(r), t if times is None else times.get(self.reference),
                            FrameStatus.SOLVED, observations=observations) for r in self.robots}
        predicted: dict[str, FilterState] = {}
        if self.filtering:
            for r in self.robots:
                f = self.filters[r]
                if f.state is None:
                    continue
                state = f.predict(t)
                why = lost_reason(state, self.options)
                if why:
                    f.state = None
                    rows[r].reason = f"track lost: {why}"
                else:
                    predicted[r] = state
        team, status, reason = (None, FrameStatus.UNPAIRED, "no frame") if observations is None else \
            self._solve(observations, predicted)
        for r in self.robots:
            row = rows[r]
            self._robot_row(row, r, team, status, reason, predicted.get(r), observations)
            if r in problems and row.estimate is None:
                row.status, note = problems[r]
                row.reason = f"{note}; {row.reason}" if row.reason else note
            elif r in problems:
                row.reason = f"{problems[r][1]} (localized from the others' views); {row.reason}".rstrip("; ")
        return rows

    def _solve(self, obs: ObservationSet, predicted: Mapping[str, FilterState]
               ) -> tuple[TeamEstimate | None, FrameStatus, str]:
        """The frame's joint estimate (warm-started from the predictions
        when they cover every robot seen), or None with a status and reason."""
        opts = dict(pixel_sigma=self.pixel_sigma, confidence=self.confidence)
        initial = self._warm_start(obs, predicted)
        if initial is not None:
            try:
                team = localize_team(self.rig, obs, self.reference, initial=initial, **opts)
                self.warm_starts += 1
                return team, FrameStatus.SOLVED, ""
            except MutlocError:
                pass  # a cold start decides (and says why if it fails too)
        try:
            return localize_team(self.rig, obs, self.reference, **opts), FrameStatus.SOLVED, ""
        except InconsistentObservationsError as exc:
            return None, FrameStatus.REJECTED, " ".join(str(exc).split())
        except ObservationError as exc:
            status = FrameStatus.TOO_FEW if "three or more" in str(exc) else FrameStatus.FAILED
            return None, status, " ".join(str(exc).split())
        except MutlocError as exc:
            return None, FrameStatus.FAILED, " ".join(str(exc).split())

    def _warm_start(self, obs: ObservationSet, predicted: Mapping[str, FilterState]) -> dict[str, Pose] | None:
        """The predicted poses of the robots the frame's observations tie
        (three or more observations among robots with a prediction), or None
        when some robot seen has no prediction (the pair solvers must start it)."""
        if not predicted or len(obs) == 0:
            return None
        owner = self.rig.owner
        try:
            ends = [(o, owner(m)) for o, m in zip(obs.observer, obs.marker) if m is not None]
        except MutlocError:
            return None  # bad input: the cold start reports it
        seen = {x for e in ends for x in e} - {self.reference}
        if not seen <= set(predicted):
            return None
        keep = set(seen)
        while True:  # drop robots with too few ties to the others kept (their block would be singular)
            ties = {r: sum(1 for a, b in ends if r in (a, b) and {a, b} <= keep | {self.reference}) for r in keep}
            weak = {r for r, n in ties.items() if n < MIN_TIES}
            if not weak:
                break
            keep -= weak
        return {r: predicted[r].pose for r in keep} or None

    def _robot_row(self, row: TrackRow, r: str, team: TeamEstimate | None, status: FrameStatus, reason: str,
                   prior: FilterState | None, obs: ObservationSet | None) -> None:
        localized = team is not None and r in team.poses
        if not self.filtering:
            if localized:
                assert team is not None
                row.estimate = _robot_estimate(team, r, team.poses[r], team.covariance(r))
                row.status = FrameStatus.UNVERIFIED if r in team.unverified else FrameStatus.SOLVED
                row.reason = _dropped(team)
            else:
                row.status, row.reason = self._not_localized(r, team, status, reason, obs)
            return
        f = self.filters[r]
        if prior is None:  # no track: a solved joint estimate starts it
            if localized:
                assert team is not None
                z, C = team.poses[r], team.covariance(r)
                row.estimate = _robot_estimate(team, r, z, C)
                if r in team.unverified or team.status != "solved":
                    row.status = FrameStatus.UNVERIFIED
                    row.reason = _join(row.reason, "three observations tie it to the team (unverified)")
                else:
                    f.reset(row.t, z, C)
                    self.rejections[r] = 0
                    row.status = FrameStatus.SOLVED
                    row.reason = _join(row.reason, _dropped(team))
            else:
                row.status, why = self._not_localized(r, team, status, reason, obs)
                row.reason = _join(row.reason, why)
            return
        if localized:
            assert team is not None
            upd = f.update_pose(team.poses[r], team.covariance(r))
            if upd.accepted:
                self.rejections[r] = 0
                row.status = FrameStatus.SOLVED
                row.estimate = _robot_estimate(team, r, upd.state.pose, upd.state.pose_covariance,
                                               {"velocity": upd.state.velocity.tolist(), "filter": "cv"})
                row.reason = _join(row.reason, _dropped(team))
                return
            self.rejections[r] += 1
            if self.rejections[r] >= self.options.reinit_after and r not in team.unverified \
                    and team.status == "solved":
                z, C = team.poses[r], team.covariance(r)
                f.reset(row.t, z, C)
                self.rejections[r] = 0
                row.status, row.estimate = FrameStatus.SOLVED, _robot_estimate(team, r, z, C)
                row.reason = _join(row.reason, f"track restarted: {self.options.reinit_after} frames in a row "
                                               "inconsistent with the track")
                return
            row.status = FrameStatus.REJECTED
            row.reason = _join(row.reason, f"joint {upd.reason}")
            row.estimate = self._predicted(r, prior)
            return
        if team is not None and obs is not None:
            done = self._partial(row, r, team, obs)
            if done:
                return
        row.status = FrameStatus.PREDICTED if status != FrameStatus.REJECTED else FrameStatus.REJECTED
        _, why = self._not_localized(r, team, status, reason, obs)
        row.reason = _join(row.reason, why)
        row.estimate = self._predicted(r, f.state if f.state is not None else prior)

    def _partial(self, row: TrackRow, r: str, team: TeamEstimate, obs: ObservationSet) -> bool:
        """Pixel updates of r's track from its observations with localized
        robots (each in that robot's frame); True when it set the row."""
        f = self.filters[r]
        used: list[str] = []
        rejected: list[str] = []
        for s in [self.reference, *[n for n in team.robots if n != r]]:
            try:
                pair = obs.pair(self.rig, r, s)
            except MutlocError:
                continue
            if len(pair.rows) == 0:
                continue
            problem = pair_problem(pair)
            A = team.poses[s].inverse()  # T_s_ref
            prior = f.state
            moved = _moved(prior, A, None if s == self.reference else team.relative(self.reference, s).covariance)
            f.state = moved
            upd = f.update(problem)
            f.state = _pulled_back(prior, moved, f.state, A) if upd.accepted else prior
            if upd.accepted:
                used += [problem.labels[k] for k in upd.used.tolist()]
            else:
                rejected.append(upd.reason)
        if not used and not rejected:
            return False
        s = f.state
        if used:
            row.status = FrameStatus.PARTIAL
            row.reason = _join(row.reason, f"{len(used)} observation(s) tie it to localized robots: updated through "
                                           "the filter")
            self.rejections[r] = 0
        else:
            row.status = FrameStatus.REJECTED
            row.reason = _join(row.reason, "; ".join(rejected))
        row.estimate = Estimate(source=r, target=self.reference, pose=s.pose, covariance=s.pose_covariance.copy(),
                                pixel_sigma=self.pixel_sigma, reprojection_rms_px=0.0,
                                markers_used=[u.rsplit(" saw ", 1)[-1] for u in used],
                                candidates=Pose.concatenate([s.pose]), consistency=None,
                                extra={"velocity": s.velocity.tolist(), "filter": "cv"})
        return True

    def _predicted(self, r: str, state: FilterState) -> Estimate:
        return Estimate(source=r, target=self.reference, pose=state.pose, covariance=state.pose_covariance.copy(),
                        pixel_sigma=self.pixel_sigma, reprojection_rms_px=0.0, markers_used=[],
                        candidates=Pose.concatenate([state.pose]), consistency=None,
                        extra={"velocity": state.velocity.tolist(), "filter": "cv"})

    def _not_localized(self, r: str, team: TeamEstimate | None, status: FrameStatus, reason: str,
                       obs: ObservationSet | None) -> tuple[FrameStatus, str]:
        """Status and reason of a robot without a joint pose this frame."""
        if team is None:
            if status == FrameStatus.SOLVED:
                status = FrameStatus.FAILED
            return status, reason
        n = 0
        if obs is not None:
            owner = self.rig.owner
            n = sum(1 for o, m in zip(obs.observer, obs.marker) if m is not None and (o == r or owner(m) == r))
        if n == 0:
            return FrameStatus.TOO_FEW if not self.filtering else FrameStatus.PREDICTED, "no markers seen"
        return FrameStatus.TOO_FEW, (f"{n} observation{'s' if n != 1 else ''} involve it: too few to tie it to "
                                     f"{self.reference!r} (three are needed)")


def _moved(state: FilterState, A: Pose, cov_A: np.ndarray | None = None) -> FilterState:
    """The state of ``T`` as the state of ``A @ T``: pose, velocity and the
    error state's covariance rotated into A's frame, plus (first order) A's
    own covariance ``cov_A`` (SPEC order) on the pose block."""
    G = np.kron(np.eye(4), A.R)
    P = G @ state.covariance @ G.T
    pose = A @ state.pose
    if cov_A is not None:
        J = np.eye(6)
        tx = pose.t - A.t  # = R_A t: translation of the moved pose by A's rotation
        J[3:, :3] = -np.array([[0.0, -tx[2], tx[1]], [tx[2], 0.0, -tx[0]], [-tx[1], tx[0], 0.0]])
        P[:6, :6] += J @ cov_A @ J.T
    return FilterState(state.time, pose, np.r_[A.R @ state.velocity[:3], A.R @ state.velocity[3:]], P)


def _pulled_back(prior: FilterState, moved: FilterState, posterior: FilterState, A: Pose) -> FilterState:
    """The update of ``prior`` (state of ``T``) implied by the update of its
    moved state ``moved`` (of ``A @ T``, with A's uncertainty) to
    ``posterior``: linear-Gaussian conditioning through the cross-covariance
    ``P G^T`` (G the rotation of the move), so A's error stays measurement
    noise and never becomes information about T.  With A exact this is the
    inverse move."""
    from ..core.geometry import so3_exp, so3_log

    G = np.kron(np.eye(4), A.R)
    m = np.r_[so3_log(posterior.pose.R @ moved.pose.R.T), posterior.pose.t - moved.pose.t,
              posterior.velocity - moved.velocity]
    gain = np.linalg.solve(moved.covariance, G @ prior.covariance).T  # P G^T P'^-1
    dx = gain @ m
    P = prior.covariance - gain @ (moved.covariance - posterior.covariance) @ gain.T
    pose = Pose(so3_exp(dx[:3]) @ prior.pose.R, prior.pose.t + dx[3:6])
    return FilterState(prior.time, pose, prior.velocity + dx[6:], 0.5 * (P + P.T))


def _dropped(team: TeamEstimate) -> str:
    if not team.rejected:
        return ""
    return "joint estimate dropped " + ", ".join(f"{d['observer']} saw {d['marker']} ({d['residual_px']:.1f} px off)"
                                                 for d in team.rejected)


def _join(a: str, b: str) -> str:
    return f"{a}; {b}" if a and b else (a or b)


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
    for robot in names:
        rig.robot(robot)
    if reference is not None and (not isinstance(reference, str) or reference not in rig.robots):
        raise ObservationError(f"unknown reference robot {reference!r} (rig has {sorted(rig.robots)})")
    return rig, reference if reference is not None else next(iter(rig.robots))


def require_streams(rig: Rig, names: Iterable[str]) -> None:
    """ObservationError unless every name is a robot of the rig and every robot has a stream."""
    names = list(names)
    for robot in names:
        rig.robot(robot)
    missing = [r for r in rig.robots if r not in names]
    if missing:
        raise ObservationError(f"no stream for robot{'s' if len(missing) > 1 else ''} {', '.join(map(repr, missing))} "
                               "(a team track needs one stream per robot of the rig)")


def track_team_log(rig: Any, frames: Iterable[tuple[float, ObservationSet]], reference: str | None = None, *,
                   pixel_sigma: float = 1.0, confidence: float = DEFAULT_CONFIDENCE, progress: bool = True,
                   total: int | None = None, filter: str | FilterOptions = "cv",
                   sink: Callable[[TrackRow, str], None] | None = None) -> TeamTrajectory:
    """Track a team over an observation log (``(time, ObservationSet)`` per
    frame, as :func:`mutloc.io.logs.iter_observation_log` yields them);
    ``sink(row, robot)`` gets every robot's row as soon as it is made (a
    team's rows are final at once: no smoothing)."""
    rig, reference = _team_setup(rig, reference, (), "log")
    tracker = TeamTracker(rig, reference, pixel_sigma=pixel_sigma, confidence=confidence, options=_options(filter))
    rows: dict[str, list[TrackRow]] = {r: [] for r in tracker.robots}
    for t, obs in tqdm(frames, total=total, unit="frame", disable=not progress, desc="track team"):
        for r, row in tracker.step(float(t), obs).items():
            rows[r].append(row)
            if sink is not None:
                sink(row, r)
    return TeamTrajectory(reference, {r: Trajectory(r, reference, rows[r]) for r in tracker.robots})


def track_team(rig: Any, streams: Mapping[str, Iterable[Frame]], reference: str | None = None, *,
               tolerance: float = 0.005, pixel_sigma: float = 1.0, confidence: float = DEFAULT_CONFIDENCE,
               fps: float | None = None, observations_out: str | Path | None = None, progress: bool = True,
               total: int | None = None, filter: str | FilterOptions = "cv",
               sink: Callable[[TrackRow, str], None] | None = None) -> TeamTrajectory:
    """Track a team from one image stream per robot (``{robot: frames}``;
    every robot of the rig needs one).  Frames are grouped by timestamp
    (:func:`sync_streams`); each robot's image is searched for every other
    robot's markers and the group localized jointly (see the module
    docstring).  ``sink`` as :func:`track_team_log`."""
    rig, reference = _team_setup(rig, reference, streams, "stream")
    require_streams(rig, streams)
    tracker = TeamTracker(rig, reference, pixel_sigma=pixel_sigma, confidence=confidence, options=_options(filter))
    rate = frame_rate(streams, fps)
    dets = {r: ObserverDetector(rig, r, [o for o in rig.robots if o != r], rate or DEFAULT_FPS) for r in rig.robots}
    log = ObservationLogWriter(observations_out) if observations_out else None
    rows: dict[str, list[TrackRow]] = {r: [] for r in tracker.robots}
    bar = tqdm(sync_streams(streams, tolerance), total=total, unit="frame", disable=not progress, desc="track team")
    try:
        for group in bar:
            for r, fr in group.items():
                dets[r].feed(fr)
            t = float(np.mean([f.t for f in group.values()]))
            problems: dict[str, tuple[FrameStatus, str]] = {}
            detections = {}
            for r in rig.robots:
                fr = group.get(r)
                if fr is None:
                    problems[r] = (FrameStatus.UNPAIRED, f"no {r} frame within {tolerance} s")
                elif fr.image is None:
                    problems[r] = (FrameStatus.CORRUPT, fr.status)
                else:
                    detections[r] = dets[r].detect(fr)
            obs = observations_of(detections, t) if detections else None
            if log is not None and obs is not None:
                log.write(t, obs)
            times = {r: f.t for r, f in group.items()}
            out = tracker.step(t, obs, times, {r: p for r, p in problems.items() if r != reference})
            if reference in problems:
                for row in out.values():
                    row.reason = _join(row.reason, f"reference {problems[reference][1]}")
            for r, row in out.items():
                row.detections = {o: d for o, d in detections.items()}
                rows[r].append(row)
                if sink is not None:
                    sink(row, r)
    finally:
        bar.close()
        if log is not None:
            log.close()
    return TeamTrajectory(reference, {r: Trajectory(r, reference, rows[r], rate) for r in tracker.robots}, rate)


def _options(filter: str | FilterOptions) -> FilterOptions:
    return filter if isinstance(filter, FilterOptions) else FilterOptions(kind=filter, smooth_lag=0)
