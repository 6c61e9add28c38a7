"""The live localizer's rule for the rig check (issue 38): no pose is
published before the rig has been tested, nor while the observations keep
disagreeing with the rig file.

:class:`RigGate` is given the rig check's window test after each record
fused (:attr:`mutloc.track.rig_check.RigCheck.last`, fed by the team
tracker: :data:`~mutloc.track.rig_check.WINDOW` tests, each a record with
degrees of freedom of its own or a pool of records fitted together) and
says whether the poses are withheld, in one of four states
(:attr:`RigGate.state`, the ``rig_check`` key-value in ``/diagnostics``):

``waiting``
    From the start until the window has been full once and agreed: its
    chi-square at most the ``1 -`` :data:`AGREE_LEVEL` quantile (0.99) of
    chi-square with its degrees of freedom -- a right rig's full window
    passes it 99 times in 100, where the window's own threshold (its
    ``1 - 1e-6`` quantile) let the first window of a rig 1-2 cm off pass
    (a team of three, 60 degrees of freedom: 2.09 per degree, the
    threshold 2.12; the 0.99 quantile 1.47, right rigs 0.6-1.24, wrong ones
    1.84-2.8: tests/test_live_rig_check.py's logs).  A rig file 1-2 cm off bends every
    record the same way, and the filter turns the first records into
    confident wrong poses before any window could say so.  With two
    markers per robot and free-running cameras the window is full after
    30 pools of five records, about 2.5 s of a pair at 30 frames/s each.
``agrees``
    Published.
``disagrees``
    From a record whose window disagrees until the windows have fitted no
    worse than a right rig's mean (chi-square at most its degrees of
    freedom) for a window's length of full windows in a row -- a right
    rig's false alarm passes; a wrong rig's windows dip below that now and
    then, not for long.  Published again then.
``not running``
    The wait ends without a window when :data:`UNTESTED` records in a row,
    each with a pose held back by the wait alone, gave the rig check no
    test: the records cannot test the rig (one camera's few observations
    that fit any rig on their own and are not pooled -- with odometry the
    pooled test is skipped -- or too few observations for a pool's degrees
    of freedom).  Then each record's own gate is the only test, as before
    the wait; the window goes on if tests come later (and a disagreeing
    window withholds the poses as always).
"""

from __future__ import annotations

from typing import Any

from ..core.consistency import chi2_quantile
from ..track.rig_check import WINDOW

__all__ = ["RigGate", "UNTESTED", "AGREE_LEVEL", "WAITING", "AGREES", "DISAGREES", "NOT_RUNNING"]

#: The wait ends at the first full window whose chi-square is at most its ``1 - AGREE_LEVEL`` quantile.
AGREE_LEVEL = 0.01
#: Records in a row, each with a pose held back by the wait, that gave the rig check no test: it does not run.
UNTESTED = WINDOW
#: The gate's states (:attr:`RigGate.state`).
WAITING, AGREES, DISAGREES, NOT_RUNNING = "waiting", "agrees", "disagrees", "not running"


class RigGate:
    """Whether the poses are withheld for the rig check (see the module docstring)."""

    def __init__(self, untested: int = UNTESTED) -> None:
        #: The last record whose window disagreed: (its capture time, the test), else None.
        self.flag: tuple[float, Any] | None = None
        #: Since when the poses are withheld because the windows disagree (a capture time), None: not.
        self.withheld: float | None = None
        #: Capture time of the record whose full window first agreed (None: none yet).
        self.agreed: float | None = None
        #: Capture time of the record after which the wait ended without a window (state ``not running``).
        self.untested_at: float | None = None
        #: Capture time of the first record with a pose held back by the wait (None: none).
        self.first_held: float | None = None
        #: The window's latest test (None before any).
        self.last: Any = None
        self.untested_limit = int(untested)
        self._untested = 0  # records in a row, while waiting, held back and without a test
        self._tested = False  # whether the last record gave a test
        self._fits = 0  # full windows in a row, while withheld, that fitted no worse than their mean

    def update(self, t: float, test: Any, tested: bool) -> bool:
        """After the record at ``t``: the window's latest test (a
        :class:`~mutloc.track.rig_check.RigTest`, None before any), and
        whether the record gave it (``tested``: else the test is an earlier
        record's); returns whether the window disagrees (the caller says the hint)."""
        self.last, self._tested = test, tested
        if tested:
            self._untested = 0
        if test is not None and test.disagrees:
            self.flag = (t, test)
            if self.withheld is None:
                self.withheld = t
            self._fits = 0
            return True
        if (test is not None and test.full and self.agreed is None
                and test.chi2 <= chi2_quantile(1.0 - AGREE_LEVEL, test.dof)):
            self.agreed = t
        if self.withheld is not None and test is not None and test.full:
            self._fits = self._fits + 1 if test.chi2 <= test.dof else 0
            if self._fits >= test.records:
                self.withheld = None
        return False

    def held_back(self, t: float) -> bool:
        """The record at ``t`` (after :meth:`update`) had a pose held back by the wait alone; returns
        True when that ends the wait (the rig check does not run: state ``not running``)."""
        if self.first_held is None:
            self.first_held = t
        if self.untested_at is not None or self.agreed is not None or self._tested:
            return False
        self._untested += 1
        if self._untested >= self.untested_limit:
            self.untested_at = t
            return True
        return False

    @property
    def waiting(self) -> bool:
        """Whether the rig has not been tested yet (no full window agreed, the wait not ended)."""
        return self.agreed is None and self.untested_at is None and self.withheld is None

    @property
    def withholding(self) -> bool:
        """Whether no pose is published now."""
        return self.withheld is not None or self.waiting

    @property
    def state(self) -> str:
        """``waiting``, ``agrees``, ``disagrees`` or ``not running`` (see the module docstring)."""
        if self.withheld is not None:
            return DISAGREES
        if self.agreed is not None:
            return AGREES
        return NOT_RUNNING if self.untested_at is not None else WAITING

    def words(self, window: int) -> str:
        """What the wait is (``window``: the tests a full window holds)."""
        return (f"waiting for the rig check: {0 if self.last is None else self.last.records} of {window} tests "
                "(no pose is published before the rig file has been tested)")
