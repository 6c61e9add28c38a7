"""The live localizer's rule for the rig check (issue 38): no pose is
published while the observations keep disagreeing with the rig file.

:class:`RigGate` is given the rig check's window test after each record
fused (:attr:`mutloc.track.rig_check.RigCheck.last`, fed by the team
tracker) and says whether the poses are withheld: from the first record
whose window disagrees until the windows have fitted no worse than a right
rig's mean (chi-square at most its degrees of freedom) for a window's length
of full windows in a row -- a right rig's false alarm passes; a wrong rig's
windows dip below that now and then, not for long.
"""

from __future__ import annotations

from typing import Any

__all__ = ["RigGate"]


class RigGate:
    """Whether the poses are withheld for the rig check (see the module docstring)."""

    def __init__(self) -> None:
        #: The last record whose window disagreed: (its capture time, the test), else None.
        self.flag: tuple[float, Any] | None = None
        #: Since when the poses are withheld (a capture time), None: not withheld.
        self.withheld: float | None = None
        self._fits = 0  # full windows in a row, while withheld, that fitted no worse than their mean

    def update(self, t: float, test: Any) -> bool:
        """After the record at ``t``, the window's latest test (a
        :class:`~mutloc.track.rig_check.RigTest`, None before any); returns
        whether it disagrees (the caller says the hint)."""
        if test is not None and test.disagrees:
            self.flag = (t, test)
            if self.withheld is None:
                self.withheld = t
            self._fits = 0
            return True
        if self.withheld is not None and test is not None and test.full:
            self._fits = self._fits + 1 if test.chi2 <= test.dof else 0
            if self._fits >= test.records:
                self.withheld = None
        return False

    @property
    def withholding(self) -> bool:
        """Whether no pose is published now."""
        return self.withheld is not None
