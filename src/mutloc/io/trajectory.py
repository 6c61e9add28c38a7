"""Pose files: TUM trajectories and the SPEC's ``trajectory.csv``.

One module, one name per format, for ``track``, ``simulate`` and the demo:
``*.tum`` (``timestamp tx ty tz qx qy qz qw``, what evo and the TUM tools
read) and ``trajectory.csv`` (SPEC "Filtered tracking": every frame with its
status, pose and the six standard deviations of its covariance).  A single
pose as JSON is :meth:`mutloc.Pose.to_dict` (written with
:func:`mutloc.io.write_json`).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from ..core.pose import Pose
from ..errors import FileFormatError
from ._files import PathLike, output_folder

__all__ = ["TUM_SUFFIX", "write_tum", "read_tum", "CSV_COLUMNS", "write_trajectory_csv", "read_trajectory_csv"]

TUM_SUFFIX = ".tum"
#: The SPEC's leading columns of ``trajectory.csv``, in order.
CSV_COLUMNS = ("t", "status", "tx", "ty", "tz", "qx", "qy", "qz", "qw",
               "sigma_rx", "sigma_ry", "sigma_rz", "sigma_tx", "sigma_ty", "sigma_tz")


def _parent(path: PathLike) -> Path:
    p = Path(path).expanduser()
    output_folder(p.parent)
    return p


def write_tum(path: PathLike, times: Sequence[float], poses: Pose, comment: str | None = None) -> None:
    """Write a TUM trajectory: one line ``t tx ty tz qx qy qz qw`` per pose of
    the stack ``poses`` (non-finite poses are skipped)."""
    times = np.asarray(times, dtype=float).reshape(-1)
    if poses.single:
        poses = Pose(poses.R[None], poses.t[None])
    if len(poses) != len(times):
        raise ValueError(f"{len(times)} times for {len(poses)} poses")
    ok = poses.isfinite() & np.isfinite(times)
    q = poses[ok].quaternion_xyzw if np.any(ok) else np.empty((0, 4))
    lines = [] if comment is None else [f"# {c}" for c in comment.splitlines()]
    for ti, t, qi in zip(times[ok], poses.t[ok], q):
        lines.append(" ".join(f"{x:.9f}" for x in (ti, *t, *qi)))
    _parent(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


def read_tum(path: PathLike) -> tuple[np.ndarray, Pose]:
    """``(times, poses)`` of a TUM file; FileFormatError naming the line if it is malformed."""
    p = Path(path).expanduser()
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise FileFormatError(f"{p}: cannot read: {exc.strerror or exc}") from None
    rows = []
    for k, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            vals = [float(x) for x in line.replace(",", " ").split()]
        except ValueError:
            raise FileFormatError(f"{p}:{k}: not 8 numbers (t tx ty tz qx qy qz qw)") from None
        if len(vals) != 8 or not all(math.isfinite(v) for v in vals):
            raise FileFormatError(f"{p}:{k}: not 8 finite numbers (t tx ty tz qx qy qz qw)")
        rows.append(vals)
    a = np.array(rows, dtype=float).reshape(-1, 8)
    if len(a) == 0:
        return np.empty(0), Pose(np.empty((0, 3, 3)), np.empty((0, 3)))
    return a[:, 0], Pose.from_quaternion_xyzw(a[:, 4:8], a[:, 1:4])


def _fmt(x: Any, digits: int = 9) -> str:
    if x is None:
        return ""
    x = float(x)
    return f"{x:.{digits}f}" if math.isfinite(x) else ""


def write_trajectory_csv(path: PathLike, rows: Iterable[dict[str, Any]], extra: Sequence[str] = ()) -> None:
    """Write ``trajectory.csv``: per row the SPEC columns, then ``extra``.

    Each row is a dict with ``t``, ``status``, optionally ``pose`` (a single
    :class:`Pose`) and ``covariance`` (6x6, SPEC order), and the ``extra``
    keys; a row without a pose has empty pose and sigma columns.
    """
    with open(_parent(path), "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow([*CSV_COLUMNS, *extra])
        for r in rows:
            out = [_fmt(r["t"]), str(r["status"])]
            pose = r.get("pose")
            if pose is not None:
                out += [_fmt(x) for x in pose.t] + [_fmt(x) for x in pose.quaternion_xyzw]
            else:
                out += [""] * 7
            cov = r.get("covariance")
            if cov is not None:
                out += [_fmt(math.sqrt(max(float(v), 0.0))) for v in np.diag(np.asarray(cov, float))]
            else:
                out += [""] * 6
            for key in extra:
                v = r.get(key)
                out.append(_fmt(v, 4) if isinstance(v, (float, np.floating)) else ("" if v is None else str(v)))
            w.writerow(out)


def read_trajectory_csv(path: PathLike) -> list[dict[str, Any]]:
    """Rows of a ``trajectory.csv`` as dicts: ``t`` (float), ``status``,
    ``pose`` (Pose or None), ``sigma`` ((6,) array or None), and every other
    column as text."""
    p = Path(path).expanduser()
    try:
        f = open(p, newline="", encoding="utf-8")
    except OSError as exc:
        raise FileFormatError(f"{p}: cannot read: {exc.strerror or exc}") from None
    with f:
        reader = csv.DictReader(f)
        missing = [c for c in CSV_COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise FileFormatError(f"{p}: not a trajectory.csv (missing columns {missing})")
        out = []
        for k, r in enumerate(reader, 2):
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
    return out
