"""Pose files: TUM trajectories and the SPEC's ``trajectory.csv``.

One module, one name per format, for ``track``, ``simulate`` and the demo:
``*.tum`` (``timestamp tx ty tz qx qy qz qw``, what evo and the TUM tools
read) and ``trajectory.csv`` (SPEC "Filtered tracking": every frame with its
status, pose and the six standard deviations of its covariance).  A single
pose as JSON is :meth:`mutloc.Pose.to_dict` (written with
:func:`mutloc.io.write_json`).

Both are written as they go (:class:`TumWriter`, :class:`TrajectoryCsvWriter`,
see :mod:`mutloc.io.streaming`): a file of a killed run ends after its last
complete line.  The readers accept such a file; a last line without its end
of line (a write cut by the kill) is dropped if it does not parse (a TUM
line: also if its quaternion is not of unit norm, or its last number is
shorter than the line before's), with a warning naming it.
"""

from __future__ import annotations

import csv
import io
import math
import warnings
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from ..core.pose import Pose
from ..errors import FileFormatError
from ._files import PathLike
from .streaming import LineFile, StreamWriter

__all__ = ["TUM_SUFFIX", "write_tum", "read_tum", "CSV_COLUMNS", "write_trajectory_csv", "read_trajectory_csv",
           "TumWriter", "TrajectoryCsvWriter"]

TUM_SUFFIX = ".tum"
#: The SPEC's leading columns of ``trajectory.csv``, in order.
CSV_COLUMNS = ("t", "status", "tx", "ty", "tz", "qx", "qy", "qz", "qw",
               "sigma_rx", "sigma_ry", "sigma_rz", "sigma_tx", "sigma_ty", "sigma_tz")


class TumWriter(StreamWriter):
    """Streams a TUM trajectory: the ``comment`` lines (``# ...``) at open,
    then one line ``t tx ty tz qx qy qz qw`` per :meth:`write`."""

    def __init__(self, path: PathLike, comment: str | None = None) -> None:
        head = "" if comment is None else "".join(f"# {c}\n" for c in comment.splitlines())
        self._file = LineFile(path, head)
        self.paths = (self._file.path,)

    def write(self, t: float, pose: Pose | None) -> bool:
        """The pose at time ``t``; a missing or non-finite one is skipped (False)."""
        if pose is None or not (pose.isfinite() and math.isfinite(float(t))):
            return False
        self._file.write(" ".join(f"{x:.9f}" for x in (float(t), *pose.t, *pose.quaternion_xyzw)) + "\n")
        self.rows += 1
        return True

    def _close(self) -> None:
        self._file.close()


def write_tum(path: PathLike, times: Sequence[float], poses: Pose, comment: str | None = None) -> None:
    """Write a TUM trajectory: one line ``t tx ty tz qx qy qz qw`` per pose of
    the stack ``poses`` (non-finite poses are skipped)."""
    times = np.asarray(times, dtype=float).reshape(-1)
    if poses.single:
        poses = Pose(poses.R[None], poses.t[None])
    if len(poses) != len(times):
        raise ValueError(f"{len(times)} times for {len(poses)} poses")
    with TumWriter(path, comment) as w:
        for t, pose in zip(times, poses):
            w.write(t, pose)


def _read(p: Path) -> str:
    try:
        return p.read_text(encoding="utf-8")
    except OSError as exc:
        raise FileFormatError(f"{p}: cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise FileFormatError(f"{p}: not a UTF-8 text file ({exc.reason} at byte {exc.start})") from None


def _cut(text: str) -> tuple[str, str]:
    """``text`` split into its complete lines and an unterminated last line
    (empty if the text ends with an end of line)."""
    if text.endswith(("\n", "\r")) or not text:
        return text, ""
    i = max(text.rfind("\n"), text.rfind("\r")) + 1
    return text[:i], text[i:]


#: How far from 1 a TUM line's quaternion norm may be (a file written with 4 decimals is within 1e-4; a
#: line cut inside its last number, qw, is off by more unless qw is tiny).
TUM_QUATERNION_TOLERANCE = 1e-3


def _tum_row(line: str, where: str) -> list[float] | None:
    line = line.strip()
    if not line or line.startswith("#"):
        return None
    try:
        vals = [float(x) for x in line.replace(",", " ").split()]
    except ValueError:
        raise FileFormatError(f"{where}: not 8 numbers (t tx ty tz qx qy qz qw)") from None
    if len(vals) != 8 or not all(math.isfinite(v) for v in vals):
        raise FileFormatError(f"{where}: not 8 finite numbers (t tx ty tz qx qy qz qw)")
    norm = math.sqrt(sum(v * v for v in vals[4:]))
    if abs(norm - 1.0) > TUM_QUATERNION_TOLERANCE:
        raise FileFormatError(f"{where}: quaternion (qx qy qz qw) of norm {norm:.6g}, not 1 within "
                              f"{TUM_QUATERNION_TOLERANCE:g}: a cut or corrupt line")
    return vals


def _decimals(line: str) -> int:
    """Digits after the point of a line's last number."""
    last = line.replace(",", " ").split()[-1].lower().split("e")[0]
    return len(last.partition(".")[2])


def read_tum(path: PathLike) -> tuple[np.ndarray, Pose]:
    """``(times, poses)`` of a TUM file; FileFormatError naming the line if
    it is malformed (not 8 finite numbers, or a quaternion whose norm is not
    1 within :data:`TUM_QUATERNION_TOLERANCE`).  A last line without its end
    of line (a write cut by a kill) that is malformed so, or whose last
    number has fewer decimals than the line before's (cut inside it), is
    dropped with a warning naming it."""
    p = Path(path).expanduser()
    body, tail = _cut(_read(p))
    lines = body.splitlines()
    rows = [r for k, line in enumerate(lines, 1) if (r := _tum_row(line, f"{p}:{k}")) is not None]
    where = f"{p}:{len(lines) + 1}"
    try:
        last = _tum_row(tail, where)
        before = next((ln for ln in reversed(lines) if ln.strip() and not ln.lstrip().startswith("#")), None)
        if last is not None and before is not None and _decimals(tail) < _decimals(before):
            raise FileFormatError(f"{where}: its last number has fewer decimals than the line before's: cut")
    except FileFormatError as exc:
        warnings.warn(f"{exc}; the last line has no end of line: dropped as a write cut by a kill", stacklevel=2)
        last = None
    if last is not None:
        rows.append(last)
    a = np.array(rows, dtype=float).reshape(-1, 8)
    if len(a) == 0:
        return np.empty(0), Pose(np.empty((0, 3, 3)), np.empty((0, 3)))
    return a[:, 0], Pose.from_quaternion_xyzw(a[:, 4:8], a[:, 1:4])


def _fmt(x: Any, digits: int = 9) -> str:
    if x is None:
        return ""
    x = float(x)
    return f"{x:.{digits}f}" if math.isfinite(x) else ""


class TrajectoryCsvWriter(StreamWriter):
    """Streams ``trajectory.csv``: the header (the SPEC columns, then
    ``extra``) at open, then one line per :meth:`write`."""

    def __init__(self, path: PathLike, extra: Sequence[str] = ()) -> None:
        self.extra = tuple(extra)
        self._buf = io.StringIO()
        self._csv = csv.writer(self._buf)
        self._file = LineFile(path, self._line([*CSV_COLUMNS, *self.extra]))
        self.paths = (self._file.path,)

    def _line(self, fields: Sequence[str]) -> str:
        self._buf.seek(0)
        self._buf.truncate()
        self._csv.writerow(fields)
        return self._buf.getvalue()

    def write(self, row: Mapping[str, Any]) -> bool:
        """One row: a mapping with ``t``, ``status``, optionally ``pose`` (a
        single :class:`Pose`) and ``covariance`` (6x6, SPEC order), and the
        ``extra`` keys; a row without a pose has empty pose and sigma columns."""
        out = [_fmt(row["t"]), str(row["status"])]
        pose = row.get("pose")
        if pose is not None:
            out += [_fmt(x) for x in pose.t] + [_fmt(x) for x in pose.quaternion_xyzw]
        else:
            out += [""] * 7
        cov = row.get("covariance")
        if cov is not None:
            out += [_fmt(math.sqrt(max(float(v), 0.0))) for v in np.diag(np.asarray(cov, float))]
        else:
            out += [""] * 6
        for key in self.extra:
            v = row.get(key)
            out.append(_fmt(v, 4) if isinstance(v, (float, np.floating)) else ("" if v is None else str(v)))
        self._file.write(self._line(out))
        self.rows += 1
        return True

    def _close(self) -> None:
        self._file.close()


def write_trajectory_csv(path: PathLike, rows: Iterable[Mapping[str, Any]], extra: Sequence[str] = ()) -> None:
    """Write ``trajectory.csv``: per row the SPEC columns, then ``extra``
    (each row as :meth:`TrajectoryCsvWriter.write` takes it)."""
    with TrajectoryCsvWriter(path, extra) as w:
        for r in rows:
            w.write(r)


def _csv_rows(p: Path, text: str, first_line: int, fieldnames: Sequence[str] | None) -> tuple[list, Sequence[str]]:
    reader = csv.DictReader(io.StringIO(text, newline=""), fieldnames=fieldnames)
    if fieldnames is None:
        missing = [c for c in CSV_COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise FileFormatError(f"{p}: not a trajectory.csv (missing columns {missing})")
    out = []
    for k, r in enumerate(reader, first_line):
        n = len(reader.fieldnames or ())
        if None in r or None in r.values():
            raise FileFormatError(f"{p}:{k}: {n} columns expected (as the header), got another number")
        try:
            row: dict[str, Any] = {"t": float(r["t"]), "status": r["status"]}
            if r["tx"]:
                row["pose"] = Pose.from_quaternion_xyzw([float(r[c]) for c in ("qx", "qy", "qz", "qw")],
                                                        [float(r[c]) for c in ("tx", "ty", "tz")])
            else:
                row["pose"] = None
            sig = [r[c] for c in CSV_COLUMNS[9:]]
            row["sigma"] = np.array([float(x) for x in sig]) if all(sig) else None
        except ValueError:
            raise FileFormatError(f"{p}:{k}: a number column is not a number") from None
        row.update({c: v for c, v in r.items() if c not in CSV_COLUMNS})
        out.append(row)
    return out, reader.fieldnames or ()


def read_trajectory_csv(path: PathLike) -> list[dict[str, Any]]:
    """Rows of a ``trajectory.csv`` as dicts: ``t`` (float), ``status``,
    ``pose`` (Pose or None), ``sigma`` ((6,) array or None), and every other
    column as text."""
    p = Path(path).expanduser()
    body, tail = _cut(_read(p))
    if not body:  # no complete line: the header alone, or nothing
        body, tail = tail, ""
    rows, names = _csv_rows(p, body, 2, None)
    if tail.strip():
        try:
            rows += _csv_rows(p, tail, len(rows) + 2, names)[0]
        except FileFormatError:
            pass  # a line cut by a kill
    return rows
