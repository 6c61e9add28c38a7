"""A track's files, each row appended as soon as its report is final.

A pair: ``trajectory.csv`` and ``trajectory.tum`` in the output folder; a
team: ``trajectory_NAME.csv`` and ``.tum`` per robot (SPEC "Filtered
tracking"); optionally a ROS 2 bag and an MCAP file with every track's poses
and ``/tf``.  Written through the crash-safe streaming writers of
:mod:`mutloc.io` (see :mod:`mutloc.io.streaming`): a run interrupted or
killed leaves files that parse and hold every row finished so far.  Pass
:meth:`TrackOutputs.write` as the ``sink`` of :func:`mutloc.track.tracker.track`
or :func:`~mutloc.track.tracker.track_log` (a pair), of
:func:`~mutloc.track.team.track_team` or
:func:`~mutloc.track.team.track_team_log` (a team: ``write(row, robot)``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..io.ros import McapPoseWriter, Ros2BagWriter
from ..io.trajectory import TrajectoryCsvWriter, TumWriter
from .rows import TrackRow
from .trajectory import CSV_EXTRA, BaseFrames, csv_row, tum_comment

__all__ = ["TrackOutputs"]


class TrackOutputs:
    """The files of a track in folder ``out``: of one pair (``sources`` a
    single robot, ``target`` the other) or of a team (``sources`` every
    robot but the reference ``target``: one ``trajectory_NAME.*`` each), and
    a ROS 2 ``bag`` folder and/or ``mcap`` file of all the poses;
    ``base_frames``: a rig whose ``base_from_camera`` every pose is moved to
    (``--frames base``).  A context manager; :meth:`write` one row at a time,
    in time order.  The files are opened with the first row: a run refused
    before any row leaves none."""

    def __init__(self, out: str | Path, sources: str | list[str], target: str, *, bag: str | Path | None = None,
                 mcap: str | Path | None = None, base_frames: Any = None) -> None:
        self.team = not isinstance(sources, str)
        self.sources = [sources] if isinstance(sources, str) else list(sources)
        self.target = target
        self.to_base = ({s: BaseFrames(base_frames, s, target) for s in self.sources}
                        if base_frames is not None else None)
        self.out = Path(out).expanduser()
        self.bag = None if bag is None else Path(bag).expanduser()
        self.mcap = None if mcap is None else Path(mcap).expanduser()
        self.writers: list[Any] = []
        self._files: dict[str, tuple[Any, Any]] = {}
        self.ros: list[Any] = []
        self.rows = 0  #: rows written (over every track)

    def _names(self, source: str) -> tuple[str, str]:
        """The track's frames as its files name them (``NAME_base`` in base frames)."""
        if self.to_base is None:
            return source, self.target
        b = self.to_base[source]
        return b.source, b.target

    def _stem(self, source: str) -> str:
        return f"trajectory_{source}" if self.team else "trajectory"

    def _open(self) -> None:
        try:
            frames = "camera" if self.to_base is None else "base"
            for s in self.sources:
                stem = self._stem(s)
                self._files[s] = (self._add(TrajectoryCsvWriter(self.out / f"{stem}.csv", extra=CSV_EXTRA)),
                                  self._add(TumWriter(self.out / f"{stem}.tum",
                                                      comment=tum_comment(*self._names(s), frames))))
            names = [self._names(s) for s in self.sources]
            if self.bag is not None:
                self.ros.append(self._add(Ros2BagWriter(self.bag, names)))
            if self.mcap is not None:
                self.ros.append(self._add(McapPoseWriter(self.mcap, names)))
        except BaseException:
            self.close()
            raise

    def _add(self, writer: Any) -> Any:
        self.writers.append(writer)
        return writer

    @property
    def paths(self) -> list[Path]:
        """Every file or folder this writes, in that order."""
        files = [self.out / f"{self._stem(s)}{ext}" for s in self.sources for ext in (".csv", ".tum")]
        return files + [p for p in (self.bag, self.mcap) if p is not None]

    @property
    def written(self) -> list[Path]:
        """The files of :attr:`paths` written so far: none before the first row."""
        return self.paths if self._files else []

    def write(self, row: TrackRow, source: str | None = None) -> None:
        """One final row of the track of ``source`` (default: the pair's)
        into every file (a row without a pose only into the CSV)."""
        if not self._files:
            self._open()
        source = self.sources[0] if source is None else source
        if self.to_base is not None:
            row = self.to_base[source](row)
        csv, tum = self._files[source]
        csv.write(csv_row(row))
        self.rows += 1
        e = row.estimate
        if e is not None:
            tum.write(row.t, e.pose)
            k = self.sources.index(source)
            for w in self.ros:
                w.write(row.t, e.pose, e.covariance, track=k)

    def close(self) -> None:
        for w in self.writers:
            w.close()

    def __enter__(self) -> "TrackOutputs":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
