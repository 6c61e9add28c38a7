"""Two-view triangulation of bearing pairs with a known relative pose."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import InputError
from .pose import Pose

__all__ = ["triangulate_midpoint"]


def triangulate_midpoint(bearings_b: Any, bearings_a: Any, T_ba: Pose) -> tuple[np.ndarray, np.ndarray]:
    """Points (n, 3) in frame b from rays ``bearings_b`` (n, 3, frame b) and
    ``bearings_a`` (n, 3, frame a) of camera a at ``T_ba``; and a mask (n,)
    of points in front of both cameras with rays not (nearly) parallel.

    The midpoint of the shortest segment between the two rays: exact for
    noise-free rays, and a cheap, unbiased-enough start for noisy ones.
    """
    d1 = np.asarray(bearings_b, float).reshape(-1, 3)
    d2 = np.asarray(bearings_a, float).reshape(-1, 3) @ T_ba.R.T
    if len(d1) != len(d2):
        raise InputError(f"{len(d1)} rays in one view, {len(d2)} in the other")
    d1 = d1 / np.linalg.norm(d1, axis=1, keepdims=True)
    d2 = d2 / np.linalg.norm(d2, axis=1, keepdims=True)
    o2 = T_ba.t
    # Normal equations of min |l1 d1 - (o2 + l2 d2)|^2 over (l1, l2).
    c = np.einsum("ij,ij->i", d1, d2)
    e1 = d1 @ o2
    e2 = d2 @ o2
    den = 1.0 - c * c
    ok = den > 1e-10
    den = np.where(ok, den, 1.0)
    l1 = (e1 - c * e2) / den
    l2 = (c * e1 - e2) / den
    X = 0.5 * (l1[:, None] * d1 + (o2 + l2[:, None] * d2))
    return X, ok & (l1 > 0) & (l2 > 0)
