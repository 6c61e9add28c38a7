"""3-vectors as tuples for compiled minimal solvers: rows, dot, difference, scale, a + s b, cross.

Tuples of floats cost nothing to pass between compiled functions, where small
arrays and their views cost reference counting; the minimal solvers
(:mod:`.minimal`, :mod:`.generalized`) run millions of times and use these.
"""

from __future__ import annotations

from numba import njit

__all__ = ["row", "dot", "sub", "scale", "axpy", "cross"]


@njit(cache=True, inline="always")
def row(a, i):
    return (a[i, 0], a[i, 1], a[i, 2])


@njit(cache=True, inline="always")
def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True, inline="always")
def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@njit(cache=True, inline="always")
def scale(a, s):
    return (a[0] * s, a[1] * s, a[2] * s)


@njit(cache=True, inline="always")
def axpy(a, s, b):
    """a + s b"""
    return (a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2])


@njit(cache=True, inline="always")
def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
