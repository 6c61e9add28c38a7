"""The public entry points: :func:`localize` (pixels, named markers, a rig)
and :func:`solve_bearings` (rays, any camera model)."""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import permutations, product
from typing import Any, Mapping, Sequence

import math

import numpy as np
from scipy.stats import chi2

from .core.camera import undistort_many
from .core.estimate import Observations, Solution, estimate
from .core.geometry import Pose, quaternion_xyzw_from_matrix, skew
from .core.rig import Rig
from .errors import InputError, MutlocError, ObservationError, TooFewObservationsError

__all__ = ["Estimate", "localize", "solve_bearings", "load_rig", "invert_covariance"]

# Assignments of anonymous markers tried at most (keeps the search bounded).
MAX_ASSIGNMENTS = 5040


def load_rig(source: Any) -> Rig:
    """A :class:`Rig` from a YAML/JSON rig file, a dict in rig-file form, or a Rig."""
    if isinstance(source, Rig):
        return source
    from .io.rig import load_rig as _load

    return _load(source)


def invert_covariance(R: np.ndarray, t: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Covariance of the inverse pose, same (left rotvec, translation) convention."""
    Rt = R.T
    J = np.zeros((6, 6))
    J[:3, :3] = -Rt
    J[3:, :3] = -Rt @ skew(t)
    J[3:, 3:] = -Rt
    return J @ cov @ J.T


@dataclass(eq=False)
class Estimate:
    """Relative pose ``T_qp`` (``x_q = R @ x_p + t``) from robot ``source``
    (p) to robot ``target`` (q), with its uncertainty."""

    source: str
    target: str
    R: np.ndarray
    t: np.ndarray
    covariance: np.ndarray
    pixel_sigma: float
    reprojection_rms_px: float
    markers_used: list[str]
    candidates_R: np.ndarray
    candidates_t: np.ndarray
    identity_ambiguous: bool | None = None
    assignment: dict[str, dict[str, Any]] | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def pose(self) -> Pose:
        return Pose(self.R, self.t)

    @property
    def candidates(self) -> list[Pose]:
        """Every distinct pose from the minimal subsets, best first."""
        return [Pose(R, t) for R, t in zip(self.candidates_R, self.candidates_t)]

    @property
    def quaternion_xyzw(self) -> np.ndarray:
        return quaternion_xyzw_from_matrix(self.R)

    def inverse(self) -> "Estimate":
        """The same estimate as ``T_pq`` (from target to source)."""
        inv = self.pose.inverse()
        return Estimate(
            source=self.target,
            target=self.source,
            R=inv.R,
            t=inv.t,
            covariance=invert_covariance(self.R, self.t, self.covariance),
            pixel_sigma=self.pixel_sigma,
            reprojection_rms_px=self.reprojection_rms_px,
            markers_used=list(self.markers_used),
            candidates_R=np.transpose(self.candidates_R, (0, 2, 1)),
            candidates_t=-np.einsum("kji,kj->ki", self.candidates_R, self.candidates_t),
            identity_ambiguous=self.identity_ambiguous,
            assignment=self.assignment,
            extra=dict(self.extra),
        )

    def to_dict(self) -> dict[str, Any]:
        """The result JSON of SPEC (plus identity fields for anonymous markers)."""
        d: dict[str, Any] = {
            "from": self.source,
            "to": self.target,
            "R": self.R.tolist(),
            "t": self.t.tolist(),
            "quaternion_xyzw": self.quaternion_xyzw.tolist(),
            "reprojection_rms_px": float(self.reprojection_rms_px),
            "covariance": self.covariance.tolist(),
            "pixel_sigma": float(self.pixel_sigma),
            "markers_used": list(self.markers_used),
        }
        if self.identity_ambiguous is not None:
            d["identity_ambiguous"] = bool(self.identity_ambiguous)
            d["assignment"] = self.assignment
        return d


def _pixel(value: Any, where: str) -> tuple[float, float]:
    try:
        if isinstance(value, (str, bytes)):
            raise TypeError
        u, v = value
        u = float(u)
        v = float(v)
    except (TypeError, ValueError, OverflowError):
        text = repr(value)
        text = text if len(text) <= 60 else text[:57] + "..."
        raise InputError(f"{where}: pixel must be two numbers [u, v], got {text}") from None
    if not (math.isfinite(u) and math.isfinite(v)):
        raise InputError(f"{where}: pixel is NaN or infinite")
    return u, v


def _check_in_image(rig: Rig, robot: str, uv: tuple[float, float], where: str) -> None:
    # Noise may push a detection just past the border; only a pixel far
    # outside (wrong camera, swapped u/v, wrong units) is an input error.
    cam = rig.robot(robot).camera
    if cam.size is None:
        return
    w, h = cam.size
    if not (-0.5 * w <= uv[0] <= 1.5 * w and -0.5 * h <= uv[1] <= 1.5 * h):
        raise ObservationError(f"{where}: pixel ({uv[0]:.2f}, {uv[1]:.2f}) is outside the {w}x{h} image")


def _collect(rig: Rig, observations: Mapping[str, Any], source: str, target: str):
    """Named and anonymous observations between source and target."""
    if not isinstance(observations, Mapping):
        raise InputError("observations must be a mapping {observer: {marker: [u, v]}}")
    named: list[tuple[int, str, np.ndarray]] = []
    anonymous: dict[int, list[np.ndarray]] = {}
    pair = (source, target)
    for observer, entries in observations.items():
        if observer not in rig.robots:
            raise ObservationError(f"observations: unknown robot {observer!r} (rig has {sorted(rig.robots)})")
        if observer not in pair:
            continue
        side = pair.index(observer)
        other = pair[1 - side]
        if isinstance(entries, Mapping):
            for marker, value in entries.items():
                where = f"observations[{observer!r}][{marker!r}]"
                owner = rig.owner(str(marker))
                if owner == observer:
                    raise ObservationError(f"{where}: robot {observer!r} cannot observe its own marker {marker!r}")
                uv = _pixel(value, where)
                _check_in_image(rig, observer, uv, where)
                if owner == other:
                    named.append((side, str(marker), uv))
        elif isinstance(entries, Sequence) and not isinstance(entries, (str, bytes)):
            pix = [_pixel(v, f"observations[{observer!r}][{i}]") for i, v in enumerate(entries)]
            for i, uv in enumerate(pix):
                _check_in_image(rig, observer, uv, f"observations[{observer!r}][{i}]")
            if pix:
                anonymous[side] = pix
        else:
            raise InputError(f"observations[{observer!r}] must be a mapping marker -> [u, v] or a list of [u, v]")
    return named, anonymous


def _build(rig: Rig, source: str, target: str, items: list[tuple[int, str, Any]]) -> Observations:
    cams = (rig.robot(source).camera, rig.robot(target).camera)
    n = len(items)
    side = np.fromiter((s for s, _, _ in items), dtype=np.int64, count=n)
    points = np.array([rig.marker(m).position for _, m, _ in items]).reshape(-1, 3)
    pixels = np.array([uv for _, _, uv in items], dtype=float).reshape(-1, 2)
    bearings = np.empty((n, 3))
    for s in (0, 1):
        idx = np.flatnonzero(side == s)
        if len(idx):
            uv = np.ascontiguousarray(pixels[idx])
            out = np.empty((len(idx), 3))
            bad = undistort_many(cams[s].K, cams[s].dist, uv, out)
            if bad >= 0:
                _, name, (u, v) = items[idx[bad]]
                raise ObservationError(
                    f"observations[{(source, target)[s]!r}][{name!r}]: pixel ({u:.2f}, {v:.2f}) "
                    "cannot be undistorted with this camera's calibration"
                )
            bearings[idx] = out
    return Observations.trusted(side, points, bearings, pixels, (cams[0].K, cams[1].K), (cams[0].dist, cams[1].dist))


def _assignments(rig: Rig, source: str, target: str, anonymous: dict[int, list[np.ndarray]]):
    """Every injective labelling of the anonymous pixels with the other robot's markers."""
    pair = (source, target)
    per_side = []
    for side, pix in sorted(anonymous.items()):
        other = rig.robot(pair[1 - side])
        names = list(other.markers)
        if len(pix) > len(names):
            raise ObservationError(
                f"observations[{pair[side]!r}]: {len(pix)} anonymous markers but robot {other.name!r} has {len(names)}"
            )
        per_side.append([[(side, n, uv) for n, uv in zip(perm, pix)] for perm in permutations(names, len(pix))])
    total = int(np.prod([len(p) for p in per_side])) if per_side else 1
    if total > MAX_ASSIGNMENTS:
        raise ObservationError(f"{total} possible marker identities: too many anonymous markers to try")
    for combo in product(*per_side):
        yield [item for part in combo for item in part]


def localize(rig: Any, observations: Mapping[str, Any], source: str | None = None, target: str | None = None, *,
             pixel_sigma: float = 1.0, refine: bool = True, root_filter: bool = False,
             initializer: str = "minimal") -> Estimate:
    """Relative pose ``T_qp`` of robot ``source`` (p) in robot ``target``'s (q) frame.

    ``observations`` maps each observing robot to ``{marker: (u, v)}`` raw
    (distorted) pixels, or to a list of ``(u, v)`` when the markers'
    identities are unknown (every labelling is tried and the result says
    whether the identity was ambiguous).  ``initializer`` is ``"minimal"``
    (every 3-marker subset), ``"essential"`` (the paper's Section III-E, five
    or more markers) or ``"both"``.
    """
    rig = load_rig(rig)
    source, target = rig.default_pair(source, target)
    try:
        if isinstance(pixel_sigma, (str, bytes, bool)):
            raise TypeError
        pixel_sigma = float(pixel_sigma)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"pixel_sigma must be a positive number, got {pixel_sigma!r}") from None
    if not (math.isfinite(pixel_sigma) and pixel_sigma > 0):
        raise InputError(f"pixel_sigma must be a positive number, got {pixel_sigma!r}")
    if initializer not in ("minimal", "essential", "both"):
        raise InputError(f"initializer must be 'minimal', 'essential' or 'both', got {initializer!r}")
    named, anonymous = _collect(rig, observations, source, target)
    n_total = len(named) + sum(len(v) for v in anonymous.values())
    if n_total < 3:
        raise TooFewObservationsError(
            f"{n_total} marker observations between {source!r} and {target!r}; at least three are needed"
        )
    results: list[tuple[float, list, Solution, Observations]] = []
    errors: list[MutlocError] = []
    labellings = list(_assignments(rig, source, target, anonymous)) if anonymous else [[]]
    for extra in labellings:
        items = named + extra
        obs = _build(rig, source, target, items)
        try:
            sol = _solve(obs, refine=refine, root_filter=root_filter, initializer=initializer)
        except MutlocError as exc:
            if not anonymous:
                raise
            errors.append(exc)
            continue
        results.append((sol.cost, items, sol, obs))
    if not results:
        raise errors[0]
    results.sort(key=lambda r: r[0])
    cost_best, items, sol, obs = results[0]
    n = sol.n_obs
    cov = sol.covariance(pixel_sigma)
    ambiguous = None
    assignment = None
    if anonymous:
        dof = 2 * n - 6
        gate = chi2.ppf(0.99, dof) * pixel_sigma**2 if dof > 0 else np.inf
        ambiguous = len(results) > 1 and results[1][0] <= max(gate, 1e-12)
        assignment = {}
        for side, name, uv in items:
            if any(uv is p for pix in anonymous.values() for p in pix):
                observer = (source, target)[side]
                assignment.setdefault(observer, {})[name] = [float(uv[0]), float(uv[1])]
    return Estimate(
        source=source,
        target=target,
        R=sol.pose.R,
        t=sol.pose.t,
        covariance=cov,
        pixel_sigma=float(pixel_sigma),
        reprojection_rms_px=float(np.sqrt(cost_best / n)),
        markers_used=[name for _, name, _ in items],
        candidates_R=sol.candidates_R,
        candidates_t=sol.candidates_t,
        identity_ambiguous=ambiguous,
        assignment=assignment,
    )


def _solve(obs: Observations, *, refine: bool, root_filter: bool, initializer: str) -> Solution:
    extra = None
    if initializer in ("essential", "both"):
        from .core.essential import essential_candidates

        extra = essential_candidates(obs.side, obs.points, obs.bearings)
    return estimate(obs, refine=refine, root_filter=root_filter, extra_candidates=extra,
                    use_minimal=initializer != "essential")


def solve_bearings(bearings_p: Any, points_q: Any, bearings_q: Any, points_p: Any, *,
                   refine: bool = True, root_filter: bool = False) -> list[Pose]:
    """Every candidate ``T_qp`` from unit rays, best first.

    ``bearings_p`` (n, 3): rays in p's frame towards q's markers at
    ``points_q`` (n, 3) in q's frame; likewise ``bearings_q`` (m, 3) and
    ``points_p`` (m, 3); ``n + m >= 3``, either may be empty.  With more than
    three rays the first pose is refined on the tangent-plane ray error.
    """
    arrs = []
    for name, a in (("bearings_p", bearings_p), ("points_q", points_q), ("bearings_q", bearings_q),
                    ("points_p", points_p)):
        try:
            x = np.asarray(a if a is not None else np.empty((0, 3)), dtype=float)
        except (TypeError, ValueError, OverflowError):
            raise InputError(f"{name} must be an array of finite numbers of shape (n, 3)") from None
        if x.size == 0:
            x = x.reshape(0, 3)
        if x.ndim != 2 or x.shape[1] != 3:
            raise InputError(f"{name} must have shape (n, 3), got {x.shape}")
        arrs.append(x)
    bp, pq, bq, pp = arrs
    if bp.shape[0] != pq.shape[0]:
        raise InputError(f"bearings_p has {bp.shape[0]} rows but points_q has {pq.shape[0]}")
    if bq.shape[0] != pp.shape[0]:
        raise InputError(f"bearings_q has {bq.shape[0]} rows but points_p has {pp.shape[0]}")
    obs = Observations(
        side=np.r_[np.zeros(len(bp), np.int64), np.ones(len(bq), np.int64)],
        points=np.vstack([pq, pp]),
        bearings=np.vstack([bp, bq]),
    )
    for s, pts in ((0, pq), (1, pp)):
        for i in range(len(pts)):
            for j in range(i + 1, len(pts)):
                if np.linalg.norm(pts[i] - pts[j]) < 1e-9:
                    from .errors import DegenerateGeometryError

                    raise DegenerateGeometryError(f"{'points_q' if s == 0 else 'points_p'}: markers {i} and {j} coincide")
    sol = estimate(obs, refine=refine, root_filter=root_filter)
    if len(obs.side) == 3 or not refine:
        return sol.candidates
    best = sol.pose
    rest = [c for c in sol.candidates if c.translation_error(best) > 1e-9 * (1 + np.linalg.norm(best.t))]
    return [best] + rest
