"""A tentative track's frames, reported again once the track is confirmed.

While a track started from three measured markers is tentative, its frames
keep their per-frame statuses (``unverified``, ``too_few``): nothing
confirms them yet.  The filter runs through them all the same, and a
frame that confirms the track (see :mod:`mutloc.track.filtering`) confirms
the track it ran through: each tentative frame was consistent with it (a
frame that contradicts a tentative track drops it).  With the fixed-lag
smoother, whose reports come ``smooth_lag`` frames late anyway, the
tentative frames within that lag of the confirming one are then reported as
the confirmed track would have reported them -- ``solved`` with three or
more markers, ``partial``, ``predicted`` -- and join the smoothed segment.
The frame that started the track keeps its status: its pose is its own
three-marker fit, which nothing tested.  Without smoothing (``smooth_lag``
0, a robot acting on each frame as it comes) no status changes afterwards.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..core.filter import FilterState
    from .tracker import TrackRow

__all__ = ["TentativeFrames"]


@dataclass
class _Pending:
    index: int  # the frame's entry in the tracker's smoothing history
    row: "TrackRow"
    status: Any
    estimate: Any
    reason: str
    prior: "FilterState"
    post: "FilterState"


class TentativeFrames:
    """The frames of the current tentative track, with what the filter made of them."""

    def __init__(self) -> None:
        self._pending: list[_Pending] = []

    def clear(self) -> None:
        """The tentative track ended (dropped, restarted or lost)."""
        self._pending.clear()

    def add(self, index: int, row: "TrackRow", trial: "TrackRow", prior: "FilterState",
            post: "FilterState") -> None:
        """Frame ``row`` (history entry ``index``) ran through the tentative
        track: ``trial`` holds the status, estimate and reason a confirmed
        track would have given it, ``prior``/``post`` the filter's states."""
        self._pending.append(_Pending(index, row, trial.status, trial.estimate, trial.reason, prior, post))

    def confirm(self, history: list | None, index: int, lag: int, t: float) -> int:
        """The frame at history entry ``index`` (time ``t``) confirmed the
        track: report the pending frames within ``lag`` entries of it as the
        track does, and put them in the smoothing ``history``.  Returns how
        many frames were reported again."""
        done = 0
        if history is not None and lag > 0:
            for p in self._pending:
                if index - p.index > lag or p.estimate is None:
                    continue
                note = f"confirmed in hindsight by the frame at t = {t:.3f} s"
                p.row.status, p.row.estimate = p.status, p.estimate
                p.row.reason = f"{note}; {p.reason}" if p.reason else note
                history[p.index] = (p.prior, p.post, p.row)
                done += 1
        self.clear()
        return done
