"""The localizer's ``--clock-offsets estimate`` (SPEC "The robots' own motion and clocks"): each robot's
offset to the reference's clock estimated as the messages come
(:class:`~mutloc.track.clocks_online.OnlineClockOffsets`: the profile likelihood over short windows,
evaluated in the localizer's slack), every stamp of the robot corrected by its current estimate before
anything else looks at it (``--max-clock-skew`` included), and each robot's estimate in ``/diagnostics``
(``clock_offset_s``, ``clock_offset_sigma_s``, ``clock_offset_status``).

The localizer gives the estimate every message it takes and those it refuses for their stamp alone (in
the future beyond ``--max-clock-skew`` after the correction): a robot whose clock is ahead would otherwise
never be estimated, and its messages never taken."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..core.observations import ObservationSet
from ..core.rig import Rig
from ..track.clocks import ClockOffset, write_clock_offsets
from ..track.clocks_online import OnlineClockOffsets
from ..track.filtering import FilterOptions

__all__ = ["LiveClocks"]


class LiveClocks:
    """The estimate and its corrections for a :class:`~mutloc.live.localizer.Localizer`; ``settings``:
    :class:`~mutloc.track.clocks_online.OnlineClockOffsets`' (``window``, ``period``, ...)."""

    def __init__(self, rig: Rig, reference: str, options: FilterOptions, pixel_sigma: float, confidence: float,
                 **settings: Any) -> None:
        self.estimator = OnlineClockOffsets(rig, reference, options=options, pixel_sigma=pixel_sigma,
                                            confidence=confidence, **settings)
        self.reference = reference

    def offset(self, robot: str) -> float:
        """The correction added to ``robot``'s stamps now (s; 0 while undetermined)."""
        return self.estimator.offset(robot)

    def corrected(self, robot: str, t: float, ns: int) -> tuple[float, int]:
        """A stamp of ``robot`` (seconds and nanoseconds) on the reference's clock."""
        off = self.estimator.offset(robot)
        return (t, ns) if off == 0.0 else (t + off, ns + round(off * 1e9))

    def add(self, t: float, obs: ObservationSet) -> None:
        """A message taken, as stamped (uncorrected)."""
        self.estimator.add(t, obs)

    def pending(self) -> bool:
        return self.estimator.pending()

    def work(self, clock: Callable[[], float] | None = None, until: float = math.inf) -> int:
        return self.estimator.work(clock, until)

    def estimate(self, robot: str) -> ClockOffset:
        return self.estimator.estimate(robot)

    def values(self, robot: str) -> dict[str, str]:
        """``robot``'s key-values in ``/diagnostics``: the offset and sigma in seconds (``none`` while it
        cannot be determined yet) and a status text."""
        if robot == self.reference:
            return {"clock_offset_s": "0", "clock_offset_sigma_s": "0", "clock_offset_status": "reference clock"}
        c = self.estimator.estimate(robot)
        if c.offset_s is None:
            return {"clock_offset_s": "none", "clock_offset_sigma_s": "none",
                    "clock_offset_status": f"cannot be determined yet ({c.reason})"}
        return {"clock_offset_s": f"{c.offset_s:.6f}", "clock_offset_sigma_s": f"{c.sigma_s:.6f}",
                "clock_offset_status": f"estimated over {len(self.estimator.windows[robot])} window(s)"
                                       + (f"; last window: {self.estimator.reasons[robot]}"
                                          if self.estimator.reasons[robot] else "")}

    def summary(self) -> str:
        """``clock offsets: r1 +39.6 ms +- 1.2 ms, r2 cannot be determined yet (...)``."""
        parts = []
        for r, c in self.estimator.estimates().items():
            parts.append(f"{r} cannot be determined yet ({c.reason})" if c.offset_s is None
                         else f"{r} {c.offset_s * 1000:+.1f} ms +- {c.sigma_s * 1000:.1f} ms")
        return "clock offsets: " + ", ".join(parts)

    def write(self, out: str | Path) -> Path:
        """``OUT/clock_offsets.json`` (as ``track`` writes it)."""
        return write_clock_offsets(out, self.estimator.estimates())
