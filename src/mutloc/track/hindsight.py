"""A tentative track's frames, reported again once the track is confirmed.

While a track started from three measured markers is tentative, its frames
keep their per-frame statuses (``unverified``, ``too_few``): nothing
confirms them yet.  The filter runs through them all the same, and when a
later frame confirms the track (see :mod:`mutloc.track.filtering`), the
tentative frames within the smoother's lag before it -- whose reports come
that late anyway -- are reported as the confirmed track does (``solved``
with three or more markers, ``partial``, ``predicted``) and join the
smoothed segment, going back from the confirming frame as long as each
three-marker frame is *verified by the frames after it*: a track run
backward in time over the ``smooth_lag`` frames after it, from the last of
them that fixes the pose on its own, must predict all of its markers within
``CONFIRM_SPREAD`` pixel sigmas and agree with them, and predict the pose
the forward track predicted within their joint uncertainty.  The forward
track cannot vouch for them: while it was tentative its prior was vague,
and one bad detection in a three-marker frame bends it without a trace.
The frame that started the track -- its pose its own untested three-marker
fit -- is checked the same way: the forward track through the others grew
from it, so unless it is verified, they report the backward track's pose
(those not verified themselves keep their statuses).  Without smoothing (``smooth_lag`` 0, a robot acting on
each frame as it comes) no status changes afterwards.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from ..core.consistency import same_pose
from ..core.filter import ConstantVelocityFilter
from ..core.observations import MIN_OBSERVATIONS
from ..errors import MutlocError
from .solving import CONFIRM_SPREAD, lost_reason, solve_row
from .status import FrameStatus

if TYPE_CHECKING:
    from ..core.filter import FilterState
    from .rows import TrackRow

__all__ = ["BackwardUpdate", "TentativeFrames", "backward_update", "verified_backward"]


@dataclass
class _Pending:
    index: int  # the frame's entry in the tracker's smoothing history
    row: "TrackRow"
    status: Any
    estimate: Any
    reason: str
    prior: "FilterState"
    post: "FilterState"
    start: bool = False  # the frame that started the tentative track


class TentativeFrames:
    """The frames of the current tentative track, with what the filter made
    of them; after a confirmation, those that may be reported again."""

    def __init__(self) -> None:
        self._pending: list[_Pending] = []
        #: Per confirmation: (its time, the tentative frames within the lag
        #: before it, the frame that started the track, its history entry).
        self.confirmed: list[tuple[float, list[_Pending], _Pending | None, int]] = []

    def clear(self) -> None:
        """The tentative track ended (dropped, restarted or lost)."""
        self._pending.clear()

    def add(self, index: int, row: "TrackRow", trial: "TrackRow", prior: "FilterState",
            post: "FilterState", start: bool = False) -> None:
        """Frame ``row`` (history entry ``index``) ran through the tentative
        track (``start``: started it): ``trial`` holds the status, estimate
        and reason a confirmed track would have given it, ``prior``/``post``
        the filter's states."""
        self._pending.append(_Pending(index, row, trial.status, trial.estimate, trial.reason, prior, post, start))

    def confirm(self, index: int, lag: int, t: float) -> None:
        """The frame at history entry ``index`` (time ``t``) confirmed the
        track: keep its tentative frames within ``lag`` entries before it."""
        near = [p for p in self._pending if index - p.index <= lag and p.estimate is not None]
        start = next((p for p in self._pending if p.start), None)
        if near:
            self.confirmed.append((t, near, start, index))
        self.clear()

    def first_unreported(self) -> float:
        """The first history entry that a confirmation not yet reported may
        report again (inf if none)."""
        return min((p.index for _, frames, _, _ in self.confirmed for p in frames), default=math.inf)

    def report(self, tracker: Any, history: list, stepped: Sequence["TrackRow"], lag: int,
               before: int | None = None) -> int:
        """Report the kept frames as the confirmed track does, going back
        from each confirming frame while every three-marker frame is
        verified by the ``lag`` frames after it (``stepped``: every row
        the tracker filtered, aligned with ``history``); ``before``: only the
        confirmations at history entries before it (their frames' ``lag``
        frames after them have come).  Returns how many."""
        done = 0
        ripe = [c for c in self.confirmed if before is None or c[3] < before]
        self.confirmed = [c for c in self.confirmed if c not in ripe]
        for t, frames, start, _ in ripe:
            # The forward track through the tentative frames grew from the
            # starting frame's untested three-marker fit.  Unless the frames
            # after it verify that frame, a bad detection there may have bent
            # it -- the next frame, verified on its own markers, was reported
            # 6-7 cm off (tests/test_track_hindsight.py) -- so the frames
            # verified then report the backward track's pose instead, and
            # the others keep their per-frame statuses.
            rooted = start is not None and verified_backward(
                tracker, start.row, stepped[start.index + 1:start.index + 1 + lag], start.prior)
            for p in reversed(frames):
                back = None
                if p.status == FrameStatus.SOLVED and not (rooted and p is start):  # start: checked above
                    back = backward_update(tracker, p.row, stepped[p.index + 1:p.index + 1 + lag], p.prior)
                    if back is None:
                        break
                elif not rooted:
                    continue
                note = f"confirmed in hindsight by the frame at t = {t:.3f} s and the frames after it"
                p.row.status, p.row.estimate = p.status, p.estimate
                p.row.reason = f"{note}; {p.reason}" if p.reason else note
                if rooted:
                    history[p.index] = (p.prior, p.post, p.row)
                else:
                    # The backward track, updated with the frame's markers:
                    # smoothed by the frames after it, independent of those
                    # before; it stays out of the forward smoother.
                    state = _forward_in_time(back.state, p.row.t)
                    est = tracker._estimate(state, [_marker(label) for label in back.labels], back.rms_px,
                                            back.test)
                    p.row.estimate = replace(est, extra=dict(est.extra, smooth_lag=lag, smoother="backward"))
                done += 1
        return done


@dataclass
class BackwardUpdate:
    """The backward track's update with a verified frame's markers."""

    state: "FilterState"  # at the frame, in reversed time (velocity negated)
    labels: list[str]
    rms_px: float
    test: Any


def verified_backward(tracker: Any, row: "TrackRow", later: Sequence["TrackRow"],
                      forward: "FilterState | None" = None) -> bool:
    """Whether a track run backward in time over ``later`` (the frames after
    ``row``, in time order) verifies ``row``: see :func:`backward_update`."""
    return backward_update(tracker, row, later, forward) is not None


def backward_update(tracker: Any, row: "TrackRow", later: Sequence["TrackRow"],
                    forward: "FilterState | None" = None) -> BackwardUpdate | None:
    """The update with ``row``'s markers of a track run backward in time over
    ``later`` (the frames after ``row``, in time order), if it predicts every
    one of them within ``CONFIRM_SPREAD`` pixel sigmas and agrees with all of
    them -- and, given the forward track's prediction at ``row``
    (``forward``), predicts the same pose within their joint uncertainty;
    else None.

    ``tracker``: the :class:`~mutloc.track.filtering.PairTracker` (its rig,
    noise, options and spread measure).  The backward track starts from the
    last frame of ``later`` that ``localize`` fixes on measured markers alone
    (three or more) and runs with time reversed; it is independent of ``row``."""

    f = ConstantVelocityFilter(tracker.options.noise, tracker.pixel_sigma, tracker.confidence,
                               measure_noise=tracker.options.measure_noise)
    for r in reversed(later):
        problem = _problem(tracker, r)
        if problem is None:
            continue
        if f.state is None:
            if len(problem.side) < MIN_OBSERVATIONS:
                continue
            alone = replace(r, reason="", estimate=None, detections={})
            solve_row(alone, tracker.rig, tracker.source, tracker.target, tracker.pixel_sigma, tracker.confidence)
            if alone.status in (FrameStatus.SOLVED, FrameStatus.UNVERIFIED) and alone.estimate is not None:
                f.reset(-r.t, alone.estimate.pose, alone.estimate.covariance)
            continue
        f.predict(-r.t)
        if lost_reason(f.state, tracker.options):
            return None
        f.update(problem)
    problem = _problem(tracker, row)
    if f.state is None or problem is None:
        return None
    state = f.predict(-row.t)
    markers = [_marker(label) for label in problem.labels]
    if max(tracker.spread_px(state, m) for m in markers) > CONFIRM_SPREAD * tracker.pixel_sigma:
        return None
    if forward is not None and not same_pose(state.pose, state.pose_covariance, forward.pose,
                                             forward.pose_covariance, tracker.confidence):
        return None
    upd = f.update(problem)
    if not (upd.accepted and len(upd.used) == len(markers)):
        return None
    return BackwardUpdate(upd.state, list(problem.labels), float(upd.rms_px), upd.test)


def _marker(label: str) -> str:
    return label.rsplit(" saw ", 1)[-1]


def _forward_in_time(state: "FilterState", t: float) -> "FilterState":
    """A backward filter's state (time and velocity reversed) in forward time."""
    flip = np.r_[np.ones(6), -np.ones(6)]
    cov = state.covariance * np.outer(flip, flip)
    gain = None if state.gain_covariance is None else state.gain_covariance * np.outer(flip, flip)
    return replace(state, time=t, velocity=-state.velocity, covariance=cov, gain_covariance=gain)




def _problem(tracker: Any, row: "TrackRow") -> Any:
    """The row's named, measured observations in the filter's form (None if none)."""
    obs = row.observations
    if obs is None or obs.has_alternatives:
        return None
    try:
        pair = obs.pair(tracker.rig, tracker.source, tracker.target)
    except MutlocError:
        return None
    return tracker.problem(pair) if len(pair.rows) else None
