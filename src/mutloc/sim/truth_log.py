"""An observation log from a simulated sequence's ``truth.json`` (``mutloc simulate --robots N --no-images``):
each frame's exact observations with Gaussian pixel noise, every observation stamped on its observer's clock
(the true time minus the robot's ``clock_offsets`` entry: what a robot whose clock is off would log)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..core.observations import ObservationSet

__all__ = ["truth_log"]


def truth_log(truth: str | Path | dict[str, Any], noise: float = 1.0, seed: int = 0,
              clocks: bool = True) -> list[tuple[float, ObservationSet]]:
    """``(time, observations)`` records in time order: per frame one record per observer robot at its own
    stamp (``clocks`` False: every robot on the true time, one record per frame)."""
    data = truth if isinstance(truth, dict) else json.loads(Path(truth).read_text(encoding="utf-8"))
    offsets = data.get("clock_offsets", {}) if clocks else {}
    rng = np.random.default_rng([int(seed), 3737])
    pieces = []
    for k, fr in enumerate(data["frames"]):
        t = float(fr["timestamp"])
        per = {}
        for robot, seen in fr["observations"].items():
            names = sorted(seen)
            uv = np.array([seen[m] for m in names], float).reshape(-1, 2) + rng.normal(0.0, noise, (len(names), 2))
            per[robot] = ([robot] * len(names), names, uv)
        for stamp, robots in _by_stamp(t, per, offsets):
            obs = ObservationSet.trusted(sum((per[r][0] for r in robots), []), sum((per[r][1] for r in robots), []),
                                         np.concatenate([per[r][2] for r in robots]).reshape(-1, 2), time=stamp)
            pieces.append((stamp, k, obs))
    pieces.sort(key=lambda p: (p[0], p[1]))
    return [(t, obs) for t, _, obs in pieces]


def _by_stamp(t: float, per: dict, offsets: dict) -> list[tuple[float, list[str]]]:
    groups: dict[float, list[str]] = {}
    for robot in per:
        groups.setdefault(t - float(offsets.get(robot, 0.0)), []).append(robot)
    return sorted(groups.items())
