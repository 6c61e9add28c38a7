"""Which robots the recent observations tie to the reference: the live
rule behind "a robot tied only by too few observations is coasted, then
dropped" (issue 38).

A record of one camera often does not determine a pose on its own: with two
markers per robot and free-running cameras every record is one camera's two
observations, ``partial``, and the pose is determined only by the cameras'
records together.  What matters is whether the observations of the last
``window`` seconds, taken together, could fix the robot: a chain of robots
from the reference, each pair tied by at least
:data:`~mutloc.core.team.MIN_TIES` *distinct* observations -- a (camera,
marker) pair counts once however often it is seen, since seeing the same two
markers from the same camera again adds no direction the pose was missing.
When q's node stops, p's camera alone keeps giving ``partial`` rows of p; its
two observations tie p to q by two, not three, and once q's last observations
are older than the window p is no longer tied: the localizer stops publishing
its pose and drops its track (the filter, fed only the two directions, drifts
in the others faster than its covariance says: bench/node_outages.py).

No I/O: :class:`TieWindow` is fed ``(time, observing camera, the robot it
belongs to, the markers' owners)`` per fused message and asked which robots
are tied at a time.
"""

from __future__ import annotations

from typing import Iterable

from ..core.team import MIN_TIES

__all__ = ["TieWindow"]


class TieWindow:
    """The distinct observations of the last ``window`` seconds between each
    pair of robots, and the robots they tie to ``reference``."""

    def __init__(self, reference: str, window: float, min_ties: int = MIN_TIES) -> None:
        self.reference, self.window, self.min_ties = reference, float(window), int(min_ties)
        #: ``{frozenset({a, b}): {(camera key, marker): newest time seen}}``
        self._ties: dict[frozenset, dict[tuple[str, str], float]] = {}

    def add(self, t: float, robot: str, key: str, seen: Iterable[tuple[str, str]]) -> None:
        """Camera ``key`` of ``robot`` saw, at ``t``, each ``(marker, its owner)`` of ``seen``."""
        for marker, owner in seen:
            if owner is None or owner == robot:
                continue
            ties = self._ties.setdefault(frozenset((robot, owner)), {})
            ties[(key, marker)] = max(t, ties.get((key, marker), t))

    def counts(self, t: float) -> dict[frozenset, int]:
        """Distinct observations per pair of robots within the window ending at ``t``."""
        since = t - self.window
        return {pair: sum(1 for s in ties.values() if s >= since) for pair, ties in self._ties.items()}

    def tied(self, t: float, counts: dict[frozenset, int] | None = None) -> set[str]:
        """The robots (not the reference) a chain of pairs, each tied by
        ``min_ties`` distinct observations within the window, links to the
        reference (``counts``: :meth:`counts` at ``t``, if already made)."""
        counts = self.counts(t) if counts is None else counts
        strong = [tuple(pair) for pair, n in counts.items() if n >= self.min_ties and len(pair) == 2]
        seen, todo = {self.reference}, [self.reference]
        while todo:
            a = todo.pop()
            for x, y in strong:
                b = y if x == a else x if y == a else None
                if b is not None and b not in seen:
                    seen.add(b)
                    todo.append(b)
        return seen - {self.reference}

    def ties_of(self, robot: str, t: float, counts: dict[frozenset, int] | None = None) -> int:
        """Distinct observations within the window between ``robot`` and any other robot."""
        counts = self.counts(t) if counts is None else counts
        return sum(n for pair, n in counts.items() if robot in pair)

    def forget_before(self, t: float) -> None:
        """Drop what is older than the window ending at ``t`` (memory stays bounded)."""
        since = t - self.window
        for pair in list(self._ties):
            kept = {k: s for k, s in self._ties[pair].items() if s >= since}
            if kept:
                self._ties[pair] = kept
            else:
                del self._ties[pair]
