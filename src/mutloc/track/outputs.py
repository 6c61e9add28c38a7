"""A track's files, each row appended as soon as its report is final.

``trajectory.csv`` and ``trajectory.tum`` in the output folder, and
optionally a ROS 2 bag and an MCAP file of the poses (SPEC "Filtered
tracking"), written through the crash-safe streaming writers of
:mod:`mutloc.io` (see :mod:`mutloc.io.streaming`): a run interrupted or
killed leaves files that parse and hold every row finished so far.  Pass
:meth:`TrackOutputs.write` as the ``sink`` of :func:`mutloc.track.tracker.track`
or :func:`~mutloc.track.tracker.track_log`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..io.ros import McapPoseWriter, Ros2BagWriter
from ..io.trajectory import TrajectoryCsvWriter, TumWriter
from .tracker import CSV_EXTRA, BaseFrames, TrackRow, csv_row, tum_comment

__all__ = ["TrackOutputs"]


class TrackOutputs:
    """The files of a pair's track in folder ``out`` (``trajectory.csv``,
    ``trajectory.tum``), and a ROS 2 ``bag`` folder and/or ``mcap`` file of
    the poses; ``base_frames``: a rig whose ``base_from_camera`` every pose
    is moved to (``--frames base``).  A context manager; :meth:`write` one row
    at a time, in time order."""

    def __init__(self, out: str | Path, source: str, target: str, *, bag: str | Path | None = None,
                 mcap: str | Path | None = None, base_frames: Any = None) -> None:
        self.to_base = BaseFrames(base_frames, source, target) if base_frames is not None else None
        if self.to_base is not None:
            source, target = self.to_base.source, self.to_base.target
        out = Path(out).expanduser()
        self.writers: list[Any] = []
        try:
            self.csv = self._open(TrajectoryCsvWriter(out / "trajectory.csv", extra=CSV_EXTRA))
            self.tum = self._open(TumWriter(out / "trajectory.tum",
                                            comment=tum_comment(source, target,
                                                                "camera" if self.to_base is None else "base")))
            self.ros = [self._open(Ros2BagWriter(bag, [(source, target)]))] if bag is not None else []
            if mcap is not None:
                self.ros.append(self._open(McapPoseWriter(mcap, [(source, target)])))
        except BaseException:
            self.close()
            raise

    def _open(self, writer: Any) -> Any:
        self.writers.append(writer)
        return writer

    @property
    def rows(self) -> int:
        """Rows written to ``trajectory.csv`` so far."""
        return self.csv.rows

    @property
    def paths(self) -> list[Path]:
        """Every file or folder written, in the order opened."""
        return [p for w in self.writers for p in w.paths]

    def write(self, row: TrackRow) -> None:
        """One final row into every file (a row without a pose only into the CSV)."""
        if self.to_base is not None:
            row = self.to_base(row)
        self.csv.write(csv_row(row))
        e = row.estimate
        if e is not None:
            self.tum.write(row.t, e.pose)
            for w in self.ros:
                w.write(row.t, e.pose, e.covariance)

    def close(self) -> None:
        for w in self.writers:
            w.close()

    def __enter__(self) -> "TrackOutputs":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
