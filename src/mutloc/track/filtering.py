"""Frame by frame, what a track reports: each frame's observations either
localized on their own (``--filter none``) or folded into the
constant-velocity filter of :mod:`mutloc.core.filter` (``--filter cv``).

With the filter (SPEC "Filtered tracking"): the track starts from the first
frame ``localize`` solves (four or more markers, consistent with their
noise); after that every frame updates it -- ``solved`` with three or more
markers consistent with the track (the prior confirms three-marker frames),
``partial`` with one or two, ``predicted`` with none, ``rejected`` (with the
predicted pose and the reason) when the observations contradict the track.
After ``reinit_after`` rejected frames in a row, a frame that ``localize``
solves on its own restarts the track (the track had gone wrong, e.g. a
robot was carried); when the predicted uncertainty grows past
``lost_sigma_t``/``lost_sigma_r_deg`` the track is lost and restarts the
same way.  A team tracker is one :class:`PairTracker` per robot against the
reference.

Blinking lights are rarely all on together, so a frame ``localize`` solves
on its own (four measured markers) may be seconds away.  A frame with exactly
three measured markers (``unverified``) therefore starts a *tentative*
track: its frames keep their per-frame statuses (nothing is reported from
it) until a frame of three markers, at least one of them not among the
starting three and predicted sharply (``CONFIRM_SPREAD``), is consistent
with it -- two different marker sets, each fixing the pose on its own,
agree through the motion prior.  From that frame on the track is confirmed
and reports as above; with the fixed-lag smoother, so do its tentative
frames within the lag that the frames after them verify (see
:mod:`.hindsight`).  A tentative track that any frame contradicts is
dropped, and a frame of four or more markers decides for itself: solved,
it confirms the track where it agrees with it as above, else starts a new
one; not solved, the tentative track goes (it may share the frame's bad
detection and so agree with it).

Cameras need not be synchronized: a record may hold one camera's
observations at its own capture time, and the filter takes it there.  A
track may also start from the records of the last ``start_window``
seconds together -- their pose and velocity fitted with every observation
at its own time (:func:`mutloc.core.filter.fit_moving_pose`), tested with
``2n - 12`` degrees of freedom -- where they hold four or more distinct
observations.  Rejections are also counted per camera: a camera whose
records the track keeps rejecting while the other camera's records (which
cannot expose it) carry it restarts the track, or drops it.

A frame of exactly three markers taken by a track that the record before
it did not confirm (four or more markers) cannot expose one bad detection
among them: a partial frame may have left the track loose in the direction
the bad marker pulls.  Within the smoother's lag such a frame can still be
undone: when a frame solved on its own then contradicts the track, the
track goes back to before the unverified frame, which is reported
``rejected`` (with that track's prediction), and the frames since are
filtered again.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ..api import Estimate, localize
from ..core.consistency import DEFAULT_CONFIDENCE
from ..core.estimate import PairProblem
from ..core.filter import (ConstantVelocityFilter, FilterState, FilterUpdate, MotionNoise, fit_moving_pose, rts_gains,
                           rts_smooth)
from ..core.observations import MIN_OBSERVATIONS, PairObservations
from ..core.pose import Pose
from ..core.rig import Rig
from ..errors import InputError, MutlocError, positive_number
from .hindsight import TentativeFrames
from .solving import CONFIRM_SPREAD, lost_reason, solve_row
from .status import FrameStatus

if TYPE_CHECKING:
    from .rows import TrackRow

__all__ = ["DEFAULT_SMOOTH_LAG", "FILTERS", "FilterOptions", "PairTracker", "solve_row", "lost_reason",
           "pair_problem"]

#: ``--filter`` choices: the constant-velocity filter, or every frame on its own.
FILTERS = ("cv", "none")
#: Frames after each frame that inform its reported pose by default (1/3 s
#: at 30 fps): the inputs are recorded, and on the issue's sequences this
#: fixed-lag smoother halves the causal filter's error (README "Filtered tracking").
DEFAULT_SMOOTH_LAG = 10
#: Seconds of records a track may start from together (see FilterOptions).
DEFAULT_START_WINDOW = 0.15
#: Degrees of freedom a start from several records must leave for its test:
#: a wrong detection among them must be able to show.
MIN_START_DOF = 4


@dataclass(frozen=True)
class FilterOptions:
    """How a track is filtered (documented defaults).

    ``kind``: ``"cv"`` (constant velocity) or ``"none"``; ``noise``: the
    motion model's :class:`~mutloc.core.filter.MotionNoise`;
    ``reinit_after``: rejected frames in a row after which a frame solved
    on its own restarts the track; ``lost_sigma_t`` (m) and
    ``lost_sigma_r_deg``: a predicted 1-sigma beyond these loses the track;
    ``smooth_lag``: frames after each frame that also inform its reported
    pose (fixed-lag RTS smoothing; 0 = the causal filter's pose; None, the
    default: ``DEFAULT_SMOOTH_LAG`` with the filter, 0 without);
    ``measure_noise``: the gain uses the detections' measured noise when it
    is clearly below ``pixel_sigma`` (see
    :attr:`~mutloc.core.filter.ConstantVelocityFilter.gain_sigma`);
    ``start_window`` (s): a track may also start from the records of the
    last ``start_window`` seconds together -- cameras that are not
    synchronized, each record one camera's frame -- their pose and velocity
    fitted with every observation at its own time (0: only from one record).
    """

    kind: str = "cv"
    noise: MotionNoise = field(default_factory=MotionNoise)
    reinit_after: int = 3
    lost_sigma_t: float = 0.5
    lost_sigma_r_deg: float = 20.0
    smooth_lag: int | None = None
    measure_noise: bool = True
    start_window: float = DEFAULT_START_WINDOW

    def __post_init__(self) -> None:
        if self.kind not in FILTERS:
            raise InputError(f"filter must be one of {', '.join(FILTERS)}, got {self.kind!r}")
        if self.smooth_lag is None:
            object.__setattr__(self, "smooth_lag", DEFAULT_SMOOTH_LAG if self.kind == "cv" else 0)
        if not (isinstance(self.reinit_after, int) and self.reinit_after >= 1):
            raise InputError(f"reinit_after must be an integer >= 1, got {self.reinit_after!r}")
        if not (isinstance(self.smooth_lag, int) and self.smooth_lag >= 0):
            raise InputError(f"smooth_lag must be an integer >= 0 (frames), got {self.smooth_lag!r}")
        if self.smooth_lag and self.kind != "cv":
            raise InputError("smoothing (--smooth-lag) needs the filter (--filter cv)")
        if not (isinstance(self.start_window, (int, float)) and 0.0 <= self.start_window < math.inf):
            raise InputError(f"start_window must be a number of seconds >= 0, got {self.start_window!r}")
        positive_number(self.lost_sigma_t, "lost_sigma_t")
        positive_number(self.lost_sigma_r_deg, "lost_sigma_r_deg")


class PairTracker:
    """Turns each frame (a :class:`~mutloc.track.tracker.TrackRow` with its
    observations) into its reported status and pose, in time order."""

    def __init__(self, rig: Rig, source: str, target: str, *, pixel_sigma: float = 1.0,
                 confidence: float = DEFAULT_CONFIDENCE, options: FilterOptions | None = None) -> None:
        self.rig, self.source, self.target = rig, source, target
        self.pixel_sigma = positive_number(pixel_sigma, "pixel_sigma")
        self.confidence = confidence
        self.options = options if options is not None else FilterOptions()
        self.filter = ConstantVelocityFilter(self.options.noise, pixel_sigma, confidence,
                                             measure_noise=self.options.measure_noise)
        self.rejections = 0
        #: Per observer: its records rejected since one of them was last accepted.
        self._contradicted: dict[str, int] = {}
        #: Whether the track's last record was an update by four or more markers
        #: (or a start): a track that can verify a frame of three markers.
        self._supported = False
        #: Frames of three markers the track took without being able to verify
        #: them, and how to undo them (see ``_judge_support``).
        self._pending: _Pending | None = None
        self._replaying = False
        #: Rows of ``history`` whose reports are final (see ``finalize``), and
        #: the smoother's gains computed for the rows not yet final.
        self._final = 0
        self._gain_cache: dict[int, np.ndarray] = {}
        self._restarted = False
        #: While the track is tentative: the markers of the three-marker frame that started it.
        self._tentative: frozenset[str] | None = None
        #: ... and its frames since, reported again once it is confirmed (see .hindsight).
        self._tentative_frames = TentativeFrames()
        #: When a list: per frame, (prediction, state after the frame, row) while the
        #: track runs, None where it (re)starts or is lost -- for smoothing.
        self.history: list[tuple[FilterState, FilterState, Any] | None] | None = \
            [] if self.options.smooth_lag > 0 and self.filtering else None
        #: Every row filtered, aligned with ``history`` (for the hindsight checks).
        self._stepped: list[Any] = []
        #: The last ``start_window`` seconds of rows with named, measured
        #: observations: ``(time, row)`` -- what a start from several records may use.
        self._recent: deque[tuple[float, Any]] = deque()

    @property
    def filtering(self) -> bool:
        return self.options.kind == "cv"

    @property
    def rows_filtered(self) -> int:
        """Rows taken into the smoothing history so far (what :meth:`finalize` counts)."""
        return len(self._stepped)

    def step(self, row: "TrackRow") -> None:
        """Set ``row``'s status, reason and estimate from its observations
        (rows without observations -- unpaired, corrupt -- are left alone)."""
        if row.observations is None:
            return
        if not self.filtering:
            solve_row(row, self.rig, self.source, self.target, self.pixel_sigma, self.confidence)
            return
        if self.filter.state is not None and row.t < self.filter.state.time:
            raise InputError(f"frame at {row.t} s comes before the previous one ({self.filter.state.time} s)")
        try:
            self._step(row)
        except _Unconfirmed:
            self._roll_back(row)
            _clear(row)
            self._step(row)  # the track no longer holds the undone frames: this cannot undo any


    def _step(self, row: "TrackRow") -> None:
        if self.history is not None:
            self._stepped.append(row)
        if self._pending is not None:
            self._pending.rows.append(row)
            if len(self._pending.rows) > self.options.smooth_lag:
                self._pending = None  # beyond the lag its report is out: taken as it stands
        self._remember(row)
        lost = ""
        if self.filter.state is not None:
            state = self.filter.predict(row.t)
            lost = self._lost(state)
            if lost:
                self.filter.state, self._pending = None, None
        if self.filter.state is None:
            self._restart(row, lost)
            self._record(None)
            return
        self._restarted = False
        try:
            if self._tentative is not None:
                self._tentative_step(row, state)
            else:
                self._filtered_step(row, state)
        finally:
            self._record(None if self._restarted or self.filter.state is None or self._tentative is not None
                         else (state, self.filter.state, row))

    def _record(self, entry: tuple[FilterState, FilterState, Any] | None) -> None:
        if self.history is not None:
            self.history.append(entry)

    def finish(self) -> None:
        """The input ended: every row's report is final (:meth:`finalize` to the end)."""
        self.finalize(end=True)

    def finalize(self, end: bool = False) -> int:
        """Make final the reports of the rows that nothing to come can change,
        in input order, and return how many of the rows filtered so far are
        final (all of them without smoothing).

        With ``smooth_lag``: each filtered row's pose and covariance become
        the fixed-lag smoothed ones (the frame and the ``smooth_lag`` frames
        after it in the same uninterrupted track) -- what a fixed-lag smoother
        reports ``smooth_lag`` frames late.  A row is final once ``smooth_lag
        + 1`` frames came after it, no confirmation of a tentative track may
        still report it again (see :mod:`.hindsight`), and no undo may still
        change the frames its smoothing spans; ``end``: the input ended, every
        row is final."""
        lag = self.options.smooth_lag
        hist = self.history
        if hist is None:
            return 0
        n = len(hist)
        limit = n if end else n - lag - 1
        ripe = None if end else n - lag
        self._tentative_frames.report(self, hist, self._stepped, lag, before=ripe)
        if not end:
            limit = min(limit, self._tentative_frames.first_unreported())
            if self._pending is not None:
                limit = min(limit, self._pending.history_len - lag)
        for k in range(self._final, limit):
            entry = hist[k]
            if entry is None or entry[2].estimate is None:
                continue
            window = [entry]
            for h in hist[k + 1:k + lag + 1]:
                if h is None:
                    break
                window.append(h)
            priors, posts = [h[0] for h in window], [h[1] for h in window]
            state = rts_smooth(priors, posts, self._gains(k, priors, posts))[0]
            row = entry[2]
            row.estimate = replace(row.estimate, pose=state.pose, covariance=state.pose_covariance.copy(),
                                   candidates=Pose.concatenate([state.pose]),
                                   extra=dict(row.estimate.extra, smooth_lag=lag, velocity=state.velocity.tolist()))
        self._final = max(self._final, limit)
        for k in [k for k in self._gain_cache if k < self._final]:
            del self._gain_cache[k]
        return self._final

    def _gains(self, k: int, priors: list[FilterState], posts: list[FilterState]) -> list[np.ndarray]:
        """The smoother's gains between history entries ``k + i`` and ``k + i + 1``
        (each computed once: consecutive rows' windows share them)."""
        out = []
        for i in range(len(posts) - 1):
            g = self._gain_cache.get(k + i)
            if g is None:
                g = self._gain_cache[k + i] = rts_gains(priors[i:i + 2], posts[i:i + 2])[0]
            out.append(g)
        return out

    def _filtered_step(self, row: "TrackRow", state: FilterState) -> None:
        try:
            obs = row.observations
            if obs.has_alternatives:
                obs = self._nearest_candidates(obs, state.pose)
            pair = obs.pair(self.rig, self.source, self.target)
        except MutlocError as exc:
            row.status = FrameStatus.FAILED
            row.reason = " ".join(str(exc).split())
            return
        if len(pair.rows) == 0:
            self._supported = False
            row.status = FrameStatus.PREDICTED
            row.reason = "no markers seen" if pair.count == 0 else \
                f"{pair.count} markers of unknown identity (the filter needs named markers)"
            row.estimate = self._estimate(state, [], 0.0, None)
            return
        problem = self.problem(pair)
        upd = self.filter.update(problem)
        observers = set(pair.parent.observer[k] for k in pair.rows.tolist())
        if upd.accepted:
            self.rejections = 0
            for o in observers:
                self._contradicted[o] = 0
            self._accepted(row, problem, upd)
            if self._tentative is None:  # (a tentative track's trial frames are judged by _confirm)
                self._judge_support(row, state, len(upd.used))
            return
        self._supported = False
        if self._pending is not None and self._pending.frames and self._measured(row) > MIN_OBSERVATIONS:
            alone = _copy_row(row)
            solve_row(alone, self.rig, self.source, self.target, self.pixel_sigma, self.confidence)
            if alone.status == FrameStatus.SOLVED:
                # A frame that holds on its own contradicts a track made by frames nothing confirmed.
                self._pending.blame = row.t
                raise _Unconfirmed()
        self.rejections += 1
        for o in observers:
            self._contradicted[o] = self._contradicted.get(o, 0) + 1
        worst, streak = max(self._contradicted.items(), key=lambda kv: kv[1])
        if streak >= self.options.reinit_after:
            why = (f"{self.rejections} frames in a row inconsistent with the track" if self.rejections == streak else
                   f"{worst}'s last {streak} records inconsistent with the track")
            restarted = self._restart(row, why, keep_failure=False)
            if restarted:
                return
        row.status = FrameStatus.REJECTED
        row.reason = upd.reason
        row.estimate = self._estimate(upd.state, [], upd.rms_px, upd.test)
        if streak >= 2 * self.options.reinit_after and streak > self.rejections:
            # One camera keeps contradicting a track that the other camera's
            # records alone carry (they cannot expose it): drop the track.
            self.filter.state = None
            row.estimate = None
            row.reason = f"track dropped: {worst}'s last {streak} records inconsistent with it; {row.reason}"

    # -- internals ------------------------------------------------------------

    def _tentative_step(self, row: "TrackRow", state: FilterState) -> None:
        """Update a tentative track with the row; the row reports its
        per-frame result unless this frame confirms the track."""
        if self._measured(row) > MIN_OBSERVATIONS:
            # Four or more markers judge themselves: solved, and consistent
            # with the track where it predicted them sharply, the frame
            # confirms the track; solved but not that, it starts a new one;
            # inconsistent, the tentative track (which may share the bad
            # detection, and so agree with it) goes too.
            alone = _copy_row(row)
            solve_row(alone, self.rig, self.source, self.target, self.pixel_sigma, self.confidence)
            if alone.status != FrameStatus.SOLVED or not self._confirm(row, state, _copy_row(row)):
                self.filter.state, self._tentative = None, None
                self._restart(row, "")
            return
        trial = _copy_row(row)
        if self._confirm(row, state, trial):
            return
        if trial.status in (FrameStatus.REJECTED, FrameStatus.FAILED) or self.filter.state is None:
            self.filter.state, self._tentative = None, None
            self._restart(row, "")
            return
        if self.history is not None:
            self._tentative_frames.add(len(self.history), row, trial, state, self.filter.state)
        solve_row(row, self.rig, self.source, self.target, self.pixel_sigma, self.confidence)

    def _confirm(self, row: "TrackRow", state: FilterState, trial: "TrackRow") -> bool:
        """Filter ``trial`` (a copy of ``row``) into the tentative track; when
        it confirms the track, report ``row`` (and the tentative frames, see
        :mod:`.hindsight`) as the confirmed track does and return True."""
        self._filtered_step(trial, state)
        used = set(trial.estimate.markers_used) if trial.estimate is not None else set()
        new = used - self._tentative
        # The new markers must have been predicted sharply: a wrong start
        # (three markers fit any one bad detection exactly) is exposed only
        # where the track's prediction could have missed them.  Every
        # measured marker must agree (none dropped).
        spread = max((self.spread_px(state, m) for m in new), default=math.inf)
        if (trial.status != FrameStatus.SOLVED or spread > CONFIRM_SPREAD * self.pixel_sigma
                or len(used) < self._measured(row)):
            return False
        started = ", ".join(sorted(self._tentative))
        self._tentative = None
        row.status, row.estimate = trial.status, trial.estimate
        note = (f"track confirmed: {', '.join(sorted(used))} agree with the track started on {started} "
                f"(new markers predicted within {spread:.1f} px)")
        row.reason = f"{note}; {trial.reason}" if trial.reason else note
        if self.history is not None:
            self._tentative_frames.confirm(len(self.history), self.options.smooth_lag, row.t)
        return True

    def _accepted(self, row: "TrackRow", problem: PairProblem, upd: FilterUpdate) -> None:
        names = [problem.labels[k] for k in upd.used.tolist()]
        row.status = FrameStatus.SOLVED if len(upd.used) >= MIN_OBSERVATIONS else FrameStatus.PARTIAL
        if len(upd.dropped):
            row.reason = "dropped " + ", ".join(
                f"{problem.labels[k]} ({upd.residuals_px[k]:.1f} px off)" for k in upd.dropped.tolist())
        row.estimate = self._estimate(upd.state, [_marker_of(n) for n in names], upd.rms_px, upd.test)

    def _restart(self, row: "TrackRow", why: str, keep_failure: bool = True) -> bool:
        """Localize the row on its own; a solved frame (re)starts the track, a
        frame of three measured markers starts a tentative one.  Returns
        whether it did; with ``keep_failure`` the row keeps the per-frame
        result either way."""
        self._tentative_frames.clear()
        trial = row if keep_failure else _copy_row(row)
        solve_row(trial, self.rig, self.source, self.target, self.pixel_sigma, self.confidence)
        # Only a frame solved on measured markers alone starts a track: four
        # positions that include predicted lights can pass their test and
        # still be centimetres off, and later three-marker frames would then
        # be called solved against a wrong track.
        started = trial.status == FrameStatus.SOLVED and trial.estimate is not None
        # Three measured markers (never predicted ones) start a tentative track.
        tentative = (not started and trial.status == FrameStatus.UNVERIFIED and trial.estimate is not None
                     and self._measured(trial) >= MIN_OBSERVATIONS)
        self._tentative = frozenset(trial.estimate.markers_used) if tentative else None
        if not (started or tentative):
            bridged = self._bridged_start(row)
            if bridged is not None:
                self.rejections = 0
                self._contradicted.clear()
                self._pending, self._supported = None, True
                self._restarted = True
                row.status, row.estimate, row.reason = bridged.status, bridged.estimate, bridged.reason
                if why:
                    row.reason = f"track restarted: {why}; {row.reason}"
                return True
        if started or tentative:
            est = trial.estimate
            self.filter.reset(row.t, est.pose, est.covariance)
            self.rejections = 0
            self._contradicted.clear()
            self._pending, self._supported = None, started
            self._restarted = True
            if tentative and self.history is not None:
                # The starting frame is a tentative frame like those after
                # it: the frames after it may verify it in hindsight (the
                # backward track that does is independent of it).
                first = _copy_row(trial)
                first.status = FrameStatus.SOLVED
                first.reason = "started the track on " + ", ".join(sorted(self._tentative))
                first.estimate = self._estimate(self.filter.state, list(est.markers_used),
                                                est.reprojection_rms_px, est.consistency)
                self._tentative_frames.add(len(self.history), row, first, self.filter.state, self.filter.state,
                                           start=True)
            if trial is not row:
                row.status, row.estimate, row.reason = trial.status, trial.estimate, trial.reason
        if why and (started or tentative or keep_failure):
            note = f"track {'restarted' if started else 'restarted tentatively' if tentative else 'lost'}: {why}"
            row.reason = f"{note}; {row.reason}" if row.reason else note
        return started or tentative

    def _judge_support(self, row: "TrackRow", prior: FilterState, used: int) -> None:
        """After an accepted update: four or more markers confirm the track
        (and every frame it took unverified); exactly three on a track not
        itself confirmed by the last record are taken, but remembered with
        the state before them, so that a frame solved on its own within the
        smoother's lag (whose reports come that late anyway) that
        contradicts the track can undo them (see ``_roll_back``).  Without
        smoothing nothing is reported again."""
        if used > MIN_OBSERVATIONS:
            self._pending, self._supported = None, True
            return
        if used == MIN_OBSERVATIONS and not self._supported and self.options.smooth_lag and not self._replaying:
            if self._pending is None:
                f = self.filter
                self._pending = _Pending(prior, deque(f._noise_window), list(f._noise_sum), dict(self._contradicted),
                                         len(self.history) if self.history is not None else 0,
                                         len(self._stepped) - 1 if self.history is not None else 0, [row])
            self._pending.frames.add(id(row))
        self._supported = False

    def _roll_back(self, row: "TrackRow") -> None:
        """Undo the track since its first unverified three-marker frame (the
        frame ``row``, solved on its own, contradicts it): those frames are
        reported ``rejected`` with the track's prediction without them, the
        other frames since are filtered again, then ``row`` goes again."""
        pend = self._pending
        assert pend is not None
        self._pending = None
        f = self.filter
        f.state, f._noise_window, f._noise_sum = pend.prior, deque(pend.noise_window), list(pend.noise_sum)
        self._contradicted = dict(pend.contradicted)
        self.rejections, self._supported = 0, False
        if self.history is not None:
            del self.history[pend.history_len:]
            del self._stepped[pend.stepped_len:]
        for r in pend.rows:
            if r is row:
                break
            if id(r) in pend.frames:
                if self.history is not None:
                    self._stepped.append(r)
                state = f.predict(r.t)
                note = (f"not confirmed: the frame at {pend.blame:.3f} s, solved on its own, contradicts the track "
                        "this frame of three markers made")
                _clear(r)
                r.status, r.reason = FrameStatus.REJECTED, note
                r.estimate = self._estimate(state, [], 0.0, None)
                self._record((state, state, r))
            else:
                _clear(r)
                self._replaying = True  # frames filtered again make nothing to undo
                try:
                    self._step(r)
                finally:
                    self._replaying = False

    def _remember(self, row: "TrackRow") -> None:
        """Keep the row among the recent records a start may bridge."""
        window = self.options.start_window
        if window <= 0.0 or any(r is row for _, r in self._recent):  # (filtered again after an undo)
            return
        self._recent.append((row.t, row))
        while self._recent and self._recent[0][0] < row.t - window:
            self._recent.popleft()

    def _bridged_start(self, row: "TrackRow") -> "TrackRow | None":
        """Start the track from the recent records together (cameras at
        their own times): the pose at ``row.t`` and the velocity fitted to
        every measured observation at its own time (the motion model
        bridges them).  Only records of one camera each are bridged (a record
        of both judges itself).  It starts only where the records hold four
        or more distinct observations (each fixing the pose without the motion), the
        fit leaves ``MIN_START_DOF`` degrees of freedom and passes its
        chi-square test, and its uncertainty is within the track's limits.
        Returns the row as reported (status ``solved``), or None."""
        records = [r for _, r in self._recent]
        if len(records) < 2 or records[-1] is not row:
            return None
        problems, times, latest = [], [], {}
        for r in records:
            try:
                pair = r.observations.pair(self.rig, self.source, self.target)
            except MutlocError:
                continue
            if len(pair.rows) == 0:
                continue
            if len(set(pair.side.tolist())) > 1:
                # A record of both cameras judges itself (a solve, or a tentative
                # track that later frames must confirm): only records of one
                # camera each -- cameras not synchronized -- are bridged.
                return None
            problems.append(self.problem(pair))
            times.append(r.t)
            obs = pair.parent
            for k in pair.rows.tolist():
                latest[(obs.observer[k], obs.marker[k])] = (r.t, obs.observer[k], obs.marker[k], obs.uv[k])
        n = sum(len(p.side) for p in problems)
        if len(latest) <= MIN_OBSERVATIONS or len(times) < 2 or 2 * n - 12 < MIN_START_DOF:
            return None
        # A first pose from the latest observation of each marker as if simultaneous (untested) ...
        from ..core.observations import ObservationSet

        rows = list(latest.values())
        union = ObservationSet([o for _, o, _, _ in rows], [m for _, _, m, _ in rows],
                               np.array([uv for *_, uv in rows]), row.t)
        try:
            first = localize(self.rig, union, self.source, self.target, pixel_sigma=self.pixel_sigma,
                             confidence=1.0)
        except MutlocError:
            return None
        # ... then pose and velocity from every observation at its own time.
        fit = fit_moving_pose(problems, times, row.t, first.pose, sigma=self.pixel_sigma,
                              confidence=self.confidence, noise=self.options.noise)
        if fit is None or not fit.test.passed or lost_reason(fit.state, self.options):
            return None
        state = self.filter.start(fit.state)
        out = _copy_row(row)
        out.status = FrameStatus.SOLVED
        markers = sorted({m for _, _, m, _ in rows})
        span = 1000.0 * (times[-1] - times[0])
        out.reason = (f"track started from {len(times)} records over {span:.0f} ms ({n} observations of "
                      f"{len(latest)} markers; pose and velocity fitted at each record's time)")
        out.estimate = self._estimate(state, markers, float(np.sqrt(np.mean(fit.residuals_px**2))), fit.test)
        return out

    def spread_px(self, state: FilterState, marker: str) -> float:
        """1-sigma (px, largest axis) of where ``state`` predicts ``marker``
        in its observer's image (unscented, from the pose covariance)."""
        for observer, other, inverse in ((self.target, self.source, False), (self.source, self.target, True)):
            if marker in self.rig.robot(other).markers:
                break
        else:
            return math.inf
        X = self.rig.robot(other).markers[marker].position
        cam = self.rig.robot(observer).camera
        P = state.pose_covariance
        try:
            L = np.linalg.cholesky(0.5 * (P + P.T) + 1e-18 * np.eye(6)) * math.sqrt(6.0)
        except np.linalg.LinAlgError:
            return math.inf
        pix = []
        for col in np.concatenate([L.T, -L.T]):
            T = Pose(Pose.from_rotvec(col[:3], np.zeros(3)).R @ state.pose.R, state.pose.t + col[3:])
            pix.append(cam.project((T.inverse() if inverse else T).apply(X)))
        d = np.asarray(pix, float)
        if not np.all(np.isfinite(d)):
            return math.inf
        d -= d.mean(axis=0)
        return float(math.sqrt(max(np.linalg.eigvalsh(d.T @ d / len(d)).max(), 0.0)))

    def _measured(self, row: "TrackRow") -> int:
        """Named markers measured (not predicted) in the row."""
        try:
            return len(row.observations.pair(self.rig, self.source, self.target).rows)
        except MutlocError:
            return 0

    def _nearest_candidates(self, obs: Any, pose: Pose) -> Any:
        """Where a detector handed over several candidates for a marker, the
        one nearest its predicted pixel (the track decides, not the score)."""
        best: dict[tuple, tuple[float, int]] = {}
        for i, (o, m) in enumerate(zip(obs.observer, obs.marker)):
            key = (o, m if m is not None else f"#{i}")
            one = obs.take(np.array([i])).pair(self.rig, self.source, self.target)
            err = float(self.filter.residuals(self.problem(one), pose)[0]) if len(one.rows) else 0.0
            if key not in best or err < best[key][0]:
                best[key] = (err, i)
        return obs.take(np.array(sorted(i for _, i in best.values()), dtype=np.int64))

    def _lost(self, state: FilterState) -> str:
        return lost_reason(state, self.options)

    def problem(self, pair: PairObservations) -> PairProblem:
        """The named observations of a frame in the filter's form (labels "p saw M1")."""
        return pair_problem(pair)

    def _estimate(self, state: FilterState, markers: list[str], rms: float, test: Any) -> Estimate:
        return Estimate(source=self.source, target=self.target, pose=state.pose,
                        covariance=state.pose_covariance.copy(), pixel_sigma=self.pixel_sigma,
                        reprojection_rms_px=float(rms), markers_used=markers,
                        candidates=Pose.concatenate([state.pose]), consistency=test,
                        extra={"velocity": state.velocity.tolist(), "filter": self.options.kind})


def pair_problem(pair: PairObservations) -> PairProblem:
    """The named observations of a pair in the filter's form (labels "p saw M1")."""
    table = pair.table
    obs = pair.parent
    rows = pair.rows
    labels = [f"{obs.observer[r]} saw {obs.marker[r]}" for r in rows.tolist()]
    return PairProblem.trusted(pair.side, np.ascontiguousarray(table.points[pair.points_index]), None,
                               np.ascontiguousarray(obs.uv[rows]), table.K, table.dist, labels)


class _Unconfirmed(Exception):
    """Internal: the current frame contradicts frames the track took unverified."""


@dataclass
class _Pending:
    """Frames of three markers taken by a track that could not verify them,
    with what undoing them restores: the prediction at the first, the
    filter's noise measurements, and the history's length then."""

    prior: FilterState
    noise_window: deque
    noise_sum: list
    contradicted: dict
    history_len: int
    stepped_len: int
    rows: list
    frames: set = field(default_factory=set)
    blame: float = math.nan


def _clear(row: "TrackRow") -> None:
    row.status, row.reason, row.estimate = FrameStatus.SOLVED, "", None


def _marker_of(label: str) -> str:
    return label.rsplit(" saw ", 1)[-1]


def _copy_row(row: "TrackRow") -> "TrackRow":
    return replace(row, reason="", estimate=None)
