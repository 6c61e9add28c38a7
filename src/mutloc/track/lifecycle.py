"""A robot's track in the team filter: its state and the rules that move it
(:class:`~mutloc.track.team_tracker.TeamTracker`; SPEC "Filtered tracking").

A track is started (:mod:`mutloc.track.starts`) in one of four states:

- ``NEW``: placed by a record's joint solve with four or more observations
  and a passing test: tentative until a later record's accepted
  observations (three or more) confirm it;
- ``ON_THREE``: placed by exactly three (which fit any one bad detection
  exactly): confirmed only the strict way (:func:`confirms`); its rows
  report what their record shows on its own until then;
- ``BRIDGED``: placed by several records' observations solved together (no
  test of their own): confirmed the strict way, as ``ON_THREE``;
- ``CONFIRMED``: confirmed by a later record, or started confirmed from
  records at their own times (:meth:`~mutloc.track.starts.Starts.moving`).

Any state: each camera's records of the robot rejected in a row are counted
(:func:`count_rejection`); too many restart the track (:func:`restart_reason`),
twice as many drop it (:func:`drop_after_restart`).  A confirmed track's
support (:func:`judge_support`) decides which records an :class:`UndoRequest`
may take back.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np

from ..core.team import MIN_TIES, TeamProblem
from .solving import CONFIRM_SPREAD


class TrackState(enum.Enum):
    NEW = "new"  #: started from four or more observations: tentative
    ON_THREE = "on_three"  #: started from exactly three: tentative, confirmed the strict way
    BRIDGED = "bridged"  #: started from several records solved together: as ON_THREE
    CONFIRMED = "confirmed"


@dataclass
class Undo:
    """Records of exactly three observations tying a robot to one other that
    its confirmed track took while the record before did not support it:
    the first one's number and all of them (see :class:`UndoRequest`)."""

    first: int
    records: set = field(default_factory=set)


@dataclass
class UndoRequest:
    """A record solved on its own (at ``t``) contradicts records of three
    that robot ``robot``'s confirmed track took unverified: take them back
    (:func:`mutloc.track.hindsight.roll_back`), then filter the record again."""

    robot: str
    t: float


@dataclass
class Track:
    """A robot's track in the joint filter (``start``: the observations that started it)."""

    start: frozenset
    state: TrackState = TrackState.NEW
    #: per camera: its records of the robot rejected in a row, and whether
    #: since the first of them another camera's record solved the robot
    #: (placed it on its own, consistent with the track).
    contradicted: dict = field(default_factory=dict)
    held_by_others: dict = field(default_factory=dict)
    #: While tentative: its records as a confirmed track would report them
    #: (see :class:`~mutloc.track.hindsight.Tentative`).
    frames: list = field(default_factory=list)
    #: Whether the robot's last update tied it to one robot by four or more
    #: (or started it): a track that can verify a record of three.
    supported: bool = True
    #: Records of three the confirmed track took without being able to verify them.
    undo: Undo | None = None

    @property
    def confirmed(self) -> bool:
        return self.state == TrackState.CONFIRMED

    @property
    def strict(self) -> bool:
        """Tentative and confirmed only the strict way (started on three, or bridged)."""
        return self.state in (TrackState.ON_THREE, TrackState.BRIDGED)

    def copy(self) -> "Track":
        return replace(self, contradicted=dict(self.contradicted), held_by_others=dict(self.held_by_others),
                       frames=list(self.frames),
                       undo=None if self.undo is None else replace(self.undo, records=set(self.undo.records)))


# -- start --------------------------------------------------------------------


def start_state(three: bool, bridged: bool, n: int) -> TrackState:
    """The state of a track started from a record's joint solve: ``three``:
    the solve placed it with exactly three (or did not verify it);
    ``bridged``: several records solved together; ``n``: the record's
    observations that started it."""
    if bridged:
        return TrackState.BRIDGED
    if three or n <= MIN_TIES:
        return TrackState.ON_THREE
    return TrackState.NEW


# -- confirm ------------------------------------------------------------------


def confirms(tr: Track, n: int, new: list, spread: Mapping[int, float], dropped: bool, pixel_sigma: float
             ) -> tuple[bool, float]:
    """Whether a later record's ``n`` accepted observations of a tentative
    track confirm it (and the worst spread of the new ones, px).  Three or
    more; a strict track (started on exactly three, which fit any one bad
    detection exactly, so its pose may be wrong, or bridged) only where
    every observation of the robot in the record agrees (none ``dropped``
    by the gate) and the observations ``new`` -- not among those that
    started it, at least one -- were predicted sharply (``spread``: their
    1-sigma, within ``CONFIRM_SPREAD`` x ``pixel_sigma``): where the
    track's prediction could have missed them, a wrong start is exposed."""
    if not tr.strict:
        return n >= MIN_TIES, 0.0
    if n < MIN_TIES or dropped or not new:
        return False, 0.0
    worst = max(spread.get(j, math.inf) for j in new)
    return worst <= CONFIRM_SPREAD * pixel_sigma, worst


def restart_on_four(tr: Track, ties: int) -> str | None:
    """A strict tentative track that a record tying it to one robot by four
    or more (``ties``) does not confirm restarts from that record."""
    if tr.strict and ties > MIN_TIES:
        return "a record of four or more observations does not confirm the tentative track"
    return None


# -- rejections: restart, drop ------------------------------------------------


def count_rejection(tr: Track, cams: set[str]) -> None:
    """A record of cameras ``cams`` rejected the robot's observations."""
    for c in cams:
        tr.contradicted[c] = tr.contradicted.get(c, 0) + 1
        if tr.contradicted[c] == 1:
            tr.held_by_others[c] = False


def count_accepted(tr: Track, cams: set[str]) -> None:
    """A record of cameras ``cams`` had the robot's observations accepted."""
    for c in cams:
        tr.contradicted[c] = 0


def held_by_others(tr: Track, cams: set[str]) -> None:
    """A record solved the robot on its own without cameras ``cams``: each
    camera at odds with the track since is the one at odds."""
    for c in tr.held_by_others:
        if c not in cams:
            tr.held_by_others[c] = True


def worst(tr: Track) -> tuple[str, int]:
    """The camera whose records of the robot the track keeps rejecting
    while no other camera's record solved the robot since (those can
    expose a wrong track: then the camera is the one at odds), and its
    streak; ("", 0) if none."""
    open_ = {c: n for c, n in tr.contradicted.items() if n and not tr.held_by_others.get(c, False)}
    if not open_:
        return "", 0
    c = max(open_, key=open_.get)
    return c, open_[c]


def restart_reason(tr: Track, reinit_after: int) -> tuple[str | None, str | None]:
    """After a rejection: why the track restarts (a tentative track at once;
    a confirmed one after ``reinit_after`` records of one camera in a row),
    else None -- and else the row's note when a camera other cameras'
    records contradict keeps being rejected."""
    cam, streak = worst(tr)
    if not tr.confirmed:
        return "a record contradicted the tentative track", None
    if streak >= reinit_after:
        return f"{cam}'s last {streak} records inconsistent with the track", None
    if tr.contradicted and max(tr.contradicted.values()) >= reinit_after:
        c = max(tr.contradicted, key=tr.contradicted.get)
        return None, (f"{c}'s last {tr.contradicted[c]} records of it inconsistent with the track that "
                      "the other cameras' records hold")
    return None, None


def drop_after_restart(tr: Track, reinit_after: int) -> bool:
    """A track due to restart that no record restarted: dropped if tentative,
    or after twice ``reinit_after`` records of one camera in a row."""
    _, streak = worst(tr)
    return not tr.confirmed or streak >= 2 * reinit_after


# -- support (what an undo may take back) -------------------------------------


def judge_support(tr: Track, n: int, k: int, remember: bool) -> None:
    """After an accepted update of a confirmed track: four or more
    observations tying it to one robot (``n``, at most) support it (and
    clear the records it took unverified); exactly three while the record
    before did not support it are taken but remembered (record number
    ``k``; ``remember``: with smoothing, not while replaying), so that a
    record solved on its own within the smoother's lag that contradicts the
    track can undo them."""
    if n > MIN_TIES:
        tr.undo, tr.supported = None, True
        return
    if n == MIN_TIES and not tr.supported and remember:
        if tr.undo is None:
            tr.undo = Undo(k)
        tr.undo.records.add(k)
    tr.supported = False



# -- what the rules read ------------------------------------------------------


def ties_to_one(problem: TeamProblem, i: int) -> int:
    """The most observations between robot ``i`` and any one other robot
    (either way): four or more place it on their own, as a pair's frame does."""
    C = problem.counts()
    ties = C[i] + C[:, i]
    ties[i] = 0
    return int(ties.max()) if len(ties) else 0


@dataclass
class PoseCov:
    """What :func:`~mutloc.track.solving.lost_reason` reads of a state."""

    pose_covariance: np.ndarray
