"""Observation logs (SPEC "Observation logs"): JSON Lines, one frame a line,
``{"time": 12.345, "observations": {observer: {marker: [u, v]}}}``.

``mutloc track --observations-out`` writes them, ``mutloc track
--observations`` and marker calibration read them.  Reading is streamed
(a log can be long) and every problem names the file and the line.  The log
is written as the frames come (:class:`ObservationLogWriter`); the log of a
killed run is read up to its last complete line.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Iterable, Iterator

from ..core.observations import ObservationSet
from ..errors import FileFormatError, MutlocError, ObservationError
from ._files import PathLike
from .streaming import LineFile, StreamWriter

__all__ = ["read_observation_log", "iter_observation_log", "write_observation_log", "ObservationLogWriter"]

# A log line is one frame's detections: far below this.
_MAX_LINE = 1024 * 1024


def read_observation_log(path: PathLike) -> Iterator[ObservationSet]:
    """The frames of a log, in file order, each an ObservationSet stamped with its time."""
    return (obs for _, obs in iter_observation_log(path))


def iter_observation_log(path: PathLike) -> Iterator[tuple[float, ObservationSet]]:
    """``(time, observations)`` per line, in file order: the time is kept
    for a frame that saw nothing (``"observations": {}``), which the tracker
    reports as a row of its own."""
    p = Path(path).expanduser()
    if p.is_dir():
        raise FileFormatError(f"{p}: is a folder, not an observation log")
    try:
        f = open(p, "rb")
    except OSError as exc:
        raise FileFormatError(f"{p}: cannot read file: {exc.strerror or exc}") from None
    with f:
        last = -math.inf
        for k, raw in enumerate(iter(lambda: f.readline(_MAX_LINE + 1), b""), 1):
            where = f"{p}:{k}"
            if len(raw) > _MAX_LINE:
                raise FileFormatError(f"{where}: line longer than {_MAX_LINE // 1024} KiB: not an observation log")
            text = raw.strip()
            if not text:
                continue
            try:
                entry = json.loads(text)
            except (json.JSONDecodeError, UnicodeDecodeError) as exc:
                if not raw.endswith(b"\n"):
                    break  # the last line, without its end: a write cut by a killed run
                raise FileFormatError(f"{where}: not JSON ({exc})") from None
            if not isinstance(entry, dict) or set(entry) - {"time", "observations"} or "observations" not in entry:
                raise FileFormatError(f"{where}: expected {{\"time\": seconds, \"observations\": {{...}}}}")
            t = entry.get("time")
            if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t):
                raise FileFormatError(f"{where}: time must be a finite number of seconds, got {t!r}")
            if t < last:
                raise FileFormatError(f"{where}: time {t} goes back (previous line {last})")
            last = float(t)
            try:
                yield float(t), ObservationSet.from_dict(entry["observations"], time=float(t),
                                                         where=f"{where}: observations")
            except MutlocError as exc:
                raise ObservationError(str(exc)) from None
        if last == -math.inf:
            # No frame read.  An empty trajectory would look like a tracked one that saw nothing.
            raise FileFormatError(f"{p}: no frames (an observation log holds one JSON object per line)")


class ObservationLogWriter(StreamWriter):
    """Appends one frame per line, each handed to the OS as it is written
    (see :mod:`mutloc.io.streaming`); use as a context manager."""

    def __init__(self, path: PathLike):
        self._file = LineFile(path)
        self.path = self._file.path
        self.paths = (self.path,)

    def write(self, time: float, observations: ObservationSet) -> bool:
        """One frame: its time and what every observer saw."""
        line = {"time": float(time), "observations": {o: ({m: list(uv) for m, uv in e.items()}
                                                          if isinstance(e, dict) else [list(uv) for uv in e])
                                                      for o, e in observations.to_dict().items()}}
        self._file.write(json.dumps(line, separators=(",", ":")) + "\n")
        self.rows += 1
        return True

    def _close(self) -> None:
        self._file.close()


def write_observation_log(path: PathLike, frames: Iterable[ObservationSet]) -> None:
    """Write frames (each stamped with one time) as a log."""
    with ObservationLogWriter(path) as w:
        for obs in frames:
            times = obs.times
            if len(times) != 1:
                raise ObservationError(f"{path}: every frame of a log needs exactly one time, got {times.tolist()}")
            w.write(float(times[0]), obs)
