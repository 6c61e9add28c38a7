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
        self.source, self.target = source, target
        self.out = Path(out).expanduser()
        self.bag = None if bag is None else Path(bag).expanduser()
        self.mcap = None if mcap is None else Path(mcap).expanduser()
        #: The writers, opened with the first row (a run refused before any row leaves no file).
        self.writers: list[Any] = []
        self.csv: Any = None

    def _open(self) -> None:
        try:
            self.csv = self._add(TrajectoryCsvWriter(self.out / "trajectory.csv", extra=CSV_EXTRA))
            self.tum = self._add(TumWriter(self.out / "trajectory.tum",
                                           comment=tum_comment(self.source, self.target,
                                                               "camera" if self.to_base is None else "base")))
            names = [(self.source, self.target)]
            self.ros = [self._add(Ros2BagWriter(self.bag, names))] if self.bag is not None else []
            if self.mcap is not None:
                self.ros.append(self._add(McapPoseWriter(self.mcap, names)))
        except BaseException:
            self.close()
            raise

    def _add(self, writer: Any) -> Any:
        self.writers.append(writer)
        return writer

    @property
    def rows(self) -> int:
        """Rows written to ``trajectory.csv`` so far."""
        return 0 if self.csv is None else self.csv.rows

    @property
    def paths(self) -> list[Path]:
        """Every file or folder this writes, in that order."""
        return [self.out / "trajectory.csv", self.out / "trajectory.tum",
                *(p for p in (self.bag, self.mcap) if p is not None)]

    def write(self, row: TrackRow) -> None:
        """One final row into every file (a row without a pose only into the CSV)."""
        if self.csv is None:
            self._open()
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
