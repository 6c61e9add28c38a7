"""Real roots of small univariate polynomials, compiled with Numba.

Roots are isolated by the derivative chain: the roots of ``p'`` split the
search interval into pieces on which ``p`` is monotone, so each piece holds at
most one root, found by safeguarded Newton.  Unlike Sturm sequences this needs
no cancellation-prone remainders, and it hands us the critical points of ``p``
for free: a critical point where ``|p|`` is at rounding level is a double root
that rounding has pushed into the complex plane.  Those are reported too, so a
caller can polish them against the original (multivariate) system instead of
silently losing a solution.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["real_roots", "real_roots_py"]

MAX_DEG = 8


@njit(cache=True, inline="always")
def _horner(c, n, x):
    y = c[n]
    for i in range(n - 1, -1, -1):
        y = y * x + c[i]
    return y


@njit(cache=True, inline="always")
def _abs_horner(c, n, x):
    ax = abs(x)
    y = abs(c[n])
    for i in range(n - 1, -1, -1):
        y = y * ax + abs(c[i])
    return y


@njit(cache=True)
def _bracketed_root(c, n, dc, ddc, a, b, fa, fb, rtol, a_crit, b_crit):
    """Root of ``c`` (degree n, derivatives ``dc``, ``ddc``) in [a, b] where
    it changes sign; safeguarded Newton.

    An end that is a critical point (p' = 0) starts Newton from the Taylor
    quadratic there, ``a + sqrt(2 |p(a) / p''(a)|)``: far better than the
    regula-falsi point in the wide outer brackets, where Newton on a
    high-degree polynomial would otherwise creep in linearly.
    """
    x = np.nan
    if a_crit and n >= 2:
        f2 = _horner(ddc, n - 2, a)
        if f2 != 0.0:
            x = a + np.sqrt(abs(2.0 * fa / f2))
    if not (a < x < b) and b_crit and n >= 2:
        f2 = _horner(ddc, n - 2, b)
        if f2 != 0.0:
            x = b - np.sqrt(abs(2.0 * fb / f2))
    if not (a < x < b):
        x = a + (b - a) * fa / (fa - fb)
    if not (a < x < b):
        x = 0.5 * (a + b)
    for _ in range(100):
        # p, p' and p'' in one pass over the coefficients; Halley's step
        # (cubic convergence) then needs fewer iterations than Newton's.
        f = c[n]
        df = 0.0
        d2 = 0.0
        for i in range(n - 1, -1, -1):
            d2 = d2 * x + df
            df = df * x + f
            f = f * x + c[i]
        if f == 0.0:
            return x
        if (f > 0.0) == (fa > 0.0):
            a = x
        else:
            b = x
        # d2 holds p''/2 (simultaneous Horner), so Halley's step is
        # x - p p' / (p'^2 - p p''/2).
        den = df * df - f * d2
        if den != 0.0:
            xn = x - f * df / den
        elif df != 0.0:
            xn = x - f / df
        else:
            xn = 0.5 * (a + b)
        if not (a < xn < b):
            xn = 0.5 * (a + b)
        if abs(xn - x) <= rtol * abs(xn) or b - a <= rtol * abs(xn):
            return xn
        x = xn
    return x


WORK_SIZE = (MAX_DEG + 1) * (MAX_DEG + 3)


@njit(cache=True)
def real_roots(c, lo, hi, roots, near_tol, rtol=1e-13, crit_rtol=1e-7):
    """Real roots of ``sum(c[i] x**i)`` in (lo, hi); see :func:`real_roots_ws`."""
    work = np.empty((c.shape[0]) * (c.shape[0] + 2))
    return real_roots_ws(c, lo, hi, roots, near_tol, rtol, crit_rtol, work)


@njit(cache=True)
def real_roots_ws(c, lo, hi, roots, near_tol, rtol, crit_rtol, work):
    """Real roots of ``sum(c[i] x**i)`` in the open interval (lo, hi).

    Writes them increasing into ``roots`` and returns ``(n_roots, n_near)``:
    the first ``n_roots`` entries are sign-change roots, the next ``n_near``
    are critical points where ``|p| <= near_tol * sum(|c_i| |x|^i)`` without a
    sign change (numerically merged double roots).  ``roots`` needs room for
    ``2 * degree`` values; ``work`` is scratch space of at least
    ``(degree + 1) * (degree + 3)`` floats, so hot loops allocate nothing.
    """
    n = c.shape[0] - 1
    cmax = 0.0
    for i in range(n + 1):
        cmax = max(cmax, abs(c[i]))
    if cmax == 0.0:
        return 0, 0
    while n > 0 and abs(c[n]) <= 1e-15 * cmax:
        n -= 1
    if n == 0:
        return 0, 0
    if lo >= 0.0:
        # Upper bound on the positive roots (Cauchy's, over the negative
        # coefficients only); no positive root if there are none.
        lead = c[n]
        kb = 0.0
        for i in range(n):
            if c[i] * lead < 0.0:
                kb = max(kb, abs(c[i] / lead))
        if kb == 0.0:
            return 0, 0
        hi = min(hi, (1.0 + kb) * (1.0 + 1e-12))
        if hi <= lo:
            return 0, 0
    # D[k] holds the k-th derivative (degree n - k).
    m = n + 1
    D = work[: m * m].reshape((m, m))
    D[:, :] = 0.0
    for i in range(n + 1):
        D[0, i] = c[i] / cmax
    for k in range(1, n + 1):
        for i in range(n - k + 1):
            D[k, i] = D[k - 1, i + 1] * (i + 1)
    crit = work[m * m : m * m + m]
    ncrit = 0
    cur = work[m * m + m : m * m + 2 * m]
    nroot = 0
    for k in range(n - 1, -1, -1):
        deg = n - k
        nroot = 0
        a = lo
        fa = _horner(D[k], deg, a)
        for j in range(ncrit + 1):
            b = crit[j] if j < ncrit else hi
            fb = _horner(D[k], deg, b)
            if (fa < 0.0 and fb > 0.0) or (fa > 0.0 and fb < 0.0):
                if deg == 1:
                    cur[nroot] = -D[k, 0] / D[k, 1]
                else:
                    cur[nroot] = _bracketed_root(D[k], deg, D[k + 1], D[min(k + 2, n)], a, b, fa, fb,
                                                 rtol if k == 0 else (crit_rtol if k == 1 else 1e3 * crit_rtol), j > 0, j < ncrit)
                nroot += 1
            elif fb == 0.0 and j < ncrit:
                cur[nroot] = b
                nroot += 1
            a = b
            fa = fb
        if k == 0:
            nnear = 0
            for j in range(ncrit):
                x = crit[j]
                dup = False
                for i in range(nroot):
                    if abs(cur[i] - x) <= 1e-12 * (1.0 + abs(x)):
                        dup = True
                if dup:
                    continue
                if abs(_horner(D[0], n, x)) <= near_tol * _abs_horner(D[0], n, x):
                    roots[nroot + nnear] = x
                    nnear += 1
            for i in range(nroot):
                roots[i] = cur[i]
            return nroot, nnear
        for i in range(nroot):
            crit[i] = cur[i]
        ncrit = nroot
    return 0, 0


def real_roots_py(coeffs_ascending, lo: float = -np.inf, hi: float = np.inf, near_tol: float = 0.0) -> np.ndarray:
    """Real roots of a polynomial (ascending coefficients) in (lo, hi), for Python callers."""
    c = np.ascontiguousarray(coeffs_ascending, dtype=float)
    if not np.isfinite(lo) or not np.isfinite(hi):
        lead = c[np.flatnonzero(c)[-1]] if np.any(c) else 1.0
        bound = 1.0 + np.max(np.abs(c / lead))
        lo = max(lo, -bound)
        hi = min(hi, bound)
    out = np.empty(2 * max(len(c) - 1, 1))
    nr, nn = real_roots(c, float(lo), float(hi), out, float(near_tol))
    return np.sort(out[: nr + nn])
