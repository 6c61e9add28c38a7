"""A robot's ball the first look missed, looked for where the rig puts it.

When one of a robot's balls was found whole and another was not, the missing
one lies at its rig distance ``L`` from the whole one: its image within the
projection of that sphere around the found ball, its apparent radius
between those of the sphere's nearest and farthest points.  Two things hide
such a ball from the first look:

* a region of nearly the ball's hue touching it (a poster at the edge of the
  hue window, speckled by the noise that moves its pixels in and out of it)
  merges with it into one coarse blob whose circle is neither's: around the
  whole ball, the marker's hue mask is *opened* (a disc of
  a quarter of the smallest radius the rig allows: thin and speckled clutter
  goes, the visible part of a ball stays) and the circles of what is left
  (:func:`~.search.coarse_blobs`) that the first look did not refine are
  refined like any blob (:func:`guided_blobs`);
* a ball hidden by more than half scores below ``min_score`` because its
  score counts the rim it shows, although ``min_visible_fraction`` allows
  it.  A candidate of the missing ball is judged by its score per share of
  visible rim (:func:`per_rim`): how much it looks like a ball, not how much
  of it is seen.  The rig check then decides between them and the ball's
  absence, with the found balls fixed.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .choose import Candidate, range_sigma
from .light import correct
from .occlusion import hue_mask
from .params import BallParams
from .search import BallSearch, Blob, coarse_blobs, same_circle

__all__ = ["MIN_OPENING_PX", "guided_blobs", "per_rim", "rig_window"]


def per_rim(c: Candidate, params: BallParams) -> float:
    """A candidate's score per share of visible rim (at least ``min_visible_fraction``): a partly hidden
    ball scores low for being hidden, not for looking less like a ball."""
    return c.score / max(float(c.info["rim_fraction"]), params.min_visible_fraction, 1e-9)


def rig_window(mate: Candidate, L: float, radius_m: float, f: float) -> tuple[float, float, float]:
    """Where a ball at ``L`` metres from the found ball ``mate`` can be seen (``radius_m``: its radius,
    ``f``: focal length in pixels): ``(reach, r_lo, r_hi)``, the largest image distance of its centre from
    ``mate``'s and the range of its apparent radius, widened by both balls' allowed range errors
    (:func:`~.choose.range_sigma`)."""
    z = float(np.linalg.norm(mate.xyz))
    slack = 0.01 + 2.0 * range_sigma(mate)
    near = max(z - L - slack, 0.25 * z, 2.0 * radius_m)
    far = z + L + slack
    reach = f * (L + slack) / near
    return reach, f * radius_m / far, f * radius_m / near


#: The opening's disc must be at least this many mask pixels in radius to strip speckle (pixels of a
#: poster at the edge of the hue window, in and out of the mask by noise, in clusters of one or two).
MIN_OPENING_PX = 2


def guided_blobs(
    img: np.ndarray, s: BallSearch, mate: Candidate, L: float, f: float, v_floor: int, gains: np.ndarray | None,
    params: BallParams, looked: list[Blob] | None = None,
    masks: list[tuple[np.ndarray, float, float]] = (),  # type: ignore[assignment]
) -> list[Blob]:
    """Seeds for ``s``'s ball, found whole as ``mate`` at ``L`` metres from it on the robot: circles of
    its hue mask, opened, within the rig's reach (:func:`rig_window`) and not one of the blobs ``looked``
    at already (:func:`~.search.same_circle`), best first, at most ``max_candidates``.  The mask is the
    coarsest of the search's (``masks``: each with the factors from its pixels to the image's) in which
    the opening's disc is :data:`MIN_OPENING_PX` of its pixels or more, else one made here at full
    resolution as the search makes it.  The seeds' ``fill`` is at least 0.6: a partly hidden ball fills little of its
    circle, and it is looked for here because it is hidden."""
    H, W = img.shape[:2]
    reach, r_lo, r_hi = rig_window(mate, L, s.radius_m, f)
    mu, mv = float(mate.centre_px[0]), float(mate.centre_px[1])
    half = reach + r_hi + 2.0
    usable = [x for x in masks if round(0.25 * r_lo / max(x[1], x[2])) >= MIN_OPENING_PX]
    m, sx, sy = max(usable, key=lambda x: x[1]) if usable else (None, 1.0, 1.0)
    x0, x1 = max(0, int((mu - half) / sx)), min(int(W / sx), int(math.ceil((mu + half) / sx)) + 1)
    y0, y1 = max(0, int((mv - half) / sy)), min(int(H / sy), int(math.ceil((mv + half) / sy)) + 1)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return []
    if m is None:
        roi = correct(np.ascontiguousarray(img[y0:y1, x0:x1]), gains)
        roi_mask = hue_mask(cv2.cvtColor(roi, cv2.COLOR_BGR2HSV_FULL), s, params.hue_tol_deg, v_floor)
    else:
        roi_mask = np.ascontiguousarray(m[y0:y1, x0:x1])
    k = max(1, round(0.25 * r_lo / sx))
    opened = cv2.morphologyEx(roi_mask, cv2.MORPH_OPEN,
                              cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * k + 1, 2 * k + 1)))
    out = []
    for b in coarse_blobs(opened, sx, sy, max(params.min_radius_px, 0.5 * r_lo), r_hi):
        b = Blob(b.u + x0 * sx, b.v + y0 * sy, b.radius, b.quality, max(b.fill, 0.6))
        d = math.hypot(b.u - mu, b.v - mv)
        # A circle less than half the smallest ball the rig allows is not one (nor a visible part
        # of one: the circle of a ball's visible arc is the ball's).
        if (b.radius >= 0.5 * r_lo and 0.5 * (b.radius + mate.radius_px) <= d <= reach + b.radius
                and not any(same_circle(b, x) for x in looked or [])):
            out.append(b)
    # Smaller circles are slivers of a ball at best.
    out.sort(key=lambda b: -b.quality * min(1.0, b.radius / r_lo))
    return out[: int(params.max_candidates)]
