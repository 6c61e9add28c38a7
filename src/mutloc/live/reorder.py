"""The live localizer's reorder buffer: the accepted messages wait in it so
that records are fused in time order.  The oldest leaves it once every
other live camera has sent a later stamp (none of theirs can come before
it: DDS delivers each writer's messages in order) or ``reorder`` seconds
after it arrived (with odometry, once the robots' odometry has passed its
stamp, a while at most: :mod:`mutloc.live.odometry`); it leaves with the
held messages of other cameras stamped within ``tolerance`` of it, one
record (:meth:`ReorderBuffer.group`)."""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field
from typing import Any

from ..core.observations import ObservationSet

__all__ = ["ReorderBuffer", "Held"]


@dataclass(order=True)
class Held:
    """One message in the buffer (ordered by its capture time, then by arrival)."""

    t: float
    seq: int
    arrival: float = field(compare=False)
    ns: int = field(compare=False)
    robot: str = field(compare=False)
    observations: ObservationSet = field(compare=False)
    #: The observing camera's key (``ROBOT`` or ``ROBOT/CAMERA``): one stream of messages, delivered in order.
    key: str = field(compare=False, default="")


class ReorderBuffer:
    """The held messages (``held``: a heap, the oldest first) of the cameras ``keys``."""

    def __init__(self, keys: list[str], reorder: float, tolerance: float, warn_after: float,
                 odometry: Any = None) -> None:
        self.keys, self.reorder, self.tolerance, self.warn_after = keys, reorder, tolerance, warn_after
        self.odometry = odometry
        self.held: list[Held] = []
        self._waiting: dict[str, int] = {}  # camera key -> its messages held
        self._stream_stamp: dict[str, float] = {}  # newest capture time of each camera's messages
        self._seq = 0
        self._first: float | None = None  # arrival of the first message held

    def __len__(self) -> int:
        return len(self.held)

    def saw(self, key: str, t: float) -> None:
        """Camera ``key`` sent a message stamped ``t`` (held or not: later ones of it come after it)."""
        self._stream_stamp[key] = max(self._stream_stamp.get(key, -math.inf), t)

    def push(self, t: float, arrival: float, ns: int, robot: str, observations: ObservationSet, key: str) -> None:
        """Hold a message (capture time ``t``, arrived at ``arrival``, stamp ``ns`` as published)."""
        self._seq += 1
        if self._first is None:
            self._first = arrival
        heapq.heappush(self.held, Held(t, self._seq, arrival, ns, robot, observations, key))
        self._waiting[key] = self._waiting.get(key, 0) + 1

    def waiting(self, key: str) -> int:
        """Messages of camera ``key`` held."""
        return self._waiting.get(key, 0)

    def due(self, now: float) -> bool:
        """Whether the oldest held message may leave at ``now`` (there is one)."""
        h = self.held[0]
        if self.odometry is not None and not self.odometry.ready(h.t, h.arrival, now):
            return False  # (waits for the robots' odometry to pass its stamp, a while at most)
        if now >= h.arrival + self.reorder:  # (the same sum as next_due: no rounding between them)
            return True
        for key in self.keys:  # each camera's messages (one node's) come in order
            if key == h.key:
                continue
            last = self._stream_stamp.get(key)
            if last is None:
                if now - self._first > self.warn_after:
                    continue  # a camera not heard since the start is not waited for
                return False
            if now - last <= self.warn_after and last < h.t:
                return False  # (a camera gone quiet is not waited for)
        return True

    def next_due(self) -> float | None:
        """The arrival-clock time at which the oldest held message leaves at the latest."""
        if not self.held:
            return None
        due = self.held[0].arrival + self.reorder
        if self.odometry is not None:
            from .odometry import ODOMETRY_WAIT

            due = max(due, self.held[0].arrival + ODOMETRY_WAIT)
        return due

    def group(self) -> list[Held]:
        """The oldest held message and the held messages of other cameras
        stamped within ``tolerance`` of it: one record (taken out)."""
        group = [heapq.heappop(self.held)]
        while (self.held and self.held[0].t - group[0].t <= self.tolerance
               and self.held[0].key not in {h.key for h in group}):
            group.append(heapq.heappop(self.held))
        for h in group:
            self._waiting[h.key] -= 1
        return group
