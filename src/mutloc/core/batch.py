"""Many minimal problems of one configuration in one call.

For Monte Carlo studies and RANSAC loops: ``N`` problems that share the split
of their three observations (``side``) are solved in one compiled loop, in
chunks so memory stays bounded however large ``N`` is.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np
from numba import njit

from ..errors import InputError
from .minimal import WORK_SIZE, solve_minimal_ws

__all__ = ["BatchResult", "iter_solve_minimal", "solve_minimal_batch", "MAX_SOLUTIONS"]

MAX_SOLUTIONS = 8
DEFAULT_CHUNK = 65536


@dataclass
class BatchResult:
    """Solutions of problems ``start .. start + len(count)``.

    ``R[i, :count[i]]`` and ``t[i, :count[i]]`` are the candidate poses T_qp of
    problem ``start + i``; unused slots are NaN.
    """

    start: int
    R: np.ndarray
    t: np.ndarray
    count: np.ndarray

    def __len__(self) -> int:
        return len(self.count)


@njit(cache=True)
def _solve_many(side, bearings, points, Rs, ts, counts):
    buf_R = np.empty((16, 3, 3))
    buf_t = np.empty((16, 3))
    buf_r = np.empty((16, 3))
    ws = np.empty(WORK_SIZE)
    iws = np.empty(6, dtype=np.int64)
    for i in range(bearings.shape[0]):
        n = solve_minimal_ws(side, bearings[i], points[i], buf_R, buf_t, buf_r, ws, iws)
        n = min(n, Rs.shape[1])
        for j in range(n):
            Rs[i, j] = buf_R[j]
            ts[i, j] = buf_t[j]
        counts[i] = n


def _check(side: np.ndarray, bearings: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    side = np.asarray(side, dtype=np.int64)
    if side.shape != (3,) or not np.all((side == 0) | (side == 1)):
        raise InputError("side must be three values, each 0 (seen by p) or 1 (seen by q)")
    bearings = np.asarray(bearings, dtype=float)
    points = np.asarray(points, dtype=float)
    if bearings.ndim != 3 or bearings.shape[1:] != (3, 3) or points.shape != bearings.shape:
        raise InputError(f"bearings and points must both have shape (N, 3, 3), got {bearings.shape} and {points.shape}")
    return side, bearings, points


def iter_solve_minimal(side, bearings, points, chunk_size: int = DEFAULT_CHUNK) -> Iterator[BatchResult]:
    """Solve ``N`` minimal problems chunk by chunk.

    ``side`` (3,): who saw each observation (0 = p, 1 = q), shared by all
    problems; ``bearings`` (N, 3, 3): unit rays in the observer's frame;
    ``points`` (N, 3, 3): the markers in their owner's frame.  Non-finite
    problems simply get no solution.
    """
    side, bearings, points = _check(side, bearings, points)
    n = bearings.shape[0]
    for start in range(0, n, chunk_size):
        b = np.ascontiguousarray(bearings[start : start + chunk_size])
        p = np.ascontiguousarray(points[start : start + chunk_size])
        m = b.shape[0]
        Rs = np.full((m, MAX_SOLUTIONS, 3, 3), np.nan)
        ts = np.full((m, MAX_SOLUTIONS, 3), np.nan)
        counts = np.zeros(m, dtype=np.int64)
        _solve_many(side, b, p, Rs, ts, counts)
        yield BatchResult(start, Rs, ts, counts)


def solve_minimal_batch(side, bearings, points, chunk_size: int = DEFAULT_CHUNK) -> BatchResult:
    """All solutions of ``N`` minimal problems at once (memory grows with N:
    use :func:`iter_solve_minimal` for very large batches)."""
    parts = list(iter_solve_minimal(side, bearings, points, chunk_size))
    if not parts:
        return BatchResult(0, np.empty((0, MAX_SOLUTIONS, 3, 3)), np.empty((0, MAX_SOLUTIONS, 3)), np.empty(0, np.int64))
    return BatchResult(0, np.concatenate([p.R for p in parts]), np.concatenate([p.t for p in parts]),
                       np.concatenate([p.count for p in parts]))
