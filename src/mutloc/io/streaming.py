"""Streaming, crash-safe output files: the common interface of the writers.

Every writer of a track's outputs (:class:`~mutloc.io.trajectory.TumWriter`,
:class:`~mutloc.io.trajectory.TrajectoryCsvWriter`,
:class:`~mutloc.io.logs.ObservationLogWriter`,
:class:`~mutloc.io.ros.McapPoseWriter`, :class:`~mutloc.io.ros.Ros2BagWriter`,
:class:`~mutloc.io.rrd.RerunWriter`, :class:`~mutloc.io.video.VideoWriter`)
is a :class:`StreamWriter`:

- the constructor creates the file (header included: a text file appears
  whole, with its header, by an atomic rename);
- ``write(...)`` appends one row and hands it to the operating system before
  it returns, so a process killed at any time (SIGKILL included) leaves a file
  that parses and holds every row whose ``write`` returned.  Nothing is
  ``fsync``-ed: a power cut may lose what the OS had not yet stored;
- ``close()`` finishes the file (an MCAP summary, a bag's ``metadata.yaml``);
  it is idempotent, and the writer is a context manager that closes also when
  the block ends by an exception (Ctrl-C's ``KeyboardInterrupt`` included).

What "a row" is, and what a kill can leave, per format:

- text files (CSV, TUM, observation log): one ``write(2)`` call per line.
  The kernel can split a write only at a page boundary, and only for a kill
  that arrives during that copy (well under a microsecond per row); the
  readers then drop the cut last line if it does not parse (it has no end of
  line: every complete line has one);
- MCAP: unchunked, and after each row the file ends with a ``DataEnd`` and a
  footer without summary (see :class:`RollingFile`), so a killed file is a
  complete MCAP; ``close`` writes the summary;
- rosbag2: SQLite storage, one transaction per row, committed before
  ``write`` returns, or MCAP storage kept complete as above;
  ``metadata.yaml`` is written at open and refreshed at most every second
  (its counts may lag; the messages are all in the storage file);
- Rerun: the recording stream is flushed to the file after each frame;
- MP4 video: one fragment per frame, flushed; the last frame's fragment is
  closed when the next frame comes (or at ``close``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from .._extras import require
from ..errors import FileFormatError
from ..signals import deferred_interrupt
from ._files import PathLike, output_folder

__all__ = ["StreamWriter", "LineFile", "RollingFile", "deferred_interrupt"]


class StreamWriter:
    """Base of the streaming writers: ``write`` a row, ``flush``, ``close``;
    a context manager.  ``rows``: the rows written so far; ``paths``: the
    files or folders it writes."""

    rows: int = 0
    closed: bool = False
    paths: tuple[Path, ...] = ()

    def write(self, *args: Any, **kwargs: Any) -> bool:  # pragma: no cover - abstract
        """Append one row; True if it was written (False: skipped, e.g. a frame without a pose)."""
        raise NotImplementedError

    def flush(self) -> None:
        """Every ``write`` already hands its row to the OS: nothing is pending."""

    def _close(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def close(self) -> None:
        """Finish the file(s); a second call does nothing."""
        if not self.closed:
            self.closed = True
            self._close()

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]


def _create(path: Path, head: bytes) -> int:
    """A new file at ``path`` holding ``head``, appearing at once (written
    under a temporary name, then renamed over ``path``); its descriptor."""
    output_folder(path.parent)
    if path.is_dir():
        raise FileFormatError(f"{path}: is a folder (a file is written there)")
    tmp = path.with_name(f".{path.name}.{os.getpid()}.part")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
    except OSError as exc:
        raise FileFormatError(f"{path}: cannot write: {exc.strerror or exc}") from None
    try:
        _write_all(fd, head)
        os.replace(tmp, path)
    except BaseException as exc:
        os.close(fd)
        tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise FileFormatError(f"{path}: cannot write: {exc.strerror or exc}") from None
        raise
    return fd


class LineFile:
    """A text file written a line (or a header) at a time: each ``write`` is
    one ``write(2)`` call, unbuffered.  Created with its header (see
    :func:`_create`); overwrites an existing file."""

    def __init__(self, path: PathLike, header: str = "") -> None:
        self.path = Path(path).expanduser()
        self._fd: int | None = _create(self.path, header.encode("utf-8"))

    def write(self, text: str) -> None:
        if self._fd is None:
            raise FileFormatError(f"{self.path}: already closed")
        _write_all(self._fd, text.encode("utf-8"))

    def close(self) -> None:
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)


class RollingFile:
    """The output stream of an ``mcap.writer.Writer`` that keeps the file a
    complete MCAP after every :meth:`commit`.

    The writer's records are gathered in memory; ``commit`` writes them with
    a ``DataEnd`` record, a footer without summary and the closing magic
    (``trailer``) in one ``pwrite`` over the previous trailer, so the file on
    disk always ends with a valid footer.  :meth:`finish` writes what
    ``Writer.finish`` produced (its summary and footer) the same way and
    truncates the file there.
    """

    def __init__(self, path: Path, trailer: bytes) -> None:
        self.path = path
        try:
            self._fd: int | None = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except OSError as exc:
            raise FileFormatError(f"{path}: cannot write: {exc.strerror or exc}") from None
        self._trailer = trailer
        self._pending = bytearray()
        self._committed = 0  # bytes of the file before its trailer

    @classmethod
    def mcap(cls, path: Path) -> "RollingFile":
        """For an MCAP file: the trailer is a ``DataEnd`` record, a footer
        without summary and the closing magic."""
        require("mcap", "an MCAP file")
        from mcap.data_stream import RecordBuilder
        from mcap.records import DataEnd, Footer
        from mcap.writer import MCAP0_MAGIC

        b = RecordBuilder()
        DataEnd(0).write(b)
        Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(b)
        return cls(path, bytes(b.end()) + MCAP0_MAGIC)

    # The file-like interface mcap's Writer uses.
    def write(self, data: bytes) -> int:
        self._pending += data
        return len(data)

    def tell(self) -> int:
        return self._committed + len(self._pending)

    def flush(self) -> None:
        """mcap's ``Writer.flush`` calls this; rows are made durable by :meth:`commit`."""

    def _pwrite(self, data: bytes) -> None:
        assert self._fd is not None
        view, at = memoryview(data), self._committed
        while view:
            n = os.pwrite(self._fd, view, at)
            view, at = view[n:], at + n

    def commit(self) -> None:
        """Write the pending records followed by the trailer."""
        self._pwrite(bytes(self._pending) + self._trailer)
        self._committed += len(self._pending)
        self._pending.clear()

    def finish(self) -> None:
        """Write the pending records (the writer's summary and footer) and close."""
        if self._fd is None:
            return
        self._pwrite(bytes(self._pending))
        self._committed += len(self._pending)
        self._pending.clear()
        os.ftruncate(self._fd, self._committed)
        fd, self._fd = self._fd, None
        os.close(fd)

    def abandon(self) -> None:
        """Close, leaving the file as of the last commit."""
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)
