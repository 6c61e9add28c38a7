"""Small compiled kernels shared by the stages (3x3 solve, circle fit, median).

The stages run many tiny loops (a few dozen rays of a few dozen samples, a
3x3 solve per IRLS step); in NumPy the per-call overhead alone would cost
about a millisecond per ball, so they are compiled with Numba.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["circle3", "column_medians", "kasa_circle", "median_inplace", "np_sum", "solve3", "sort_inplace"]


@numba.njit(cache=True, fastmath=False)
def solve3(M, b, x) -> bool:
    """``x = M^-1 b`` for a 3x3 ``M`` by cofactors; False if singular."""
    c00 = M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1]
    c01 = M[1, 2] * M[2, 0] - M[1, 0] * M[2, 2]
    c02 = M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]
    det = M[0, 0] * c00 + M[0, 1] * c01 + M[0, 2] * c02
    if not (abs(det) > 1e-300) or not math.isfinite(det):
        return False
    c10 = M[0, 2] * M[2, 1] - M[0, 1] * M[2, 2]
    c11 = M[0, 0] * M[2, 2] - M[0, 2] * M[2, 0]
    c12 = M[0, 1] * M[2, 0] - M[0, 0] * M[2, 1]
    c20 = M[0, 1] * M[1, 2] - M[0, 2] * M[1, 1]
    c21 = M[0, 2] * M[1, 0] - M[0, 0] * M[1, 2]
    c22 = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
    x[0] = (c00 * b[0] + c10 * b[1] + c20 * b[2]) / det
    x[1] = (c01 * b[0] + c11 * b[1] + c21 * b[2]) / det
    x[2] = (c02 * b[0] + c12 * b[1] + c22 * b[2]) / det
    return True


@numba.njit(cache=True, fastmath=False)
def kasa_circle(pts, mask, out) -> bool:
    """Algebraic least-squares circle of ``pts[mask]`` into ``out`` = (u, v, r); False if degenerate."""
    n = pts.shape[0]
    mx = 0.0
    my = 0.0
    k = 0
    for i in range(n):
        if mask[i]:
            mx += pts[i, 0]
            my += pts[i, 1]
            k += 1
    if k < 3:
        return False
    mx /= k
    my /= k
    # Centred for conditioning: x^2 + y^2 = a x + b y + c.
    M = np.zeros((3, 3))
    rhs = np.zeros(3)
    for i in range(n):
        if mask[i]:
            x = pts[i, 0] - mx
            y = pts[i, 1] - my
            z = x * x + y * y
            row = (x, y, 1.0)
            for r in range(3):
                rhs[r] += row[r] * z
                for c in range(3):
                    M[r, c] += row[r] * row[c]
    sol = np.empty(3)
    if not solve3(M, rhs, sol):
        return False
    cx = 0.5 * sol[0]
    cy = 0.5 * sol[1]
    r2 = sol[2] + cx * cx + cy * cy
    if not (r2 > 0.0) or not math.isfinite(r2):
        return False
    out[0] = cx + mx
    out[1] = cy + my
    out[2] = math.sqrt(r2)
    return True


@numba.njit(cache=True, fastmath=False)
def sort_inplace(a, k) -> None:
    """Sort ``a[:k]`` in place (no NaN).

    Insertion sort: k is at most a hundred, and it compiles in a fraction of
    the time ``np.sort`` takes.
    """
    for i in range(1, k):
        x = a[i]
        j = i - 1
        while j >= 0 and a[j] > x:
            a[j + 1] = a[j]
            j -= 1
        a[j + 1] = x


@numba.njit(cache=True, fastmath=False)
def median_inplace(a, k) -> float:
    """Median of ``a[:k]`` (k >= 1; sorts it in place, see :func:`sort_inplace`)."""
    sort_inplace(a, k)
    if k % 2 == 1:
        return a[k // 2]
    return 0.5 * (a[k // 2 - 1] + a[k // 2])


@numba.njit(cache=True, fastmath=False)
def column_medians(a, out) -> None:
    """Median of each column of ``a`` (n, m) into ``out`` (m,), as ``np.median(a, axis=0)``; NaN when n is 0."""
    n = a.shape[0]
    buf = np.empty(n)
    for c in range(a.shape[1]):
        if n == 0:
            out[c] = np.nan
            continue
        for i in range(n):
            buf[i] = a[i, c]
        out[c] = median_inplace(buf, n)


@numba.njit(cache=True, fastmath=False, inline="always")
def circle3(ax, ay, bx, by, cx, cy):
    """Circle through three points: ``(ok, u, v, r)``; not ok when they are collinear."""
    d = 2.0 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
    if abs(d) < 1e-9:
        return False, 0.0, 0.0, 0.0
    a2 = ax * ax + ay * ay
    b2 = bx * bx + by * by
    c2 = cx * cx + cy * cy
    ux = (a2 * (by - cy) + b2 * (cy - ay) + c2 * (ay - by)) / d
    uy = (a2 * (cx - bx) + b2 * (ax - cx) + c2 * (bx - ax)) / d
    return True, ux, uy, math.hypot(ax - ux, ay - uy)


@numba.njit(cache=True, fastmath=False)
def _block_sum(a, lo, hi):
    """NumPy's sum of at most 128 values: eight running sums, then the rest in turn."""
    n = hi - lo
    if n < 8:
        res = 0.0
        for i in range(lo, hi):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = lo + 8
    while i < hi - n % 8:
        r0 += a[i]
        r1 += a[i + 1]
        r2 += a[i + 2]
        r3 += a[i + 3]
        r4 += a[i + 4]
        r5 += a[i + 5]
        r6 += a[i + 6]
        r7 += a[i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < hi:
        res += a[i]
        i += 1
    return res


@numba.njit(cache=True, fastmath=False)
def np_sum(a, lo, hi):
    """``a[lo:hi].sum()`` added in NumPy's order, so compiled code gives the very figures of the array code
    it replaces.

    NumPy sums pairwise: a range of more than 128 values is split in two
    (the first half a multiple of 8 long) and each half summed so; up to
    128, :func:`_block_sum`.  The halving runs on an explicit stack (a
    recursive kernel crashes when loaded from Numba's cache).
    """
    if hi - lo <= 128:
        return _block_sum(a, lo, hi)
    los = np.empty(64, np.int64)
    his = np.empty(64, np.int64)
    mids = np.empty(64, np.int64)
    left_done = np.zeros(64, np.bool_)
    vals = np.empty(64)
    top = 0
    los[0] = lo
    his[0] = hi
    ret = 0.0
    returning = False
    while True:
        if returning:
            if top < 0:
                return ret
            if not left_done[top]:  # the left half is summed: now the right one
                vals[top] = ret
                left_done[top] = True
                los[top + 1] = mids[top]
                his[top + 1] = his[top]
                left_done[top + 1] = False
                top += 1
                returning = False
            else:
                ret = vals[top] + ret
                top -= 1
            continue
        n = his[top] - los[top]
        if n <= 128:
            ret = _block_sum(a, los[top], his[top])
            top -= 1
            returning = True
            continue
        n2 = n // 2
        n2 -= n2 % 8
        mids[top] = los[top] + n2
        left_done[top] = False
        los[top + 1] = los[top]
        his[top + 1] = mids[top]
        left_done[top + 1] = False
        top += 1
