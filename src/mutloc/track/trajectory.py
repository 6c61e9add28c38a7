"""A track's rows in time order (:class:`Trajectory`) and how they are
written: ``trajectory.csv`` rows, the TUM comment, base frames."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..api import load_rig
from ..core.pose import Pose, sandwich_covariance
from ..errors import InputError
from ..io.trajectory import write_trajectory_csv, write_tum
from .rows import TrackRow
from .status import FrameStatus

__all__ = ["Trajectory", "CSV_EXTRA", "csv_row", "tum_comment", "BaseFrames"]


@dataclass
class Trajectory:
    """Every frame of a track, in time order; ``T_qp`` of ``source`` in ``target``'s frame."""

    source: str
    target: str
    rows: list[TrackRow]
    fps: float | None = None
    frames: str = "camera"  # "camera": optical frames (SPEC); "base": the robots' base frames
    #: One line each, for people: what the track found wrong beyond its rows (the rig check's hint).
    notes: list[str] = field(default_factory=list)

    @property
    def solved(self) -> list[TrackRow]:
        """The rows with a pose."""
        return [r for r in self.rows if r.estimate is not None]

    def summary(self) -> str:
        """``60 frames: 52 solved, 3 unverified, 5 rejected`` (statuses in their order)."""
        counts = {st: sum(r.status == st for r in self.rows) for st in FrameStatus}
        parts = [f"{n} {st.value}" for st, n in counts.items() if n]
        return f"{len(self.rows)} frames: {', '.join(parts) or 'none'}"

    @property
    def poses(self) -> Pose:
        """A stack with every row's pose (NaN where a row has none)."""
        R = np.full((len(self.rows), 3, 3), np.nan)
        t = np.full((len(self.rows), 3), np.nan)
        for i, r in enumerate(self.rows):
            if r.estimate is not None:
                R[i], t[i] = r.estimate.R, r.estimate.t
        return Pose(R, t)

    @property
    def times(self) -> np.ndarray:
        return np.array([r.t for r in self.rows], dtype=float)

    def write_tum(self, path: str | Path) -> None:
        """TUM format: ``timestamp tx ty tz qx qy qz qw`` of the rows with a pose."""
        write_tum(path, self.times, self.poses, comment=tum_comment(self.source, self.target, self.frames))

    def in_base_frames(self, rig: Any) -> "Trajectory":
        """The same track between the robots' base frames (``base_from_camera``
        in the rig): ``T = B_q @ T_qp @ inv(B_p)`` with its covariance; the
        robots are then named ``NAME_base``."""
        to_base = BaseFrames(rig, self.source, self.target)
        return Trajectory(to_base.source, to_base.target, [to_base(r) for r in self.rows], self.fps, frames="base",
                          notes=list(self.notes))

    @property
    def covariances(self) -> np.ndarray:
        """(n, 6, 6): every row's pose covariance, SPEC order (NaN where a row has none)."""
        out = np.full((len(self.rows), 6, 6), np.nan)
        for i, r in enumerate(self.rows):
            if r.estimate is not None:
                out[i] = r.estimate.covariance
        return out

    def write_ros(self, bag: str | Path | None = None, mcap: str | Path | None = None) -> None:
        """The poses with their covariances as ROS 2 messages (PoseWithCovarianceStamped and /tf):
        a rosbag2 folder ``bag`` and/or an MCAP file ``mcap`` (see :mod:`mutloc.io.ros`)."""
        from ..io.ros import write_mcap, write_ros2_bag

        args = (self.times, self.poses, self.covariances, self.source, self.target)
        if bag is not None:
            write_ros2_bag(bag, *args)
        if mcap is not None:
            write_mcap(mcap, *args)

    def write_csv(self, path: str | Path) -> None:
        """SPEC's ``trajectory.csv``: every frame with its status, pose and sigmas."""
        write_trajectory_csv(path, (csv_row(r) for r in self.rows), extra=CSV_EXTRA)


#: Columns ``trajectory.csv`` adds after the SPEC's.
CSV_EXTRA = ("reason", "t_source", "t_target", "reprojection_rms_px", "markers_used")


def csv_row(r: TrackRow) -> dict[str, Any]:
    """A row of ``trajectory.csv`` (:func:`mutloc.io.trajectory.write_trajectory_csv`'s form)."""
    e = r.estimate
    return {"t": r.t, "status": r.status, "pose": None if e is None else e.pose,
            "covariance": None if e is None else e.covariance, "reason": r.reason,
            "t_source": r.t_source, "t_target": r.t_target,
            "reprojection_rms_px": None if e is None else e.reprojection_rms_px,
            "markers_used": None if e is None else " ".join(e.markers_used)}


def tum_comment(source: str, target: str, frames: str = "camera") -> str:
    """The comment line of a track's TUM file."""
    return f"mutloc: pose of {source} in {target}'s {frames} frame (T_qp)"


class BaseFrames:
    """A row's pose (and covariance) between the robots' base frames
    (``base_from_camera`` in the rig): ``T = B_q @ T_qp @ inv(B_p)``; the
    robots are then named ``NAME_base``.  Called on a row, returns a copy."""

    def __init__(self, rig: Any, source: str, target: str) -> None:
        rig = load_rig(rig)
        B = {}
        for r in (source, target):
            B[r] = rig.robot(r).base_from_camera
            if B[r] is None:
                raise InputError(f"base frames asked for, but robot {r!r} has no base_from_camera in the rig")
        self.A, self.C = B[target], B[source].inverse()
        self.source, self.target = f"{source}_base", f"{target}_base"

    def __call__(self, row: TrackRow) -> TrackRow:
        new = replace(row)
        e = row.estimate
        if e is not None:
            A, C = self.A, self.C
            new.estimate = replace(e, source=self.source, target=self.target, pose=A @ e.pose @ C,
                                   covariance=sandwich_covariance(A, e.pose, C, e.covariance),
                                   candidates=A @ e.candidates @ C)
        return new
