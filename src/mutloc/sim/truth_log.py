"""An observation log from a simulated sequence's ``truth.json`` (``mutloc simulate --robots N --no-images``):
each frame's exact observations with Gaussian pixel noise, every observation stamped on its observer's clock
(the true time minus the robot's ``clock_offsets`` entry: what a robot whose clock is off would log)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..core.geometry import so3_exp, so3_log
from ..core.observations import ObservationSet
from ..core.pose import Pose

__all__ = ["truth_log", "truth_pose_at"]


def _load(truth: str | Path | dict[str, Any]) -> dict[str, Any]:
    return truth if isinstance(truth, dict) else json.loads(Path(truth).read_text(encoding="utf-8"))


def truth_pose_at(truth: str | Path | dict[str, Any]) -> Callable[[str, float], Pose]:
    """``at(robot, t)``: the robot's true pose in the reference robot's frame (``T_r0_r``) at time ``t``,
    interpolated between the capture instants of ``truth.json`` (rotation along the geodesic, translation
    linearly; held at the first and last instants outside them)."""
    frames = _load(truth)["frames"]
    times = np.array([f["timestamp"] for f in frames], float)
    if len(times) < 2:
        raise ValueError("truth: at least two frames are needed to interpolate")

    def at(robot: str, t: float) -> Pose:
        i = int(np.clip(np.searchsorted(times, t), 1, len(times) - 1))
        a, b = frames[i - 1], frames[i]
        w = float(np.clip((t - a["timestamp"]) / (b["timestamp"] - a["timestamp"]), 0.0, 1.0))
        A, B = (Pose(np.array(f["robots"][robot]["R"], float), np.array(f["robots"][robot]["t"], float))
                for f in (a, b))
        return Pose(so3_exp(w * so3_log(B.R @ A.R.T)) @ A.R, (1 - w) * A.t + w * B.t)

    return at


def truth_log(truth: str | Path | dict[str, Any], noise: float = 1.0, seed: int = 0,
              clocks: bool = True) -> list[tuple[float, ObservationSet]]:
    """``(time, observations)`` records in time order: per frame one record per observer robot at its own
    stamp (``clocks`` False: every robot on the true time, one record per frame)."""
    data = _load(truth)
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
