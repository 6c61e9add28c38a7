"""What the live localizer says about itself: each robot's counts
(:class:`RobotCounts`, the ``/diagnostics`` key-values), each robot's
``/diagnostics`` status (:func:`robot_statuses`: its level and message, from
the age of its observations, its ties, the rig check, what was refused or
shed), the rate-limited lines to ``notify`` (:class:`Notices`) and the
run's summary line (:func:`summary`).

Read from a :class:`~mutloc.live.localizer.Localizer`'s public state (its
``counts``, ``rig_gate``, ``odometry``, ``clocks``, ...); nothing here
changes what is fused or published.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable

from .messages import ERROR, OK, STALE, WARN, RobotStatus

__all__ = ["RobotCounts", "Tally", "Notices", "level", "robot_statuses", "summary", "NOTICE_HOLD", "NOTICE_PERIOD"]

#: Seconds a robot stays WARN after its last refused message (or another localizer's pose of it).
NOTICE_HOLD = 5.0
#: Seconds between two printed lines of one cause (robot and kind of refusal): the first is printed at once.
NOTICE_PERIOD = 10.0



@dataclass
class RobotCounts:
    """What one robot's observation topic brought (the diagnostics' key-values)."""

    received: int = 0
    fused: int = 0
    dropped_late: int = 0
    #: Messages not fused because a newer one of the same camera waited while the localizer was behind.
    shed: int = 0
    duplicates: int = 0
    refused_rig_id: int = 0
    refused_malformed: int = 0
    refused_clock: int = 0
    poses: int = 0
    #: Its poses (or their /tf) that DDS did not take (``write`` failed).
    unsent: int = 0
    #: Newest capture time among its messages taken (None: none yet).
    last_stamp: float | None = None
    #: Stamp (ns) of its last pose on ``/tf`` (see :attr:`LivePose.tf`).
    last_tf_ns: int | None = None
    #: Its track's status at the last record (robots whose pose is published).
    status: str = ""
    #: Time of its track's last measured row (solved, unverified or partial).
    last_measured: float | None = None
    #: Whether the observations of the last ``max_coast`` s tied it to the reference at the last record
    #: (see :mod:`mutloc.live.ties`; its pose is published only then), and since when they do not.
    tied: bool = False
    untied_since: float | None = None
    #: Distinct observations tying it to other robots within the last ``max_coast`` s, at the last record.
    ties: int = 0
    #: Its rows not published because the observations of the last ``max_coast`` s did not tie it.
    untied: int = 0
    #: Its rows not published because the records kept disagreeing with the rig (see ``Localizer.rig_withheld``).
    rig_withheld: int = 0
    #: Its rows not published because the rig had not been tested yet (see :mod:`mutloc.live.rig_gate`).
    rig_waiting: int = 0
    #: Frame numbers of its cameras' messages that never came (skipped between two that did: frames its
    #: node dropped, or messages DDS lost, e.g. overwritten in a full reader); a node restarting (its numbers
    #: going back) is not counted.
    not_received: int = 0
    #: Arrival time of its last refused message, and why it was refused (None: none refused).
    last_refused_at: float | None = None
    last_refusal: str = ""
    #: Clock time at which a message of it was last shed (None: none shed).
    last_shed_at: float | None = None
    #: Arrival time of the last pose of it that another localizer published, and who that is.
    foreign_at: float | None = None
    foreign: str = ""
    seen: set = field(default_factory=set, repr=False)
    order: deque = field(default_factory=deque, repr=False)

    @property
    def refused(self) -> int:
        return self.refused_rig_id + self.refused_malformed + self.refused_clock




class Notices:
    """The lines to ``notify`` (the CLI: stderr): each cause once, then rate-limited."""

    def __init__(self, notify: Callable[[str], None] | None) -> None:
        #: Where a line saying what is wrong goes (None: nowhere).
        self.notify = notify
        self._causes: dict[tuple, list] = {}  # cause -> [time printed, said since]

    def say(self, cause: tuple, line: str, now: float, once: bool = False) -> None:
        """Print ``line`` (to :attr:`notify`) the first time of ``cause``, then at most every
        :data:`NOTICE_PERIOD` s with how many more there were (``once``: only the first time)."""
        state = self._causes.get(cause)
        if state is None:
            self._causes[cause] = [now, 0]
            if self.notify is not None:
                self.notify(line)
            return
        state[1] += 1
        if not once and now - state[0] >= NOTICE_PERIOD:
            if self.notify is not None:
                self.notify(f"{line} ({state[1]} more in the last {now - state[0]:.0f} s)")
            state[:] = [now, 0]


def level(c: RobotCounts, now: float, warn_after: float, max_coast: float) -> int:
    """OK, WARN (last observation older than ``warn_after``) or STALE (older than ``max_coast``, or none)."""
    if c.last_stamp is None:
        return STALE
    age = now - c.last_stamp
    return OK if age <= warn_after else WARN if age <= max_coast else STALE


def robot_statuses(loc: Any, now: float) -> list[RobotStatus]:
    """One :class:`~mutloc.live.messages.RobotStatus` per robot of ``loc``'s rig (a
    :class:`~mutloc.live.localizer.Localizer`), in rig order."""
    return [robot_status(loc, r, now) for r in loc.names]


def robot_status(loc: Any, r: str, now: float) -> RobotStatus:
    """Robot ``r``'s status in ``loc``'s ``/diagnostics`` at ``now``."""
    c = loc.counts[r]
    lv, message = _level_and_message(loc, r, now)
    age = None if c.last_stamp is None else now - c.last_stamp
    gate = loc.rig_gate
    said = []
    if c.last_refused_at is not None and now - c.last_refused_at <= NOTICE_HOLD:
        said.append(f"refused {c.refused} observations: {c.last_refusal}")
    if c.last_shed_at is not None and now - c.last_shed_at <= NOTICE_HOLD:
        said.append(f"falling behind: shed {c.shed} of {c.received}")
    if c.foreign_at is not None and now - c.foreign_at <= NOTICE_HOLD:
        said.append(f"another localizer publishes on this domain: {c.foreign}")
    if (gate.flag is not None and now - gate.flag[0] <= NOTICE_HOLD
            and not message.startswith("not published since")):
        said.append(gate.flag[1].words())
    if loc.odometry is not None:
        said += loc.odometry.said(r, now, NOTICE_HOLD)
    if said:
        # (none received: what was refused is the news; a robot not stale is WARN)
        message = "; ".join(said if age is None else [message, *said])
        lv = WARN if age is None or lv == OK else lv
    return RobotStatus(r, lv, message, _values(loc, r, now))


def _level_and_message(loc: Any, r: str, now: float) -> tuple[int, str]:
    """Robot ``r``'s level and message from its observations' age, its ties and the rig check."""
    c = loc.counts[r]
    lv = level(c, now, loc.warn_after, loc.max_coast)
    age = None if c.last_stamp is None else now - c.last_stamp
    if age is None:
        message = "no observations received"
    elif lv == OK:
        message = f"observations {age:.2f} s old" + ("" if r == loc.reference else f"; track {_track(loc, r)}")
    elif lv == WARN:
        message = f"no observations for {age:.2f} s"
    else:
        message = f"dropped: no observations for {age:.2f} s"
    if lv == OK and r != loc.reference and not c.tied and c.untied_since is not None:
        # observations come, but too few of them (over the last max_coast s) to fix its pose
        lv = STALE
        message = (f"not published: tied by {c.ties} distinct observation(s) in the last {loc.max_coast:g} s "
                   f"(three fix a pose), for {max(0.0, now - c.untied_since):.2f} s")
    gate = loc.rig_gate
    if lv == OK and r != loc.reference and gate.withheld is not None and gate.flag is not None:
        lv = ERROR
        message = f"not published since {max(0.0, now - gate.withheld):.2f} s ago: " + gate.flag[1].words()
    elif lv == OK and r != loc.reference and gate.waiting:
        lv = WARN
        message = "not published yet: " + gate.words(loc.engine.tracker.rig_check.window)
    return lv, message


def _track(loc: Any, r: str) -> str:
    return "reference" if r == loc.reference else (loc.counts[r].status or "none")


def _values(loc: Any, r: str, now: float) -> dict[str, Any]:
    """Robot ``r``'s key-values in ``/diagnostics``."""
    c = loc.counts[r]
    age = None if c.last_stamp is None else now - c.last_stamp
    values: dict[str, Any] = {
        "status": _track(loc, r), "age_s": "none" if age is None else f"{age:.3f}", "received": c.received,
        "fused": c.fused, "dropped_late": c.dropped_late, "duplicates": c.duplicates, "shed": c.shed,
        "refused": c.refused, "refused_rig_id": c.refused_rig_id, "refused_malformed": c.refused_malformed,
        "refused_clock": c.refused_clock, "poses_published": c.poses, "poses_unsent": c.unsent, "ties": c.ties,
        "untied_not_published": c.untied, "rig_withheld": c.rig_withheld, "rig_waiting": c.rig_waiting,
        "rig_check": loc.rig_gate.state, "not_received": c.not_received}
    if loc.odometry is not None:
        values.update(loc.odometry.values(r, now))
    if loc.clocks is not None:
        values.update(loc.clocks.values(r))
    rig_test = loc.engine.tracker.rig_check.last
    if rig_test is not None:
        values.update(rig_chi2=f"{rig_test.chi2:.1f}", rig_dof=rig_test.dof,
                      rig_threshold=f"{rig_test.threshold:.1f}")
    return values


def summary(loc: Any) -> str:
    """``612 records fused; 598 poses published; refused 3, late 0, duplicates 1, shed 0`` (of a
    :class:`~mutloc.live.localizer.Localizer`), then what else there is to say (``poses not published:
    150 waiting for the rig check, ...``)."""
    cs = loc.counts.values()
    refused = sum(c.refused for c in cs) + loc.unattributed
    kinds = [f"{what} {n}" for what, n in (
        ("rig_id", sum(c.refused_rig_id for c in cs)), ("malformed", sum(c.refused_malformed for c in cs)
                                                        + loc.unattributed),
        ("clock", sum(c.refused_clock for c in cs))) if n]
    held = [f"{n} {what}" for what, n in (("waiting for the rig check", sum(c.rig_waiting for c in cs)),
                                           ("while the rig disagreed", sum(c.rig_withheld for c in cs))) if n]
    return (f"{loc.records} records fused; {sum(c.poses for c in cs)} poses published; refused {refused}"
            + (f" ({', '.join(kinds)})" if kinds else "")
            + f", late {sum(c.dropped_late for c in cs)}, duplicates {sum(c.duplicates for c in cs)}"
            + f", shed {sum(c.shed for c in cs)}, not received {sum(c.not_received for c in cs)}"
            + (f"; {loc.records_unsmoothed} record{'s' if loc.records_unsmoothed != 1 else ''} written "
               "unsmoothed (behind)" if loc.records_unsmoothed else "")
            + (f"; poses not published: {', '.join(held)}" if held else "")
            + (f"; {loc.odometry.summary()}" if loc.odometry is not None else "")
            + ("" if loc.clocks is None else "; " + loc.clocks.summary()))


class Tally:
    """What each robot's topics brought (``robots``: robot -> :class:`RobotCounts`), the refused
    messages that named no robot of the rig (``unattributed``), and the lines said about them
    (``notices``)."""

    def __init__(self, names: list[str], notify: Callable[[str], None] | None) -> None:
        self.robots = {r: RobotCounts() for r in names}
        self.unattributed = 0
        self.notices = Notices(notify)
        self._frame_numbers: dict[str, int] = {}  # camera key -> the last frame number of its messages

    def numbered(self, c: RobotCounts, key: str, frame: int) -> None:
        """Camera ``key`` (of the robot counted by ``c``) sent frame number ``frame``: the numbers skipped since
        its last one are counted as not received (seen again, or going back -- a node restarted: not counted)."""
        last = self._frame_numbers.get(key)
        if last is not None and frame > last + 1:
            c.not_received += frame - last - 1
        self._frame_numbers[key] = frame

    def refuse(self, robot: str | None, what: str, why: str, now: float | None = None) -> str:
        """Count a message of ``robot`` (None: naming no robot of the rig) refused as ``what`` (a
        :class:`RobotCounts` field, ``refused_...``) for ``why``, arrived at ``now`` (None: not said);
        returns ``refused: <why>``."""
        why = " ".join(why.split())
        if robot is None:
            self.unattributed += 1
        else:
            c = self.robots[robot]
            c.received += 1
            setattr(c, what, getattr(c, what) + 1)
            if now is not None:
                c.last_refused_at, c.last_refusal = now, why
        if now is not None:
            self.notices.say((robot, what), f"{'robot ' + robot if robot else 'a message naming no robot of the rig'}: "
                             f"refused observations ({what[len('refused_'):]}): {why}", now)
        return "refused: " + why

    def foreign(self, robot: str, topic: str, publisher: str, now: float) -> None:
        """Another localizer (``publisher``: how it names itself) published a pose of ``robot`` on ``topic``
        at ``now``: WARN in the diagnostics, a line to ``notify`` once per publisher."""
        c = self.robots[robot]
        c.foreign_at, c.foreign = now, f"{topic} by {publisher}"
        self.notices.say(("foreign", publisher), f"another localizer publishes on this domain: {c.foreign} (two "
                         "localizers double every pose: stop one, or give each its own --domain)", now, once=True)
