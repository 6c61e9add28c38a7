"""Do a track's observations keep disagreeing with the rig file?  A window
test over records (issue 38), not only each record's own gate.

A rig whose markers are 1-2 cm off (measured by hand) bends every record a
little the same way: each record on its own may pass its chi-square gate,
or fail it now and then, and a filter smooths the records into a confident
wrong pose.  Summed over a window of records the excess shows: with a
correct rig and honest noise (detections as noisy as ``--pixel-sigma``
says), each record's own least-squares residual ``chi2_k`` (squared
residuals over ``pixel_sigma**2`` at the record's best pose) follows
chi-square with its ``dof_k`` degrees of freedom, independent from record
to record, so the window's sum follows chi-square with ``sum dof_k``.  The
window disagrees when its sum exceeds that distribution's ``1 -``
:data:`FALSE_ALARM` quantile.

The level.  The test is made at every record over the last :data:`WINDOW`
records, so a long track makes many (correlated) tests: one per window's
length is roughly independent, a 10-minute track at 30 records a second
about 600.  :data:`FALSE_ALARM` (1e-6 per window) keeps a correct rig with
honest noise quiet on such a track with probability about 0.9994; a rig
1-2 cm off (bench/rig_check.py measures both) exceeds it within one window.

Stray detections must not raise it: each record counts at most its own
``1 -`` :data:`RECORD_CAP` quantile (0.99: a record with a wrong detection
counts as one bad record, not as thousands), which keeps the test at or
below its level on a correct rig with honest noise (a capped sum is never
larger) while a rig that keeps disagreeing drives most records to the cap.
Measured (bench/rig_check.py, docs/benchmarks.md) on correct logs with 2 %
of records holding a detection 30-60 px off, each record refitted on its
own, the largest window of 20 ten-second logs reached 0.80 of its threshold
(0.96 with the cap at the 0.999 quantile); fed by the team tracker, 0.72
(the pair) and 0.89 (a team of three).  Noise above
``--pixel-sigma`` raises it too (every record's chi-square scaled by the
ratio squared, about 1.5x at the default window and level): the hint names
the rig, the docs say to check the noise as well.

Records that fit any rig on their own (one camera's two observations: no
degree of freedom) are pooled with the next such records of the last
:data:`POOL_SPAN` seconds and fitted together once they have :data:`POOL_DOF`
degrees of freedom, each robot's pose and velocity over the pool free
(:mod:`mutloc.core.nearby_times`): with two markers per robot and
free-running cameras this is the only test there is -- five records of a
pair, 1/60 s apart, leave 8 degrees of freedom.  Each record enters one test
(a pool is emptied once it yields degrees of freedom), so the window's terms
stay independent; the test owes nothing to the filter (chi-square while the
velocities stay constant over 0.07 s).  Not where odometry moves the robots
(:class:`~mutloc.track.team_tracker.TeamTracker` leaves such records out).  Measured (bench/node_outages.py's
logs, tests/test_nearby_times.py): 0.98 per degree of freedom on the right
rig, 1.9-4.2 with every marker 1-2 cm off.

No I/O; :class:`RigCheck` is fed one ``(chi2, dof)`` per record: the team
tracker (:class:`~mutloc.track.team_tracker.TeamTracker`, which ``track``
runs for a pair and for a team, and the live localizer) feeds it each
record's observations fitted on their own -- the record's joint solve's
chi-square when it had one, else the sum of its filter updates' own
residuals (:attr:`mutloc.core.team_filter.TeamUpdate.own`, accepted or
rejected by the gate: a rig that is off makes the gate reject records, and
those say the most).
"""

from __future__ import annotations

import copy
import math
from collections import deque
from dataclasses import dataclass
from typing import Any

from ..core.consistency import chi2_quantile
from ..core.nearby_times import fitted_together
from ..core.team import TeamProblem

__all__ = ["RigCheck", "RigTest", "RIG_HINT", "WINDOW", "FALSE_ALARM", "RECORD_CAP", "POOL_SPAN", "POOL_DOF"]

#: The one-line hint a track that keeps disagreeing with its rig prints.
RIG_HINT = "observations keep disagreeing with the rig file: run `mutloc calibrate-markers`"
#: Records in the window (those with degrees of freedom; a record of three
#: observations or fewer fits any rig and says nothing).
WINDOW = 30
#: Probability that a window of a correct rig with honest noise disagrees.
FALSE_ALARM = 1e-6
#: Each record counts at most its chi-square's ``1 - RECORD_CAP`` quantile.
RECORD_CAP = 1e-2
#: Seconds over which records without degrees of freedom of their own are
#: fitted together (three frame periods at 30 fps: a constant velocity over
#: it is well within a pixel's worth of the motion).
POOL_SPAN = 0.1
#: Degrees of freedom a pool gathers before it is tested (five records of a
#: two-marker pair: 8; a window of :data:`WINDOW` such tests has the power to
#: see a rig 1-2 cm off).
POOL_DOF = 6


@dataclass(frozen=True)
class RigTest:
    """The window's test after a record: ``chi2`` (summed, each record
    capped), ``dof`` (summed), ``threshold`` (the ``1 - false_alarm``
    quantile of chi-square with ``dof``), ``records`` in the window and
    whether it is full (``full``: only a full window decides)."""

    chi2: float
    dof: int
    threshold: float
    records: int
    full: bool

    @property
    def disagrees(self) -> bool:
        return self.full and self.chi2 > self.threshold

    def words(self) -> str:
        """The row's note when the window disagrees."""
        return (f"the rig disagrees: chi2 {self.chi2:.1f} over {self.dof} degrees of freedom in the last "
                f"{self.records} records, above {self.threshold:.1f}; {RIG_HINT}")

    def to_dict(self) -> dict[str, Any]:
        return {"chi2": self.chi2, "dof": self.dof, "threshold": self.threshold, "records": self.records,
                "disagrees": self.disagrees}


class RigCheck:
    """The sliding-window test of rig disagreement: :meth:`add` each record's
    own ``(chi2, dof)`` (at the stated noise), get the window's
    :class:`RigTest`.  ``flagged`` counts the records after which the
    window disagreed; :meth:`hint` is :data:`RIG_HINT` once any did."""

    def __init__(self, window: int = WINDOW, false_alarm: float = FALSE_ALARM, record_cap: float = RECORD_CAP
                 ) -> None:
        if int(window) < 1:
            raise ValueError(f"window {window!r}: at least one record")
        if not 0.0 < false_alarm < 1.0 or not 0.0 < record_cap < 1.0:
            raise ValueError("false_alarm and record_cap are probabilities in (0, 1)")
        self.window, self.false_alarm, self.record_cap = int(window), float(false_alarm), float(record_cap)
        self._records: deque[tuple[float, int]] = deque()
        self._chi2, self._dof = 0.0, 0
        self.flagged = 0
        self.records = 0
        self.last: RigTest | None = None
        #: Records without degrees of freedom of their own, not yet tested: ``(time, ray-mode rows, velocities)``.
        self._pool: list[tuple[float, TeamProblem, Any]] = []

    def add(self, chi2: float, dof: int) -> RigTest | None:
        """Add one record's own chi-square and its degrees of freedom; a
        record without degrees of freedom (or a NaN: nothing fitted) is not
        counted, and the last test stands (None before any)."""
        dof = int(dof)
        if dof <= 0 or chi2 is None or math.isnan(chi2):
            return self.last
        c = min(float(chi2), chi2_quantile(1.0 - self.record_cap, dof))
        self._records.append((c, dof))
        self._chi2 += c
        self._dof += dof
        if len(self._records) > self.window:
            c0, d0 = self._records.popleft()
            self._chi2 -= c0
            self._dof -= d0
        self.records += 1
        chi2_sum = max(self._chi2, 0.0)
        test = RigTest(chi2_sum, self._dof, chi2_quantile(1.0 - self.false_alarm, self._dof),
                       len(self._records), len(self._records) == self.window)
        if test.disagrees:
            self.flagged += 1
        self.last = test
        return test

    def pooled(self, t: float, rows: TeamProblem, before: tuple[Any, Any], R: Any, tr: Any, reference: int,
               pixel_sigma: float) -> tuple[float, int]:
        """A record's ``rows`` (ray mode) that fit any rig on their own, at
        ``t``; ``before``: the filter's velocities (per robot) and its tracked
        robots as they were before the rows came.  Fitted with the pooled ones
        of the last :data:`POOL_SPAN` s, each robot's pose and velocity over
        the pool free (:func:`mutloc.core.nearby_times.fitted_together`),
        linearised at ``R``, ``tr`` (the poses at ``t``) and the velocities
        before the pool's first record.  Returns the pool's ``(chi2, dof)``
        once it has :data:`POOL_DOF` (the pool is then emptied), else ``(nan, 0)``."""
        self._pool = [e for e in self._pool if t - e[0] <= POOL_SPAN]
        self._pool.append((float(t), rows, before))
        if len(self._pool) < 2:
            return math.nan, 0
        vel, robots = self._pool[0][2]
        if any(not set(p.cam.tolist() + p.own.tolist()) <= set(robots.tolist()) | {reference}
               for _, p, _ in self._pool):
            self._pool = self._pool[-1:]  # (a robot the first record's state did not track: start again here)
            return math.nan, 0
        chi2, dof = fitted_together([(p, t - s) for s, p, _ in self._pool], R, tr, vel, robots, reference,
                                    pixel_sigma)
        if dof < POOL_DOF or math.isnan(chi2):
            return math.nan, 0
        self._pool = []
        return chi2, dof

    def copy(self) -> "RigCheck":
        """An independent copy (the tracker's state an undo goes back to)."""
        new = copy.copy(self)
        new._records = deque(self._records)
        new._pool = list(self._pool)
        return new

    @property
    def disagrees(self) -> bool:
        """Whether the latest window disagrees."""
        return self.last is not None and self.last.disagrees

    def hint(self) -> str | None:
        """:data:`RIG_HINT` once any window disagreed, else None."""
        return RIG_HINT if self.flagged else None

    def summary(self) -> str | None:
        """``observations keep disagreeing ... (the window disagreed at 158 of 187 records that test it)``,
        or None (records that test it: those with degrees of freedom)."""
        if not self.flagged:
            return None
        return f"{RIG_HINT} (the window disagreed at {self.flagged} of {self.records} records that test it)"
