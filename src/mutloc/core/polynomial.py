"""Real roots of small univariate polynomials, compiled with Numba.

Roots are isolated by the derivative chain: the roots of ``p'`` split the
search interval into pieces on which ``p`` is monotone, so each piece holds at
most one root, found by safeguarded Newton.  Unlike Sturm sequences this needs
no cancellation-prone remainders, and it hands us the critical points of ``p``
for free: a critical point where ``|p|`` is at rounding level is a double root
that rounding has pushed into the complex plane.  Those are reported too, so a
caller can polish them against the original (multivariate) system instead of
silently losing a solution.

The derivative chain solves for the roots of every derivative, about 20
bracketed solves for degree 8.  When only the positive roots are wanted
(:func:`positive_roots_ws`, the minimal solver's case) a faster path comes
first: Laguerre's method from above the roots, deflating each one, stops as
soon as the quotient has only positive coefficients, which *certifies* that
no positive root and no complex pair near the positive axis (a merged double
root) is left.  Whenever that certificate is not reached the derivative
chain runs instead, so the fast path changes the speed, not the contract.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["positive_roots_ws", "real_roots", "real_roots_py"]

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


@njit(cache=True, inline="always")
def _eval012(q, x):
    """p(x), p'(x) and p''(x)/2 of a polynomial of degree <= 8 stored in
    q[0..8] (zero-padded), by Estrin's scheme.

    Horner's rule is one long chain of dependent multiply-adds; Estrin's
    pairing halves its depth, which is what limits a Laguerre step (the
    three evaluations then run side by side).  The rounding error is of the
    same order.
    """
    x2 = x * x
    x4 = x2 * x2
    p = ((q[0] + q[1] * x) + x2 * (q[2] + q[3] * x)) + x4 * (
        ((q[4] + q[5] * x) + x2 * (q[6] + q[7] * x)) + x4 * q[8]
    )
    dp = ((q[1] + 2.0 * q[2] * x) + x2 * (3.0 * q[3] + 4.0 * q[4] * x)) + x4 * (
        (5.0 * q[5] + 6.0 * q[6] * x) + x2 * (7.0 * q[7] + 8.0 * q[8] * x)
    )
    hp = ((q[2] + 3.0 * q[3] * x) + x2 * (6.0 * q[4] + 10.0 * q[5] * x)) + x4 * (
        (15.0 * q[6] + 21.0 * q[7] * x) + x2 * (28.0 * q[8])
    )
    return p, dp, hp


@njit(cache=True)
def _laguerre(q, m, x, rtol, max_iter):
    """A root of the monic ``q`` (degree m, stored zero-padded in q[0..8]) by
    Laguerre's method from x.

    For a polynomial with only real roots Laguerre's method converges
    monotonically (and cubically) to the nearest root on the side the step
    points to, from any start; above the largest root that is the largest
    root.  With complex roots nothing is promised, so the caller checks the
    result.  Returns NaN if the iteration does not settle in max_iter.
    """
    for _ in range(max_iter):
        f, df, d2 = _eval012(q, x)
        if f == 0.0:
            return x
        # Laguerre's step  m q / (q' +- sqrt((m-1) ((m-1) q'^2 - m q q''))),
        # written without dividing by q.  A negative radicand means complex
        # roots nearby: it is clamped (a Newton-like step m q / q').
        disc = (m - 1) * ((m - 1) * df * df - 2.0 * m * f * d2)
        sq = np.sqrt(disc) if disc > 0.0 else 0.0
        den = df + sq if df >= 0.0 else df - sq
        if den == 0.0:
            return np.nan
        dx = m * f / den
        x -= dx
        if abs(dx) <= rtol * abs(x):
            return x
    return np.nan


@njit(cache=True)
def _positive_roots_certified(c, n, lo, hi, roots, q, rtol):
    """Fast path of :func:`positive_roots_ws`: the real roots of ``c``
    (degree n <= 8) in (lo, hi), lo >= 0, or -1 when they cannot be
    certified complete.

    Roots are found from the top down by Laguerre's method, each one
    deflated out of the monic polynomial.  The search stops as soon as the
    quotient has only positive coefficients: such a polynomial has no root
    in the sector |arg z| < pi / degree (there every term points into the
    open upper half plane), so neither a positive root nor a complex pair
    close to the positive axis, which is what a numerically merged double
    root looks like, can hide in it.  The argument needs only that every
    deflated value is a root (checked by the remainder of its deflation),
    not that Laguerre found them in order; any doubt returns -1 and the
    caller uses the derivative chain instead.
    """
    inv = 1.0 / c[n]
    for i in range(9):
        q[i] = c[i] * inv if i <= n else 0.0
    # Start at Laguerre's limit from +infinity: the mean of the roots plus
    # sqrt(n - 1) times their spread (an upper bound when all are real).
    mu = -q[n - 1] / n
    var = (q[n - 1] * q[n - 1] - 2.0 * q[n - 2]) / n - mu * mu
    x = mu + np.sqrt(max(var, 0.0) * (n - 1))
    x += 1e-9 * abs(x)
    nr = 0
    m = n
    while True:
        certified = True
        for i in range(m):
            if not q[i] > 0.0:
                certified = False
                break
        if certified:
            return nr
        x = _laguerre(q, m, x, rtol, 40)
        if not np.isfinite(x):
            return -1
        # Deflate by x (in place, synthetic division).  The remainder is
        # q(x), which must be at rounding level of its terms for x to be a
        # root.
        ax = abs(x)
        b = q[m]
        scale = 1.0
        for i in range(m - 1, -1, -1):
            t = q[i]
            q[i] = b
            b = t + x * b
            scale = scale * ax + abs(t)
        if not abs(b) <= 1e-10 * scale:
            return -1
        q[m] = 0.0
        m -= 1
        if lo < x < hi:
            if nr >= roots.shape[0]:
                return -1
            # Keep the roots increasing (insertion; at most eight).
            j = nr
            while j > 0 and roots[j - 1] > x:
                roots[j] = roots[j - 1]
                j -= 1
            roots[j] = x
            nr += 1
        if m == 0:
            return nr


@njit(cache=True)
def positive_roots_ws(c, lo, hi, roots, near_tol, rtol, crit_rtol, work):
    """Same contract as :func:`real_roots_ws` for ``lo >= 0`` and degree
    <= 8, usually several times faster.

    Tries :func:`_positive_roots_certified` (Laguerre plus deflation, three
    to six iterations per root) and falls back to the derivative chain
    whenever its result is not certified complete.  The fast path reports
    no merged double roots (``n_near == 0``): it only succeeds when there
    are none near the positive axis.  ``work`` as for :func:`real_roots_ws`
    (at least 9 floats).
    """
    n = c.shape[0] - 1
    cmax = 0.0
    for i in range(n + 1):
        if not np.isfinite(c[i]):
            return 0, 0
        cmax = max(cmax, abs(c[i]))
    if cmax == 0.0:
        return 0, 0
    while n > 0 and abs(c[n]) <= 1e-15 * cmax:
        n -= 1
    if 2 <= n <= MAX_DEG and lo >= 0.0:
        nr = _positive_roots_certified(c, n, lo, hi, roots, work, rtol)
        if nr >= 0:
            return nr, 0
    return real_roots_ws(c, lo, hi, roots, near_tol, rtol, crit_rtol, work)


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
