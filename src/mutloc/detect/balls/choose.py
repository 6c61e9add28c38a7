"""Choice: score the refined candidates and give each marker its blob.

Each candidate is scored by the fraction of its rim that fits, the fit
residual, the hue and chroma of the ball, how solid the blob is, its
shading and the length of fitting rim (bigger blobs are stronger evidence).
Balls of one robot are then chosen jointly, consistent with their known
distances on the robot (:func:`choose_consistent`), and markers take their
best blobs greedily so two never share one (:func:`assign`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .cues import evidence, hue_chroma, shading_contrast, vivid
from .fit import CameraModel, Fit, centre_sigma_scale
from .numeric import column_medians
from .params import BallParams
from .rim import Rim
from .search import BallSearch

__all__ = [
    "Candidate",
    "assign",
    "choose_consistent",
    "pair_error",
    "worst_pair_error",
    "range_sigma",
    "rig_mates",
    "same_blob",
    "score_candidate",
]

#: Shading contrast (:func:`~.cues.shading_contrast`) from which a candidate looks fully like a lit
#: sphere in the score; below, less (a printed disc is flat).
SHADED = 0.12


@dataclass
class Candidate:
    """A refined blob for one marker."""

    search: BallSearch
    uv: np.ndarray
    centre_px: np.ndarray  # centre of the fitted image curve (ray origin)
    radius_px: float
    score: float
    info: dict[str, Any] = field(default_factory=dict)
    # With a camera: the ball's centre in the camera frame, from its
    # direction and apparent size (metres).
    xyz: np.ndarray | None = None
    # The fitted outline (n, 2) pixels.
    outline: np.ndarray | None = None


def score_candidate(
    img: np.ndarray,
    lut: np.ndarray,
    search: BallSearch,
    fill: float,
    rim: Rim,
    fit: Fit,
    cam: CameraModel | None,
    params: BallParams,
    *,
    gains: np.ndarray | None = None,
    rim_gains: np.ndarray | None = None,
) -> Candidate | None:
    """Score the ball that ``fit`` (through ``rim``) found for ``search``; None if implausible.

    ``fill`` is the coarse blob's fill of its circle, ``lut`` the image's
    unmixing values, ``gains`` the light's colour to divide out of the
    rim's colours (in those values) before the hue is compared, unless
    :func:`~.rim.sample_rim` did already (with ``rim_gains``, which the shading cue's samples of the
    image then take too).  With a camera, a distance (from the apparent size and
    the marker's radius) outside ``params.distance_range_m`` is implausible.
    """
    cx, cy = float(fit.centre_px[0]), float(fit.centre_px[1])
    inl = fit.weights > 0
    rim_frac = float(inl.sum()) / len(fit.weights)
    inner = rim.inner[inl]
    # Hue of the ball as seen (inner colours of the inlier rays), vs nominal.
    ball = np.empty(3)
    column_medians(inner, ball)
    ring = ball.copy()
    if gains is not None:
        # As under white light (gains in the rim values, see .light).
        ball = ball * gains
    # Colours corrected for the light may exceed full scale.
    ball = ball / max(1.0, float(ball.max()))
    hue, chroma = hue_chroma(ball, lut)
    # Shading is a soft cue: balls in perfectly diffuse light look flat too.
    mid = np.column_stack([cx + 0.5 * fit.radii[inl] * np.cos(rim.ang[inl]),
                           cy + 0.5 * fit.radii[inl] * np.sin(rim.ang[inl])])
    shading = shading_contrast(img, lut, cx, cy, inner, ring, mid, rim_gains, 2.0 * params.hue_tol_deg)
    if cam is not None:
        assert fit.direction is not None
        uv = cam.camera.project(fit.direction)
    else:
        uv = fit.ellipse_centre
    return scored(search, fill, fit, cam is not None, params, rim_frac, hue, chroma, shading, uv, rim.ang)


def scored(
    search: BallSearch, fill: float, fit: Fit, with_camera: bool, params: BallParams, rim_frac: float, hue: float,
    chroma: float, shading: float, uv: np.ndarray | None, ang: np.ndarray,
) -> Candidate | None:
    """The score of :func:`score_candidate` from its measurements (rim fraction, the ball's hue, chroma and
    shading, the reported pixel ``uv``, the rim rays' angles ``ang``); None if implausible."""
    r = fit.radius_px
    dh = abs((hue - search.hue_deg + 180.0) % 360.0 - 180.0)
    colour = math.exp(-0.5 * (dh / (1.5 * params.hue_tol_deg)) ** 2)
    shape = 1.0 / (1.0 + (fit.rms / 0.5) ** 2)
    # A blob that fills little of its circle is a ring or a crescent.
    solid = min(1.0, fill / 0.6)
    relief = 0.6 + 0.4 * min(1.0, shading / SHADED)
    score = rim_frac * colour * vivid(chroma) * shape * solid * evidence(rim_frac * 2.0 * math.pi * r) * relief
    info: dict[str, Any] = {
        "radius_px": r,
        "rim_fraction": rim_frac,
        "rms_px": float(fit.rms),
        "sigma_scale": centre_sigma_scale(ang, fit.weights > 0),
        "hue_deg": float(hue),
        "chroma": chroma,
        "shading": shading,
    }
    xyz = None
    if with_camera:
        assert fit.direction is not None
        dist_m = search.radius_m / max(math.sqrt(max(1.0 - fit.cos_theta**2, 0.0)), 1e-12)
        info["distance_m"] = float(dist_m)
        if not (params.distance_range_m[0] <= dist_m <= params.distance_range_m[1]):
            return None
        xyz = fit.direction * dist_m
    if uv is None or not np.all(np.isfinite(uv)):
        return None
    return Candidate(search, np.asarray(uv, float), fit.centre_px, r, float(score), info, xyz, fit.outline)


def same_blob(a: Candidate, b: Candidate) -> bool:
    """Whether two candidates are (mostly) the same blob of the image."""
    return bool(np.hypot(*(a.centre_px - b.centre_px)) < 0.5 * (a.radius_px + b.radius_px))


def range_sigma(c: Candidate) -> float:
    """Allowed error of a ball's distance (m): Z dr / r for dr = 0.2 px, plus 3 % for its true size.

    Not widened for a partly hidden ball: at a distance a wider allowance
    lets printed discs pass for a robot's balls (measured: a robot found its
    own balls on posters in its own image), and the partly hidden balls of
    the rendered scenes lose no pose to it.
    """
    z = float(c.info["distance_m"])
    return z * (0.03 + 0.2 / max(c.radius_px, 1e-9))


def rig_mates(searches: Iterable[BallSearch]) -> dict[str, list[BallSearch]]:
    """Per robot, its searched balls, for robots with two or more at distinct known places."""
    groups: dict[str, list[BallSearch]] = {}
    for s in searches:
        if s.robot is not None and s.position is not None:
            groups.setdefault(s.robot, []).append(s)
    out = {}
    for robot, g in groups.items():
        pos = np.array([s.position for s in g])
        if len(g) >= 2 and np.ptp(pos, axis=0).max() > 1e-6:
            out[robot] = g
    return out


def pair_error(ci: Candidate, cj: Candidate) -> float | None:
    """Normalised error of two balls' distance in the camera frame against their distance on the robot:
    -inf when both are one blob, None when they sit at one place on the robot (nothing to check)."""
    if same_blob(ci, cj):
        return -math.inf
    L = float(np.linalg.norm(ci.search.position - cj.search.position))  # type: ignore[operator]
    if L < 1e-6:
        return None
    return (float(np.linalg.norm(ci.xyz - cj.xyz)) - L) / (0.01 + range_sigma(ci) + range_sigma(cj))


def worst_pair_error(picked: list[Candidate]) -> float:
    """The largest ``|pair_error|`` among the chosen balls of one robot (0 for fewer than two)."""
    zs = [abs(z) for a, b in itertools.combinations(picked, 2) if a.xyz is not None and b.xyz is not None
          and (z := pair_error(a, b)) is not None]
    return max(zs, default=0.0)


def choose_consistent(
    group: list[BallSearch], per_marker: Mapping[str, list[Candidate]], params: BallParams,
    key: Callable[[Candidate], float] | None = None,
) -> tuple[list[Candidate], bool]:
    """The candidates of one robot's balls (or none of some) that best fit the rig.

    Maximises the sum of log scores, with a marker left out costing a score
    below ``params.min_score``, plus, for each pair of chosen balls, the
    Gaussian log-likelihood of their distance in the camera frame (from
    directions and apparent sizes) given their distance on the robot; the
    error allowed grows with range (see :func:`range_sigma`).  Exhaustive: a
    few markers with a few candidates each.  Also says whether the choice is
    clean: every marker with a candidate has one and every pair is within 3
    sigma.  ``key``: what stands for a candidate's score (its ``score`` when
    None).
    """
    value = (lambda c: c.score) if key is None else key
    top = [sorted(per_marker.get(s.name, []), key=lambda c: -value(c))[: params.max_joint_options] for s in group]
    options: list[list[Candidate | None]] = [[None, *t] for t in top]
    if math.prod(len(o) for o in options) > params.max_joint_combos:
        # Too many to try (a robot with many balls): each marker's best.
        return [t[0] for t in top if t], False
    n = len(group)
    miss = math.log(0.5 * params.min_score) if params.min_score > 0 else -math.inf
    best_val = -math.inf
    best: tuple[Candidate | None, ...] = tuple(None for _ in group)
    best_worst = 0.0
    # Each pair of candidates is checked once, not once per combination.
    pairs: dict[tuple[int, int, int, int], float | None] = {}

    def pair_z(i: int, ci: Candidate, j: int, cj: Candidate) -> float | None:
        """Normalised error of the pair's distance; -inf when one blob; None when nothing to check."""
        key = (i, j, id(ci), id(cj))
        if key not in pairs:
            pairs[key] = pair_error(ci, cj)
        return pairs[key]

    for combo in itertools.product(*options):
        val = 0.0
        for c in combo:
            val += miss if c is None else math.log(value(c))
        if val <= best_val:
            continue  # consistency can only lower it
        worst = 0.0
        for i in range(n):
            ci = combo[i]
            if ci is None or ci.xyz is None:
                continue
            for j in range(i + 1, n):
                cj = combo[j]
                if cj is None or cj.xyz is None:
                    continue
                z = pair_z(i, ci, j, cj)
                if z == -math.inf:
                    val = -math.inf
                    break
                if z is None:
                    continue
                val -= 0.5 * z * z
                worst = max(worst, abs(z))
            if val == -math.inf:
                break
        if val > best_val:
            best_val, best, best_worst = val, combo, worst
    clean = best_worst <= 3.0 and all(c is not None or not opts[1:] for c, opts in zip(best, options))
    return [c for c in best if c is not None], clean


def assign(chosen: list[Candidate], rest: list[Candidate]) -> list[Candidate]:
    """Greedy one-to-one assignment: at most one candidate per marker, no blob for two markers.

    The rig-checked ``chosen`` go first, then ``rest``, each best score
    first, so a blob is never reported for two markers of similar colour.
    """
    taken: list[Candidate] = []
    names: set[str] = set()
    for c in sorted(chosen, key=lambda c: -c.score) + sorted(rest, key=lambda c: -c.score):
        if c.search.name in names or any(same_blob(c, t) for t in taken):
            continue
        taken.append(c)
        names.add(c.search.name)
    return taken
